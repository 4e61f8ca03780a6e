"""The node's ROS interface in one place: topic names, joint names, QoS, message builders, decoders.

Used by the node (publishers, subscriptions), the recorder (what it writes), replay and analysis
(what they read). Importing this module does not import rclpy: QoS profiles are functions that
build an rclpy ``QoSProfile`` when called, and message builders import the message packages on
first use. The QoS values also exist as plain dicts (``QOS``) in the keys rosbag2 writes, for the
recorder's ``offered_qos_profiles``.

Sample rows are the core's output rows (``cvt_ros.solver.output.COLUMNS``, ``COL``).

``joint_states`` carries, per joint ``crank, rocker, clutch_output, output_shaft`` (J1..J4):
position φ1..φ4 [rad] (whole turns included), velocity ω1..ω4 [rad/s], effort [N·m] = motor
torque on the crank, clutch torque on the rocker, shaft torque on the clutch output, load torque
on the output shaft. The torsion twist is not a field: decoders take θ = φ3 − φ4. Both angles
are float64 and grow without bound, so θ keeps an absolute precision of about
2.2e-16·|φ4| rad (2e-12 rad at φ4 = 1e4 rad, i.e. after ~4 minutes at 40 rad/s; 3e-11 rad after an
hour): far below anything the model resolves.

A machine of N ≥ 2 paths (``paths.count``) publishes one rocker per path: the joints are
``crank, rocker_1 … rocker_N, clutch_output, output_shaft`` (``joint_names(n)``; for N = 1 they
stay ``crank, rocker, clutch_output, output_shaft``), rocker k's effort being the torque its
clutch passes to J3 (their sum is the one-path ``clutch_torque``), and a second JointState,
``clutch_states`` (N ≥ 2 only), carries each clutch as a joint ``clutch_1 … clutch_N``:
position = 1.0 engaged / 0.0 overrunning, velocity = ω2,k − ω3 (the rocker relative to the
driven member: 0 while engaged, < 0 while overrunning) [rad/s], effort = the clutch's torque
[N·m]; one message per control period, and one at each clutch switch stamped with the switch's
own time carrying positions only (velocity and effort empty, as JointState allows).
``clutch_engaged`` stays one Bool: *any* clutch engaged, published when that changes.

Besides the rclpy builders there are byte-level CDR encoders for the recorder's hot path
(``joint_state_cdr`` & co.: the same CDR as ``rclpy.serialization.serialize_message``, with
zeroed padding bytes where rmw leaves them uninitialised; about 10x faster) and a decoder of
JointState CDR bytes (``decode_joint_state_cdr``) that needs no ROS.
"""

from __future__ import annotations

import math
import operator
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from .solver.output import COL, N_COLUMNS, PATH_QUANTITIES

__all__ = [
    'ACTUATOR_JOINT', 'CLOCK', 'CLUTCH_ENGAGED', 'CRANK_LENGTH_CMD', 'DEVICE_JOINTS', 'DIAGNOSTICS',
    'JOINTS', 'JOINT_COMMANDS', 'JOINT_STATES', 'JointStateDecoder', 'JointStateEncoder',
    'LOAD_TORQUE_CMD', 'QOS',
    'STATE', 'STATE_QOS', 'CLUTCH_STATES', 'SampleLayout', 'clutch_names', 'joint_names',
    'device_joint_names', 'rocker_order', 'joint_state_arrays_cdr', 'topics_for', 'PATH_TOPICS',
    'parse_joint_state_cdr',
    'TOPICS', 'TopicSpec', 'JointStateValues', 'command_subscription_qos', 'state_qos',
    'POSITION_COLUMNS', 'VELOCITY_COLUMNS', 'EFFORT_COLUMNS',
    'bool_cdr', 'clock_cdr', 'clock_msg', 'clock_qos', 'clutch_msg', 'clutch_qos',
    'command_msg', 'command_qos', 'decode_joint_state', 'decode_joint_state_cdr',
    'diagnostics_qos', 'float64_cdr', 'float64_value', 'joint_command_crank_length',
    'joint_command_position',
    'joint_order', 'joint_state_cdr', 'joint_state_from_row', 'joint_state_stamp_ns',
    'joint_states_qos', 'qos_profile', 'resolve_topic', 'resolved_topics', 'set_stamp',
    'stamp_ns', 'time_to_ns', 'topic_key',
]

