"""Launch the pulse-CVT virtual device (node cvt_sim, executable cvt_node) in a ROS 2 install.

    ros2 launch cvt_ros cvt_sim.launch.py
    ros2 launch cvt_ros cvt_sim.launch.py scene:=mixer time_mode:=lockstep
    ros2 launch cvt_ros cvt_sim.launch.py scene:=/path/to/my_scene.yaml namespace:=line1

Arguments:
  scene           scene name under share/cvt_ros/config/scenes (conveyor, paper, mixer, ...) or
                  a path to a scene file; passed as the node's params file
  namespace       ROS namespace, so several transmissions can run side by side
  time_mode       realtime | fast | lockstep
  real_time_factor, publish_rate   realtime mode: simulated seconds per wall second; samples
                  per simulated second
  publish_clock   true: the node publishes /clock (give it to one transmission only)
  use_sim_time    the node's own clock follows /clock (its stamps are simulation time anyway)
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription

ARGUMENTS = (
    ('scene', 'conveyor', 'scene name (config/scenes) or path of a scene file'),
    ('namespace', '', 'namespace of the transmission'),
    ('time_mode', 'realtime', 'realtime | fast | lockstep'),
    ('real_time_factor', '1.0', 'realtime mode: simulated seconds per wall-clock second'),
    ('publish_rate', '1000.0', 'samples (control periods) per simulated second'),
    ('publish_clock', 'true', 'publish /clock (the node is the time source)'),
    ('use_sim_time', 'false', "the node's own ROS clock follows /clock"),
)


def _scene_file(scene):
    if os.path.isfile(scene):
        return scene
    path = os.path.join(get_package_share_directory('cvt_ros'), 'config', 'scenes',
                        f'{scene}.yaml')
    if not os.path.isfile(path):
        raise RuntimeError(f"scene {scene!r} is neither a file nor installed as {path}")
    return path


def _node(context):
    scene = LaunchConfiguration('scene').perform(context)
    return [Node(
        package='cvt_ros',
        executable='cvt_node',
        name='cvt_sim',
        namespace=LaunchConfiguration('namespace'),
        output='screen',
        emulate_tty=True,
        parameters=[
            _scene_file(scene),
            {
                'time_mode': LaunchConfiguration('time_mode'),
                'real_time_factor': ParameterValue(LaunchConfiguration('real_time_factor'),
                                                   value_type=float),
                'publish_rate': ParameterValue(LaunchConfiguration('publish_rate'),
                                               value_type=float),
                'publish_clock': ParameterValue(LaunchConfiguration('publish_clock'),
                                                value_type=bool),
                'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                               value_type=bool),
            },
        ],
        # SIGINT first; the node stops within 2 s (launch escalates to SIGTERM after 5 s)
        sigterm_timeout='5',
    )]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in ARGUMENTS]
        + [OpaqueFunction(function=_node)])
