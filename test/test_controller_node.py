"""The reference controller's ROS node without DDS traffic: its callbacks fed with the device's
samples (as the core produces them) in a private context; parameters checked and applied."""
import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from cvt_ros.control.node import SpeedControllerNode  # noqa: E402
from cvt_ros.interface import DEVICE_JOINTS, joint_state_from_row  # noqa: E402
from cvt_ros.scene import load_scene  # noqa: E402
from cvt_ros.solver.output import COL  # noqa: E402
from cvt_ros.solver.simulator import Simulator  # noqa: E402


@pytest.fixture
def node(tmp_path):
    ctx = Context()
    rclpy.init(context=ctx, domain_id=0)
    (tmp_path / 'sp.csv').write_text('t,setpoint\n0,55\n0.2,65\n')
    n = SpeedControllerNode(context=ctx, start_parameter_services=False, parameter_overrides=[
        Parameter('setpoint_file', value=str(tmp_path / 'sp.csv'))])
    n.sent = []
    n.crank_length_cmd_publisher.publish = lambda msg: n.sent.append(msg.data)
    n.setpoints = []
    n.setpoint_publisher.publish = lambda msg: n.setpoints.append(msg.data)
    yield n
    n.destroy_node()
    ctx.try_shutdown()


def state_msg(row):
    msg = joint_state_from_row(row)
    msg.name = list(DEVICE_JOINTS)
    msg.position = list(msg.position) + [float(row[COL['crank_length']])]
    msg.velocity = list(msg.velocity) + [0.0]
    msg.effort = list(msg.effort) + [float('nan')]
    return msg


def drive(node, seconds):
    sim = Simulator(load_scene('conveyor'))
    node.state_callback(state_msg(sim.sample()))
    for _ in range(int(seconds / 1e-3)):
        if node.sent:
            sim.command_crank_length(node.sent[-1])
        sim.advance(1e-3)
        node.state_callback(state_msg(sim.sample()))
    return sim


def test_one_command_per_sample_and_the_set_point_by_sim_time(node):
    drive(node, 0.3)
    assert len(node.sent) == 301                      # every sample answered (lockstep steps)
    assert node.setpoints and set(node.setpoints) <= {55.0, 65.0}   # once per turn it acts
    assert node.setpoint_at(0.1) == 55.0 and node.setpoint_at(0.25) == 65.0
    msg = Float64()
    msg.data = 40.0
    node.speed_setpoint_callback(msg)                 # the topic overrides the file
    assert node.setpoint_at(0.25) == 40.0
    msg.data = float('nan')
    node.speed_setpoint_callback(msg)                 # refused: the last valid one stays
    assert node.setpoint_at(0.25) == 40.0
    assert np.all(np.diff(node.sent) >= -1e-15)       # too slow at first: the crank lengthens


def test_gains_change_live_and_bad_values_are_refused(node):
    ok = node.set_parameters([Parameter('kp', value=3e-3)])[0]
    assert ok.successful and node.law.gains.kp == 3e-3
    bad = node.set_parameters([Parameter('crank_max', value=-1.0)])[0]
    assert not bad.successful and 'crank_max' in bad.reason
    assert node.law.gains.crank_max == 0.09


def test_the_set_point_topic_takes_the_publishers_of_ros2_topic_pub_and_latched_ones(node):
    """`ros2 topic pub --once /speed_setpoint ...` offers reliable + volatile: a transient-local
    subscription refused it (the docs' example never reached the controller)."""
    from rclpy.qos import DurabilityPolicy, QoSCompatibility, QoSProfile, qos_check_compatible
    sub = node.speed_setpoint_subscription.qos_profile
    for publisher in (QoSProfile(depth=10),        # ros2 topic pub's default, most nodes'
                      QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)):
        compatibility, reason = qos_check_compatible(publisher, sub)
        assert compatibility != QoSCompatibility.ERROR, reason   # (WARNING: system defaults)


RACE = """
import sys
from rclpy.node import Node
from std_msgs.msg import Float64
from cvt_ros.control.node import spin

class Racer(Node):
    def __init__(self):
        super().__init__('racer')
        self.publisher = self.create_publisher(Float64, 'x', 10)
        self.timer = self.create_timer(0.01, self.race)

    def race(self):
        if sys.argv[1] == 'sigint':
            self.context.try_shutdown()   # SIGINT's handler, between two lines of a callback
        else:
            raise RuntimeError('a callback failed')
        self.publisher.publish(Float64())  # RCLError: publisher's context is invalid

sys.exit(spin(Racer, []))
"""


@pytest.mark.parametrize('what, code', [('sigint', 0), ('error', 1)])
def test_a_controller_node_stopped_while_it_publishes_exits_0(what, code):
    """Ctrl-C that lands while a callback publishes is a stop like any other (it once ended
    cvt_speed_controller with RCLError and exit code 1); a callback's own error is not."""
    import subprocess
    import sys
    proc = subprocess.run([sys.executable, '-c', RACE, what], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == code, proc.stderr[-2000:]