# ---------------------------------------------------------------------------------- names
#: Joint names of joint_states, J1..J4 (the node may prefix them: parameter joint_prefix).
JOINTS = ('crank', 'rocker', 'clutch_output', 'output_shaft')
#: The crank-length actuator as a prismatic joint, after J1..J4 in the node's joint_states:
#: position = actual (rate-limited) crank length [m], velocity = its rate [m/s], effort = NaN (the
#: actuator's force is not modelled). What ros2_control's joint_state_broadcaster publishes and
#: topic_based_ros2_control reads: a joint by name, with position and velocity.
ACTUATOR_JOINT = 'crank_length'
#: All joints the node publishes, in order.
DEVICE_JOINTS = JOINTS + (ACTUATOR_JOINT,)
ROCKER = 'rocker'
CLUTCH = 'clutch'


def joint_names(n_paths: int = 1, prefix: str = '') -> tuple[str, ...]:
    """J1..J4 of joint_states for a machine of ``n_paths``: ``JOINTS`` for one path; ``crank,
    rocker_1 … rocker_N, clutch_output, output_shaft`` for N ≥ 2."""
    rockers = (ROCKER,) if n_paths == 1 else tuple(f'{ROCKER}_{k}' for k in range(1, n_paths + 1))
    return tuple(prefix + j for j in (JOINTS[0], *rockers, *JOINTS[2:]))


def device_joint_names(n_paths: int = 1, prefix: str = '') -> tuple[str, ...]:
    """Every joint of the node's joint_states: ``joint_names`` and the actuator."""
    return joint_names(n_paths, prefix) + (prefix + ACTUATOR_JOINT,)


def clutch_names(n_paths: int, prefix: str = '') -> tuple[str, ...]:
    """The joints of clutch_states: ``clutch_1 … clutch_N``."""
    return tuple(f'{prefix}{CLUTCH}_{k}' for k in range(1, n_paths + 1))
#: Sample-row columns behind position, velocity and effort, joint by joint.
POSITION_COLUMNS = ('phi1', 'phi2', 'phi3', 'phi4')
VELOCITY_COLUMNS = ('omega1', 'omega2', 'omega3', 'omega4')
EFFORT_COLUMNS = ('motor_torque', 'clutch_torque', 'shaft_torque', 'load_torque')
_POSITION = [COL[c] for c in POSITION_COLUMNS]
_VELOCITY = [COL[c] for c in VELOCITY_COLUMNS]
_EFFORT = [COL[c] for c in EFFORT_COLUMNS]
_T = COL['t']
_FIELDS = _POSITION + _VELOCITY + _EFFORT

# Topic names as the node creates them: relative (the namespace applies) except /clock and
# /diagnostics. The keys are the node's own keys for them (CvtSimNode._topic).
JOINT_STATES = 'joint_states'
CLUTCH_ENGAGED = 'clutch_engaged'
CLOCK = '/clock'
#: N ≥ 2 paths: every clutch's state, torque and slip (a JointState; see the module text)
CLUTCH_STATES = 'clutch_states'
DIAGNOSTICS = '/diagnostics'
CRANK_LENGTH_CMD = 'crank_length_cmd'
LOAD_TORQUE_CMD = 'load_torque_cmd'
#: topic_based_ros2_control's command topic (its ``joint_commands_topic``, remapped here): a
#: sensor_msgs/JointState whose entry ``<joint_prefix>crank_length`` carries the crank-length
#: command as its position [m]; every other entry is ignored.
JOINT_COMMANDS = 'joint_commands'
#: The latest sample, latched (transient local, keep last 1): a controller that starts after the
#: node (or after a reset) gets the present sample at once. Same content as joint_states; not in
#: TOPICS (recordings carry joint_states, not this copy).
STATE = 'state'
STATE_QOS = {'history': 'keep_last', 'depth': 1, 'reliability': 'reliable',
             'durability': 'transient_local'}

_INFINITE = {'sec': 9223372036, 'nsec': 854775807}


def _qos(history: str, depth: int, reliability: str, durability: str) -> dict[str, Any]:
    return {'history': history, 'depth': depth, 'reliability': reliability,
            'durability': durability}


