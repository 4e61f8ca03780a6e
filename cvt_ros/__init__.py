"""cvt_ros: a mechanical pulse CVT as a real-time virtual device for ROS 2.

The physics core (``physics``, ``solver``) imports no ROS; ``device`` holds the ROS node
(docs/architecture.md: the rooms and their layers).
"""
__version__ = '0.1.0'
