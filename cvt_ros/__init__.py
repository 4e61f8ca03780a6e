"""cvt_ros: a mechanical pulse CVT as a real-time virtual device for ROS 2.

The physics core (``physics``, ``solver``) imports no ROS; ``node`` is the only ROS node module.
"""
__version__ = '0.1.0'