#: QoS of each topic as a plain map (policy names as rosbag2 writes them).
QOS: dict[str, dict[str, Any]] = {
    # what robot_state_publisher, `ros2 topic echo` and PlotJuggler expect by default
    'joint_states': _qos('keep_last', 10, 'reliable', 'volatile'),
    # latched: a late subscriber gets the present clutch state
    'clutch_engaged': _qos('keep_last', 1, 'reliable', 'transient_local'),
    # rclcpp::ClockQoS, as rosbag2's player publishes it
    'clock': _qos('keep_last', 1, 'best_effort', 'volatile'),
    'diagnostics': _qos('keep_last', 10, 'reliable', 'volatile'),
    'crank_length_cmd': _qos('keep_last', 10, 'reliable', 'volatile'),
    'load_torque_cmd': _qos('keep_last', 10, 'reliable', 'volatile'),
    # what topic_based_ros2_control's publisher offers (rclcpp::QoS(1)) and more
    'joint_commands': _qos('keep_last', 10, 'reliable', 'volatile'),
    # as joint_states, but latched (a late subscriber gets the present states at once, as with
    # clutch_engaged; volatile subscribers — PlotJuggler, `ros2 topic echo` — match it)
    'clutch_states': _qos('keep_last', 10, 'reliable', 'transient_local'),
}


@dataclass(frozen=True)
class TopicSpec:
    """One topic of the node: key, name as created (relative unless it starts with '/'),
    message type, direction ('out' published, 'in' subscribed) and what it carries."""

    key: str
    name: str
    type_name: str
    direction: str
    description: str

    @property
    def qos(self) -> dict[str, Any]:
        return dict(QOS[self.key])


TOPICS: dict[str, TopicSpec] = {s.key: s for s in (
    TopicSpec('joint_states', JOINT_STATES, 'sensor_msgs/msg/JointState', 'out',
              'one sample per control period; stamp = simulation time'),
    TopicSpec('clutch_engaged', CLUTCH_ENGAGED, 'std_msgs/msg/Bool', 'out',
              'one message per clutch switch (latched)'),
    TopicSpec('clock', CLOCK, 'rosgraph_msgs/msg/Clock', 'out', 'simulation time'),
    TopicSpec('diagnostics', DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray', 'out',
              '~1 Hz of wall time'),
    TopicSpec('crank_length_cmd', CRANK_LENGTH_CMD, 'std_msgs/msg/Float64', 'in',
              'crank length command [m]'),
    TopicSpec('load_torque_cmd', LOAD_TORQUE_CMD, 'std_msgs/msg/Float64', 'in',
              'load torque command [N·m]'),
    TopicSpec('joint_commands', JOINT_COMMANDS, 'sensor_msgs/msg/JointState', 'in',
              'crank length command [m] as the position of joint crank_length '
              '(topic_based_ros2_control)'),
)}
#: Topics a machine of N ≥ 2 paths has besides TOPICS.
PATH_TOPICS: dict[str, TopicSpec] = {'clutch_states': TopicSpec(
    'clutch_states', CLUTCH_STATES, 'sensor_msgs/msg/JointState', 'out',
    'N ≥ 2 paths: clutch_1 … clutch_N, position 1/0 engaged, velocity ω2,k − ω3, effort the '
    'clutch torque; per period and at each switch')}


def topics_for(n_paths: int = 1) -> dict[str, TopicSpec]:
    """The topics of a node simulating ``n_paths`` paths (TOPICS for one)."""
    return TOPICS if n_paths == 1 else {**TOPICS, **PATH_TOPICS}


def resolve_topic(name: str, namespace: str = '/') -> str:
    """Fully qualified name of ``name`` in ``namespace`` (as rclpy resolves it, no remapping)."""
    if name.startswith('/'):
        return name
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return f'{ns}/{name}'


def resolved_topics(namespace: str = '/', n_paths: int = 1) -> dict[str, str]:
    """Key -> fully qualified topic name for a node in ``namespace``."""
    return {key: resolve_topic(spec.name, namespace) for key, spec in topics_for(n_paths).items()}


# ---------------------------------------------------------------------------------- QoS
def qos_profile(key: str):
    """The rclpy ``QoSProfile`` of topic ``key`` (imports rclpy)."""
    return _profile(QOS[key])


def _profile(q: Mapping[str, Any]):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        history={'keep_last': HistoryPolicy.KEEP_LAST,
                 'keep_all': HistoryPolicy.KEEP_ALL}[q['history']],
        depth=q['depth'],
        reliability={'reliable': ReliabilityPolicy.RELIABLE,
                     'best_effort': ReliabilityPolicy.BEST_EFFORT}[q['reliability']],
        durability={'volatile': DurabilityPolicy.VOLATILE,
                    'transient_local': DurabilityPolicy.TRANSIENT_LOCAL}[q['durability']])


