"""The device's one-call period (solver/period.py: PeriodStepper) is the Simulator's
``command_crank_length`` / ``advance(dt)`` / ``sample()`` to the bit — over crank commands every
period, load changes, clutch events, the whole-turn rebase of the angles, every fidelity — and
the Device built on it equals the offline core driven with the same commands."""
import math
import time

import numpy as np
import pytest

from cvt_ros.device.core import Device
from cvt_ros.device.diagnostics import WARN, Reporter, Stats
from cvt_ros.scene import load_scene
from cvt_ros.solver.fidelity import make_simulator
from cvt_ros.solver.period import PeriodStepper

DT = 1e-3
CASES = [
    ('conveyor', {'solver.method': 'rk4'}),
    ('conveyor', {'solver.method': 'dopri5'}),
    ('paper', {'solver.method': 'rk4', 'model.formulation': 'paper'}),
    ('conveyor', {'solver.method': 'rk4', 'model.fidelity': 'rigid_shaft'}),
    ('conveyor', {'solver.method': 'rk4', 'model.fidelity': 'averaged'}),
]


def commands(sim, n, seed=0):
    """A controller-like command sequence: small moves most periods, a jump every 50, none
    every 7th period; a load change now and then. (period, crank length or None, load or
    None) for n periods."""
    rng = np.random.default_rng(seed)
    bound = sim.grashof_bound
    target = sim.crank_length_target
    out = []
    for k in range(n):
        crank = load = None
        if k % 7 != 3:
            target = (rng.uniform(0.2, 0.9) * bound if k % 50 == 0
                      else target + rng.normal(0.0, 1e-4))
            crank = float(min(max(target, 0.0), 0.95 * bound))
        if k % 397 == 5:
            load = float(rng.uniform(0.0, 12.0))
        out.append((crank, load))
    return out


@pytest.mark.parametrize('scene,overrides', CASES, ids=lambda c: str(c))
def test_period_stepper_is_the_simulator_to_the_bit(scene, overrides):
    values = load_scene(scene, overrides)
    offline, fast = make_simulator(values), make_simulator(values)
    stepper = PeriodStepper(fast, DT)
    switches = 0
    # 3000 periods: ~450 crank turns, so φ1's whole turns are folded out (rebase) on the way
    for k, (crank, load) in enumerate(commands(offline, 3000)):
        if crank is not None:
            offline.command_crank_length(crank)
            fast.command_crank_length(crank)
        if load is not None:
            offline.set_load_torque(load)
            fast.set_load_torque(load)
        expected = offline.advance(DT)
        row = offline.sample()
        assert np.array_equal(stepper.advance(), row), k
        assert [(s.t, s.engaged, s.kind) for s in stepper.switches] == \
            [(s.t, s.engaged, s.kind) for s in expected], k
        switches += len(expected)
    assert offline.turns_phi1 > 0.0                     # the rebase happened
    assert (fast.t, fast.switch_count) == (offline.t, offline.switch_count)
    assert np.array_equal(fast.ACT, offline.ACT) and np.array_equal(fast.y, offline.y)
    if overrides.get('model.fidelity') != 'averaged':
        assert switches > 100                            # clutch events inside periods


