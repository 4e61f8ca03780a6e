"""`cvt-sim analyze` and `cvt-sim export` (cvt_ros.analysis): every figure against the truth.

The truth of a figure is computed here, independently and more simply, from the CSV of the same
run (linear interpolation, trapezoids, the motor's torque law) or taken from the core itself
(its exact clutch switch times); start-up included. Damaged inputs must give partial results and
one clear line on stderr, never a traceback.
"""
import csv
import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest
from recording_helpers import child_env

from cvt_ros.analysis import analyze_trace, crank_length_from_angles, load
from cvt_ros.analysis.plots import step_title
from cvt_ros.analysis.steady import find_steady_state, settled_tail
from cvt_ros.analysis.steps import response_metrics
from cvt_ros.recording.recorder import SimulationRecorder
from cvt_ros.scene import load_scene
from cvt_ros.solver.output import COL
from cvt_ros.solver.simulator import Simulator

CLI = [sys.executable, '-m', 'cvt_ros']
TWO_PI = 2 * math.pi
DT = 5e-4
DURATION = 3.0


def cvt_sim(*args, code=0):
    proc = subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=120,
                          env=child_env())
    assert proc.returncode == code, proc.stdout + proc.stderr
    assert 'Traceback' not in proc.stderr
    return proc


@pytest.fixture(scope='module')
def paper(tmp_path_factory):
    """`cvt-sim run paper` for 3 s at 0.5 ms from rest: the MCAP and the CSV of the same run."""
    d = tmp_path_factory.mktemp('paper')
    cvt_sim('run', 'paper', '--duration', DURATION, '--sample-dt', DT, '--quiet',
            '--csv', d / 'paper.csv', '--mcap', d / 'paper.mcap')
    return d / 'paper.mcap', d / 'paper.csv'


@pytest.fixture(scope='module')
def core():
    """The core's own run of the same scene and grid (deterministic: the same run)."""
    return Simulator(load_scene('paper')).run(DURATION, DT)


def record_node_like(path, steps, commands, scene='paper'):
    """Simulator.advance per 1 ms, recorded through the recorder's API as the node does;
    ``commands``: {step index: (key, value)}. Returns the sample rows (the truth)."""
    sim = Simulator(load_scene(scene))
    rows = [sim.sample()]
    with SimulationRecorder(path, parameters=sim.values, scene=scene, source='test') as rec:
        rec.record_clutch_state(sim.engaged, 0.0)
        rec.record_sample(rows[0])
        for i in range(steps):
            if i in commands:
                key, value = commands[i]
                if key == 'joint_commands':   # topic_based_ros2_control's crank command
                    from rclpy.serialization import serialize_message
                    from sensor_msgs.msg import JointState
                    rec.write(rec.topics[key], serialize_message(JointState(
                        name=['crank_length'], position=[value])), round(sim.t * 1e9))
                else:
                    rec.record_command(key, value, sim.t)
                if key in ('crank_length_cmd', 'joint_commands'):
                    sim.command_crank_length(value)
                else:
                    sim.set_load_torque(value)
            for sw in sim.advance(1e-3):
                rec.record_switch(sw)
            rows.append(sim.sample())
            rec.record_sample(rows[-1])
            rec.record_clock(sim.t)
    return np.array(rows)


@pytest.fixture(scope='module')
def stepped(tmp_path_factory):
    """A node-like recording with commands: crank length 0.03 → 0.05 m at 1.0 s, load torque
    5 → 8 N·m at 3.5 s, 4.5 s in all."""
    path = tmp_path_factory.mktemp('steps') / 'steps.mcap'
    rows = record_node_like(path, 4500, {1000: ('crank_length_cmd', 0.05),
                                         3500: ('/load_torque_cmd', 8.0)})
    return path, rows


# ---------------------------------------------------------------------------------- truth
def kloss(p, w1):
    """The induction motor's torque law, written out again (physics.md §5)."""
    s = (p['motor.synchronous_speed'] - w1) / p['motor.synchronous_speed']
    sk = p['motor.breakdown_slip']
    return 2 * p['motor.breakdown_torque'] * sk * s / (s * s + sk * sk)


