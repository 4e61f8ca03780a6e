"""The loop in one command: the device, the reference controller, the linkage markers and a
recording, from a scenario file (a ROS 2 install with launch; see docs/controller.md).

    ros2 launch cvt_ros cvt_controller.launch.py scenario:=conveyor_setpoint_steps
    ros2 launch cvt_ros cvt_controller.launch.py scenario:=my.yaml record:=run.mcap

Arguments:
  scenario          a shipped scenario name (config/scenarios) or a path
  time_mode         realtime (default: watch it live, e.g. in Foxglove) | lockstep
  real_time_factor  realtime mode: simulated seconds per wall-clock second
  record            MCAP file the device records to (empty: no recording)

The device gets every scene value of the scenario, the controller its gains, limits and the
set-point schedule (by simulation time). The load schedule is not played here: for a run with
disturbances and metrics use ``cvt-sim scenario run SCENARIO --backend dds [--realtime]``.
"""
import tempfile

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

ARGUMENTS = (
    ('scenario', 'conveyor_setpoint_steps', 'scenario name (config/scenarios) or path'),
    ('time_mode', 'realtime', 'realtime | lockstep'),
    ('real_time_factor', '1.0', 'realtime mode: simulated seconds per wall-clock second'),
    ('record', '', 'MCAP file to record to (empty: off)'),
)


def _nodes(context):
    from cvt_ros.scenario.launch_files import prepare
    files = prepare(LaunchConfiguration('scenario').perform(context),
                    tempfile.mkdtemp(prefix='cvt_controller_launch_'),
                    LaunchConfiguration('time_mode').perform(context),
                    float(LaunchConfiguration('real_time_factor').perform(context)),
                    LaunchConfiguration('record').perform(context))
    return [
        Node(package='cvt_ros', executable='cvt_node', name='cvt_sim', output='screen',
             parameters=[files.device_params], sigterm_timeout='5'),
        Node(package='cvt_ros', executable='cvt_speed_controller', output='screen',
             parameters=[dict(files.controller, setpoint_file=files.setpoint_file)]),
        Node(package='cvt_ros', executable='cvt_linkage_markers', output='screen',
             parameters=[files.geometry]),
    ]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in ARGUMENTS]
        + [OpaqueFunction(function=_nodes)])
