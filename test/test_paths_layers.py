"""N paths through the layers above the core (issue 33), without a ROS graph: the recording,
replay's input, the analysis per path, export, the scenario back ends and the sweep metrics —
and one path exactly as it was (the node's own test: test_node_paths.py).

Each N-path figure is checked against the same run's truth: the core's own switches and
samples (trace_of_samples of the offline run), not against numbers written down here.
"""
import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from cvt_ros import interface as I
from cvt_ros.analysis.analyze import analyze_trace
from cvt_ros.analysis.export import export_csv, export_events
from cvt_ros.analysis.inputs import load
from cvt_ros.analysis.path_metrics import path_metrics
from cvt_ros.analysis.report import format_run, to_json
from cvt_ros.analysis.trace import trace_of_samples
from cvt_ros.device.core import Device
from cvt_ros.parameters import ParameterError
from cvt_ros.recording.cdr_check import cdr_matches, message_shape
from cvt_ros.recording.definitions import message_definition_text
from cvt_ros.recording.reader import read_messages
from cvt_ros.recording.recorder import write_run
from cvt_ros.scenario import load_scenario, run_scenario
from cvt_ros.scenario.recording import write_mcap
from cvt_ros.scene import load_scene
from cvt_ros.solver.clutch_sets import any_switches, set_changes
from cvt_ros.solver.fidelity import make_simulator
from cvt_ros.solver.output import COL, path_columns
from cvt_ros.solver.simulator import ClutchSwitch
from cvt_ros.sweep.metrics import scene_metrics

SPAN = 1.5   # s: start-up, locked crank, handoffs and ~20 crank turns
JOINT_STATE = message_definition_text('sensor_msgs/msg/JointState')


@pytest.fixture(scope='module')
def four(tmp_path_factory):
    """1.5 s of conveyor_4path: the offline run, its recording (cvt-sim run --mcap's writer)
    and the analysis of both."""
    values = load_scene('conveyor_4path')
    sim = make_simulator(values)
    result = sim.run(SPAN, 1e-3)
    path = tmp_path_factory.mktemp('four') / 'run.mcap'
    count, error = write_run(path, sim, result, scene='conveyor_4path')
    assert error is None and count > 3 * len(result.samples)
    truth = trace_of_samples(result.samples, result.columns, result.switches,
                             source='offline', kind='run', parameters=values)
    return values, sim, result, path, truth


# ------------------------------------------------------------------ one path: as it was
def _old_joint_states(row, rate):
    """joint_states bytes as the recorder made them before paths existed (its field list)."""
    fields = ([COL[c] for c in I.POSITION_COLUMNS] + [COL['crank_length']]
              + [COL[c] for c in I.VELOCITY_COLUMNS] + [COL['crank_length']]
              + [COL[c] for c in I.EFFORT_COLUMNS] + [COL['crank_length']])
    values = row.take(fields).tolist()
    values[9], values[14] = rate, math.nan
    ns = I.stamp_ns(row[0])
    return I.JointStateEncoder(I.DEVICE_JOINTS).encode(*divmod(ns, 1_000_000_000), values)


def test_one_path_recording_and_analysis_are_what_they_were(tmp_path):
    values = load_scene('paper')
    sim = make_simulator(values)
    result = sim.run(0.3, 1e-3)
    path = tmp_path / 'one.mcap'
    write_run(path, sim, result, scene='paper')
    messages = list(read_messages(path))
    assert {m.topic for m in messages} == {'/joint_states', '/clutch_engaged', '/clock'}
    samples = [m.data for m in messages if m.topic == '/joint_states']
    rates = np.gradient(result.column('crank_length'), result.column('t'))
    assert samples == [_old_joint_states(row, rate) for row, rate in zip(
        result.samples, rates, strict=True)]
    bools = [m.data for m in messages if m.topic == '/clutch_engaged']
    switches = [s for s in result.switches if s.kind != 'graze']
    assert bools == [I.bool_cdr(bool(result.samples[0, COL['engaged']]))] + [
        I.bool_cdr(s.engaged) for s in switches]
    traces, info = load(str(path))
    analysis = analyze_trace(traces[0])
    assert traces[0].paths is None and analysis.paths == {}
    assert 'paths' not in to_json([analysis], info)['runs'][0]
    assert 'per path' not in format_run(analysis)
    # the device's events stay ClutchSwitch objects
    device = Device(load_scene('paper'), 1e-3)
    events = [e for _ in range(300) if device.advance_row() is not None for e in device.events]
    assert events and all(type(e) is ClutchSwitch for e in events)