def crossings(t, p1):
    """Crank cycle boundaries: linear interpolation of φ1 = 2πk between samples."""
    k = np.floor(p1 / TWO_PI)
    i = np.flatnonzero(np.diff(k) > 0)
    return t[i] + (k[i + 1] * TWO_PI - p1[i]) / (p1[i + 1] - p1[i]) * (t[i + 1] - t[i])


def exact_engaged_time(core, ta, tb):
    """Time engaged in [ta, tb] from the core's own switch times (grazes are no switches)."""
    switches = [(s.t, s.engaged) for s in core.switches if s.kind != 'graze']
    state = bool(core.samples[0, COL['engaged']])
    total, t_prev = 0.0, core.samples[0, COL['t']]
    for t_sw, on in [*switches, (math.inf, state)]:
        a, b = max(t_prev, ta), min(t_sw, tb)
        if state and b > a:
            total += b - a
        state, t_prev = on, t_sw
    return total


def window_truth(d, p, ta, tb):
    """Window figures over [ta, tb] from the CSV columns: integrals of the linear interpolant
    (the samples inside plus the interpolated ends), peaks of the samples inside."""
    t = d['t']
    sel = np.flatnonzero((t > ta) & (t < tb))
    tt = np.r_[ta, t[sel], tb]

    def series(f):
        return np.r_[np.interp(ta, t, f), f[sel], np.interp(tb, t, f)]

    def mean(f):
        return np.trapezoid(series(f), tt) / (tb - ta)

    m1 = kloss(p, d['omega1'])
    w_in = np.trapezoid(series(m1 * d['omega1']), tt)
    w_out = np.trapezoid(series(d['load_torque'] * d['omega4']), tt)
    n = round((np.interp(tb, t, d['phi1']) - np.interp(ta, t, d['phi1'])) / TWO_PI)
    dphi4 = np.interp(tb, t, d['phi4']) - np.interp(ta, t, d['phi4'])
    return {
        'cycles': n,
        'ratio': dphi4 / (TWO_PI * n),
        'crank_speed': TWO_PI * n / (tb - ta),
        'output_speed': dphi4 / (tb - ta),
        'twist_peak': series(d['twist']).max(),
        'twist_mean': mean(d['twist']),
        'clutch_torque_peak': series(d['clutch_torque']).max(),
        'clutch_torque_mean': mean(d['clutch_torque']),
        'motor_power': w_in / (tb - ta),
        'output_power': w_out / (tb - ta),
        'efficiency': w_out / w_in,
    }


