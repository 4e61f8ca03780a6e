"""`cvt-sim analyze` and `cvt-sim export` (cvt_ros.analysis).

The metrics of a recording are checked against values computed here, independently and more
simply, from the CSV of the same run; damaged inputs must give partial results and one clear
line on stderr, never a traceback.
"""
import csv
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from cvt_ros.analysis import analyze_trace, crank_length_from_angles, load
from cvt_ros.recording.recorder import SimulationRecorder
from cvt_ros.scene import load_scene
from cvt_ros.solver.simulator import Simulator

CLI = [sys.executable, '-m', 'cvt_ros']
TWO_PI = 2 * math.pi
DT = 5e-4


def _env():
    env = dict(os.environ)
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    env['MPLBACKEND'] = 'Agg'
    return env


def cvt_sim(*args, code=0):
    proc = subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=120,
                          env=_env())
    assert proc.returncode == code, proc.stdout + proc.stderr
    assert 'Traceback' not in proc.stderr
    return proc


@pytest.fixture(scope='module')
def paper(tmp_path_factory):
    """`cvt-sim run paper` for 1 s at 0.5 ms: the MCAP and the CSV of the same run."""
    d = tmp_path_factory.mktemp('paper')
    cvt_sim('run', 'paper', '--duration', 1.0, '--sample-dt', DT, '--quiet',
            '--csv', d / 'paper.csv', '--mcap', d / 'paper.mcap')
    return d / 'paper.mcap', d / 'paper.csv'


@pytest.fixture(scope='module')
def stepped(tmp_path_factory):
    """A node-like recording with commands: crank length 0.03 → 0.05 m at 1.0 s, load torque
    5 → 8 N·m at 3.5 s (Simulator.advance per 1 ms, recorded through the recorder's API)."""
    path = tmp_path_factory.mktemp('steps') / 'steps.mcap'
    sim = Simulator(load_scene('paper'))
    with SimulationRecorder(path, parameters=sim.values, scene='paper', source='test') as rec:
        rec.record_clutch_state(sim.engaged, 0.0)
        rec.record_sample(sim.sample())
        for i in range(4500):
            if i == 1000:
                rec.record_command('crank_length_cmd', 0.05, sim.t)
                sim.command_crank_length(0.05)
            if i == 3500:
                rec.record_command('/load_torque_cmd', 8.0, sim.t)
                sim.set_load_torque(8.0)
            for sw in sim.advance(1e-3):
                rec.record_switch(sw)
            rec.record_sample(sim.sample())
            rec.record_clock(sim.t)
    return path


def independent_metrics(csv_path):
    """Cycle metrics straight from the CSV: linear interpolation, trapezoids, Kloss torque."""
    d = np.genfromtxt(csv_path, delimiter=',', names=True)
    t, p1, p4, w1, w4 = d['t'], d['phi1'], d['phi4'], d['omega1'], d['omega4']
    k = np.floor(p1 / TWO_PI)
    i = np.flatnonzero(np.diff(k) > 0)
    tb = t[i] + (k[i + 1] * TWO_PI - p1[i]) / (p1[i + 1] - p1[i]) * (t[i + 1] - t[i])
    n = len(tb) - 1
    ta, te = tb[0], tb[-1]
    inside = (t > ta) & (t < te)
    on = d['engaged']
    mid = 0.5 * (t[1:] + t[:-1])
    change = np.flatnonzero(on[1:] != on[:-1])
    # engaged time: the 0/1 signal switches half-way between samples
    fine = np.linspace(ta, te, 400_001)
    state = on[np.clip(np.searchsorted(mid, fine), 0, len(on) - 1)]
    p = load_scene('paper')
    s = (p['motor.synchronous_speed'] - w1) / p['motor.synchronous_speed']
    sk = p['motor.breakdown_slip']
    m1 = 2 * p['motor.breakdown_torque'] * sk * s / (s * s + sk * sk)
    m4 = d['load_torque']
    sel = np.flatnonzero(inside)
    tt = t[sel]
    w_in = np.trapezoid(m1[sel] * w1[sel], tt)
    w_out = np.trapezoid(m4[sel] * w4[sel], tt)
    energy = 0.5 * (p['inertia.motor'] * w1**2 + p['inertia.rocker'] * d['omega2']**2
                    + p['inertia.clutch_driven'] * d['omega3']**2 + p['inertia.output'] * w4**2
                    + p['shaft.stiffness'] * d['twist']**2)
    residual = (energy[-1] - energy[0]) - (np.trapezoid(m1 * w1, t) - np.trapezoid(m4 * w4, t))
    return {
        'cycles': n,
        'ratio': (np.interp(te, t, p4) - np.interp(ta, t, p4)) / (TWO_PI * n),
        'crank_speed': TWO_PI * n / (te - ta),
        'twist_peak': d['twist'][inside].max(),
        'clutch_torque_peak': d['clutch_torque'][inside].max(),
        'clutch_torque_mean': np.trapezoid(d['clutch_torque'][sel], tt) / (tt[-1] - tt[0]),
        'engaged_fraction': float(np.mean(state)),
        'switches_per_cycle': np.sum((mid[change] >= ta) & (mid[change] < te)) / n,
        'motor_power': w_in / (tt[-1] - tt[0]),
        'efficiency': w_out / w_in,
        'residual': residual,
        'period': (te - ta) / n,
    }