def test_sample_layout_of_one_path_is_the_old_one():
    row = make_simulator(load_scene('conveyor')).run(0.05, 0.05).samples[-1]
    layout = I.SampleLayout(1)
    assert layout.names == I.DEVICE_JOINTS and layout.clutch_names == ()
    assert layout.joint_states(row, 0.25, I.stamp_ns(row[0])) == _old_joint_states(row, 0.25)
    assert I.topics_for(1) is I.TOPICS and 'clutch_states' in I.topics_for(4)


# ------------------------------------------------------------------ N paths
def test_clutch_states_bytes_are_rclpy_s(four):
    _, _, result, _, _ = four
    layout = I.SampleLayout(4, 'l1_')
    row = result.samples[-1]
    for data, fill in ((layout.clutch_states(row, 1234), True),
                       (layout.clutch_switch(0b0101, 1234), False)):
        msg = JointState(name=['l1_clutch_1', 'l1_clutch_2', 'l1_clutch_3', 'l1_clutch_4'])
        msg.header.stamp.nanosec = 1234
        if fill:
            ns, _, _, position, velocity, effort = I.parse_joint_state_cdr(data)
            msg.position, msg.velocity, msg.effort = position, velocity, effort
            n0 = len(COL)
            assert list(position) == list(row[n0 + 8:n0 + 12])
            assert list(effort) == list(row[n0 + 12:n0 + 16])
        else:
            msg.position = [1.0, 0.0, 1.0, 0.0]
        ours = serialize_message(msg)
        # rmw leaves the padding bytes uninitialised (and reserves a few past an empty last
        # array): the same message, field for field, both ways
        assert I.parse_joint_state_cdr(ours) == I.parse_joint_state_cdr(data)
        assert deserialize_message(data, JointState) == msg
        assert cdr_matches(data, message_shape('sensor_msgs/msg/JointState', JOINT_STATE))


def test_switches_of_one_instant_are_one_change():
    handoff = [ClutchSwitch(0.1, False, 'release', 0.0, 1), ClutchSwitch(0.1, True, 'engage',
                                                                          0.0, 2),
               ClutchSwitch(0.2, True, 'engage', 0.0, 1), ClutchSwitch(0.2, False, 'graze', 0.0, 3),
               ClutchSwitch(0.3, False, 'release', 0.0, 1),
               ClutchSwitch(0.3, False, 'release', 0.0, 2)]
    changes, mask = set_changes(handoff, 0b001)
    assert [(c.t, c.before, c.after, c.any_changed) for c in changes] == [
        (0.1, 0b001, 0b010, False), (0.2, 0b010, 0b011, False), (0.3, 0b011, 0b000, True)]
    assert mask == 0 and any_switches(handoff, 0b001) == [(0.3, False)]
    tuples = [(s.t, s.engaged, s.path) for s in handoff if s.kind != 'graze']
    assert [(c.t, c.after) for c in set_changes(tuples, 0b001)[0]] == [
        (c.t, c.after) for c in changes]