def joint_states_qos():
    """joint_states: reliable, keep last 10, volatile."""
    return qos_profile('joint_states')


def clutch_qos():
    """clutch_engaged: reliable, keep last 1, transient local (latched)."""
    return qos_profile('clutch_engaged')


def clock_qos():
    """/clock: best effort, keep last 1, volatile (rclcpp::ClockQoS)."""
    return qos_profile('clock')


def diagnostics_qos():
    """/diagnostics: reliable, keep last 10, volatile."""
    return qos_profile('diagnostics')


def command_qos():
    """crank_length_cmd, load_torque_cmd as publishers offer them: reliable, keep last 10."""
    return qos_profile('crank_length_cmd')


def command_subscription_qos():
    """The node's command subscriptions: reliable, keep all, volatile. The reader keeps every
    command until the node takes it (no silent loss when commands come faster than periods);
    history is not part of QoS matching, so any reliable publisher matches."""
    return _profile({'history': 'keep_all', 'depth': 0, 'reliability': 'reliable',
                     'durability': 'volatile'})


def state_qos():
    """state: reliable, keep last 1, transient local (the latest sample, latched)."""
    return _profile(STATE_QOS)


# ---------------------------------------------------------------------------------- time
def stamp_ns(t: float) -> int:
    """Simulation time [s] -> integer nanoseconds (rounded, as the node stamps)."""
    return int(round(t * 1e9))


def set_stamp(stamp: Any, ns: int) -> None:
    """Write ``ns`` into a builtin_interfaces/Time (``sec``, ``nanosec``)."""
    stamp.sec, stamp.nanosec = divmod(int(ns), 1_000_000_000)


def time_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time (rclpy or rosbags object) -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


# ---------------------------------------------------------------------------------- builders
def joint_state_from_row(row: Sequence[float], stamp: int | None = None,
                         names: Sequence[str] = JOINTS, msg: Any = None):
    """sensor_msgs/JointState of one sample row; ``stamp`` [ns] defaults to the row's time.

    ``msg``: a JointState to fill in place (the node reuses one), else a new one.
    """
    import array

    from sensor_msgs.msg import JointState

    if msg is None:
        msg = JointState()
    msg.name = list(names)
    set_stamp(msg.header.stamp, stamp_ns(row[_T]) if stamp is None else stamp)
    msg.position = array.array('d', [float(row[i]) for i in _POSITION])
    msg.velocity = array.array('d', [float(row[i]) for i in _VELOCITY])
    msg.effort = array.array('d', [float(row[i]) for i in _EFFORT])
    return msg


def clutch_msg(engaged: bool):
    """std_msgs/Bool: the clutch state (true = engaged)."""
    from std_msgs.msg import Bool

    return Bool(data=bool(engaged))


def clock_msg(ns: int):
    """rosgraph_msgs/Clock at ``ns`` nanoseconds of simulation time."""
    from rosgraph_msgs.msg import Clock

    msg = Clock()
    set_stamp(msg.clock, ns)
    return msg


def command_msg(value: float):
    """std_msgs/Float64 command (crank length [m] or load torque [N·m])."""
    from std_msgs.msg import Float64

    return Float64(data=float(value))


# ---------------------------------------------------------------------------------- CDR bytes
# Plain little-endian CDR (XCDR1) as rmw_fastrtps writes it: 4-byte encapsulation header, each
# primitive aligned to its size relative to the end of the header.
_ENCAPSULATION = b'\x00\x01\x00\x00'
_TIME = struct.Struct('<iI')


def _pad(offset: int, align: int) -> int:
    return (-offset) % align


def _string(text: str, offset: int) -> bytes:
    data = text.encode('utf-8') + b'\x00'
    return b'\x00' * _pad(offset, 4) + struct.pack('<I', len(data)) + data


