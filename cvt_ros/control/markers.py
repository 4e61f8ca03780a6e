"""``cvt_linkage_markers``: the mechanism as visualization_msgs/MarkerArray, live or from a replay.

Subscribes ``joint_states`` (what the node publishes and every recording replays) and publishes
``linkage_markers`` at most ``display_rate`` times per wall second (a display needs ~30 Hz, not
the 1 kHz control rate) in the frame ``frame_id`` (x along the frame line O1→O2, z up):

* the frame O1O2 (grey), the crank O1A (blue), the coupler AB (orange), the rocker O2B (purple);
* the one-way clutch at O2 as a disc, green while it transmits torque (effort of clutch_output's
  joint > 0), red while it overruns;
* the output shaft as two spokes behind O2: the shaft's input end at φ3 and its output end at φ4
  (the twist φ3 − φ4 drawn ``twist_gain`` times larger), and a text with ω4 and the crank length.

A machine of N ≥ 2 paths (joint_states with ``rocker_1 … rocker_N``, issue 33) is drawn path by
path, stacked along the crank shaft (z = ``path_spacing``·(k − 1)): path k's crank at φ1 + δ_k
(``phase_offsets``, [] = 2π·(k − 1)/N, the scene's default), its coupler, its rocker at φ2,k and
its clutch disc, green while that clutch transmits torque (rocker k's effort > 0). Path 1 keeps
the one-path picture's marker ids (0 … 7); path k ≥ 2 adds ids 8 + 4·(k − 2) … (crank, coupler,
rocker, clutch), so a display set up for one path shows the first path of any machine.

Geometry (paper eq. 1, physics/linkage.py): O1 = (0, 0), A = a·(cos φ1, sin φ1), O2 = (h, 0),
B = O2 + b·(cos φ2, sin φ2); the coupler length d closes the loop. The crank length a is the
``crank_length`` joint when the message has it, else solved from φ1, φ2 (an older recording).
Parameters: rocker_length, coupler_length, pivot_distance [m] (the scene's ``linkage.*``),
phase_offsets [rad] and path_spacing [m] (N ≥ 2).
"""
import math
import sys
import time

from geometry_msgs.msg import Point
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from .. import interface

NODE_NAME = 'cvt_linkage_markers'
LINE_WIDTH = 0.008       # m
COLORS = {'frame': (0.5, 0.5, 0.5), 'crank': (0.12, 0.47, 0.71), 'coupler': (1.0, 0.5, 0.05),
          'rocker': (0.58, 0.4, 0.74), 'engaged': (0.17, 0.63, 0.17), 'free': (0.84, 0.15, 0.16),
          'input': (0.3, 0.3, 0.3), 'output': (0.1, 0.1, 0.1)}


def path_offsets(n, offsets=()):
    """Each path's crank phase δ_k [rad]: ``offsets`` when it has one per path, else the
    scene's default 2π·(k − 1)/N."""
    if len(offsets) == n:
        return [float(x) for x in offsets]
    return [2.0 * math.pi * k / n for k in range(n)]


def linkage_points(phi1, phi2, a, b, h):
    """(O1, A, O2, B) as (x, y) [m] (physics/linkage.py's frame)."""
    return ((0.0, 0.0), (a * math.cos(phi1), a * math.sin(phi1)), (h, 0.0),
            (h + b * math.cos(phi2), b * math.sin(phi2)))


def crank_length_from(phi1, phi2, b, d, h):
    """a from eq. 1 for given φ1, φ2: a² − 2a(h cos φ1 + b cos(φ1 − φ2)) + (b² + h² − d² +
    2bh cos φ2) = 0, the root with 0 ≤ a (the crank is the short link)."""
    p = h * math.cos(phi1) + b * math.cos(phi1 - phi2)
    q = b * b + h * h - d * d + 2.0 * b * h * math.cos(phi2)
    disc = p * p - q
    if disc < 0.0:
        return math.nan
    roots = [r for r in (p - math.sqrt(disc), p + math.sqrt(disc)) if r >= -1e-12]
    return max(min(roots), 0.0) if roots else math.nan


def _color(name, alpha=1.0):
    r, g, b = COLORS[name]
    return ColorRGBA(r=r, g=g, b=b, a=alpha)