def test_whole_run_figures_match_the_csv_and_the_core_start_up_included(paper, core):
    mcap_path, csv_path = paper
    d = np.genfromtxt(csv_path, delimiter=',', names=True)
    # the same run (the CSV keeps 12 significant digits)
    assert np.allclose(d['t'], core.samples[:, COL['t']], rtol=1e-11, atol=1e-15)
    assert np.allclose(d['clutch_torque'], core.samples[:, COL['clutch_torque']], rtol=1e-9,
                       atol=1e-6)
    p = load_scene('paper')
    traces, info = load(str(mcap_path))
    assert len(traces) == 1 and not info.problems and traces[0].switches_exact
    got = analyze_trace(traces[0]).whole_run
    t, span = d['t'], d['t'][-1] - d['t'][0]
    m1 = kloss(p, d['omega1'])
    w_in = np.trapezoid(m1 * d['omega1'], t)
    w_out = np.trapezoid(d['load_torque'] * d['omega4'], t)
    switches = sum(1 for s in core.switches if s.kind != 'graze' and 0 < s.t <= t[-1])
    truth = {
        't_start': 0.0, 't_end': DURATION,
        'crank_turns': (d['phi1'][-1] - d['phi1'][0]) / TWO_PI,
        'ratio': (d['phi4'][-1] - d['phi4'][0]) / (d['phi1'][-1] - d['phi1'][0]),
        'crank_speed': (d['phi1'][-1] - d['phi1'][0]) / span,
        'output_speed': (d['phi4'][-1] - d['phi4'][0]) / span,
        'output_speed_min': d['omega4'].min(), 'output_speed_max': d['omega4'].max(),
        'twist_peak': d['twist'].max(), 'twist_min': d['twist'].min(),
        'twist_mean': np.trapezoid(d['twist'], t) / span,
        'clutch_torque_peak': d['clutch_torque'].max(),          # 288.3 N·m: the start-up
        'clutch_torque_mean': np.trapezoid(d['clutch_torque'], t) / span,
        'load_factor': d['clutch_torque'].max() / (np.trapezoid(d['clutch_torque'], t) / span),
        'motor_torque_peak': m1.max(),
        'engaged_fraction': exact_engaged_time(core, 0.0, DURATION) / span,
        'switches': switches,
        'switches_per_cycle': switches / ((d['phi1'][-1] - d['phi1'][0]) / TWO_PI),
        'motor_work': w_in, 'output_work': w_out,
        'motor_power': w_in / span, 'output_power': w_out / span,
        'efficiency': w_out / w_in,
    }
    assert set(got) == set(truth)
    for key, value in truth.items():
        # switch times are stored in whole nanoseconds: ≤ 0.5 ns each
        slack = switches * 1e-9 / span if key == 'engaged_fraction' else 1e-12
        assert got[key] == pytest.approx(value, rel=1e-9, abs=slack), key
    # the start-up holds the peaks: the steady-state figure is an order of magnitude below
    assert got['clutch_torque_peak'] > 280 and got['twist_peak'] > 0.5
    assert got['switches'] == len([s for s in core.switches if s.kind != 'graze'])


def test_steady_state_is_detected_and_its_figures_match_the_csv(paper, core):
    mcap_path, csv_path = paper
    d = np.genfromtxt(csv_path, delimiter=',', names=True)
    p = load_scene('paper')
    result = analyze_trace(load(str(mcap_path))[0][0])
    steady = result.steady
    assert steady.found and steady.stop == len(result.cycles) and steady.cycles >= 10
    got = result.steady_metrics
    ta, tb = steady.t_start, steady.t_end
    assert got['t_start'] == ta and got['t_end'] == tb and tb > DURATION - 0.05
    truth = window_truth(d, p, ta, tb)
    assert got['cycles'] == truth['cycles'] == steady.cycles
    assert got['ratio'] == pytest.approx(truth['ratio'], rel=1e-6)
    assert got['ratio'] == pytest.approx(0.2538, abs=5e-4)       # the paper's i ≈ 0.25
    assert got['crank_speed'] == pytest.approx(truth['crank_speed'], rel=1e-6)
    assert got['output_speed'] == pytest.approx(truth['output_speed'], rel=1e-6)
    assert got['twist_peak'] == pytest.approx(truth['twist_peak'], rel=1e-9)
    assert got['clutch_torque_peak'] == pytest.approx(truth['clutch_torque_peak'], rel=1e-9)
    for key in ('twist_mean', 'clutch_torque_mean', 'motor_power', 'output_power',
                'efficiency'):
        assert got[key] == pytest.approx(truth[key], rel=1e-6), key
    # the paper's scene has no shaft damping: lossless, so the steady state's η is 1
    assert got['efficiency'] == pytest.approx(1.0, abs=2e-3)
    assert got['engaged_fraction'] == pytest.approx(      # switch times in whole ns
        exact_engaged_time(core, ta, tb) / (tb - ta), abs=2 * steady.cycles * 1e-9 / (tb - ta))
    assert got['switches_per_cycle'] == 2.0
    # independently: every cycle mean of the window is in the ±0.5 % band, the one before not
    bounds = crossings(d['t'], d['phi1'])
    w4 = np.diff(np.interp(bounds, d['t'], d['phi4'])) / np.diff(bounds)
    first = int(np.argmin(np.abs(bounds - ta)))
    inside = w4[first:first + steady.cycles]
    assert np.ptp(inside) <= 2 * 5e-3 * np.mean(inside)
    assert steady.first > 0 and result.steady_metrics != result.whole_run


