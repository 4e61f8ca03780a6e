"""The dds back end against cvt_node in its own process: the same answer as offline, an external
controller process, the pytest fixture's held domain, and the realtime rehearsal. Every wait is
on a matched publisher or on a sample's simulation time (never on the wall clock)."""
import sys

import numpy as np
import pytest

from cvt_ros.scenario import load_scenario, run_scenario
from cvt_ros.solver.output import COL
from cvt_ros.testing import DeviceUnderTest

JOINT_COLUMNS = ('phi1', 'phi2', 'phi3', 'phi4', 'omega1', 'omega2', 'omega3', 'omega4',
                 'clutch_torque', 'crank_length', 'motor_torque', 'shaft_torque', 'load_torque')


@pytest.fixture(scope='module')
def steps():
    sc = load_scenario('conveyor_setpoint_steps', {'duration': 3.0})
    return sc, run_scenario(sc, backend='offline')


def close_to(run, offline, rtol):
    assert len(run.t) == len(offline.t)
    assert np.allclose(run.t, offline.t, rtol=0, atol=1e-9)
    for c in JOINT_COLUMNS:
        a, b = run.column(c), offline.column(c)
        scale = np.max(np.abs(b)) + 1e-12
        assert np.max(np.abs(a - b)) <= rtol * scale, c


@pytest.mark.parametrize('name', ['conveyor_setpoint_steps', 'conveyor_load_step'])
def test_dds_lockstep_is_bit_identical_to_offline(name):
    sc = load_scenario(name, {'duration': 5.0})
    offline = run_scenario(sc, backend='offline')
    run = run_scenario(sc, backend='dds')
    assert run.ok, run.error
    assert run.backend == 'dds'
    close_to(run, offline, 0.0)                   # every joint value, to the bit
    assert np.array_equal(run.t, offline.t)       # the times too: both are the stamps' whole ns
    assert np.array_equal(run.commands, offline.commands, equal_nan=True)
    assert [e for _, e in run.switches] == [e for _, e in offline.switches]
    # at their own times (the node's recording: a stamp's whole ns), not at the sample after
    assert np.allclose([t for t, _ in run.switches], [t for t, _ in offline.switches],
                       rtol=0, atol=1e-9)
    assert f'on ROS domain {run.domain}' in run.summary_line()
    # so every metric is the same number
    assert list(run.metrics) == list(offline.metrics)
    for key, value in offline.metrics.items():
        got = run.metrics[key]
        assert got == value or (value != value and got != got), key


def test_dds_lockstep_with_four_paths_is_bit_identical_to_offline():
    """Issue 33: cvt_node simulating the 4-path conveyor, its rockers read from state and each
    clutch's switches from clutch_states (the node's recording): every column the messages
    carry — each path's rocker, clutch torque and state included — to the bit."""
    sc = load_scenario('conveyor_4path_setpoint_steps', {'duration': 2.5})
    offline = run_scenario(sc, backend='offline')
    run = run_scenario(sc, backend='dds')
    assert run.ok, run.error
    close_to(run, offline, 0.0)
    per_path = slice(len(COL), None)   # phi2_k, omega2_k, engaged_k, clutch_torque_k
    assert run.samples.shape == offline.samples.shape
    assert np.array_equal(run.samples[:, per_path], offline.samples[:, per_path])
    assert np.array_equal(run.column('engaged'), offline.column('engaged'))
    assert np.array_equal(run.commands, offline.commands, equal_nan=True)
    assert [s[1:] for s in run.switches] == [s[1:] for s in offline.switches]
    assert np.allclose([s[0] for s in run.switches], [s[0] for s in offline.switches],
                       rtol=0, atol=1e-9)
    for key, value in offline.metrics.items():
        assert run.metrics[key] == value or (value != value and run.metrics[key] != value), key


def test_external_controller_process(steps):
    sc, offline = steps
    cmd = f"{sys.executable} -m cvt_ros.control.node"
    run = run_scenario(sc, backend='dds', controller_cmd=cmd)
    assert run.ok, run.error
    assert run.controller == cmd
    close_to(run, offline, 1e-5)
    # the node answered every sample; its commands are the law's once per turn and the one in
    # force in between
    assert np.isfinite(run.commands[:-1]).all()
    turns = np.isfinite(offline.commands)
    assert np.allclose(run.commands[turns], offline.commands[turns], rtol=1e-6)


