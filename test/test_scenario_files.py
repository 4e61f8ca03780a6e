"""Scenario files and schedules: the shipped scenarios load; every bad input is refused with the
file, the key and the value; schedules evaluate as documented."""
import math
import textwrap

import numpy as np
import pytest

from cvt_ros.scenario.model import ScenarioError, available_scenarios, load_scenario
from cvt_ros.scenario.schedule import ScheduleError, parse_schedule

SHIPPED = ('conveyor_startup', 'conveyor_setpoint_steps', 'conveyor_load_step',
           'mixer_speed_steps')


def write(tmp_path, text, name='s.yaml'):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


BASE = """\
scene: conveyor
duration: 4.0
setpoint: {initial: 55.0, changes: [{at: 1.0, step: 60.0}]}
"""


def test_shipped_scenarios_load():
    names = available_scenarios()
    for name in SHIPPED:
        assert name in names
        sc = load_scenario(name)
        assert sc.duration > 0 and sc.periods == round(sc.duration / sc.control_period)
        assert sc.crank_limits.max < 0.1          # below the Grashof bound of the geometry
    assert sum('conveyor' in n for n in names) >= 3
    mixer = load_scenario('mixer_speed_steps')
    assert mixer.values['load.quadratic'] > 0


def test_minimal_file_and_defaults(tmp_path):
    sc = load_scenario(write(tmp_path, BASE))
    assert sc.control_period == 1e-3 and sc.seed == 0
    assert sc.load.initial == sc.values['load.torque'] == 8.0     # the conveyor scene's load
    assert sc.crank_limits.rate == sc.values['linkage.crank_rate_limit']
    assert not sc.sensors.enabled and not sc.actuator.enabled
    assert sc.setpoint.sample(np.array([0.0, 0.999, 1.0, 3.0])).tolist() == [55, 55, 60, 60]


@pytest.mark.parametrize('extra, key, value', [
    ('setpont: 3', 'setpont', 'did you mean setpoint'),
    ('duration: .nan', 'duration', 'nan'),
    ('duration: -1', 'duration', '-1'),
    ('control_period: 0.0', 'control_period', '0'),
    ('seed: 1.5', 'seed', '1.5'),
    ('overrides: {load.torqe: 3}', 'load.torqe', 'did you mean load.torque'),
    ('overrides: {linkage.crank_length: 0.2}', 'linkage.crank_length', '0.2'),
    ('load: {changes: [{at: 5.0, step: 9.0}]}', 'load.changes[0].at', '5 s'),
    ('load: {changes: [{at: 3.0, ramp: {to: 9.0, duration: 2.0}}]}', 'load.changes[0].ramp',
     '5 s'),
    ('load: {changes: [{at: 1.0, step: .inf}]}', 'load.changes[0].step', 'inf'),
    ('load: {changes: [{at: 1.0, step: 5000}]}', 'load.changes[0].step', '5000'),
    ('load: {changes: [{at: 1.0, sine: {amplitude: 1, frequency: 2}}]}',
     'load.changes[0].sine.duration', 'missing'),
    ('load: {changes: [{at: 1.0, jump: 3}]}', 'load.changes[0]', 'exactly one of'),
    ('load: {changes: [{at: 2.0, step: 3}, {at: 1.0, step: 4}]}', 'load.changes[1].at',
     'time order'),
    ('load: {changes: [{at: 1.0, ramp: {to: 3, duration: 2}}, {at: 2.0, step: 4}]}',
     'load.changes[1].at', 'still runs'),
    ('crank_limits: {max: 0.1}', 'crank_limits', 'Grashof'),
    ('crank_limits: {rate: 0}', 'crank_limits', 'rate'),
    ('sensors: {noise: {speed: 0.1}}', 'sensors.noise', 'speed'),
    ('sensors: {delay: 0.0015}', 'sensors.delay', 'whole number'),
    ('sensors: {counts_per_turn: -4}', 'sensors.counts_per_turn', '-4'),
    ('actuator: {backlash: .nan}', 'actuator.backlash', 'nan'),
    ('controller: {kp: -1}', 'controller.kp', '-1'),
    ('controller: {kd: 1}', 'controller', 'kd'),
])
def test_bad_input_names_file_key_value(tmp_path, extra, key, value):
    path = write(tmp_path, BASE + extra + '\n')
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    text = str(info.value)
    assert str(path) in text and key in text and value in text, text


def test_missing_keys_and_files(tmp_path):
    with pytest.raises(ScenarioError, match='setpoint: missing'):
        load_scenario(write(tmp_path, 'scene: conveyor\nduration: 2\n'))
    with pytest.raises(ScenarioError, match='not found'):
        load_scenario(tmp_path / 'nope.yaml')
    with pytest.raises(ScenarioError, match='scene'):
        load_scenario(write(tmp_path, BASE.replace('conveyor', 'no_such_scene')))
    with pytest.raises(ScenarioError, match='YAML'):
        load_scenario(write(tmp_path, 'scene: [unclosed\n'))
    # a misspelled override is the caller's mistake, not the shipped file's
    with pytest.raises(ScenarioError, match=r"^override of .*conveyor_load_step.yaml: unknown "
                                            r"key 'duraton' \(did you mean duration\?\)"):
        load_scenario('conveyor_load_step', {'duraton': 3.0})


def test_schedule_kinds_evaluate_as_documented(tmp_path):
    (tmp_path / 'belt.csv').write_text('t,load_torque\n0,10\n1,12\n2,11\n')
    sched = parse_schedule({'initial': 8.0, 'changes': [
        {'at': 1.0, 'step': 10.0},
        {'at': 2.0, 'ramp': {'to': 14.0, 'duration': 2.0}},
        {'at': 5.0, 'sine': {'amplitude': 2.0, 'frequency': 0.5, 'duration': 2.0}},
        {'at': 8.0, 'profile': {'file': 'belt.csv'}},
    ]}, 'load', 12.0, base_dir=tmp_path)
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 4.5, 5.5, 7.0, 7.5, 8.0, 8.5, 9.0, 10.0, 11.0])
    expect = [8, 10, 10, 12, 14, 14, 14 + 2 * math.sin(math.pi * 0.5), 14, 14, 10, 11, 12, 11,
              11]
    assert np.allclose(sched.sample(t), expect)
    assert sched.change_times() == [1.0, 2.0, 5.0, 8.0]


def test_profile_errors_name_the_row(tmp_path):
    (tmp_path / 'bad.csv').write_text('t,v\n0,1\n0.5,nan\n')
    with pytest.raises(ScheduleError, match='row 3'):
        parse_schedule({'changes': [{'at': 0.0, 'profile': 'bad.csv'}]}, 'load', 5.0, 1.0,
                       base_dir=tmp_path)
    (tmp_path / 'back.csv').write_text('t,v\n0,1\n1,1\n0.5,1\n')
    with pytest.raises(ScheduleError, match='does not increase'):
        parse_schedule({'changes': [{'at': 0.0, 'profile': 'back.csv'}]}, 'load', 5.0, 1.0,
                       base_dir=tmp_path)
    (tmp_path / 'long.csv').write_text('t,v\n0,1\n9,1\n')
    with pytest.raises(ScheduleError, match='past the scenario'):
        parse_schedule({'changes': [{'at': 0.0, 'profile': 'long.csv'}]}, 'load', 5.0, 1.0,
                       base_dir=tmp_path)
    with pytest.raises(ScheduleError, match='cannot read'):
        parse_schedule({'changes': [{'at': 0.0, 'profile': 'none.csv'}]}, 'load', 5.0, 1.0,
                       base_dir=tmp_path)