def test_device_equals_the_offline_core_with_the_same_commands():
    """What test_node_lockstep checks over DDS, in process: a repeated set point does not
    re-plan (the offline loop commands only changes), a refused command changes nothing."""
    values = load_scene('conveyor', {'solver.method': 'rk4'})
    device = Device(values, DT)
    sim = make_simulator(values)
    rows = [device.present_state().row]
    expected = [sim.sample()]
    for k in range(1500):
        value = (0.04, 0.06, math.nan, 0.06, 0.2)[(k // 100) % 5]
        try:
            device.command_crank_length(value)
        except ValueError:
            pass
        if math.isfinite(value) and value < 0.1 and value != sim.crank_length_target:
            sim.command_crank_length(value)
        rows.append(device.advance_row().copy())
        sim.advance(DT)
        expected.append(sim.sample())
    assert np.array_equal(np.array(rows), np.array(expected))


@pytest.mark.parametrize('copy_with', ['deepcopy', 'pickle'])
def test_a_copied_simulator_steps_on_from_its_own_state(copy_with):
    """The Simulator's arrays are views of its blocks (what the compiled period reads); a copy
    (copy.deepcopy, pickle) gets views of its own blocks, and then both run on to the bit."""
    import copy
    import pickle
    sim = make_simulator(load_scene('conveyor', {'solver.method': 'dopri5'}))
    stepper = PeriodStepper(sim, DT)
    for _ in range(300):
        stepper.advance()
    twin = copy.deepcopy(sim) if copy_with == 'deepcopy' else pickle.loads(pickle.dumps(sim))
    for name in ('y', 'P', 'ACT', 'S', 'h_io', 'ledger'):
        assert np.shares_memory(getattr(twin, name), twin._floats), name
        assert not np.shares_memory(getattr(twin, name), sim._floats), name
    assert np.shares_memory(twin.counters, twin._ints)
    twin_stepper = PeriodStepper(twin, DT)
    for k in range(300):
        sim.command_crank_length(0.04 + 1e-4 * math.sin(k / 30))
        twin.command_crank_length(0.04 + 1e-4 * math.sin(k / 30))
        assert np.array_equal(stepper.advance(), twin_stepper.advance()), k


def test_diagnostics_report_one_snapshot_of_the_simulation():
    """sim_time and samples_published come from the same snapshot (the loop takes one every
    0.25 s): a report made after more periods ran still pairs t = 0.1 s with its 100 samples;
    the deadline and command counters are live."""
    device = Device(load_scene('paper'), DT)
    stats = Stats()
    for _ in range(100):
        row = device.advance().row
        stats.samples += 1
    snap = dict(device.snapshot(row), wall_ns=time.monotonic_ns(), samples=stats.samples,
                resets=0)
    for _ in range(50):   # the loop goes on; the next snapshot is not due yet
        device.advance()
        stats.samples += 1
    stats.missed = 3
    settings = {'mode': 'realtime', 'state': 'realtime', 'real_time_factor': 1.0,
                'publish_rate': 1000.0, 'control_period': DT, 'fault': None, 'policy': 'p'}
    level, message, values = Reporter().report(snap, stats, device.step_ns, settings)
    values = dict(values)
    assert float(values['sim_time']) == pytest.approx(0.1)
    assert values['samples_published'] == '100'
    assert values['missed_deadlines'] == '3'
    assert float(values['crank_length_m']) == pytest.approx(device.sim.crank_length)
    # the solver's self-check: which method, no possibly missed clutch event, so no warning
    assert values['solver'] == 'dopri5, rtol 2e-06' and values['possible_missed_events'] == '0'
    assert level != WARN or 'missed deadlines' in message


def test_diagnostics_warn_of_a_possibly_missed_clutch_event():
    """A run whose solver found a guard beyond its band after a step (a possibly missed event)
    says so on /diagnostics: WARN, with the count and the time of the first (issue 32)."""
    device = Device(dict(load_scene('paper'), **{'solver.method': 'rk4'}), DT)
    row = device.advance().row
    snap = dict(device.snapshot(row), wall_ns=time.monotonic_ns(), samples=1, resets=0)
    snap['self_check'] = dict(snap['self_check'], possible_missed_events=2,
                              first_possible_missed_event_s=0.0005)
    settings = {'mode': 'realtime', 'state': 'realtime', 'real_time_factor': 1.0,
                'publish_rate': 1000.0, 'control_period': DT, 'fault': None, 'policy': 'p'}
    level, message, values = Reporter().report(snap, Stats(), device.step_ns, settings)
    values = dict(values)
    assert level == WARN and '2 possibly missed clutch events' in message
    assert values['possible_missed_events'] == '2'
    assert values['solver'].startswith('rk4, fixed step')
