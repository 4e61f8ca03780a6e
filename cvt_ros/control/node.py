"""``cvt_speed_controller``: the reference controller as a ROS 2 node (the law: speed_pi.py).

Subscribes the device's latched ``state`` (sensor_msgs/JointState: the joints crank, rocker,
clutch_output, output_shaft and the actuator's prismatic joint crank_length; transient local, so
a controller started after the device still gets the present sample) and publishes one
``crank_length_cmd`` (std_msgs/Float64 [m]) per sample — in lockstep that command is what
advances the device one control period. The set point [rad/s] comes from the parameter
``setpoint``, the topic ``speed_setpoint`` (std_msgs/Float64; any reliable publisher, volatile
as ``ros2 topic pub`` or latched, as the device's command topics take; overrides the parameter
from its arrival on) or a set-point file (``setpoint_file``: CSV ``t,setpoint``, the value in
force from each t on, read against the samples' simulation-time stamps — reproducible to the
period, which is how ``cvt-sim scenario run --backend dds`` drives it). ``~/cycle_mean_speed``
and ``~/setpoint`` (Float64 [rad/s]) publish the law's measurement and the set point it
follows once per crank turn, when it acts (the Foxglove layout plots them).

    .venv/bin/cvt_speed_controller --ros-args -p setpoint:=60.0 -p kp:=2e-3 -p ki:=4e-3
    ./run.sh ros2 topic pub --once /speed_setpoint std_msgs/msg/Float64 "{data: 70.0}"
"""
import argparse
import math
import os
import sys
from dataclasses import fields

import numpy as np
import rclpy
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from .. import interface
from .speed_pi import SpeedPI, SpeedPIGains

NODE_NAME = 'cvt_speed_controller'
STATE_TOPIC = 'state'
SETPOINT_TOPIC = 'speed_setpoint'
ACTUATOR_JOINT = 'crank_length'
SETPOINT_FILE_ENV = 'CVT_SETPOINT_FILE'   # set by cvt-sim scenario run --controller-cmd
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
_UNITS = {'kp': 'm per rad/s', 'ki': 'm per rad', 'crank_min': 'm', 'crank_max': 'm',
          'rate_limit': 'm/s', 'tracking_time': 's'}


