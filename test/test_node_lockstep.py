"""The lockstep protocol (issue 10, docs/lockstep.md): the first sample is latched for early and
late controllers, time advances only by the controller's command (steps_per_command) or ~/step
(step_periods), load commands never advance it, every command is applied in order, runs equal
the offline core to the bit; pause / step / resume, fast mode with /clock, reset.

Nothing here waits on the wall clock for the device's sake: every wait is for a handshake, a
matched subscription or a count of simulation-time samples (the timeouts only end a broken run).
"""
import math
import re
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from node_harness import (
    BEST_EFFORT,
    KEEP_ALL,
    LATCHED,
    NodeProcess,
    Probe,
    diagnostics_values,
    domain_id,
    flood,
    reset_sample,
    ros_env,
    stamp_ns,
    wait_for,
)
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool, Trigger

from cvt_ros.recording.reader import read_messages
from cvt_ros.scene import load_scene
from cvt_ros.solver.output import COL
from cvt_ros.solver.simulator import Simulator

NODE = '/cvt_sim'
DT = 1e-3
MS = 1_000_000
COLUMNS = [COL[c] for c in ('phi1', 'phi2', 'phi3', 'phi4', 'crank_length', 'omega1', 'omega2',
                            'omega3', 'omega4', 'motor_torque', 'clutch_torque',
                            'shaft_torque', 'load_torque')]
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope='module')
def device():
    domain = domain_id()
    probe = Probe(domain)
    try:
        # a controller that is up before the node: subscribed before the node exists
        early = probe.subscribe(JointState, 'state', STATE_QOS)
        joints = probe.subscribe(JointState, 'joint_states', KEEP_ALL)
        diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics')
        crank = probe.publisher(Float64, 'crank_length_cmd')
        load = probe.publisher(Float64, 'load_torque_cmd')
        joint_commands = probe.publisher(JointState, 'joint_commands')
        with NodeProcess(domain, ['-p', 'time_mode:=lockstep']) as proc:
            assert wait_for(lambda: len(early) > 0, 180.0), proc.output()   # (a cold kernel cache)
            assert wait_for(lambda: crank.get_subscription_count() > 0
                            and load.get_subscription_count() > 0
                            and joint_commands.get_subscription_count() > 0
                            and joints.subscription.get_publisher_count() > 0, 10.0)
            yield SimpleNamespace(proc=proc, probe=probe, joints=joints, crank=crank, load=load,
                                  joint_commands=joint_commands, diagnostics=diagnostics,
                                  early=early, domain=domain)
            assert proc.alive(), proc.output()
    finally:
        probe.close()


def row(msg):
    """position (J1..J4, crank_length), velocity (J1..J4), effort (J1..J4) of a sample."""
    return np.array(list(msg.position) + list(msg.velocity[:4]) + list(msg.effort[:4]))


def reset(device):
    """~/reset; returns the index of the t = 0 sample it publishes on joint_states."""
    requested_ns = time.time_ns()
    response = device.probe.call(Trigger, f'{NODE}/reset')
    assert response.success, response.message
    assert response.message.startswith("reset to the scene's initial state: t=0.000000000 s")
    return reset_sample(device.joints, requested_ns, timeout=10.0)


def set_params(device, **values):
    for result in device.probe.set_parameters(NODE, **values):
        assert result.successful, result.reason


def wait_stamp(device, ns, timeout=10.0):
    assert wait_for(lambda: (m := device.joints.last()) is not None and stamp_ns(m) >= ns,
                    timeout), (ns, stamp_ns(device.joints.last()))


def holds_load(device, value):
    """Wait until the node holds load torque ``value``: a ~/pause false reply (it changes
    nothing in lockstep) names the load in force. Two topics, or a topic and a service, have no
    common order, so a test that needs the disturbance before its next command waits for it."""
    assert wait_for(lambda: f"load_torque={value:g} N*m" in device.probe.call(
        SetBool, f'{NODE}/pause', SetBool.Request(data=False)).message, 10.0)


