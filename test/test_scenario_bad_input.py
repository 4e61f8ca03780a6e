"""The reproductions of issue 34 on the controller kit and the offline run: each was a traceback,
a hang, a file lost or an exit 0 with a wrong answer; now one clear line and an exit code, checked
before the run where it can be (test_fuzz_scenarios.py draws many more)."""
import json
import os
import textwrap

import numpy as np
import pytest

from cvt_ros.cli import main as cvt_sim
from cvt_ros.scenario import harness
from cvt_ros.scenario.harness import run_scenario
from cvt_ros.scenario.model import load_scenario
from cvt_ros.scenario.schedule import Schedule

BIG = '1' + '0' * 400
BASE = """\
    scene: conveyor
    duration: 0.05
    setpoint: 55.0
    """


def scenario_file(folder, extra='', name='s.yaml', base=BASE):
    path = folder / name
    path.write_text(textwrap.dedent(base) + textwrap.dedent(extra))
    return path


def run(capsys, *argv):
    code = cvt_sim([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert 'Traceback' not in err
    return code, out, err


@pytest.mark.parametrize('extra, reason', [
    (f"seed: {BIG}", 'seed: 1000'),
    (f"crank_limits: {{max: {BIG}}}", 'beyond the float range'),
    (f"controller: {{kp: {BIG}}}", 'controller.kp'),
    ("crank_limits: {min: 0, max: 0}", 'max: 0 m must be above min 0 m'),
    ("crank_limits: {min: 0.06}\ncontroller: {crank_max: 0.05}", "controller/crank_limits"),
    ("overrides: {model.fidelity: averaged, motor.model: constant_speed, motor.speed: -100}",
     'the averaged fidelity needs a crank turning forward'),
    ("load: {changes: [{at: 0.01, profile: {file: /dev/zero}}]}", 'not a regular file'),
])
def test_scenario_values_that_broke_a_later_stage_are_refused_at_load(tmp_path, capsys, extra,
                                                                       reason):
    code, out, err = run(capsys, 'scenario', 'run', scenario_file(tmp_path, extra), '--quiet')
    assert code == 2 and reason in err and len(err.strip().splitlines()) == 1, err


def test_a_fifo_profile_is_refused_not_read(tmp_path, capsys):
    os.mkfifo(tmp_path / 'load.csv')   # reading it would block for ever
    path = scenario_file(tmp_path, "load: {changes: [{at: 0.01, profile: {file: load.csv}}]}")
    code, _, err = run(capsys, 'scenario', 'run', path, '--quiet')
    assert code == 2 and 'load.csv: not a regular file' in err


def test_a_node_level_parameter_beyond_float_range(capsys):
    code, _, err = run(capsys, 'run', 'paper', '--duration', '0.01', '--set',
                       f'steps_per_command={BIG}')
    assert code == 2 and 'steps_per_command' in err and 'beyond any float' in err


def test_a_run_too_short_to_measure_is_refused(tmp_path, capsys):
    code, out, err = run(capsys, 'scenario', 'run', scenario_file(tmp_path), '--duration', '1e-9',
                         '--quiet')
    assert code == 2 and 'shorter than 2 control periods' in err and 'completed' not in out


@pytest.mark.parametrize('kind, value', [('text', '0.05'), ('bool', True), ('number', 10 ** 400),
                                         ('float_raises', None), ('decimal', None)])
def test_a_controller_answer_that_is_not_a_number_stops_the_run(tmp_path, capsys, kind, value):
    spec = json.dumps({'kind': kind, 'value': value, 'at': 3})
    path = scenario_file(tmp_path, f"description: {json.dumps(spec)}\n")
    code, out, err = run(capsys, 'scenario', 'run', path, '--quiet', '--controller',
                         'fuzz_controllers:make')
    assert code == 1 and 'STOPPED: the controller returned' in out and '(period 3)' in out, out


# ------------------------------------------------------------------------------ outputs
@pytest.mark.parametrize('targets, reason', [
    (['--json', 's.yaml', '--overwrite'], 'is an input of this command'),
    (['--json', 'same', '--mcap', 'same'], 'named for two outputs'),
    (['--plot', 'out.svgx'], 'the format follows the suffix'),
    (['--plot', 'sub'], 'is a directory; name a file in it'),
    (['--json', 'notes.json'], 'exists (use --overwrite to replace it)'),
    (['--json', '/proc/cvt-test.json'], 'cannot write in /proc'),
    (['--json', 'no/such/x.json'], 'no such directory'),
])
def test_an_output_that_cannot_be_written_is_refused_before_the_run(tmp_path, capsys,
                                                                     monkeypatch, targets,
                                                                     reason):
    monkeypatch.chdir(tmp_path)
    path = scenario_file(tmp_path)
    (tmp_path / 'sub').mkdir()
    (tmp_path / 'notes.json').write_text('mine')
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    code, out, err = run(capsys, 'scenario', 'run', path, '--quiet', *targets)
    assert code == 2 and reason in err, err
    assert out == ''   # (before the run: no summary line)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before


def test_a_full_disk_is_one_line_and_no_partial_file(tmp_path, capsys):
    code, out, err = run(capsys, 'scenario', 'run', scenario_file(tmp_path), '--quiet', '--json',
                         '/dev/full', '--plot', tmp_path / 'p.png')
    assert code == 2 and 'No space left on device' in err and 'no output file was written' in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['s.yaml']
    code, out, err = run(capsys, 'run', 'paper', '--duration', '0.05', '--quiet', '--csv',
                         '/dev/full')
    assert code == 2 and 'No space left on device' in err


def test_the_plot_is_where_it_says(tmp_path, capsys):
    code, out, _ = run(capsys, 'scenario', 'run', scenario_file(tmp_path), '--quiet', '--plot',
                       tmp_path / 'run.svg', '--json', tmp_path / 'run.json')
    assert code == 0 and f"plot → {tmp_path / 'run.svg'}" in out
    assert (tmp_path / 'run.svg').read_text().lstrip().startswith('<?xml')
    assert json.loads((tmp_path / 'run.json').read_text())['completed'] is True


# ------------------------------------------------------------------------------ memory, time
def test_a_scenario_beyond_the_longest_is_refused_before_it_runs(tmp_path, capsys):
    """A day at 1 ms streams (test_scenario_stream.py); a day at 0.1 ms is refused."""
    path = scenario_file(tmp_path, base="scene: conveyor\nduration: 86400\ncontrol_period: 1e-4\n"
                                        "setpoint: 55.0\n")
    code, _, err = run(capsys, 'scenario', 'run', path, '--quiet')
    assert code == 2 and '8.64e+08 control periods, more than 1e+08' in err
    day = scenario_file(tmp_path, base="scene: conveyor\nduration: 86400\nsetpoint: 55.0\n")
    assert load_scenario(day).periods == 86_400_000


def test_the_schedules_are_streamed_in_chunks_with_the_same_answer(tmp_path, monkeypatch):
    """Chunks of 7 periods against one chunk: the same samples and metrics to the bit."""
    path = scenario_file(tmp_path, base="""\
        scene: conveyor
        duration: 0.2
        setpoint: {initial: 55.0, changes: [{at: 0.05, ramp: {to: 60, duration: 0.05}},
                                            {at: 0.12, sine: {amplitude: 2, frequency: 20,
                                                              duration: 0.05}}]}
        load: {changes: [{at: 0.031, step: 9.0}]}
        """)
    scenario = load_scenario(path)
    whole = run_scenario(scenario)
    monkeypatch.setattr(harness, 'SCHEDULE_CHUNK', 7)
    chunked = run_scenario(scenario)
    assert np.array_equal(whole.samples, chunked.samples)
    assert np.array_equal(whole.setpoint, chunked.setpoint)
    assert whole.metrics == pytest.approx(chunked.metrics, nan_ok=True, rel=0, abs=0)


def test_many_schedule_changes_cost_a_few_schedule_evaluations(tmp_path, monkeypatch):
    """5000 changes made the metrics quadratic (two evaluations of every change per change:
    43 s with --json); the step events now take two evaluations per schedule."""
    changes = ', '.join(f"{{at: {0.001 * (k + 1):.3f}, step: {55 + k % 3}}}" for k in range(500))
    path = scenario_file(tmp_path, base=f"scene: conveyor\nduration: 0.6\n"
                                        f"setpoint: {{initial: 55.0, changes: [{changes}]}}\n")
    run = run_scenario(load_scenario(path))
    calls = []
    real = Schedule.sample
    monkeypatch.setattr(Schedule, 'sample', lambda self, t: calls.append(1) or real(self, t))
    assert len(run.events()) == 501
    assert len(calls) == 4   # (before and after, for the set point and for the load)


def test_schedule_sample_matches_its_definition_change_by_change():
    """The bisecting sample against the definition (each change from its start on, time order),
    at times out of order too."""
    from cvt_ros.scenario.schedule import Change
    changes = (Change(0.1, 'step', value=3.0), Change(0.2, 'ramp', value=5.0, duration=0.1),
               Change(0.35, 'sine', amplitude=1.0, frequency=3.0, duration=0.2, phase=0.5),
               Change(0.6, 'profile', duration=0.1, times=np.array([0.0, 0.1]),
                      values=np.array([1.0, 2.0])))
    s = Schedule(1.0, changes)
    t = np.random.default_rng(1).uniform(-0.1, 1.0, 400)
    expected = np.full(t.shape, 1.0)
    level = 1.0
    for c in changes:
        live = t >= c.at
        if c.kind == 'step':
            level = c.value
            expected[live] = level
        elif c.kind == 'ramp':
            expected[live] = level + (c.value - level) * np.clip((t[live] - c.at) / c.duration,
                                                                 0, 1)
            level = c.value
        elif c.kind == 'sine':
            expected[live] = level
            on = live & (t < c.end)
            expected[on] += np.sin(2 * np.pi * 3.0 * (t[on] - c.at) + 0.5)
        else:
            expected[live] = np.interp(t[live] - c.at, c.times, c.values)
    assert np.array_equal(s.sample(t), expected)
