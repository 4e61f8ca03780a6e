"""Benchmarks, one module per thing measured (the top layer: nothing imports them).

``cvt-sim bench`` / ``./run.sh bench`` run :mod:`cvt_ros.bench.main`; ``cvt-sim bench node`` the
ROS node's benchmark (:mod:`cvt_ros.bench.node`).
"""