class JointStateEncoder:
    """JointState CDR for fixed joint names and frame_id: a constant layout, one pack per row
    (the same bytes as rclpy's serialize_message, zero padding)."""

    def __init__(self, names: Sequence[str], frame_id: str = ''):
        body = bytearray(8)  # stamp, packed per message
        body += _string(frame_id, len(body))
        body += b'\x00' * _pad(len(body), 4) + struct.pack('<I', len(names))
        for name in names:
            body += _string(name, len(body))
        n = len(names)
        self._prefix = bytes(body[8:])  # frame_id and names, constant
        parts = []
        offset = len(body)
        for _ in range(3):  # position, velocity, effort
            pad = _pad(offset, 4)
            offset += pad + 4
            pad8 = _pad(offset, 8) if n else 0
            parts.append((pad, pad8))
            offset += pad8 + 8 * n
        self.n = n
        self.size = 4 + offset
        fmt = '<iI' + f'{len(self._prefix)}s'
        for pad, pad8 in parts:
            fmt += f'{pad}xI{pad8}x{n}d'
        self._struct = struct.Struct(fmt)

    def encode(self, sec: int, nanosec: int, values: Sequence[float]) -> bytes:
        """``values``: the position, velocity and effort values (n each), joint by joint."""
        n = self.n
        return _ENCAPSULATION + self._struct.pack(sec, nanosec, self._prefix, n, *values[0:n],
                                                  n, *values[n:2 * n], n, *values[2 * n:3 * n])


class JointStateDecoder:
    """Raw JointState CDR (a subscription with ``raw=True``) → ``(ns, position, velocity,
    effort)``, the three as tuples of floats. The layout (frame_id, names) is learnt from the
    first message by the general parser; later messages with that layout — a node's stream,
    whose names do not change — are read with one struct call (~1 µs; rclpy's message object
    takes ~12 µs), any other one by the parser again. ``names``: the joint names of the last
    message. ValueError for bytes that are not a little-endian CDR JointState."""

    def __init__(self):
        self.names: list[str] | None = None
        self._layout: JointStateEncoder | None = None

    def decode(self, data: bytes) -> tuple[int, tuple, tuple, tuple]:
        layout = self._layout
        if layout is not None and len(data) == layout.size:
            f = layout._struct.unpack_from(data, len(_ENCAPSULATION))
            n = layout.n
            if f[2] == layout._prefix and f[3] == f[4 + n] == f[5 + 2 * n] == n:
                return (f[0] * 1_000_000_000 + f[1], f[4:4 + n], f[5 + n:5 + 2 * n],
                        f[6 + 2 * n:6 + 3 * n])
        ns, frame_id, names, *values = _parse_joint_state(data)
        self.names = names
        self._layout = None
        if all(len(v) == len(names) for v in values):
            layout = JointStateEncoder(names, frame_id)
            if layout.size == len(data):   # (a publisher that pads differently: no fast path)
                self._layout = layout
        return (ns, *values)


def joint_state_stamp_ns(data: bytes) -> int:
    """The header stamp [ns] of raw JointState CDR (the first field of any stamped message)."""
    sec, nanosec = _TIME.unpack_from(data, len(_ENCAPSULATION))
    return sec * 1_000_000_000 + nanosec


_ENCODERS: dict[tuple[tuple[str, ...], str], JointStateEncoder] = {}


def joint_state_cdr(row: Sequence[float], stamp: int | None = None,
                    names: Sequence[str] = JOINTS, frame_id: str = '') -> bytes:
    """CDR bytes of :func:`joint_state_from_row` without rclpy (rclpy's layout, zero padding)."""
    key = (tuple(names), frame_id)
    encoder = _ENCODERS.get(key)
    if encoder is None:
        if len(names) != 4:
            raise ValueError(f'joint_states has 4 joints, got names {list(names)!r}')
        encoder = _ENCODERS[key] = JointStateEncoder(key[0], frame_id)
    ns = stamp_ns(row[_T]) if stamp is None else int(stamp)
    sec, nanosec = divmod(ns, 1_000_000_000)
    if hasattr(row, 'take'):  # a numpy row: one gather instead of 12 scalar reads
        values = row.take(_FIELDS).tolist()
    else:
        values = [float(row[i]) for i in _FIELDS]
    return encoder.encode(sec, nanosec, values)


def _path_column(quantity: str, k: int, n_paths: int) -> int:
    """Index of ``{quantity}_{k}`` in a sample row of ``output.path_columns(n_paths)``."""
    return N_COLUMNS + PATH_QUANTITIES.index(quantity) * n_paths + (k - 1)