def test_per_cycle_table_matches_the_csv(paper):
    mcap_path, csv_path = paper
    d = np.genfromtxt(csv_path, delimiter=',', names=True)
    p = load_scene('paper')
    cy = analyze_trace(load(str(mcap_path))[0][0]).cycles
    for k in (0, 5, len(cy) - 1):
        ta, tb = cy['t_start'][k], cy.t_end[k]
        truth = window_truth(d, p, ta, tb)
        assert cy['ratio'][k] == pytest.approx(truth['ratio'], rel=1e-5)
        assert cy['clutch_torque_peak'][k] == pytest.approx(truth['clutch_torque_peak'],
                                                            rel=1e-9)
        assert cy['motor_power'][k] == pytest.approx(truth['motor_power'], rel=1e-6)
    window = cy.window(0, len(cy))     # sums of the cycles = the window computed at once
    truth = window_truth(d, p, cy['t_start'][0], cy.t_end[-1])
    assert window['ratio'] == pytest.approx(truth['ratio'], rel=1e-6)
    assert window['efficiency'] == pytest.approx(truth['efficiency'], rel=1e-6)


def test_energy_residual_matches_the_csv(paper):
    mcap_path, csv_path = paper
    d = np.genfromtxt(csv_path, delimiter=',', names=True)
    p = load_scene('paper')
    t = d['t']
    energy = 0.5 * (p['inertia.motor'] * d['omega1']**2 + p['inertia.rocker'] * d['omega2']**2
                    + p['inertia.clutch_driven'] * d['omega3']**2
                    + p['inertia.output'] * d['omega4']**2 + p['shaft.stiffness'] * d['twist']**2)
    residual = (energy[-1] - energy[0]) - (np.trapezoid(kloss(p, d['omega1']) * d['omega1'], t)
                                           - np.trapezoid(d['load_torque'] * d['omega4'], t))
    e = analyze_trace(load(str(mcap_path))[0][0]).energy
    assert e['available'] and e['relative_residual'] < 1e-3
    assert e['residual'] == pytest.approx(residual, abs=1e-6 * e['work_motor'])


def test_csv_input_gives_the_same_metrics(paper):
    mcap_path, csv_path = paper
    from_mcap = analyze_trace(load(str(mcap_path))[0][0])
    traces, info = load(str(csv_path), scene='paper')
    assert traces[0].kind == 'csv' and not info.problems
    result = analyze_trace(traces[0])
    for key in ('ratio', 'twist_peak', 'clutch_torque_peak', 'motor_power', 'efficiency'):
        assert result.whole_run[key] == pytest.approx(from_mcap.whole_run[key], rel=1e-6), key
    assert result.steady.found and result.steady.first == from_mcap.steady.first
    assert result.energy['available']
    bare = analyze_trace(load(str(csv_path))[0][0])
    assert not bare.energy['available'] and '--scene' in bare.energy['reason']
    assert not any('--scene' in note for note in traces[0].notes)   # the right scene: no word
    # a scene that is not the run's: replacing the recording's parameters, or a CSV's crank
    # length that is not the scene's, is said (the energy residual became 36 % of the work)
    (over,), _ = load(str(mcap_path), scene='conveyor')
    (wrong,), _ = load(str(csv_path), scene='conveyor')
    assert any('replaces the parameters the recording holds' in n for n in over.notes)
    for trace in (over, wrong):
        assert any('crank length 0.04 m is not the recorded one (0.03 m' in n
                   for n in trace.notes), trace.notes


def test_crank_length_from_angles_inverts_the_linkage():
    from cvt_ros.physics.linkage import rocker_angle
    phi1 = np.linspace(0, 20, 2001)
    for a in (0.0, 0.001, 0.03, 0.0999):
        phi2 = np.array([rocker_angle(x, a, 0.1, 0.2, 0.2, 1.0) for x in phi1])
        got = crank_length_from_angles(phi1, phi2, 0.1, 0.2, 0.2, 1.0)
        assert np.nanmax(np.abs(got - a)) < 1e-9 and np.mean(np.isnan(got)) < 0.01


