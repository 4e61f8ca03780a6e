"""The node simulating an N-path machine (issue 33): joint_states with one rocker per path,
clutch_states (each clutch), clutch_engaged as "any clutch engaged", /diagnostics per path, the
recording analysed per path, all equal to the offline core's run to the bit; ``paths.count``
refused on the running node with the reason, through the real ``ros2 param set``.

One node for the module (conveyor_4path, lockstep): nothing waits on the wall clock for the
device's sake — a ~/step call advances the periods, and every wait is for a sample's
simulation time or a matched subscription (the timeouts only end a broken run).
"""
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from node_harness import (
    KEEP_ALL,
    LATCHED,
    SCENES,
    NodeProcess,
    Probe,
    diagnostics_values,
    domain_id,
    ros_env,
    stamp_ns,
    wait_for,
)
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from cvt_ros import interface as I
from cvt_ros.analysis.analyze import analyze_trace
from cvt_ros.analysis.inputs import load
from cvt_ros.analysis.trace import trace_of_samples
from cvt_ros.device.core import Device
from cvt_ros.device.descriptors import node_values
from cvt_ros.solver.output import COL, N_COLUMNS, path_columns

NODE = '/cvt_sim'
PERIODS = 300          # one ~/step: 0.3 s, through the locked-crank start-up and handoffs
MS = 1_000_000
ROS2 = Path(sys.prefix) / 'bin' / 'ros2'
SCENE = str(Path(SCENES) / 'conveyor_4path.yaml')


@pytest.fixture(scope='module')
def node(tmp_path_factory):
    domain = domain_id()
    recording = tmp_path_factory.mktemp('paths') / 'run.mcap'
    probe = Probe(domain)
    try:
        state = probe.subscribe(JointState, 'state', LATCHED)
        joints = probe.subscribe(JointState, 'joint_states', KEEP_ALL)
        clutches = probe.subscribe(JointState, 'clutch_states', LATCHED)
        engaged = probe.subscribe(Bool, 'clutch_engaged', LATCHED)
        diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics')
        args = ['--params-file', SCENE, '-p', 'time_mode:=lockstep',
                '-p', f'step_periods:={PERIODS}', '-p', f'record.path:={recording}']
        with NodeProcess(domain, args) as proc:
            assert wait_for(lambda: len(state) > 0 and len(clutches) > 0, 180.0), proc.output()
            assert wait_for(lambda: joints.subscription.get_publisher_count() > 0, 10.0)
            response = probe.call(Trigger, f'{NODE}/step', timeout=60.0)
            assert response.success, response.message
            assert wait_for(lambda: (m := joints.last()) is not None
                            and stamp_ns(m) == PERIODS * MS, 60.0), proc.output()
            # every clutch_states and clutch_engaged message of the run, before the analysis
            # reads them (two topics have no common order with joint_states)
            assert wait_for(lambda: any(stamp_ns(m) == PERIODS * MS
                                        for m in clutches.messages()), 30.0)
            yield SimpleNamespace(proc=proc, probe=probe, state=state, joints=joints,
                                  clutches=clutches, engaged=engaged, diagnostics=diagnostics,
                                  domain=domain, recording=recording)
    finally:
        probe.close()


@pytest.fixture(scope='module')
def offline():
    """The same periods on the device core in this process (what the node runs)."""
    device = Device(node_values(SCENE, {'time_mode': 'lockstep'}), 1e-3)
    rows, changes = [device.present_state().row.copy()], []
    mask0 = device.engaged_set
    for _ in range(PERIODS):
        rows.append(device.advance_row().copy())
        changes += device.events
    return SimpleNamespace(rows=np.array(rows), changes=changes, mask0=mask0,
                           values=device.values, sim=device.sim)


def arrays(msg):
    return np.array(list(msg.position) + list(msg.velocity) + list(msg.effort))


def test_joint_states_carry_every_rocker_to_the_bit(node, offline):
    layout = I.SampleLayout(4)
    # the t = 0 sample may have gone out before the probe's joint_states matched: latched on
    # state (every later one on joint_states: the node waits for ~/step)
    messages = node.joints.messages()
    if not messages or stamp_ns(messages[0]) != 0:
        messages = node.state.messages()[:1] + messages
    assert [stamp_ns(m) for m in messages] == [k * MS for k in range(PERIODS + 1)]
    assert list(messages[0].name) == ['crank', 'rocker_1', 'rocker_2', 'rocker_3', 'rocker_4',
                                      'clutch_output', 'output_shaft', 'crank_length']
    for msg, row in zip(messages, offline.rows, strict=True):
        expected = layout.joint_values(row, 0.0)
        got = arrays(msg)
        rate = layout.rate_slot
        assert np.array_equal(np.delete(got, [rate, layout.force_slot]),
                              np.delete(np.array(expected), [rate, layout.force_slot]))
    # each rocker's effort is its clutch's torque: their sum is the one-path clutch_torque
    last = messages[-1]
    assert sum(last.effort[1:5]) == pytest.approx(offline.rows[-1][COL['clutch_torque']],
                                                  rel=1e-12)
    # an older controller's view: J1..J4 with path 1's rocker as 'rocker'
    assert I.joint_order(list(last.name)) == [0, 1, 5, 6]