class LinkageMarkersNode(Node):
    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.b = float(self.declare_parameter('rocker_length', 0.10).value)
        self.d = float(self.declare_parameter('coupler_length', 0.20).value)
        self.h = float(self.declare_parameter('pivot_distance', 0.20).value)
        self.frame_id = str(self.declare_parameter('frame_id', 'cvt').value)
        self.display_rate = float(self.declare_parameter('display_rate', 30.0).value)
        self.twist_gain = float(self.declare_parameter('twist_gain', 10.0).value)
        self.phase_offsets = list(self.declare_parameter(
            'phase_offsets', [0.0]).value)   # (a double array: [0.0] stands for the default)
        self.path_spacing = float(self.declare_parameter('path_spacing', 0.02).value)
        self._next_wall = 0.0
        self._order = None
        self._actuator = None
        self._rockers = []
        self.linkage_markers_publisher = self.create_publisher(MarkerArray, 'linkage_markers', 10)
        self.joint_states_subscription = self.create_subscription(
            JointState, interface.JOINT_STATES, self.joint_states_callback,
            interface.joint_states_qos())

    def joint_states_callback(self, msg):
        now = time.monotonic()
        if now < self._next_wall:
            return
        self._next_wall = now + 1.0 / self.display_rate
        if self._order is None:
            self._order = interface.joint_order(list(msg.name))
            hits = [i for i, n in enumerate(msg.name) if n.endswith('crank_length')]
            self._actuator = hits[0] if len(hits) == 1 else None
            self._rockers = interface.rocker_order(list(msg.name))
            if self._order is None:
                return
        self.linkage_markers_publisher.publish(self.markers(msg))

    def markers(self, msg):
        s = interface.decode_joint_state(msg, self._order)
        phi1, phi2, phi3, phi4 = s.position
        a = (float(msg.position[self._actuator]) if self._actuator is not None
             else crank_length_from(phi1, phi2, self.b, self.d, self.h))
        rockers = self._rockers if len(self._rockers) > 1 else []
        offsets = path_offsets(len(rockers), self.phase_offsets) if rockers else [0.0]
        o1, pa, o2, pb = linkage_points(phi1 + offsets[0], phi2, a, self.b, self.h)
        torques = [float(msg.effort[i]) for i in rockers] if len(msg.effort) else []
        engaged = (torques[0] if torques else s.effort[1]) > 0.0
        out = MarkerArray()

        def marker(mid, kind, color, scale=LINE_WIDTH):
            m = Marker()
            m.header = msg.header
            m.header.frame_id = self.frame_id
            m.ns, m.id, m.type, m.action = 'cvt', mid, kind, Marker.ADD
            m.pose.orientation.w = 1.0
            m.scale.x = m.scale.y = m.scale.z = scale
            m.color = color
            out.markers.append(m)
            return m

        for mid, (name, p, q) in enumerate((('frame', o1, o2), ('crank', o1, pa),
                                             ('coupler', pa, pb), ('rocker', o2, pb))):
            m = marker(mid, Marker.LINE_STRIP, _color(name))
            m.points = [Point(x=p[0], y=p[1]), Point(x=q[0], y=q[1])]
        disc = marker(4, Marker.CYLINDER, _color('engaged' if engaged else 'free', 0.8))
        disc.pose.position.x = o2[0]
        disc.scale.x = disc.scale.y = 0.25 * self.b
        disc.scale.z = 0.01
        spoke = 0.6 * self.b
        shown3 = phi4 + self.twist_gain * (phi3 - phi4)
        for mid, (name, angle, z) in enumerate((('input', shown3, -0.03),
                                                 ('output', phi4, -0.06)), start=5):
            m = marker(mid, Marker.LINE_STRIP, _color(name))
            m.points = [Point(x=o2[0], y=0.0, z=z),
                        Point(x=o2[0] + spoke * math.cos(angle), y=spoke * math.sin(angle), z=z)]
        text = marker(7, Marker.TEXT_VIEW_FACING, _color('output'), scale=0.02)
        text.pose.position.x, text.pose.position.y = 0.5 * self.h, -0.12
        if rockers:
            held = [str(k) for k, torque in enumerate(torques, 1) if torque > 0.0]
            clutches = f"clutches engaged {','.join(held) or 'none'} of {len(rockers)}"
        else:
            clutches = f"clutch {'engaged' if engaged else 'free'}"
        text.text = f"ω4 {s.velocity[3]:6.2f} rad/s   a {a * 1e3:5.2f} mm   {clutches}"
        for k in range(1, len(rockers)):   # paths 2 … N, stacked along the crank shaft
            z = self.path_spacing * k
            phi2_k = float(msg.position[rockers[k]])
            _, pa_k, _, pb_k = linkage_points(phi1 + offsets[k], phi2_k, a, self.b, self.h)
            base = 8 + 4 * (k - 1)
            for i, (name, p, q) in enumerate((('crank', o1, pa_k), ('coupler', pa_k, pb_k),
                                              ('rocker', o2, pb_k))):
                m = marker(base + i, Marker.LINE_STRIP, _color(name))
                m.points = [Point(x=p[0], y=p[1], z=z), Point(x=q[0], y=q[1], z=z)]
            disc = marker(base + 3, Marker.CYLINDER,
                          _color('engaged' if torques[k] > 0.0 else 'free', 0.8))
            disc.pose.position.x, disc.pose.position.z = o2[0], z
            disc.scale.x = disc.scale.y = 0.25 * self.b
            disc.scale.z = 0.01
        return out


def main(args=None):
    from .node import spin
    return spin(LinkageMarkersNode, args, 'cvt_linkage_markers', __doc__.split('\n\n')[0])


if __name__ == '__main__':
    sys.exit(main())