def read_setpoint_file(path):
    """(times [s], set points [rad/s]) of a CSV ``t,setpoint`` (header line, times increasing).
    Raises ValueError naming the file and the problem."""
    try:
        data = np.loadtxt(path, delimiter=',', skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise ValueError(f"setpoint_file {path}: {exc}") from None
    if data.shape[1] != 2 or not len(data):
        raise ValueError(f"setpoint_file {path}: expected two columns t,setpoint")
    if not np.all(np.isfinite(data)) or np.any(np.diff(data[:, 0]) <= 0):
        raise ValueError(f"setpoint_file {path}: times must increase and values be finite")
    return data[:, 0].copy(), data[:, 1].copy()


class SpeedControllerNode(Node):
    """The reference cycle-mean output-speed PI controller on ROS topics."""

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        defaults = SpeedPIGains()
        for f in fields(SpeedPIGains):
            self.declare_parameter(f.name, float(getattr(defaults, f.name)), ParameterDescriptor(
                description=f"reference controller: {f.name} [{_UNITS[f.name]}]"))
        self.declare_parameter('setpoint', 55.0, ParameterDescriptor(
            description='output speed set point [rad/s] until speed_setpoint or setpoint_file'))
        self.declare_parameter('setpoint_file', os.environ.get(SETPOINT_FILE_ENV, ''),
                               ParameterDescriptor(
            description='CSV t,setpoint [s, rad/s]: set point by simulation time (empty: off; '
                        f'default: the environment variable {SETPOINT_FILE_ENV})'))
        self.law = SpeedPI(self._gains())
        self.setpoint = float(self.get_parameter('setpoint').value)
        self.schedule = None
        path = self.get_parameter('setpoint_file').value
        if path:
            self.schedule = read_setpoint_file(path)
        self.topic_setpoint = None
        self._order = None
        self._actuator_index = None
        self.add_on_set_parameters_callback(self.check_parameters_callback)
        self.crank_length_cmd_publisher = self.create_publisher(
            Float64, interface.CRANK_LENGTH_CMD, interface.command_qos())
        self.cycle_mean_speed_publisher = self.create_publisher(Float64, '~/cycle_mean_speed', 10)
        self.setpoint_publisher = self.create_publisher(Float64, '~/setpoint', 10)
        self.state_subscription = self.create_subscription(
            JointState, STATE_TOPIC, self.state_callback, LATCHED)
        # a command input: volatile, so that any reliable publisher matches (a transient-local
        # subscription refuses the volatile publishers of `ros2 topic pub` and most nodes)
        self.speed_setpoint_subscription = self.create_subscription(
            Float64, SETPOINT_TOPIC, self.speed_setpoint_callback,
            interface.command_subscription_qos())
        self._command = Float64()
        self._speed = Float64()
        self._setpoint = Float64()

    def _gains(self, changes=None):
        values = {f.name: float(self.get_parameter(f.name).value) for f in fields(SpeedPIGains)}
        values.update(changes or {})
        return SpeedPIGains(**values).check()

    def check_parameters_callback(self, parameters):
        """Gains and limits change live (checked, refused with the reason); so does setpoint."""
        changes = {p.name: p.value for p in parameters}
        gains = {k: v for k, v in changes.items() if k in {f.name for f in fields(SpeedPIGains)}}
        try:
            if gains:
                new = self._gains({k: float(v) for k, v in gains.items()})
            if 'setpoint' in changes and not math.isfinite(float(changes['setpoint'])):
                raise ValueError(f"setpoint: {changes['setpoint']!r} is not finite")
            if changes.get('setpoint_file'):
                raise ValueError('setpoint_file is read at start only')
        except (TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if gains:
            self.law.gains = new
        if 'setpoint' in changes:
            self.setpoint = float(changes['setpoint'])
        return SetParametersResult(successful=True)

    def speed_setpoint_callback(self, msg):
        if math.isfinite(msg.data):
            self.topic_setpoint = float(msg.data)
        else:
            self.get_logger().warning(f"refused speed_setpoint = {msg.data!r}: not finite")

    def setpoint_at(self, t):
        if self.topic_setpoint is not None:
            return self.topic_setpoint
        if self.schedule is not None:
            times, values = self.schedule
            i = int(np.searchsorted(times, t + 1e-9, side='right')) - 1
            return float(values[max(i, 0)])
        return self.setpoint

    def state_callback(self, msg):
        """One sample: the law, then one command (the last one again while the law holds)."""
        if self._order is None:
            self._order = interface.joint_order(list(msg.name))
            hits = [i for i, n in enumerate(msg.name) if n.endswith(ACTUATOR_JOINT)]
            self._actuator_index = hits[0] if len(hits) == 1 else None
            if self._order is None:
                self.get_logger().error(f"state without the device's joints: {list(msg.name)}")
                return
        s = interface.decode_joint_state(msg, self._order)
        t = s.stamp_ns * 1e-9
        i = self._actuator_index
        crank = float(msg.position[i]) if i is not None else math.nan
        setpoint = self.setpoint_at(t)
        a = self.law.update(t, s.position[0], s.position[3], crank, setpoint, s.effort[1] > 0.0)
        if a is not None:
            self._speed.data = float(self.law.speed.value)
            self.cycle_mean_speed_publisher.publish(self._speed)
            self._setpoint.data = float(setpoint)
            self.setpoint_publisher.publish(self._setpoint)
        else:
            a = self.law.command if self.law.command is not None else crank
        if math.isfinite(a):
            self._command.data = float(a)
            self.crank_length_cmd_publisher.publish(self._command)


def spin(make_node, args=None, prog=None, description=None):
    """Run the node ``make_node()`` builds until SIGINT / SIGTERM; the exit code (2 when it
    refused its parameters or its command line). The main of every controller-kit node.

    ``args``: the command line without the program name (None: sys.argv[1:]). Arguments before
    ``--ros-args`` are the program's own: only ``-h/--help`` (which prints ``description`` and
    exits 0 without starting ROS)."""
    argv = list(sys.argv[1:] if args is None else args)
    if description:   # a module docstring's first paragraph, without its ``name``: lead
        description = ' '.join(description.split()).split('``: ', 1)[-1]
    parser = argparse.ArgumentParser(
        prog=prog or make_node.__name__, description=description,
        epilog='ROS parameters and remappings follow --ros-args (-p name:=value, '
               '--params-file FILE, -r from:=to).')
    parser.parse_args(remove_ros_args(['x'] + argv)[1:])   # exits 0 on --help, 2 on unknowns
    try:
        rclpy.init(args=['x'] + argv)
        node = make_node()
    except ValueError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return 130
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # SIGINT shut the context down while a callback was publishing (RCLError "publisher's
        # context is invalid"): the same stop, not an error; one while running is an error
        if rclpy.ok():
            raise
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def main(args=None):
    return spin(SpeedControllerNode, args, 'cvt_speed_controller', __doc__.split('\n\n')[0])


if __name__ == '__main__':
    sys.exit(main())