def test_fixture_device_holds_a_domain_of_its_own():
    with DeviceUnderTest('dds') as device:
        domain = device.domain
        assert 21 <= domain <= 101
        from cvt_ros.device import domains
        assert domains.try_acquire(domain) is None          # held while the device lives
        run = device.run('conveyor_load_step', duration=1.0)
        assert run.ok and run.backend == 'dds' and len(run.t) == 1001
    lease = domains.try_acquire(domain)
    assert lease is not None
    lease.release()


def test_realtime_rehearsal_records_every_period(tmp_path):
    sc = load_scenario('conveyor_load_step', {'duration': 1.5})
    run = run_scenario(sc, backend='dds', realtime=1.0)
    assert run.ok, run.error
    assert 'dds, realtime 1x' in run.summary_line() and run.to_dict()['realtime'] == 1.0
    # the node's timing against the wall clock: in the table, the JSON and the MCAP
    timing = run.to_dict()['node_timing']
    assert timing['missed_deadlines'] >= 0 and timing['jitter_max_us'] >= timing['jitter_p50_us']
    assert 'missed deadlines' in run.format_table() and run.diagnostics
    from cvt_ros.recording import summary
    from cvt_ros.scenario.recording import write_mcap
    count, error = write_mcap(run, tmp_path / 'rt.mcap')
    assert error is None and summary(tmp_path / 'rt.mcap').topics['/diagnostics'].message_count
    assert len(run.t) == sc.periods + 1                       # from the node's own recording
    assert np.allclose(np.diff(run.t), sc.control_period)
    assert np.isfinite(run.commands).sum() > 10               # the law acted once per turn
    assert run.column('crank_length')[-1] != run.column('crank_length')[0]
    assert len(run.switches) == pytest.approx(sc.duration * 54, rel=0.3)
    assert np.all(np.isfinite(run.samples[:, COL['omega4']]))


def test_topic_based_ros2_control_convention():
    """A JointState on joint_commands (as topic_based_ros2_control's TopicBasedSystem sends it:
    every command joint, crank_length among them) steps the device like crank_length_cmd; the
    state comes back with the crank_length joint. Checked against the offline core given the
    command, to the bit."""
    from sensor_msgs.msg import JointState

    from cvt_ros import interface
    from cvt_ros.scenario.dds import DdsPlant
    from cvt_ros.scenario.plants import OfflinePlant, plant_values
    sc = load_scenario('conveyor_load_step', {'duration': 1.0})
    offline = OfflinePlant(plant_values(sc), sc.control_period)
    offline.start()
    plant = DdsPlant(sc)
    try:
        plant.start()
        publisher = plant.node.create_publisher(JointState, interface.JOINT_COMMANDS,
                                                interface.command_qos())
        plant._spin_until(lambda: publisher.get_subscription_count() > 0, 60,
                          'joint_commands subscription')
        for k in range(60):
            # as TopicBasedSystem sends it: every joint named, a position only for the joint
            # with a position command interface (crank_length, listed anywhere); or one each
            msg = JointState(name=['output_shaft', 'crank_length'], position=[0.0, 0.05]) \
                if k % 2 else JointState(name=['output_shaft', 'crank', 'crank_length'],
                                         position=[0.05])
            publisher.publish(msg)
            row, _ = plant._next_sample()
            if k == 0:   # given again, the set point in force changes nothing (no re-plan)
                offline.command_crank_length(0.05)
            expect, _ = offline.step()
            for c in JOINT_COLUMNS:
                assert row[COL[c]] == expect[COL[c]], (k, c)
        assert row[COL['crank_length']] > 0.04                       # the actuator moves
    finally:
        plant.close()


def test_the_node_gets_the_domain_of_ros_domain_id_when_it_is_free(monkeypatch):
    """`ROS_DOMAIN_ID=42 cvt-sim scenario run ... --backend dds` and `ros2 topic echo` in the
    same shell see the same node; a domain another run holds is not shared."""
    from cvt_ros.device import domains
    from cvt_ros.scenario.dds import lease_domain
    free = domains.acquire()
    wanted = free.domain
    free.release()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(wanted))
    with lease_domain() as lease:
        assert lease.domain == wanted
        with lease_domain() as other:                 # held: another one, not shared
            assert other.domain != wanted