class SampleLayout:
    """joint_states (and, N ≥ 2, clutch_states) of a machine of ``n_paths`` paths from its
    sample rows (``output.path_columns(n_paths)``): the node's and the recorder's encoders.

    joint_states: ``device_joint_names`` (``prefix`` applied); position φ1, φ2 (each rocker),
    φ3, φ4, a; velocity ω1, ω2 (each), ω3, ω4, ȧ; effort M1, the clutch torque (each path's),
    Ts, M4, NaN (the actuator's force is not modelled). For N = 1 the bytes are today's.
    """

    def __init__(self, n_paths: int = 1, prefix: str = '', frame_id: str = ''):
        self.n_paths = n = int(n_paths)
        self.names = device_joint_names(n, prefix)
        if n == 1:
            rockers = [(COL['phi2'], COL['omega2'], COL['clutch_torque'])]
        else:
            rockers = [(_path_column('phi2', k, n), _path_column('omega2', k, n),
                        _path_column('clutch_torque', k, n)) for k in range(1, n + 1)]
        a = COL['crank_length']
        fields = ([COL['phi1']] + [r[0] for r in rockers] + [COL['phi3'], COL['phi4'], a]
                  + [COL['omega1']] + [r[1] for r in rockers] + [COL['omega3'], COL['omega4'], a]
                  + [COL['motor_torque']] + [r[2] for r in rockers]
                  + [COL['shaft_torque'], COL['load_torque'], a])
        self.fields = fields
        joints = len(self.names)
        self.rate_slot, self.force_slot = 2 * joints - 1, 3 * joints - 1
        self.gather = operator.itemgetter(*fields)
        self.encoder = JointStateEncoder(self.names, frame_id)
        self.clutch_names = clutch_names(n, prefix) if n > 1 else ()
        if n > 1:
            self._engaged = operator.itemgetter(*[_path_column('engaged', k, n)
                                                  for k in range(1, n + 1)])
            self._speeds = operator.itemgetter(*[_path_column('omega2', k, n)
                                                 for k in range(1, n + 1)])
            self._torques = operator.itemgetter(*[_path_column('clutch_torque', k, n)
                                                  for k in range(1, n + 1)])
            self._omega3 = COL['omega3']
            self.clutch_encoder = JointStateEncoder(self.clutch_names, frame_id)
            self._frame_id = frame_id

    def joint_values(self, row: Sequence[float], crank_rate: float) -> list[float]:
        """position, velocity and effort values of ``row`` (a list or a numpy row)."""
        values = list(self.gather(row.tolist() if hasattr(row, 'tolist') else row))
        values[self.rate_slot] = crank_rate
        values[self.force_slot] = math.nan
        return values

    def joint_states(self, row: Sequence[float], crank_rate: float, ns: int) -> bytes:
        """joint_states CDR of ``row`` stamped ``ns``."""
        return self.encoder.encode(*divmod(ns, 1_000_000_000),
                                   self.joint_values(row, crank_rate))

    def clutch_states(self, row: Sequence[float], ns: int) -> bytes:
        """clutch_states CDR of ``row`` (N ≥ 2) stamped ``ns``."""
        r = row.tolist() if hasattr(row, 'tolist') else row
        w3 = r[self._omega3]
        values = [*self._engaged(r), *[w - w3 for w in self._speeds(r)], *self._torques(r)]
        return self.clutch_encoder.encode(*divmod(ns, 1_000_000_000), values)

    def clutch_switch(self, mask: int, ns: int) -> bytes:
        """clutch_states CDR of a switch at ``ns``: positions only, 1.0 for each path in the
        engaged set ``mask`` (bit k − 1 = path k)."""
        return joint_state_arrays_cdr(
            ns, self.clutch_names,
            [1.0 if mask >> k & 1 else 0.0 for k in range(self.n_paths)], (), (), self._frame_id)


def joint_state_arrays_cdr(ns: int, names: Sequence[str], position: Sequence[float],
                           velocity: Sequence[float], effort: Sequence[float],
                           frame_id: str = '') -> bytes:
    """CDR bytes of any JointState (arrays of their own lengths, e.g. empty), rclpy's layout."""
    body = bytearray(_TIME.pack(*divmod(int(ns), 1_000_000_000)))
    body += _string(frame_id, len(body))
    body += b'\x00' * _pad(len(body), 4) + struct.pack('<I', len(names))
    for name in names:
        body += _string(name, len(body))
    for values in (position, velocity, effort):
        body += b'\x00' * _pad(len(body), 4) + struct.pack('<I', len(values))
        if len(values):
            body += b'\x00' * _pad(len(body), 8) + struct.pack(f'<{len(values)}d', *values)
    return _ENCAPSULATION + bytes(body)


def clock_cdr(ns: int) -> bytes:
    """CDR bytes of rosgraph_msgs/Clock at ``ns``."""
    return _ENCAPSULATION + _TIME.pack(*divmod(int(ns), 1_000_000_000))