def test_clutch_states_each_clutch_per_period_and_at_each_switch(node, offline):
    names = ['clutch_1', 'clutch_2', 'clutch_3', 'clutch_4']
    messages = node.clutches.messages()
    periodic = [m for m in messages if len(m.velocity)]
    switches = [m for m in messages if not len(m.velocity)]
    assert all(list(m.name) == names for m in messages)
    assert [stamp_ns(m) for m in periodic] == [k * MS for k in range(PERIODS + 1)]
    for msg, row in zip(periodic, offline.rows, strict=True):
        n0 = N_COLUMNS
        assert list(msg.position) == list(row[n0 + 8:n0 + 12])            # engaged_k
        assert list(msg.effort) == list(row[n0 + 12:n0 + 16])             # clutch_torque_k
        assert list(msg.velocity) == [w - row[COL['omega3']] for w in row[n0 + 4:n0 + 8]]
    # one message at t = 0 (the set in force), then one per switching instant, at its time
    assert stamp_ns(switches[0]) == 0
    assert [(stamp_ns(m), [int(p) for p in m.position]) for m in switches[1:]] == [
        (I.stamp_ns(c.t), [c.after >> k & 1 for k in range(4)]) for c in offline.changes]
    assert len(offline.changes) >= 8 and any(len(c.switches) == 2 for c in offline.changes)


def test_clutch_engaged_is_any_clutch_and_changes_only_when_that_does(node, offline):
    states = [m.data for m in node.engaged.messages()]
    expected = [offline.mask0 != 0] + [c.engaged for c in offline.changes if c.any_changed]
    assert states == expected
    assert len(expected) < len(offline.changes) + 1   # handoffs are no switch of "any"


def test_diagnostics_name_the_paths(node, offline):
    def per_path(values):
        return values if values.get('switches_per_path') == ','.join(
            str(c) for c in offline.sim.path_switch_counts) else None
    values = wait_for(lambda: any(per_path(diagnostics_values(m))
                                  for m in node.diagnostics.messages()), 30.0)
    assert values, [diagnostics_values(m) for m in node.diagnostics.messages()[-1:]]
    last = next(v for v in map(diagnostics_values, reversed(node.diagnostics.messages()))
                if per_path(v))
    mask = offline.sim.engaged_set
    assert last['paths'] == '4'
    assert last['clutches_engaged'] == (','.join(str(k + 1) for k in range(4) if mask >> k & 1)
                                        or 'none')
    assert last['clutch_engaged'] == str(mask != 0).lower()


def _ros2_param_set(domain, name, value):
    for _ in range(3):   # a new participant may miss the parameter services in its fixed 5 s
        out = subprocess.run([sys.executable, str(ROS2), 'param', 'set', NODE, name, value,
                              '--timeout', '60'], env=ros_env(domain), text=True,
                             capture_output=True, timeout=120)
        text = out.stdout + out.stderr
        if 'Wait for service timed out' not in text:
            return text
    return text


@pytest.mark.skipif(not ROS2.exists(), reason=f"no ros2 command in {ROS2.parent}")
def test_ros2_param_set_paths_count_is_refused_with_the_reason(node):
    out = _ros2_param_set(node.domain, 'paths.count', '2')
    assert "Setting parameter failed: paths.count: 2 refused: the paths are the machine's build" \
        in out, out
    assert 'Start it again with the new value' in out and 'Traceback' not in out, out
    out = _ros2_param_set(node.domain, 'paths.phase_offsets', '[0.0, 1.0, 2.0, 3.0]')
    assert 'paths.phase_offsets: [0.0, 1.0, 2.0, 3.0] refused' in out, out
    assert node.probe.get_parameters(NODE, ['paths.count'])['paths.count'] == 4
    assert node.proc.alive(), node.proc.output()


def test_the_recording_is_analysed_per_path(node, offline):
    node.proc.stop()   # SIGINT finishes the file
    traces, info = load(str(node.recording))
    assert not info.problems and len(traces) == 1
    recorded = analyze_trace(traces[0])
    own = trace_of_samples(offline.rows, path_columns(4), [
        s for c in offline.changes for s in c.switches], source='offline', kind='run',
        parameters=dict(offline.values))
    direct = analyze_trace(own)
    assert [p['switches'] for p in recorded.paths['whole_run']] == \
        [p['switches'] for p in direct.paths['whole_run']] == list(
            map(float, offline.sim.path_switch_counts))
    for got, want in zip(recorded.paths['whole_run'], direct.paths['whole_run'], strict=True):
        assert got['clutch_torque_peak'] == want['clutch_torque_peak']
        # switch times: the recording's are whole nanoseconds
        assert got['engaged_fraction'] == pytest.approx(want['engaged_fraction'], abs=1e-8)
    assert recorded.whole_run['engaged_fraction'] == pytest.approx(
        direct.whole_run['engaged_fraction'], abs=1e-8)
    assert recorded.energy['relative_residual'] < 1e-3
