"""The hybrid solver against independent references: convergence order, scipy, the paper's
formulation, the energy balance and the clutch's unilateral constraint."""
import math

import numpy as np
import pytest

from cvt_ros.scene import load_scene
from cvt_ros.solver.reference import solve_reference
from cvt_ros.solver.simulator import Simulator

PAPER = load_scene('paper')
TIGHT = {'solver.rtol': 1e-12, 'solver.atol': 1e-14, 'solver.max_step': 1e-3}


def scene(base=PAPER, **changes):
    return dict(base, **{k.replace('__', '.'): v for k, v in changes.items()})


@pytest.fixture(scope='module')
def paper_reference():
    """Tight DP5 run of the paper scene to 0.3 s (checked against scipy below)."""
    sim = Simulator(dict(PAPER, **TIGHT))
    switches = sim.advance(0.3)
    return sim.y.copy(), [s.t for s in switches if s.kind != 'graze']


@pytest.mark.parametrize('rtol, switch_error, state_error', [
    (1e-8, 1e-9, 1e-8),      # switch times to 1e-9 s
    (None, 1e-6, 1e-6),      # default settings
])
def test_scipy_and_compiled_solver_agree_on_switch_times_and_state(rtol, switch_error,
                                                                  state_error):
    ref = solve_reference(PAPER, 1.0, rtol=1e-12, atol=1e-14)
    values = PAPER if rtol is None else scene(solver__rtol=rtol, solver__atol=rtol * 1e-2)
    sim = Simulator(values)
    switches = [s.t for s in sim.advance(1.0) if s.kind != 'graze']
    assert len(switches) == len(ref.switch_times) > 40
    assert np.max(np.abs(np.array(switches) - ref.switch_times)) < switch_error
    assert sim.y[6] == pytest.approx(ref.y[6], rel=state_error)      # φ4
    assert sim.y[7] == pytest.approx(ref.y[7], rel=state_error * 100)  # ω4


@pytest.mark.parametrize('rtol', [PAPER['solver.rtol'], 1e-10])
def test_located_switches_sit_on_the_guard_zero(rtol):
    # the root is found on the dense output to 1e-13 s; the state there then comes from a true
    # step, which differs from the interpolant by about the local tolerance
    sim = Simulator(scene(solver__rtol=rtol, solver__atol=rtol * 1e-2))
    switches = [s for s in sim.advance(2.0) if s.kind != 'graze']
    assert {s.kind for s in switches} == {'engage', 'release'}
    for s in switches:
        if s.kind == 'release':    # clutch torque [N·m]; torque scale 40 N·m
            assert abs(s.value) < 100.0 * rtol * 40.0
        else:                      # slip [rad/s]; speed scale 50 rad/s
            assert abs(s.value) < 10.0 * rtol * 50.0


def test_exact_and_integrated_output_subsystem_agree():
    runs = {}
    for how in ('exact', 'integrate'):
        sim = Simulator(scene(solver__output_subsystem=how, solver__rtol=1e-10,
                              solver__atol=1e-12))
        switches = [s.t for s in sim.advance(2.0) if s.kind != 'graze']
        runs[how] = (sim.sample(), switches)
    (ex, sw_e), (it, sw_i) = runs['exact'], runs['integrate']
    assert len(sw_e) == len(sw_i) > 90
    assert np.max(np.abs(np.subtract(sw_e, sw_i))) < 1e-9
    assert ex[4] == pytest.approx(it[4], rel=1e-10)
    assert ex[8] == pytest.approx(it[8], rel=1e-8)


def test_default_settings_meet_1e_6_on_phi4_after_10_s():
    ref = Simulator(dict(PAPER, **TIGHT))
    ref.advance(10.0)
    sim = Simulator(PAPER)
    sim.advance(10.0)
    phi4 = sim.sample()[4]
    phi4_ref = ref.sample()[4]
    assert abs(phi4 - phi4_ref) / abs(phi4_ref) <= 1e-6


@pytest.mark.parametrize('formulation', ['reduced', 'paper'])
def test_fixed_step_rk4_converges_with_order_4(paper_reference, formulation):
    y_ref, sw_ref = paper_reference
    errors = []
    for h in (4e-4, 2e-4, 1e-4, 5e-5):
        sim = Simulator(scene(solver__method='rk4', solver__fixed_step=h,
                              model__formulation=formulation))
        switches = [s.t for s in sim.advance(0.3) if s.kind != 'graze']
        assert len(switches) == len(sw_ref)
        errors.append(max(abs(sim.y[6] - y_ref[6]), abs(sim.y[7] - y_ref[7]) * 1e-2,
                          np.max(np.abs(np.subtract(switches, sw_ref))) * 100.0))
    orders = [math.log2(e1 / e2) for e1, e2 in zip(errors, errors[1:], strict=False)]
    # events located inside the step on a cubic Hermite interpolant keep the method's order
    assert all(3.4 < p < 4.7 for p in orders), (errors, orders)