# ---------------------------------------------------------------------------------- steady state
def test_settled_tail_finds_where_a_signal_entered_its_band():
    x = np.concatenate([np.linspace(0.0, 1.0, 50), np.ones(30)])
    assert settled_tail({'x': x}, 5e-3, 10) == 49            # linspace ends at 1.0
    assert settled_tail({'x': x[:55]}, 5e-3, 10) is None          # ends in the ramp
    assert settled_tail({'x': x, 'y': np.r_[np.ones(70), np.linspace(1, 2, 10)]},
                        5e-3, 10) is None                          # one signal still moves
    assert settled_tail({'x': np.r_[x, np.nan]}, 5e-3, 10) is None
    assert settled_tail({'x': np.zeros(20)}, 5e-3, 10) == 0         # zero: the floor
    assert settled_tail({'x': np.ones(5)}, 5e-3, 10) is None        # too few


def test_a_run_ending_in_a_transient_has_no_steady_state_and_no_settling_time(tmp_path):
    """The crank step needs 2 s of actuator travel; the recording stops 1 s into it."""
    path = tmp_path / 'transient.mcap'
    record_node_like(path, 2500, {1500: ('crank_length_cmd', 0.05)})
    result = analyze_trace(load(str(path))[0][0])
    assert not result.steady.found and 'not settled' in result.steady.reason
    assert result.steady_metrics == {}
    (step,) = result.steps
    assert not step.settled
    assert math.isnan(step.settling_time) and math.isnan(step.rise_time)
    proc = cvt_sim('analyze', path, '--cycles', 'all')
    assert 'steady state: none (not settled' in proc.stdout
    assert 'not settled' in proc.stdout.split('step at t = 1.5000 s')[1]
    assert 'settling (±2%)' not in proc.stdout


def test_no_impossible_figure_is_printed_without_a_flag(tmp_path):
    """A run that ends while the output runs down (crank length cut at 2.5 s): the flywheel
    gives back energy, so over the last cycles P4 > P1 — the old "last quarter" printed
    efficiencies above 100 % as plain numbers."""
    path = tmp_path / 'rundown.mcap'
    record_node_like(path, 3000, {2500: ('crank_length_cmd', 0.005)})
    result = analyze_trace(load(str(path))[0][0])
    assert np.nanmax(result.cycles['efficiency']) > 1.0      # the case is there
    assert not result.steady.found
    out = cvt_sim('analyze', path, '--cycles', 'all').stdout
    flagged = 0
    for line in out.splitlines():
        if 'steady state:' in line:     # the reason text, not a figure
            continue
        for value, flag in re.findall(r'(-?\d+\.\d+)%\s?(!?)', line):
            if float(value) > 100.0 or float(value) < 0.0:
                assert flag == '!', line
                flagged += 1
            else:   # a flag on a value printed inside 0–100 % ('100.000%!') reads wrong
                assert not flag, line
    assert flagged and '! efficiency outside 0–100 %' in out
    data = json.loads(cvt_sim('analyze', path, '--json', tmp_path / 'r.json').stdout and
                      (tmp_path / 'r.json').read_text())
    assert data['runs'][0]['steady_state'] == {
        'found': False, 'reason': result.steady.reason, 'tolerance': 5e-3, 'min_cycles': 10,
        'first_cycle': None, 'last_cycle': None}


def test_step_metrics_of_a_first_order_response():
    tau = 0.2
    t = np.linspace(0, 3, 30001)
    y = 1.0 + 2.0 * (1 - np.exp(-np.maximum(t - 1.0, 0) / tau))
    m = response_metrics(t, y, 1.0, 1.0, 3.0)
    assert m.rise_time == pytest.approx(tau * math.log(9), rel=1e-3)      # 10 → 90 %
    assert m.settling_time == pytest.approx(tau * math.log(50), rel=1e-3)  # ±2 %
    assert m.overshoot == 0.0
    assert math.isnan(response_metrics(t[t < 1.3], y[t < 1.3], 1.0, 1.0, 3.0).settling_time)
    # still creeping up at the end: its final value a tail mean, below the last values; the
    # last value is its peak, not an overshoot (it was reported as 0.7 % on such a ramp)
    creep = response_metrics(t, y, 1.0, 1.0, float(np.mean(y[t > 1.5])))
    assert creep.peak == y[-1] > creep.final and creep.overshoot == 0.0
    # a real overshoot: 18 % of the change over the final value, then back onto it
    over = 1.0 + 2.0 * (1 - np.exp(-np.maximum(t - 1.0, 0) / tau)) \
        + 0.4 * np.exp(-((t - 1.8) / 0.1) ** 2)
    m = response_metrics(t, over, 1.0, 1.0, 3.0)
    assert m.overshoot == pytest.approx((over.max() - 3.0) / 2.0) and 0.15 < m.overshoot < 0.2