def test_recording_carries_every_clutch_and_analysis_gives_each_path(four):
    values, sim, result, path, truth = four
    messages = list(read_messages(path))
    topics = {m.topic for m in messages}
    assert topics == {'/joint_states', '/clutch_engaged', '/clock', '/clutch_states'}
    states = [I.parse_joint_state_cdr(m.data) for m in messages if m.topic == '/clutch_states']
    switch_messages = [s for s in states if not s[4]]
    periodic = [s for s in states if s[4]]   # every sample: the clutches' torques and slips
    assert [s[0] for s in periodic] == [I.stamp_ns(t) for t in result.column('t')]
    assert np.array_equal([s[5] for s in periodic], result.samples[:, len(COL) + 12:])
    changes, _ = set_changes(result.switches, 0b0010)   # the set at t = 0 (the first message)
    assert [int(sum(1 << k for k, v in enumerate(s[3]) if v)) for s in switch_messages] == [
        0b0010] + [c.after for c in changes]
    assert [s[0] for s in switch_messages[1:]] == [I.stamp_ns(c.t) for c in changes]
    bools = [m.data for m in messages if m.topic == '/clutch_engaged']
    assert len(bools) == 1 + sum(c.any_changed for c in changes) < 1 + len(changes)
    traces, info = load(str(path))
    assert not info.problems and len(traces) == 1
    recorded, direct = analyze_trace(traces[0]), analyze_trace(truth)
    for got, want in zip(recorded.paths['whole_run'], direct.paths['whole_run'], strict=True):
        assert got['switches'] == want['switches'] > 50
        assert got['clutch_torque_peak'] == want['clutch_torque_peak']
        assert got['clutch_torque_mean'] == pytest.approx(want['clutch_torque_mean'], rel=1e-12)
        assert got['engaged_fraction'] == pytest.approx(want['engaged_fraction'], abs=1e-8)
    assert [p['switches'] for p in direct.paths['whole_run']] == list(
        map(float, sim.path_switch_counts))
    # the machine's own figures: the total clutch torque (every rocker's effort summed) and
    # "any clutch engaged"
    assert np.array_equal(traces[0].effort[:, 1], result.column('clutch_torque'))
    assert recorded.whole_run['engaged_fraction'] == pytest.approx(
        direct.whole_run['engaged_fraction'], abs=1e-8)
    # the energy balance with each rocker's J2 closes as the one-path one does
    assert recorded.energy['relative_residual'] < 1e-4
    assert 'paths' in to_json([recorded], info)['runs'][0]
    assert 'per path: each clutch' in format_run(recorded)


def test_path_figures_are_the_samples_own(four):
    """Engaged fraction, peak, mean and K of each clutch against the raw columns of the run."""
    _, _, result, _, truth = four
    t = result.column('t')
    i, j = np.searchsorted(t, [0.6 - 1e-9, 1.4 - 1e-9])   # a window on samples
    a, b = t[i], t[j]
    inside = np.arange(len(t))[i:j + 1]
    figures = path_metrics(truth, a, b)
    for k, got in enumerate(figures, 1):
        torque = result.column(f'clutch_torque_{k}')
        assert got['clutch_torque_peak'] == pytest.approx(torque[inside].max(), rel=1e-12)
        assert got['clutch_torque_mean'] == pytest.approx(
            np.trapezoid(torque[inside], t[inside]) / (b - a), rel=1e-9)
        assert got['load_factor'] == pytest.approx(
            got['clutch_torque_peak'] / got['clutch_torque_mean'])
        own = [s for s in result.switches if s.path == k and s.kind != 'graze']
        assert got['switches'] == sum(a < s.t <= b for s in own)
        sampled = result.column(f'engaged_{k}')[inside].mean()
        assert got['engaged_fraction'] == pytest.approx(sampled, abs=0.02)   # 1 ms samples
    # "any clutch engaged" (the Trace's own switches) lies between the most engaged clutch's
    # fraction and their sum (two at once at times)
    any_time = truth.engaged_time(np.array([a, b]))
    any_fraction = (any_time[1] - any_time[0]) / (b - a)
    fractions = [p['engaged_fraction'] for p in figures]
    assert max(fractions) <= any_fraction + 1e-12 <= sum(fractions) + 2e-12
    assert any_fraction < 1.0