def step(device):
    response = device.probe.call(Trigger, f'{NODE}/step')
    assert response.success, response.message
    return response.message


def test_first_sample_reaches_early_and_late_controllers(device):
    # subscribed before the node started: the t = 0 sample, the scene's initial state
    first = device.early.messages()[0]
    assert stamp_ns(first) == 0
    assert list(first.name) == ['crank', 'rocker', 'clutch_output', 'output_shaft',
                                'crank_length']
    assert first.position[4] == 0.04 and first.velocity[4] == 0.0      # the actuator at rest
    assert first.velocity[0] == 150.0                                   # initial.crank_speed
    assert math.isnan(first.effort[4])                                  # not modelled
    # subscribed now (after the start, before any step): the same latched sample
    late = device.probe.subscribe(JointState, 'state', STATE_QOS)
    try:
        assert wait_for(lambda: len(late) > 0, 10.0)
        assert stamp_ns(late.messages()[0]) == 0
        assert np.array_equal(row(late.messages()[0]), row(first))
    finally:
        device.probe.unsubscribe(late)


def test_time_advances_only_when_stepped(device):
    n0 = reset(device)
    for k in (1, 2, 3):
        assert step(device).startswith(f"t={k * DT:.9f} s")
    wait_stamp(device, 3 * MS)
    # no sample but the stepped ones: had the node advanced by itself, the next sample after
    # another ~/step would not be 4 ms
    assert step(device).startswith(f"t={4 * DT:.9f} s")
    wait_stamp(device, 4 * MS)
    assert [stamp_ns(m) for m in device.joints.messages(n0)] == [0, MS, 2 * MS, 3 * MS, 4 * MS]


def test_step_periods_and_load_commands_that_never_advance_time(device):
    n0 = reset(device)
    set_params(device, step_periods=25)
    try:
        # disturbances: applied at the next period, in arrival order; they do not advance time
        for value in (9.0, 11.0, 12.0):
            device.load.publish(Float64(data=value))
        holds_load(device, 12.0)   # in arrival order: the last one is in force
        message = step(device)
    finally:
        set_params(device, step_periods=1)
    # the response names the load torque in force (the last command), not the parameter (8)
    assert message.startswith(f"t={25 * DT:.9f} s") and 'load_torque=12 N*m' in message, message
    wait_stamp(device, 25 * MS)
    stamps = [stamp_ns(m) for m in device.joints.messages(n0)]
    assert stamps == [k * MS for k in range(26)]
    efforts = [m.effort[3] for m in device.joints.messages(n0)]
    assert efforts[0] == 8.0 + 0.05 * 0.0 and all(
        e == pytest.approx(12.0 + 0.05 * m.velocity[3]) for e, m in
        zip(efforts[1:], device.joints.messages(n0 + 1), strict=True))
    assert not device.probe.set_parameters(NODE, step_periods=0)[0].successful


# A scripted controller: (topic, value); a crank command advances STEPS periods, a load
# command advances nothing and acts from the next period on.
STEPS = 20
SCRIPT = ([('crank', 0.04)] * 15 + [('crank', 0.06)] * 10 + [('load', 12.0)]
          + [('crank', math.nan)] + [('crank', 0.05)] * 10 + [('load', 1e9)]
          + [('crank', 0.05)] * 8)
N_CRANK = sum(1 for topic, _ in SCRIPT if topic == 'crank')
# the same script's crank commands sent on joint_commands (topic_based_ros2_control): the entry
# of joint crank_length is the command, the others are ignored
OTHER_JOINTS = ['crank', 'rocker', 'output_shaft']


def acked(publisher):
    """Delivered to every matched reader: a message published after this one cannot overtake
    it, whatever topic it is on (the node takes the load subscription's messages first)."""
    assert publisher.wait_for_all_acked(Duration(seconds=10))


def joint_command(value, name='crank_length'):
    return JointState(name=OTHER_JOINTS[:2] + [name] + OTHER_JOINTS[2:],
                      position=[1.0, -2.0, value, 3.0])