# ---------------------------------------------------------------------------------- CLI
def test_analyze_cli_prints_metrics_writes_plots_json_and_step_responses(stepped, tmp_path):
    path, rows = stepped
    plots = tmp_path / 'plots'
    proc = cvt_sim('analyze', path, '--plots', plots, '--json', tmp_path / 'a.json',
                   '--cycles-csv', tmp_path / 'cycles.csv', '--cycles', 3)
    out = proc.stdout
    for text in ('whole run   steady state', 'mean ratio i = ω4/ω1', 'output speed ripple',
                 'peak torsion twist', 'dynamic load factor', 'engaged fraction',
                 'clutch switches per crank turn', 'efficiency', 'energy residual',
                 'per cycle (last 3 of', 'steady state: ',
                 'step at t = 1.0000 s: crank length → 0.05 m (was 0.03 m)',
                 'step at t = 3.5000 s: load torque → 8 N·m (was 5 N·m)'):
        assert text in out, text
    names = sorted(p.name for p in plots.iterdir())
    assert names == ['fig2_twist_cycle.png', 'fig3_speeds_cycle.png',
                     'step_01_crank_length_cmd.png', 'step_02_load_torque_cmd.png',
                     'timeseries.png']
    for p in plots.iterdir():
        assert p.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and p.stat().st_size > 20_000
    data = json.loads((tmp_path / 'a.json').read_text())
    run = data['runs'][0]
    # whole run: the peak of the recorded samples, start-up included
    assert run['whole_run']['clutch_torque_peak'] == pytest.approx(
        rows[:, COL['clutch_torque']].max(), rel=1e-12)
    assert run['whole_run']['twist_peak'] == pytest.approx(rows[:, COL['twist']].max(), rel=1e-9)
    steps = run['steps']
    assert [s['topic'] for s in steps] == ['crank_length_cmd', 'load_torque_cmd']
    crank = steps[0]
    assert crank['previous'] == 0.03 and crank['value'] == 0.05 and crank['settled']
    assert crank['ratio_before'] == pytest.approx(0.25, abs=0.01)
    assert crank['ratio_after'] > 0.4
    # the actuator needs (0.02 m)/(0.01 m/s) = 2 s: the ratio settles after that, not before
    assert 2.0 < crank['settling_time'] < 2.5 and 1.0 < crank['rise_time'] < 2.0
    assert steps[1]['output_speed_after'] < steps[1]['output_speed_before']
    with open(tmp_path / 'cycles.csv') as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(run['cycles'])
    assert float(table[-1]['ratio']) == pytest.approx(run['cycles'][-1]['ratio'])
    # one numbering from 1 everywhere: the printed table, the CSV and the JSON
    n = len(table)
    assert [row['cycle'] for row in table] == [str(k) for k in range(1, n + 1)]
    assert [c['cycle'] for c in run['cycles']] == list(range(1, n + 1))
    assert f'{n:9d}' in out.splitlines()[[i for i, line in enumerate(out.splitlines())
                                          if 'per cycle (last 3 of' in line][0] + 4]
    # the crank step leaves the flywheels trading energy: the motion has settled (the step's
    # final value), the powers have not (no steady-state figures for the run)
    assert not run['steady_state']['found'] and 'motor power' in run['steady_state']['reason']


