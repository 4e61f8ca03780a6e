"""The device: the pulse CVT as a ROS 2 node (``cvt_node``) and what drives it.

ROS domains for programs that start nodes (tests, benchmarks, demos): :mod:`.domains`.
"""