def run_script(device, on_joint_commands=False):
    n0 = reset(device)
    advanced = 0
    for topic, value in SCRIPT:
        if topic == 'load':
            device.load.publish(Float64(data=value))
            acked(device.load)   # delivered before the next crank command is sent
            continue
        if on_joint_commands:
            device.joint_commands.publish(joint_command(value))
        else:
            device.crank.publish(Float64(data=value))
        advanced += STEPS
        wait_stamp(device, advanced * MS)
    msgs = device.joints.messages(n0)
    assert [stamp_ns(m) for m in msgs] == [k * MS for k in range(N_CRANK * STEPS + 1)]
    return np.array([row(m) for m in msgs])


def run_offline(script=SCRIPT, disturbance=()):
    """The offline core driven as the device drives it: a crank command that changes the set
    point is given (a repeated one changes nothing), refused ones (NaN, beyond
    limits.load_torque) change nothing, and a refused crank command still advances its periods
    with the last valid command; ``disturbance``: (t, load) rows applied at the first period
    k with k·DT >= t."""
    sim = Simulator(load_scene('conveyor'))   # dopri5: the node's solver in lockstep
    rows = [sim.sample()[COLUMNS]]
    target = sim.crank_length_target
    pending = list(disturbance)
    k = 0
    for topic, value in script:
        if topic == 'load':
            if abs(value) <= 1000.0:
                sim.set_load_torque(value)
            continue
        if math.isfinite(value) and value != target:
            sim.command_crank_length(value)
            target = value
        for _ in range(STEPS):
            due = [load for t, load in pending if t <= k * DT]
            if due:
                sim.set_load_torque(due[-1])
                pending = pending[len(due):]
            sim.advance(DT)
            k += 1
            rows.append(sim.sample()[COLUMNS])
    return np.array(rows)


def test_lockstep_controller_run_is_reproducible_to_the_bit(device):
    set_params(device, steps_per_command=STEPS)
    try:
        first = run_script(device)
        second = run_script(device)     # after ~/reset: the same run again
        # topic_based_ros2_control's joint_commands: the same commands, the same run
        third = run_script(device, on_joint_commands=True)
    finally:
        set_params(device, steps_per_command=0)
    assert np.array_equal(first, second)
    assert np.array_equal(first, third)
    # and it is the offline core's run: same scene, same step, commands at the same steps
    offline = run_offline()
    assert np.array_equal(first, offline), np.abs(first - offline).max()
    # the crank step did move the output, and the actuator joint shows the actual length
    assert first[-1, 8] > first[15 * STEPS, 8]
    # (rate-limited to 10 mm/s: still on its way up at the end, short of the 0.05 m target)
    assert 0.04 < first[15 * STEPS + 1, 4] < first[25 * STEPS, 4] < first[-1, 4] < 0.05