def test_step_plots_are_titled_with_the_command_as_given(stepped):
    result = analyze_trace(load(str(stepped[0]))[0][0])
    titles = [step_title(s) for s in result.steps]
    assert titles[0].startswith('Response to crank_length_cmd = 0.05 m at t = 1.0000 s '
                                '(was 0.03 m)')
    assert titles[1].startswith('Response to load_torque_cmd = 8 N·m at t = 3.5000 s '
                                '(was 5 N·m)')


def test_a_repeated_command_keeps_the_values_apart(tmp_path):
    """Three commands on one topic: each step names its own value and the one before it."""
    path = tmp_path / 'three.mcap'
    record_node_like(path, 1500, {300: ('crank_length_cmd', 0.035),
                                  700: ('crank_length_cmd', 0.04),
                                  1100: ('crank_length_cmd', 0.045)})
    steps = analyze_trace(load(str(path))[0][0]).steps
    assert [(s.previous, s.command.value) for s in steps] == [(0.03, 0.035), (0.035, 0.04),
                                                              (0.04, 0.045)]


def test_a_command_stream_is_a_closed_loop_not_steps(tmp_path):
    """A controller that commands every 5 ms for a second (a closed loop), then one command left
    alone: only that one is a step; the stream is counted per topic, in the text and the JSON,
    and gets no step lines or plots."""
    path = tmp_path / 'loop.mcap'
    stream = {i: ('crank_length_cmd', 0.03 + 1e-5 * (i // 5 % 7)) for i in range(500, 1500, 5)}
    record_node_like(path, 2500, {**stream, 1600: ('crank_length_cmd', 0.04)})
    result = analyze_trace(load(str(path))[0][0])
    assert [s.command.t for s in result.steps] == [pytest.approx(1.6)]
    assert result.steps[0].previous == stream[1495][1]
    assert result.streamed_commands == {'crank_length_cmd': 200}
    out = cvt_sim('analyze', path, '--plots', tmp_path / 'p', '--json', tmp_path / 'r.json').stdout
    assert out.count('step at t = ') == 1 and '200 commands on crank_length_cmd' in out
    assert [p.name for p in (tmp_path / 'p').iterdir() if p.name.startswith('step_')] == \
        ['step_01_crank_length_cmd.png']
    run = json.loads((tmp_path / 'r.json').read_text())['runs'][0]
    assert run['streamed_commands'] == {'crank_length_cmd': 200} and len(run['steps']) == 1


def test_joint_commands_are_crank_length_commands(tmp_path):
    """A ros2_control controller commands through joint_commands (the crank_length joint's
    position): analysis reads those as crank-length commands, as the node applies them."""
    path = tmp_path / 'r2c.mcap'
    record_node_like(path, 2000, {500: ('joint_commands', 0.04)})
    (step,) = analyze_trace(load(str(path))[0][0]).steps
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    from cvt_ros.interface import joint_command_crank_length
    for names, positions, value in ((['crank', 'crank_length'], [0.0, 0.05], 0.05),
                                    (['crank', 'crank_length'], [0.05], 0.05),  # TopicBasedSystem
                                    (['crank', 'crank_length', 'x'], [0.0, 0.05], None),
                                    (['crank'], [0.05], None)):
        data = serialize_message(JointState(name=names, position=positions))
        assert joint_command_crank_length(data) == value, names
    assert (step.command.key, step.command.value, step.previous) == ('crank_length_cmd', 0.04,
                                                                     0.03)
    assert step.command.t == pytest.approx(0.5)


def test_actual_crank_length_is_read_from_the_recording_old_ones_are_solved(stepped, tmp_path):
    path, rows = stepped
    trace = load(str(path))[0][0]
    assert trace.crank_length_source == 'recorded'
    assert np.array_equal(trace.crank_length, rows[:, COL['crank_length']])
    # a recording made before the actuator joint existed: J1..J4 only
    old = tmp_path / 'old.mcap'
    from cvt_ros import interface as I
    with SimulationRecorder(old, parameters=load_scene('paper')) as rec:
        rec.record_clutch_state(True, 0.0)
        for row in rows:
            rec.write(rec.topics['joint_states'], I.joint_state_cdr(row), I.stamp_ns(row[0]))
    trace = load(str(old))[0][0]
    assert trace.crank_length_source == 'reconstructed'
    assert np.nanmax(np.abs(trace.crank_length - rows[:, COL['crank_length']])) < 1e-9


def test_export_csv_matches_the_run_csv(paper, tmp_path):
    mcap_path, csv_path = paper
    out, events = tmp_path / 'export.csv', tmp_path / 'events.csv'
    proc = cvt_sim('export', mcap_path, '--csv', out, '--events', events)
    assert f'→ {out}' in proc.stdout
    exported = np.genfromtxt(out, delimiter=',', names=True)
    original = np.genfromtxt(csv_path, delimiter=',', names=True)
    assert exported.dtype.names[:14] == original.dtype.names
    assert exported.dtype.names[14:] == ('motor_torque', 'shaft_torque')
    for name in original.dtype.names:
        assert np.allclose(exported[name], original[name], rtol=1e-11, atol=1e-11), name
    with open(events) as f:
        rows = list(csv.DictReader(f))
    on = original['engaged']
    assert len(rows) == int(np.sum(on[1:] != on[:-1])) and rows[0]['topic'] == 'clutch_engaged'


def _cut(src, dst, fraction=None, size=None):
    data = src.read_bytes()
    dst.write_bytes(data[:size if size is not None else int(len(data) * fraction)])
    return dst


def test_damaged_inputs_give_partial_results_and_one_error_line(paper, tmp_path):
    mcap_path, csv_path = paper
    cut = _cut(mcap_path, tmp_path / 'cut.mcap', 0.6)
    proc = cvt_sim('analyze', cut, code=1)
    assert 'mean ratio i' in proc.stdout
    err = proc.stderr.strip().splitlines()
    assert len(err) == 1 and 'error' in err[0] and 'readable part' in err[0]
    proc = cvt_sim('export', cut, '--csv', tmp_path / 'cut.csv', code=1)
    rows = len((tmp_path / 'cut.csv').read_text().splitlines()) - 1
    assert 100 < rows < DURATION / DT
    short = _cut(csv_path, tmp_path / 'short.csv', 0.5)
    proc = cvt_sim('analyze', short, code=1)
    assert 'mean ratio i' in proc.stdout and 'cut off' in proc.stderr


@pytest.mark.parametrize('content, fragment', [
    (b'', 'empty file'),
    (b'\x89MCAP0\r\n' + b'\x00' * 7, 'truncated'),
    (b'hello,world\n1,2\n', 'not a cvt-sim CSV'),
    (b'\x00\x01' * 50, 'not an MCAP recording'),
    (None, 'nothing readable'),     # the first 40 bytes of a recording
    ('missing', 'no such file'),
])
def test_unusable_inputs_exit_2_with_one_line(paper, tmp_path, capsys, content, fragment):
    from cvt_ros.cli import main

    bad = tmp_path / 'bad.mcap'
    if content is None:
        _cut(paper[0], bad, size=40)
    elif isinstance(content, bytes):
        bad.write_bytes(content)
    for command in (['analyze', str(bad)], ['export', str(bad), '--csv', str(tmp_path / 'x')]):
        assert main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and fragment in err[0], err


def test_a_reset_splits_the_recording_into_runs(tmp_path):
    path = tmp_path / 'reset.mcap'
    sim = Simulator(load_scene('paper'))
    with SimulationRecorder(path, parameters=sim.values) as rec:
        for run in range(2):
            if run:
                rec.mark_reset()
                sim.reset()
            rec.record_clutch_state(sim.engaged, 0.0)
            rec.record_sample(sim.sample())
            for _ in range(300):
                for sw in sim.advance(1e-3):
                    rec.record_switch(sw)
                rec.record_sample(sim.sample())
    traces, _ = load(str(path))
    assert [tr.run_index for tr in traces] == [0, 1]
    a, b = (analyze_trace(tr) for tr in traces)
    assert np.array_equal(a.trace.t, b.trace.t)
    assert np.array_equal(a.trace.switch_t, b.trace.switch_t)  # deterministic: same run twice
    assert a.whole_run == b.whole_run
    assert find_steady_state(a.cycles).reason == find_steady_state(b.cycles).reason