def bool_cdr(value: bool) -> bytes:
    """CDR bytes of std_msgs/Bool."""
    return _ENCAPSULATION + (b'\x01' if value else b'\x00')


def float64_cdr(value: float) -> bytes:
    """CDR bytes of std_msgs/Float64."""
    return _ENCAPSULATION + struct.pack('<d', float(value))


_FLOAT64_LE = struct.Struct('<d')
_FLOAT64_BE = struct.Struct('>d')


def float64_value(data: bytes) -> float:
    """The value of std_msgs/Float64 CDR bytes (either byte order: the encapsulation's low bit
    says which, CDR or XCDR2 alike; the double right after the 4-byte header). ValueError for
    bytes too short to be one."""
    if len(data) < 12:
        raise ValueError(f"{len(data)} bytes are not a std_msgs/Float64 (12 bytes)")
    return (_FLOAT64_LE if data[1] & 1 else _FLOAT64_BE).unpack_from(data, 4)[0]


# ---------------------------------------------------------------------------------- decoders
@dataclass(frozen=True)
class JointStateValues:
    """A decoded joint_states sample in the joint order J1..J4 (``JOINTS``).

    ``stamp_ns`` simulation time; ``position``, ``velocity``, ``effort`` 4-tuples (NaN where the
    message had no value).
    """

    stamp_ns: int
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]

    @property
    def twist(self) -> float:
        """Torsion twist θ = φ3 − φ4 [rad] (absolute precision ~2.2e-16·|φ4|)."""
        return self.position[2] - self.position[3]

    def as_columns(self) -> dict[str, float]:
        """The sample-row columns this message carries (t, phi1..4, omega1..4, twist, torques)."""
        out = {'t': self.stamp_ns * 1e-9}
        out.update(zip(POSITION_COLUMNS, self.position, strict=True))
        out.update(zip(VELOCITY_COLUMNS, self.velocity, strict=True))
        out.update(zip(EFFORT_COLUMNS, self.effort, strict=True))
        out['twist'] = self.twist
        return out


def _joint_index(names: Sequence[str], joint: str) -> int | None:
    hits = [i for i, n in enumerate(names) if n == joint]
    if not hits:
        hits = [i for i, n in enumerate(names) if n.endswith(joint)]
    return hits[0] if len(hits) == 1 else None


def joint_order(names: Sequence[str]) -> list[int] | None:
    """Index of each of ``JOINTS`` in a message's name list (a name may carry a prefix, e.g.
    ``line1_crank``); None if a joint is missing or ambiguous. A machine of N ≥ 2 paths has
    ``rocker_1`` in the place of ``rocker``: path 1's rocker (``rocker_order`` gives them all)."""
    order = []
    for joint in JOINTS:
        i = _joint_index(names, joint)
        if i is None and joint == ROCKER:
            i = _joint_index(names, f'{ROCKER}_1')
        if i is None:
            return None
        order.append(i)
    return order


def rocker_order(names: Sequence[str]) -> list[int]:
    """Index of each rocker in a message's name list: ``rocker_1 … rocker_N`` (N ≥ 2, as many
    as there are in a row from 1), else ``[rocker]``'s; [] if none."""
    order = []
    while (i := _joint_index(names, f'{ROCKER}_{len(order) + 1}')) is not None:
        order.append(i)
    if order:
        return order
    i = _joint_index(names, ROCKER)
    return [] if i is None else [i]


def _pick(values: Sequence[float], order: Sequence[int]) -> tuple[float, ...]:
    n = len(values)
    return tuple(float(values[i]) if i < n else math.nan for i in order)


def decode_joint_state(msg: Any, order: Sequence[int] | None = None) -> JointStateValues:
    """JointState (rclpy or rosbags object) -> :class:`JointStateValues` in joint order.

    ``order``: from :func:`joint_order` (pass it to skip the name matching per message).
    Raises ValueError if the joints of this node are not in the message.
    """
    if order is None:
        order = joint_order(list(msg.name))
        if order is None:
            raise ValueError(f'joint_states without the joints {JOINTS}: {list(msg.name)!r}')
    return JointStateValues(time_to_ns(msg.header.stamp), _pick(msg.position, order),
                            _pick(msg.velocity, order), _pick(msg.effort, order))