def test_the_docs_controller_runs_as_written(device, tmp_path):
    """docs/lockstep.md's minimal rclpy controller, copied from the page and started in its own
    process (after the node: it gets the latched sample): it drives the device to t = 5 s, one
    command per sample, and its run is the offline core's with the same PI law, to the bit."""
    page = (Path(__file__).resolve().parent.parent / 'docs' / 'lockstep.md').read_text()
    (block,) = re.findall(r'^```python\n(.*?)^```', page, re.S | re.M)
    script = tmp_path / 'speed_controller.py'
    script.write_text(block)
    # the samples from the node's own recording: the controller, unpaced, runs ahead of this
    # test's probe, whose joint_states reader (the node keeps the last 10 for it) can fall
    # behind on a loaded machine and lose some; the recording has every one the node published
    recording = tmp_path / 'docs_controller.mcap'
    set_params(device, **{'record.path': str(recording)})
    reset(device)
    set_params(device, steps_per_command=1)
    try:
        proc = subprocess.run([sys.executable, str(script)], env=ros_env(device.domain),
                              capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        wait_stamp(device, 5000 * MS)
    finally:
        set_params(device, steps_per_command=0, **{'record.path': ''})   # (closes the file)
    recorded = [deserialize_message(m.data, JointState)
                for m in read_messages(recording, ['/joint_states'])]
    msgs = recorded[max(i for i, m in enumerate(recorded) if stamp_ns(m) == 0):]   # the reset's
    # one period per sample it received: t = 0 … 5 s (its command at 5 s advances one more)
    assert [stamp_ns(m) for m in msgs][:5001] == [k * MS for k in range(5001)]
    node = np.array([row(m) for m in msgs[:5001]])
    # the same law offline: the sample at t gives the command that makes the sample at t + dt
    target, kp, ki = (float(x) for x in re.search(
        r'TARGET, KP, KI, DT = ([\d.e-]+), ([\d.e-]+), ([\d.e-]+)', block).groups())
    sim = Simulator(load_scene('conveyor'))   # dopri5: the node's solver in lockstep
    rows, integral = [sim.sample()[COLUMNS]], 0.0
    for _ in range(5000):
        error = target - rows[-1][8]
        integral += error * DT
        crank = min(max(0.04 + kp * error + ki * integral, 0.0), 0.09)
        if crank != sim.crank_length_target:
            sim.command_crank_length(crank)
        sim.advance(DT)
        rows.append(sim.sample()[COLUMNS])
    assert np.array_equal(node, np.array(rows)), np.abs(node - np.array(rows)).max()
    assert abs(node[-1, 8] - target) < abs(node[0, 8] - target)   # it does control the speed


def test_disturbance_file_lands_in_its_period(device, tmp_path):
    """disturbance.file: load steps given up front land at the first period with k·DT >= t,
    whatever the timing of the controller's commands — the run equals the offline core's with
    the loads applied at those periods, to the bit."""
    rows = [(0.0, 8.0), (0.1, 11.0), (0.2105, 14.0), (0.45, 9.5)]
    path = tmp_path / 'disturbance.csv'
    path.write_text('t,load_torque\n' + ''.join(f'{t!r},{m!r}\n' for t, m in rows))
    script = [('crank', 0.04)] * 5 + [('crank', 0.06)] * 20
    set_params(device, steps_per_command=STEPS, **{'disturbance.file': str(path)})
    try:
        n0 = reset(device)   # the schedule starts at t = 0
        for k, (_, value) in enumerate(script, start=1):
            device.crank.publish(Float64(data=value))
            wait_stamp(device, k * STEPS * MS)
        got = np.array([row(m) for m in device.joints.messages(n0)])
    finally:
        set_params(device, steps_per_command=0, **{'disturbance.file': ''})
    offline = run_offline(script, rows)
    assert np.array_equal(got, offline), np.abs(got - offline).max()
    # the load torque (effort of the output shaft: M + viscous·ω4) follows the schedule
    k_step = 211   # 0.2105 s: the first period that starts at or after it
    assert got[k_step, 12] == pytest.approx(11.0 + 0.05 * got[k_step, 8])
    assert got[k_step + 1, 12] == pytest.approx(14.0 + 0.05 * got[k_step + 1, 8])


def test_bad_disturbance_files_and_joint_commands_are_refused_with_the_reason(device, tmp_path):
    bad = tmp_path / 'bad.csv'
    for text, reason in (('t,load_torque\n0,8\n0,9\n', 'does not increase'),
                         ('0,nan\n', 'not a finite number'),
                         ('0,2e3\n', 'beyond the limit |M| <= 1000.0 N*m'),
                         ('0;8\n', 'expected 2 fields')):
        bad.write_text(text)
        result = device.probe.set_parameters(NODE, **{'disturbance.file': str(bad)})[0]
        assert not result.successful
        assert str(bad) in result.reason and reason in result.reason, result.reason
    result = device.probe.set_parameters(NODE, **{'disturbance.file': str(tmp_path / 'no')})[0]
    assert not result.successful and 'cannot read' in result.reason
    # joint_commands without the crank_length joint, or with a bad value: refused, the
    # period goes on with the last valid command (as on crank_length_cmd)
    n0 = reset(device)
    set_params(device, steps_per_command=1)
    try:
        for msg in (joint_command(math.nan), joint_command(0.05, name='crank_len'),
                    joint_command(0.2), JointState(name=['crank_length'], position=[])):
            device.joint_commands.publish(msg)
            acked(device.joint_commands)
        wait_stamp(device, 4 * MS)
        # bytes that are not a Float64 on crank_length_cmd (the node takes commands raw)
        device.crank.publish(b'\x00\x01\x00\x00\x00\x00\x00\x00')   # (DDS pads to 4)
        wait_stamp(device, 5 * MS)
    finally:
        set_params(device, steps_per_command=0)
    msgs = device.joints.messages(n0)
    assert [stamp_ns(m) for m in msgs] == [k * MS for k in range(6)]
    assert all(m.position[4] == 0.04 and m.velocity[4] == 0.0 for m in msgs)
    # each reason is logged (a repeated one at most once a second), naming value and limit
    for text in ('refused joint_commands crank_length = nan m: not a finite number',
                 "refused joint_commands = names [crank, rocker, crank_len, output_shaft]: no "
                 "joint 'crank_length'",
                 'refused joint_commands crank_length = 0.2 m: outside the Grashof range; '
                 'limit [0, 0.1) m',
                 "refused joint_commands = 0 positions: no position for joint 'crank_length'",
                 'refused crank_length_cmd = 8 bytes: 8 bytes are not a std_msgs/Float64'):
        assert wait_for(lambda text=text: text in device.proc.output(), 10.0), \
            (text, device.proc.output()[-2000:])


def test_every_command_is_applied_in_order(device):
    """2000 crank commands published as fast as one process can, 1 period each (issue 14),
    from a publisher that keeps them all until delivered: every one advances its own period,
    in order, none is lost or dropped. (A publisher with a shorter history than its backlog
    loses commands on its own side; the node counts those from the sequence gaps,
    commands_lost, docs/lockstep.md.)"""
    def counts():
        d = device.diagnostics.last()
        if d is None:
            return None
        v = diagnostics_values(d)
        return int(v['commands_received']), int(v['commands_lost']), int(v['commands_dropped'])
    n0 = reset(device)
    set_params(device, steps_per_command=1)
    # a report made after everything before this test was handled (reports come ~1 Hz)
    n_diag = len(device.diagnostics)
    assert wait_for(lambda: len(device.diagnostics) >= n_diag + 2, 10.0)
    received0, lost0, _ = counts()
    try:
        values = [0.04 + 1e-5 * (k % 7) for k in range(2000)]
        flooder = flood(device.domain, 'crank_length_cmd', 1e6, 2000 / 1e6, values, keep_all=True)
        out, _ = flooder.communicate(timeout=60)
        assert int(out.split('\n')[-2].split()[0]) == 2000, out   # (DDS may log above it)
        assert wait_for(lambda: counts()[0] - received0 == 2000, 30.0), counts()
        received = counts()[0] - received0
        # the node's time: one period per command, none skipped or doubled (the latched state
        # topic ends on the latest sample, whatever a burst did to the samples before it)
        assert wait_for(lambda: stamp_ns(device.early.last()) >= received * MS, 60.0)
        assert stamp_ns(device.early.last()) == received * MS
    finally:
        set_params(device, steps_per_command=0)
    assert counts()[1:] == (lost0, 0)
    # what the probe received of the burst (2000 samples in ~0.1 s from a writer that keeps 10:
    # a subscriber starved on a busy machine may lose some in DDS): in order, whole periods
    stamps = np.array([stamp_ns(m) for m in device.joints.messages(n0)])
    assert stamps[0] == 0 and stamps[-1] <= received * MS
    assert np.all(np.diff(stamps) > 0) and np.all(stamps % MS == 0)


def test_pause_step_and_resume_in_realtime(device):
    probe, joints = device.probe, device.joints
    reset(device)
    set_params(device, time_mode='realtime')
    try:
        n0 = len(joints)
        assert wait_for(lambda: len(joints) >= n0 + 100, 10.0)
        paused = probe.call(SetBool, f'{NODE}/pause', SetBool.Request(data=True))
        assert paused.success, paused.message
        # the response names the time it holds at; that sample is the last one published
        held_ns = round(float(paused.message.split('t=')[1].split()[0]) * 1e9)
        wait_stamp(device, held_ns)
        n_held = len(joints)
        assert step(device).startswith(f"t={(held_ns + MS) * 1e-9:.9f} s")
        wait_stamp(device, held_ns + MS)
        assert stamp_ns(joints.messages(n_held)[0]) == held_ns + MS
        assert len(joints) == n_held + 1
        resumed = probe.call(SetBool, f'{NODE}/pause', SetBool.Request(data=False))
        assert resumed.success, resumed.message
        assert wait_for(lambda: len(joints) >= n_held + 100, 10.0)
        # one sample per control period throughout: no gap, no repeat across pause/step/resume
        stamps = np.array([stamp_ns(m) for m in joints.messages(n0)])
        assert np.all(np.diff(stamps) == MS)
    finally:
        set_params(device, time_mode='lockstep')


def test_fast_mode_publishes_clock_and_sim_time_follows(device):
    probe = device.probe
    reset(device)
    # fast mode publishes thousands of samples per second: a keep-all Python subscriber would
    # take seconds to work through them (and hold up the probe's service calls) — listen to
    # /clock only while it runs
    probe.unsubscribe(device.joints)
    clock = probe.subscribe(Clock, '/clock', BEST_EFFORT)
    consumer = Node('sim_time_consumer', context=probe.context,
                    parameter_overrides=[Parameter('use_sim_time', value=True)])
    probe.executor.add_node(consumer)
    try:
        set_params(device, time_mode='fast')
        # two simulated seconds pass without a single ~/step: the node runs by itself
        assert wait_for(lambda: (c := clock.last()) is not None and c.clock.sec >= 2, 30.0)
        # a node with use_sim_time follows /clock
        assert wait_for(lambda: consumer.get_clock().now().nanoseconds >= 2_000_000_000, 10.0)
        assert wait_for(lambda: (d := device.diagnostics.last()) is not None
                        and diagnostics_values(d)['time_mode'] == 'fast', 5.0)
    finally:
        set_params(device, time_mode='lockstep')
        probe.executor.remove_node(consumer)
        consumer.destroy_node()
        probe.unsubscribe(clock)
        device.joints = probe.subscribe(JointState, 'joint_states', KEEP_ALL)
        # matched on both sides (the node's writer learns of a new reader some ms after the
        # reader sees the writer): a sample stepped now reaches it
        assert wait_for(lambda: step(device) and wait_for(lambda: len(device.joints), 0.5),
                        30.0)
    ticks = [m.clock.sec * 10**9 + m.clock.nanosec for m in clock.messages()]
    assert ticks == sorted(ticks)
    reset(device)


def test_reset_returns_to_the_initial_state_and_latches_it(device):
    n0 = reset(device)
    initial = row(device.joints.messages(n0)[0])
    for _ in range(5):
        step(device)
    wait_stamp(device, 5 * MS)
    n1 = reset(device)
    assert np.array_equal(row(device.joints.messages(n1)[0]), initial)
    # a controller that joins now gets the reset state, not the old run's last sample
    late = device.probe.subscribe(JointState, 'state', STATE_QOS)
    try:
        assert wait_for(lambda: len(late) > 0, 10.0)
        assert stamp_ns(late.messages()[0]) == 0
    finally:
        device.probe.unsubscribe(late)
    # the clutch state is latched as well
    clutch = device.probe.subscribe(Bool, 'clutch_engaged', LATCHED)
    try:
        assert wait_for(lambda: len(clutch) > 0, 10.0)
    finally:
        device.probe.unsubscribe(clutch)