def test_metrics_match_an_independent_computation_from_the_csv(paper):
    mcap_path, csv_path = paper
    ref = independent_metrics(csv_path)
    traces, info = load(str(mcap_path))
    assert len(traces) == 1 and not info.problems and traces[0].switches_exact
    result = analyze_trace(traces[0])
    got = result.summary['all']
    assert got['cycles'] == ref['cycles'] >= 20
    assert got['ratio'] == pytest.approx(ref['ratio'], rel=1e-6)
    assert got['crank_speed'] == pytest.approx(ref['crank_speed'], rel=1e-6)
    assert got['twist_peak'] == pytest.approx(ref['twist_peak'], rel=1e-9)
    assert got['clutch_torque_peak'] == pytest.approx(ref['clutch_torque_peak'], rel=1e-9)
    assert got['clutch_torque_mean'] == pytest.approx(ref['clutch_torque_mean'], rel=2e-3)
    assert got['load_factor'] == pytest.approx(ref['clutch_torque_peak']
                                               / ref['clutch_torque_mean'], rel=2e-3)
    # exact switch times vs the CSV's sampled state: within half a sample per switch
    tol = got['switches_per_cycle'] * 0.5 * DT / ref['period']
    assert got['engaged_fraction'] == pytest.approx(ref['engaged_fraction'], abs=tol)
    assert abs(got['switches_per_cycle'] - ref['switches_per_cycle']) * ref['cycles'] <= 1
    assert got['motor_power'] == pytest.approx(ref['motor_power'], rel=1e-3)
    assert got['efficiency'] == pytest.approx(ref['efficiency'], rel=1e-3)
    energy = result.energy
    assert energy['available']
    assert energy['residual'] == pytest.approx(ref['residual'], abs=1e-4 * energy['work_motor'])
    assert energy['relative_residual'] < 1e-3
    # per cycle, the steady state of the paper scene: i ≈ 0.25, two switches per cycle
    cy = result.cycles
    assert cy['ratio'][-1] == pytest.approx(0.25, abs=0.01)
    assert list(cy['switches'][-5:]) == [2, 2, 2, 2, 2]
    assert np.all(cy['engaged_fraction'] > 0) and np.all(cy['engaged_fraction'] < 1)
    assert np.allclose(cy['crank_length'], 0.03, atol=1e-12)   # solved from (φ1, φ2)


def test_csv_input_gives_the_same_metrics(paper):
    mcap_path, csv_path = paper
    from_mcap = analyze_trace(load(str(mcap_path))[0][0]).summary['all']
    traces, info = load(str(csv_path), scene='paper')
    assert traces[0].kind == 'csv' and not info.problems
    result = analyze_trace(traces[0])
    got = result.summary['all']
    for key in ('ratio', 'twist_peak', 'clutch_torque_peak', 'motor_power', 'efficiency'):
        assert got[key] == pytest.approx(from_mcap[key], rel=1e-6), key
    assert result.energy['available']
    bare = analyze_trace(load(str(csv_path))[0][0])
    assert not bare.energy['available'] and '--scene' in bare.energy['reason']


def test_crank_length_from_angles_inverts_the_linkage():
    from cvt_ros.physics.linkage import rocker_angle
    phi1 = np.linspace(0, 20, 2001)
    for a in (0.0, 0.001, 0.03, 0.0999):
        phi2 = np.array([rocker_angle(x, a, 0.1, 0.2, 0.2, 1.0) for x in phi1])
        got = crank_length_from_angles(phi1, phi2, 0.1, 0.2, 0.2, 1.0)
        assert np.nanmax(np.abs(got - a)) < 1e-9 and np.mean(np.isnan(got)) < 0.01


def test_analyze_cli_prints_metrics_writes_plots_json_and_step_responses(stepped, tmp_path):
    plots = tmp_path / 'plots'
    proc = cvt_sim('analyze', stepped, '--plots', plots, '--json', tmp_path / 'a.json',
                   '--cycles-csv', tmp_path / 'cycles.csv', '--cycles', 3)
    out = proc.stdout
    for text in ('mean ratio i = ω4/ω1', 'output speed ripple', 'peak torsion twist',
                 'dynamic load factor', 'engaged fraction', 'clutch switches per cycle',
                 'efficiency', 'energy residual', 'per cycle (last 3 of',
                 'step at t = 1.0000 s: crank length 0.03 → 0.05 m',
                 'step at t = 3.5000 s: load torque 5 → 8 N·m'):
        assert text in out, text
    names = sorted(p.name for p in plots.iterdir())
    assert names == ['fig2_twist_cycle.png', 'fig3_speeds_cycle.png',
                     'step_01_crank_length_cmd.png', 'step_02_load_torque_cmd.png',
                     'timeseries.png']
    for p in plots.iterdir():
        assert p.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and p.stat().st_size > 20_000
    data = json.loads((tmp_path / 'a.json').read_text())
    run = data['runs'][0]
    steps = run['steps']
    assert [s['topic'] for s in steps] == ['crank_length_cmd', 'load_torque_cmd']
    crank = steps[0]
    assert crank['previous'] == 0.03 and crank['value'] == 0.05
    assert crank['ratio_before'] == pytest.approx(0.25, abs=0.01)
    assert crank['ratio_after'] > 0.4
    # the actuator needs (0.02 m)/(0.01 m/s) = 2 s: the ratio settles after that, not before
    assert 2.0 < crank['settling_time'] < 2.5 and 1.0 < crank['rise_time'] < 2.0
    assert steps[1]['output_speed_after'] < steps[1]['output_speed_before']
    with open(tmp_path / 'cycles.csv') as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == run['summary']['all']['cycles']
    assert float(rows[-1]['ratio']) == pytest.approx(run['cycles'][-1]['ratio'])


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
    assert 100 < rows < 2001
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
    from cvt_ros.tools.cli import main

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
    assert a.summary['all']['ratio'] == b.summary['all']['ratio']