class _Cursor:
    __slots__ = ('data', 'pos')

    def __init__(self, data: bytes):
        self.data = data
        self.pos = 4  # after the encapsulation header

    def align(self, n: int) -> None:
        self.pos += (-(self.pos - 4)) % n

    def u32(self) -> int:
        self.align(4)
        (value,) = struct.unpack_from('<I', self.data, self.pos)
        self.pos += 4
        return value

    def string(self) -> str:
        n = self.u32()
        text = self.data[self.pos:self.pos + n - 1].decode('utf-8')
        self.pos += n
        return text

    def doubles(self) -> tuple[float, ...]:
        n = self.u32()
        if not n:
            return ()
        self.align(8)
        values = struct.unpack_from(f'<{n}d', self.data, self.pos)
        self.pos += 8 * n
        return values


def decode_joint_state_cdr(data: bytes, order: Sequence[int] | None = None
                           ) -> tuple[JointStateValues, list[str]]:
    """Decode sensor_msgs/JointState CDR bytes without ROS: (values in joint order, names).

    Raises ValueError on bytes that are not a little-endian CDR JointState of this node.
    """
    ns, _, names, position, velocity, effort = _parse_joint_state(data)
    if order is None:
        order = joint_order(names)
        if order is None:
            raise ValueError(f'joint_states without the joints {JOINTS}: {names!r}')
    values = JointStateValues(ns, _pick(position, order), _pick(velocity, order),
                              _pick(effort, order))
    return values, names


def joint_command_position(names: Sequence[str], positions: Sequence[float], index: int
                           ) -> float:
    """The position a joint_commands message gives the joint ``names[index]``: its own entry
    when there is one position per name, the only one when there is one (TopicBasedSystem names
    every joint but sends positions only for those with a position command interface: here
    crank_length alone). ValueError(what, reason) otherwise."""
    name = names[index]
    if not positions:
        raise ValueError('0 positions', f"no position for joint {name!r} (entry {index})")
    if len(positions) == len(names):
        return float(positions[index])
    if len(positions) == 1:
        return float(positions[0])
    raise ValueError(f"{len(positions)} positions for {len(names)} names",
                     f"which one is joint {name!r}'s? (one position per name, or one position: "
                     f"{name!r}'s, as TopicBasedSystem sends it when only {name!r} has a "
                     f"position command interface)")


def joint_command_crank_length(data: bytes) -> float | None:
    """The crank-length command [m] of joint_commands CDR bytes, read as the node reads it
    (:func:`joint_command_position` of the entry named ACTUATOR_JOINT, with any joint prefix);
    None when there is none or it is not finite (the node refuses those)."""
    try:
        _, _, names, positions, _, _ = _parse_joint_state(data)
        index = next(i for i, name in enumerate(names) if name.endswith(ACTUATOR_JOINT))
        value = joint_command_position(names, positions, index)
    except (ValueError, StopIteration):
        return None
    return value if math.isfinite(value) else None


def parse_joint_state_cdr(data: bytes) -> tuple[int, str, list[str], tuple, tuple, tuple]:
    """Any little-endian CDR JointState: (stamp [ns], frame_id, names, position, velocity,
    effort), each array as long as the message has it (e.g. clutch_states' switch messages:
    positions only); ValueError for other bytes."""
    return _parse_joint_state(data)


def _parse_joint_state(data: bytes) -> tuple[int, str, list[str], tuple, tuple, tuple]:
    """Any little-endian CDR JointState: (stamp [ns], frame_id, names, position, velocity,
    effort); ValueError for other bytes."""
    if len(data) < 12 or data[1] != 1:
        raise ValueError('not a little-endian CDR message')
    try:
        sec, nanosec = _TIME.unpack_from(data, 4)
        cur = _Cursor(data)
        cur.pos = 12
        frame_id = cur.string()
        names = [cur.string() for _ in range(cur.u32())]
        position, velocity, effort = cur.doubles(), cur.doubles(), cur.doubles()
    except (struct.error, UnicodeDecodeError) as exc:
        raise ValueError(f'damaged JointState bytes: {exc}') from None
    return (sec * 1_000_000_000 + nanosec, frame_id, names, tuple(position), tuple(velocity),
            tuple(effort))


def topic_key(name: str, keys: Mapping[str, str] | None = None) -> str | None:
    """The interface key of a recorded topic name (``/line1/joint_states`` -> 'joint_states');
    ``keys`` maps resolved names to keys when known. None for a foreign topic."""
    if keys and name in keys:
        return keys[name]
    for key, spec in topics_for(2).items():
        if name == spec.name or (not spec.name.startswith('/')
                                 and name.endswith('/' + spec.name)):
            return key
    return None