def test_export_and_its_csv_round_trip(four, tmp_path):
    _, _, result, path, truth = four
    traces, _ = load(str(path))
    csv_path = tmp_path / 'four.csv'
    with open(csv_path, 'w') as f:
        assert export_csv(traces, f) == len(result.samples)
    header = csv_path.read_text().split('\n', 1)[0].split(',')
    assert header[-16:] == list(path_columns(4)[len(COL):])
    back, _ = load(str(csv_path))
    assert back[0].paths is not None and back[0].paths.n_paths == 4
    assert np.allclose(back[0].paths.torque, result.samples[:, len(COL) + 12:], rtol=1e-11,
                       atol=1e-9)
    switches = [analyze_trace(back[0]).paths['whole_run'][k]['switches'] for k in range(4)]
    assert switches == [p['switches'] for p in analyze_trace(truth).paths['whole_run']]
    events = tmp_path / 'events.csv'
    with open(events, 'w') as f:
        export_events(traces, f)
    rows = events.read_text().splitlines()[1:]
    assert sum(r.split(',')[2] == 'clutch_3' for r in rows) == sum(
        1 for s in result.switches if s.path == 3 and s.kind != 'graze')


def test_device_refuses_a_change_of_the_paths(four):
    values = four[0]
    device = Device(values, 1e-3)
    for name, value in (('paths.count', 2), ('paths.phase_offsets', [0.0, 1.0, 2.0, 3.0]),
                        ('paths.phase_offsets', 'x')):
        with pytest.raises(ParameterError, match=rf"{name}: .* refused: the paths are the "
                                                 r"machine's build"):
            device.check_parameters({name: value})
    # the same build, however spelt, is no change
    device.check_parameters({'paths.count': 4, 'paths.phase_offsets': []})
    device.update_parameters({'paths.phase_offsets': list(np.arange(4) * math.pi / 2),
                              'load.torque': 6.0})
    assert device.values['load.torque'] == 6.0


def test_scenario_back_ends_with_four_paths(tmp_path):
    sc = load_scenario('conveyor_4path_setpoint_steps', {'duration': 2.5})
    offline = run_scenario(sc, backend='offline')
    lockstep = run_scenario(sc, backend='lockstep')
    assert offline.ok and lockstep.ok
    assert offline.samples.shape[1] == len(path_columns(4))
    assert np.array_equal(offline.samples, lockstep.samples)
    assert offline.switches == lockstep.switches and len(offline.switches[0]) == 3
    assert offline.metrics == lockstep.metrics
    trace = offline.trace()
    assert trace.paths.n_paths == 4
    assert len(trace.switch_t) < len(offline.switches)   # "any clutch": handoffs left out
    path = tmp_path / 'run.mcap'
    count, error = write_mcap(offline, str(path))
    assert error is None
    traces, _ = load(str(path))
    recorded = analyze_trace(traces[0]).paths['whole_run']
    assert [p['switches'] for p in recorded] == [
        float(sum(1 for s in offline.switches if s[2] == k)) for k in range(1, 5)]


def test_sweep_path_metrics():
    names = ('peak_clutch_torque', 'peak_path_clutch_torque', 'path_engaged_fraction',
             'engaged_fraction', 'run_peak_path_clutch_torque', 'run_peak_clutch_torque')
    for n in (1, 3):
        values = load_scene('conveyor', {'paths.count': n})
        result = make_simulator(values).run(4.0, 1e-3)
        out, _ = scene_metrics(values, result, 4.0, 'steady', names)
        assert out['steady']
        if n == 1:   # one clutch: its figures are the machine's
            assert out['peak_path_clutch_torque'] == out['peak_clutch_torque']
            assert out['path_engaged_fraction'] == out['engaged_fraction']
            assert out['run_peak_path_clutch_torque'] == out['run_peak_clutch_torque']
        else:
            peaks = [result.column(f'clutch_torque_{k}') for k in (1, 2, 3)]
            assert out['run_peak_path_clutch_torque'] == pytest.approx(max(map(np.max, peaks)))
            assert out['peak_path_clutch_torque'] <= out['peak_clutch_torque']
            assert out['path_engaged_fraction'] == pytest.approx(out['engaged_fraction'] / 3,
                                                                 rel=0.02)
