"""Deterministic timing modes (issue 3): lockstep (~/step, steps_per_command), pause / step /
reset, and fast mode with /clock for use_sim_time consumers. One node, started in lockstep mode."""
import math
import time
from types import SimpleNamespace

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from node_harness import (
    BEST_EFFORT,
    NodeProcess,
    Probe,
    diagnostics_values,
    domain_id,
    stamp_ns,
    wait_for,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from cvt_ros.scene import load_scene
from cvt_ros.solver.output import COL
from cvt_ros.solver.simulator import Simulator

NODE = '/cvt_sim'
DT = 1e-3
MS = 1_000_000
COLUMNS = [COL[c] for c in ('phi1', 'phi2', 'phi3', 'phi4', 'omega1', 'omega2', 'omega3',
                            'omega4', 'motor_torque', 'clutch_torque', 'shaft_torque',
                            'load_torque')]


@pytest.fixture(scope='module')
def device():
    domain = domain_id()
    with NodeProcess(domain, ['-p', 'time_mode:=lockstep']) as proc:
        probe = Probe(domain)
        try:
            joints = probe.subscribe(JointState, 'joint_states')
            diagnostics = probe.subscribe(DiagnosticArray, '/diagnostics')
            # the t = 0 sample went out before this probe matched: ~/reset publishes one again
            assert wait_for(lambda: joints.subscription.get_publisher_count() > 0, 30.0), \
                proc.output()
            crank = probe.publisher(Float64, 'crank_length_cmd')
            load = probe.publisher(Float64, 'load_torque_cmd')
            assert wait_for(lambda: crank.get_subscription_count() > 0
                            and load.get_subscription_count() > 0, 10.0)
            yield SimpleNamespace(proc=proc, probe=probe, joints=joints, crank=crank, load=load,
                                  diagnostics=diagnostics)
        finally:
            probe.close()
        assert proc.alive(), proc.output()


def row(msg):
    return np.array(list(msg.position) + list(msg.velocity) + list(msg.effort))


def reset(device):
    """~/reset; returns the index of the t = 0 sample it publishes."""
    n = len(device.joints)
    response = device.probe.call(Trigger, f'{NODE}/reset')
    assert response.success, response.message
    index = wait_for(lambda: next((n + i + 1 for i, m in enumerate(device.joints.messages(n))
                                   if stamp_ns(m) == 0), None), 5.0)
    assert index, 'no t = 0 sample after ~/reset'
    return index - 1


def set_params(device, **values):
    for result in device.probe.set_parameters(NODE, **values):
        assert result.successful, result.reason


def wait_stamp(device, ns, timeout=5.0):
    assert wait_for(lambda: (m := device.joints.last()) is not None and stamp_ns(m) >= ns,
                    timeout), (ns, stamp_ns(device.joints.last()))


def test_lockstep_holds_until_stepped(device):
    n0 = reset(device)
    # the only "wait and see nothing" in these tests: lockstep must not advance by itself
    time.sleep(0.3)
    assert [stamp_ns(m) for m in device.joints.messages(n0)] == [0]


def test_step_advances_exactly_one_control_period(device):
    n0 = reset(device)
    for k in (1, 2, 3):
        response = device.probe.call(Trigger, f'{NODE}/step')
        assert response.success, response.message
        assert response.message.startswith(f"t={k * DT:.9f} s")
    wait_stamp(device, 3 * MS)
    assert [stamp_ns(m) for m in device.joints.messages(n0)] == [0, MS, 2 * MS, 3 * MS]


# A scripted controller: (topic, value) per command; each advances STEPS control periods.
STEPS = 20
SCRIPT = ([('crank', 0.04)] * 15 + [('crank', 0.06)] * 10 + [('load', 12.0)] * 5
          + [('crank', math.nan)] + [('crank', 0.05)] * 10 + [('load', 1e9)]
          + [('crank', 0.05)] * 8)


def run_script(device):
    n0 = reset(device)
    for i, (topic, value) in enumerate(SCRIPT, start=1):
        (device.crank if topic == 'crank' else device.load).publish(Float64(data=value))
        wait_stamp(device, i * STEPS * MS)
    msgs = device.joints.messages(n0)
    assert [stamp_ns(m) for m in msgs] == [k * MS for k in range(len(SCRIPT) * STEPS + 1)]
    return np.array([row(m) for m in msgs])


def run_offline():
    sim = Simulator(load_scene('conveyor', {'solver.method': 'rk4'}))
    rows = [sim.sample()[COLUMNS]]
    for topic, value in SCRIPT:
        # refused commands (NaN, beyond limits.load_torque) still grant their steps; the last
        # valid command stays
        if topic == 'crank' and math.isfinite(value):
            sim.command_crank_length(value)
        elif topic == 'load' and abs(value) <= 1000.0:
            sim.set_load_torque(value)
        for _ in range(STEPS):
            sim.advance(DT)
            rows.append(sim.sample()[COLUMNS])
    return np.array(rows)


def test_lockstep_controller_run_is_reproducible_to_the_bit(device):
    set_params(device, steps_per_command=STEPS)
    try:
        first = run_script(device)
        second = run_script(device)     # after ~/reset: the same run again
    finally:
        set_params(device, steps_per_command=0)
    assert np.array_equal(first, second)
    # and it is the offline core's run: same scene, same step, commands at the same steps
    offline = run_offline()
    assert np.array_equal(first, offline), np.abs(first - offline).max()
    # the crank step did move the output: the ratio changed
    assert first[-1, 7] > first[15 * STEPS, 7]


def test_pause_step_and_resume_in_realtime(device):
    probe, joints = device.probe, device.joints
    reset(device)
    set_params(device, time_mode='realtime')
    try:
        n0 = len(joints)
        assert wait_for(lambda: len(joints) >= n0 + 100, 5.0)
        paused = probe.call(SetBool, f'{NODE}/pause', SetBool.Request(data=True))
        assert paused.success, paused.message
        # the response names the time it holds at; that sample is the last one published
        held_ns = round(float(paused.message.split('t=')[1].split()[0]) * 1e9)
        wait_stamp(device, held_ns)
        n_held = len(joints)
        stepped = probe.call(Trigger, f'{NODE}/step')
        assert stepped.success, stepped.message
        wait_stamp(device, held_ns + MS)
        assert stamp_ns(joints.messages(n_held)[0]) == held_ns + MS
        assert len(joints) == n_held + 1
        resumed = probe.call(SetBool, f'{NODE}/pause', SetBool.Request(data=False))
        assert resumed.success, resumed.message
        assert wait_for(lambda: len(joints) >= n_held + 100, 5.0)
        # one sample per control period throughout: no gap, no repeat across pause/step/resume
        stamps = np.array([stamp_ns(m) for m in joints.messages(n0)])
        assert np.all(np.diff(stamps) == MS)
    finally:
        set_params(device, time_mode='lockstep')


def test_fast_mode_runs_ahead_of_the_wall_clock_and_sim_time_follows(device):
    probe = device.probe
    reset(device)
    clock = probe.subscribe(Clock, '/clock', BEST_EFFORT)
    consumer = Node('sim_time_consumer', context=probe.context,
                    parameter_overrides=[Parameter('use_sim_time', value=True)])
    probe.executor.add_node(consumer)
    try:
        set_params(device, time_mode='fast')
        assert wait_for(lambda: len(clock) > 10, 5.0)
        t0, first = time.monotonic(), clock.last()
        assert wait_for(lambda: time.monotonic() - t0 > 1.0, 2.0)
        last = clock.last()
        wall = time.monotonic() - t0
        advanced = (last.clock.sec - first.clock.sec) + (last.clock.nanosec
                                                         - first.clock.nanosec) * 1e-9
        # faster than real time by a wide margin (the core alone is ~50x on this machine)
        assert advanced / wall > 3.0, advanced / wall
        # a node with use_sim_time follows /clock
        now = consumer.get_clock().now().nanoseconds * 1e-9
        assert now > 1.0 and abs(now - (last.clock.sec + last.clock.nanosec * 1e-9)) < 1.0
        rate = device.diagnostics
        assert wait_for(lambda: rate.last() is not None
                        and diagnostics_values(rate.last())['time_mode'] == 'fast', 3.0)
    finally:
        set_params(device, time_mode='lockstep')
        probe.executor.remove_node(consumer)
        consumer.destroy_node()
        probe.unsubscribe(clock)
    reset(device)


def test_reset_returns_to_the_initial_state(device):
    n0 = reset(device)
    initial = row(device.joints.messages(n0)[0])
    for _ in range(5):
        assert device.probe.call(Trigger, f'{NODE}/step').success
    wait_stamp(device, 5 * MS)
    n1 = reset(device)
    assert np.array_equal(row(device.joints.messages(n1)[0]), initial)