def test_adaptive_error_is_proportional_to_tolerance(paper_reference):
    y_ref, _ = paper_reference
    err = {}
    for rtol in (1e-6, 1e-9):
        sim = Simulator(scene(solver__rtol=rtol, solver__atol=rtol * 1e-2))
        sim.advance(0.3)
        err[rtol] = abs(sim.y[6] - y_ref[6]) + abs(sim.y[7] - y_ref[7]) * 1e-2
    assert err[1e-6] / err[1e-9] > 200.0


def test_paper_formulation_agrees_with_reduced_to_solver_tolerance():
    runs = {}
    for formulation in ('reduced', 'paper'):
        sim = Simulator(scene(model__formulation=formulation, solver__rtol=1e-11,
                              solver__atol=1e-13))
        result = sim.run(2.0, 1e-3)
        runs[formulation] = (sim.sample(), [s.t for s in result.switches], result)
    (red, sw_r, _), (pap, sw_p, res_p) = runs['reduced'], runs['paper']
    assert len(sw_r) == len(sw_p) > 90
    assert np.max(np.abs(np.subtract(sw_r, sw_p))) < 1e-8
    assert pap[4] == pytest.approx(red[4], rel=1e-9)         # φ4
    assert pap[8] == pytest.approx(red[8], rel=1e-7)         # ω4
    assert pap[2] == pytest.approx(red[2], abs=1e-8)         # φ2: integrated vs closed form
    # Baumgarte keeps the paper's index-reduced DAE on its constraint f(φ1, φ2) = 0 [m²]
    assert np.max(np.abs(res_p.column('constraint'))) < 1e-10


def test_energy_balance_closes_to_1e_9_of_the_work_at_tight_tolerance():
    sim = Simulator(scene(solver__rtol=1e-10, solver__atol=1e-12))
    result = sim.run(10.0, 1e-2)
    assert result.energy['work_motor'] > 1000.0
    assert result.energy['relative_residual'] <= 1e-9


def test_energy_balance_counts_damping_viscous_load_and_actuator_work():
    sim = Simulator(dict(load_scene('conveyor'), **{'solver.rtol': 1e-10, 'solver.atol': 1e-12}))
    sim.advance(0.5)
    sim.command_crank_length(0.07)     # moves while the clutch switches: actuator does work
    sim.advance(1.0)
    sim.set_load_torque(-2.0)          # load reversal
    sim.advance(0.5)
    e = sim.energy_balance()
    assert abs(e['work_actuator']) > 1e-3
    assert e['dissipated_damping'] > 1e-3
    assert e['relative_residual'] <= 1e-9


def test_clutch_never_slips_backwards_nor_pulls():
    sim = Simulator(PAPER)
    sim.advance(2.0)
    result = sim.run(0.2, 1e-5)
    engaged = result.column('engaged') == 1
    slip = result.column('omega3') - result.column('omega2')
    speed_scale = np.max(np.abs(result.column('omega2')))
    assert np.min(slip[~engaged]) >= -1e-7 * speed_scale
    torque = result.column('clutch_torque')
    assert np.min(torque[engaged]) >= -1e-7 * np.max(torque)
    assert engaged.any() and (~engaged).any()


def test_switch_count_is_two_per_crank_turn_in_steady_state():
    sim = Simulator(PAPER)
    sim.advance(5.0)
    phi1_before = sim.sample()[1]
    switches = [s for s in sim.advance(2.0) if s.kind != 'graze']
    turns = (sim.sample()[1] - phi1_before) / (2 * math.pi)
    assert len(switches) == pytest.approx(2 * turns, abs=2)
    kinds = [s.kind for s in switches]
    assert all(a != b for a, b in zip(kinds, kinds[1:], strict=False))  # alternating


def test_angles_stay_continuous_across_turn_rebasing():
    sim = Simulator(PAPER)
    result = sim.run(30.0, 1e-2)    # φ1 passes the rebasing threshold many times
    phi1, phi4 = result.column('phi1'), result.column('phi4')
    dphi1 = np.diff(phi1)
    w1 = result.column('omega1')
    # each increment matches ω1·dt (no 2π jumps)
    assert np.max(np.abs(dphi1 - 0.5 * (w1[1:] + w1[:-1]) * 1e-2)) < 0.05
    assert sim.turns_phi1 > 0.0
    assert phi4[-1] == pytest.approx(np.trapezoid(result.column('omega4'), dx=1e-2), rel=1e-3)
