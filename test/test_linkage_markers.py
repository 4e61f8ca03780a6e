"""The linkage picture: the drawn points close the loop of eq. 1, the crank length is recovered
from the angles of an older recording, the clutch disc shows the clutch state."""
import math

import numpy as np
import pytest

from cvt_ros.control.markers import crank_length_from, linkage_points
from cvt_ros.physics.linkage import rocker_angle

B, D, H = 0.10, 0.20, 0.20


@pytest.mark.parametrize('a', [0.0, 0.01, 0.04, 0.09])
def test_points_close_the_loop_and_give_the_crank_back(a):
    for phi1 in np.linspace(0, 2 * math.pi, 13):
        phi2 = rocker_angle(phi1, a, B, D, H, 1.0)
        o1, pa, o2, pb = linkage_points(phi1, phi2, a, B, H)
        assert math.dist(pa, pb) == pytest.approx(D, abs=1e-12)
        assert math.dist(o2, pb) == pytest.approx(B, abs=1e-12)
        assert crank_length_from(phi1, phi2, B, D, H) == pytest.approx(a, abs=1e-9)


def test_marker_array_from_a_device_sample():
    rclpy = pytest.importorskip('rclpy')
    from rclpy.context import Context

    from cvt_ros.control.markers import LinkageMarkersNode
    from cvt_ros.interface import joint_state_from_row
    from cvt_ros.scene import load_scene
    from cvt_ros.solver.simulator import Simulator
    sim = Simulator(load_scene('conveyor'))
    sim.advance(0.5)
    row = sim.sample()
    msg = joint_state_from_row(row)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=0)
    try:
        node = LinkageMarkersNode(context=ctx, start_parameter_services=False)
        node._order = [0, 1, 2, 3]
        out = node.markers(msg)
        kinds = [m.type for m in out.markers]
        assert len(out.markers) == 8 and kinds.count(4) == 6      # 6 line strips
        crank = out.markers[1].points[1]
        a = crank_length_from(row[1], row[2], B, D, H)
        assert math.hypot(crank.x, crank.y) == pytest.approx(a, rel=1e-9)
        disc = out.markers[4].color
        engaged = row[11] > 0
        assert (disc.g > disc.r) == engaged
        node.destroy_node()
    finally:
        ctx.try_shutdown()


def test_marker_array_draws_every_path():
    """N = 4: each path's loop closes at its own crank phase, its disc shows its own clutch."""
    rclpy = pytest.importorskip('rclpy')
    from rclpy.context import Context
    from sensor_msgs.msg import JointState

    from cvt_ros.control.markers import LinkageMarkersNode
    from cvt_ros.interface import SampleLayout, decode_joint_state_cdr
    from cvt_ros.scene import load_scene
    from cvt_ros.solver.fidelity import make_simulator
    sim = make_simulator(load_scene('conveyor_4path'))
    sim.advance(0.52)
    row = sim.sample()
    layout = SampleLayout(4)
    values = layout.joint_values(row, 0.0)
    msg = JointState(name=list(layout.names), position=values[:8], velocity=values[8:16],
                     effort=values[16:])
    ctx = Context()
    rclpy.init(context=ctx, domain_id=0)
    try:
        node = LinkageMarkersNode(context=ctx, start_parameter_services=False)
        node.joint_states_callback(msg)   # (learns the layout: the rockers of 4 paths)
        out = node.markers(msg)
        assert sorted(m.id for m in out.markers) == list(range(8 + 4 * 3))
        by_id = {m.id: m for m in out.markers}
        a = row[12]
        for k in range(4):
            crank, coupler, rocker, disc = ((1, 2, 3, 4) if k == 0 else
                                            range(8 + 4 * (k - 1), 12 + 4 * (k - 1)))
            pa, pb = by_id[coupler].points
            assert math.hypot(pa.x, pa.y) == pytest.approx(a, rel=1e-9)
            assert math.atan2(pa.y, pa.x) == pytest.approx(
                math.remainder(row[1] + k * math.pi / 2, 2 * math.pi), abs=1e-9)
            assert math.dist((pa.x, pa.y), (pb.x, pb.y)) == pytest.approx(D, abs=1e-12)
            assert by_id[rocker].points[1] == pb
            color = by_id[disc].color
            assert (color.g > color.r) == (values[17 + k] > 0), k
        assert {v > 0 for v in values[17:21]} == {True, False}   # (both states drawn)
        assert decode_joint_state_cdr(layout.joint_states(row, 0.0, 0))[1] == list(layout.names)
        node.destroy_node()
    finally:
        ctx.try_shutdown()
