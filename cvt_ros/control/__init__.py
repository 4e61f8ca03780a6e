"""Controllers for the device: the controller-facing Measurement and the reference controller
(cycle-mean output-speed PI). No rclpy at import: control/node.py is the ROS node around the law.
"""
from .measurement import JOINTS, ControllerError, Measurement
from .speed_pi import CycleMeanSpeed, SpeedPI, SpeedPIGains, reference_controller

__all__ = ['JOINTS', 'ControllerError', 'CycleMeanSpeed', 'Measurement', 'SpeedPI',
           'SpeedPIGains', 'reference_controller']
