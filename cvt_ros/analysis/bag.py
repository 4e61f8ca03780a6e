"""An MCAP recording (ours, or ``ros2 bag record`` of the node's topics) into runs.

``joint_states`` messages are decoded in one numpy gather when they share a layout; the clutch
switches and commands are attached to the run whose log-time span holds them, on the
simulation-time axis (our recorder keeps a message's simulation time in ``publish_time``; for
other recorders the log time is mapped onto simulation time through the joint_states stamps).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import interface as I
from ..physics.linkage import GrashofError, check_crank_length
from .errors import AnalysisError
from .trace import Command, PathTrace, RecordingInfo, Trace

#: the set point of a controller-kit recording (``cvt-sim scenario run --mcap``; std_msgs/Float64)
SETPOINT_TOPIC = '/setpoint'

__all__ = ['load_mcap']


#: Joint name of the crank-length actuator in the node's joint_states (position = the actual
#: crank length [m]); recordings made before it was published have none.
ACTUATOR_JOINT = 'crank_length'
#: More runs than this (simulation time going back again and again) is no recording of a node.
MAX_RUNS = 1000
GAP_FACTOR = 4.0   # a damaged file: a hole of more than this many sample intervals splits a run


@dataclass(frozen=True)
class _Layout:
    """Where the values sit in one JointState CDR message of this recording."""

    order: list[int]          # index of J1..J4 in the message's arrays
    actuator: int | None      # index of the crank-length joint, if published
    rockers: list[int]        # index of each rocker (N ≥ 2 paths: rocker_1 … rocker_N)
    offsets: list[int]        # byte offsets of the position / velocity / effort doubles
    count: int                # joints per array
    size: int                 # message length

    def structure_mask(self) -> np.ndarray:
        """True for the bytes every message of this layout shares (all but stamp and values)."""
        mask = np.ones(self.size, dtype=bool)
        mask[4:12] = False
        for off in self.offsets:
            mask[off:off + 8 * self.count] = False
        return mask


def _actuator_index(names: list[str]) -> int | None:
    hits = [i for i, n in enumerate(names) if n == ACTUATOR_JOINT]
    if not hits:
        hits = [i for i, n in enumerate(names) if n.endswith('_' + ACTUATOR_JOINT)]
    return hits[0] if len(hits) == 1 else None


def _jointstate_layout(data: bytes) -> _Layout | None:
    """The layout of one JointState CDR message; None if it is not one of this node."""
    try:
        _, names = I.decode_joint_state_cdr(data)
    except ValueError:
        return None
    order = I.joint_order(names)
    if order is None:
        return None
    try:
        cur = I._Cursor(data)
        cur.pos = 12
        cur.string()
        for _ in range(cur.u32()):
            cur.string()
        offsets = []
        count = len(names)
        for _ in range(3):
            if cur.u32() != count:
                return None
            cur.align(8)
            offsets.append(cur.pos)
            cur.pos += 8 * count
    except (ValueError, UnicodeDecodeError, struct.error):
        return None
    if cur.pos != len(data):
        return None
    return _Layout(order, _actuator_index(names), I.rocker_order(names), offsets, count,
                   len(data))


def _decode_joint_states(datas: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray, np.ndarray, np.ndarray,
                                                       list[str], list[np.ndarray] | None]:
    """Decode many JointState messages: decoded (m,) bool, stamp_ns (m,), position, velocity,
    effort (m, 4), actual crank length (m,) (NaN: not published), problems, and for N ≥ 2
    paths each rocker's position, velocity and effort (m, N) (None for one path; effort J2 is
    then their sum: what all the clutches pass to J3).

    Messages with the layout (and the same names, frame and counts, byte for byte) of the first
    decodable one are decoded in one numpy gather; the others one by one.
    """
    m = len(datas)
    stamps = np.zeros(m, dtype=np.int64)
    out = [np.full((m, 4), np.nan) for _ in range(3)]
    crank = np.full(m, np.nan)
    problems: list[str] = []
    first, layout = next(((k, lay) for k, lay in enumerate(map(_jointstate_layout, datas))
                          if lay is not None), (None, None))
    if layout is None:
        raise AnalysisError('joint_states messages do not carry the joints '
                            f'{", ".join(I.JOINTS)}')
    n_paths = len(layout.rockers)
    rockers = [np.full((m, n_paths), np.nan) for _ in range(3)] if n_paths > 1 else None
    lengths = np.fromiter((len(d) for d in datas), dtype=np.int64, count=m)
    same_size = np.flatnonzero(lengths == layout.size)
    fast = np.zeros(m, dtype=bool)
    if len(same_size):
        buf = np.frombuffer(b''.join(datas[i] for i in same_size),
                            dtype=np.uint8).reshape(-1, layout.size)
        mask = layout.structure_mask()
        template = np.frombuffer(datas[first], dtype=np.uint8)[mask]
        ok = np.all(buf[:, mask] == template, axis=1)
        rows, buf = same_size[ok], buf[ok]
        fast[rows] = True
        sec = buf[:, 4:8].copy().view('<i4')[:, 0].astype(np.int64)
        nsec = buf[:, 8:12].copy().view('<u4')[:, 0].astype(np.int64)
        stamps[rows] = sec * 1_000_000_000 + nsec
        for k, off in enumerate(layout.offsets):
            block = buf[:, off:off + 8 * layout.count].copy().view('<f8')
            out[k][rows] = block[:, layout.order]
            if rockers is not None:
                rockers[k][rows] = block[:, layout.rockers]
            if k == 0 and layout.actuator is not None:
                crank[rows] = block[:, layout.actuator]
    bad = 0
    for i in np.flatnonzero(~fast):  # fast: decoded so far
        try:
            values, names = I.decode_joint_state_cdr(datas[i])
            if rockers is not None:
                order = I.rocker_order(names)
                if len(order) != n_paths:
                    raise ValueError(f'{len(order)} rockers')
                arrays = I.parse_joint_state_cdr(datas[i])[3:]
                for k in range(3):
                    rockers[k][i] = [arrays[k][j] if j < len(arrays[k]) else np.nan
                                     for j in order]
        except ValueError:
            bad += 1
            continue
        stamps[i] = values.stamp_ns
        fast[i] = True
        out[0][i], out[1][i], out[2][i] = values.position, values.velocity, values.effort
    if bad:
        problems.append(f'{bad} joint_states message(s) could not be decoded and were skipped')
    if rockers is not None:   # J2's effort: every clutch's torque on J3, summed in path order
        total = np.zeros(m)
        for k in range(n_paths):
            total = total + rockers[2][:, k]
        out[2][:, 1] = total
    return fast, stamps, out[0], out[1], out[2], crank, problems, rockers


def _finite_samples(stamps: np.ndarray, pos: np.ndarray, vel: np.ndarray, eff: np.ndarray
                    ) -> np.ndarray:
    """Samples a node can have published: a stamp ≥ 0 and finite values (an effort column the
    recording never fills, e.g. no motor torque, stays NaN and does not count)."""
    carried = np.any(np.isfinite(eff), axis=0)
    with np.errstate(invalid='ignore'):
        return ((stamps >= 0) & np.all(np.isfinite(pos), axis=1)
                & np.all(np.isfinite(vel), axis=1)
                & ~np.any(~np.isfinite(eff) & carried, axis=1))


def _pick_topics(topics: Mapping[str, tuple[str, int]], namespace: str | None,
                 recorded: Any) -> dict[str, str]:
    """Interface key -> topic name in this recording (``recorded``: the recorder's own map,
    used when it is a plain str → str map naming recorded topics)."""
    if isinstance(recorded, dict) and namespace is None:
        mapped = {k: v for k, v in recorded.items() if isinstance(k, str) and isinstance(v, str)
                  and k in I.topics_for(2) and v in topics}
        if mapped.get('joint_states') and \
                topics[mapped['joint_states']][0] == 'sensor_msgs/msg/JointState':
            return mapped
    js = [name for name, (type_name, _) in topics.items()
          if type_name == 'sensor_msgs/msg/JointState']
    if namespace is not None:
        want = I.resolve_topic(I.JOINT_STATES, namespace)
        js = [name for name in js if name == want]
        if not js:
            raise AnalysisError(f'no topic {want} (sensor_msgs/msg/JointState) in the recording')
    if not js:
        raise AnalysisError('no sensor_msgs/msg/JointState topic in the recording: not a '
                            'recording of the cvt_sim node')
    if len(js) > 1:
        named = [name for name in js if name.endswith('/' + I.JOINT_STATES)]
        if len(named) != 1:
            raise AnalysisError(f'several JointState topics ({", ".join(sorted(js)[:5])}); '
                                'choose one with --namespace')
        js = named
    joint_states = js[0]
    ns = joint_states[:-len(I.JOINT_STATES)] if joint_states.endswith(I.JOINT_STATES) else '/'
    picked = {'joint_states': joint_states}
    for key, spec in I.topics_for(2).items():
        if key == 'joint_states':
            continue
        name = I.resolve_topic(spec.name, ns)
        if name in topics and topics[name][0] == spec.type_name:
            picked[key] = name
    return picked


def _yaml(text: Any) -> Any:
    """A metadata value read as YAML (no aliases, bounded nesting); None if it is not YAML."""
    from ..yaml_file import parse_value

    if not isinstance(text, str):
        return None
    value = parse_value(text)
    return None if value is text and text.strip() else value


def _recorded_parameters(meta: Mapping[str, str], notes: list[str]) -> dict[str, Any] | None:
    """The scene parameters stored by the recorder, validated like a scene (names this version
    does not know are left out with a note); None, with a note, if they are unusable."""
    from ..parameters import SPECS, validate
    from ..physics.linkage import GrashofError

    if 'parameters' not in meta:
        return None
    raw = _yaml(meta['parameters'])
    if not isinstance(raw, dict) or not raw:
        notes.append('the recorded scene parameters are unreadable: energy figures need '
                     '--scene')
        return None
    unknown = sorted(str(k) for k in raw if k not in SPECS)
    known = {k: v for k, v in raw.items() if k in SPECS}
    if unknown:
        notes.append(f'recorded parameters not known to this version left out: '
                     f'{", ".join(unknown[:5])}' + (' …' if len(unknown) > 5 else ''))
    try:
        return validate(known)
    except (ValueError, TypeError, GrashofError) as exc:
        notes.append(f'the recorded scene parameters are invalid ({exc}): energy figures need '
                     '--scene')
        return None


def load_mcap(path: str, *, namespace: str | None = None
              ) -> tuple[list[Trace], RecordingInfo]:
    """Read an MCAP recording (ours, or ``ros2 bag record`` of the node's topics)."""
    from ..recording import RecordingReadError, read_messages, summary
    from ..recording.recorder import METADATA_NAME, PARAMETER_CHANGE_NAME

    info = RecordingInfo(path, 'mcap')
    try:
        bag = summary(path)
    except RecordingReadError as exc:
        raise AnalysisError(str(exc)) from None
    info.problems.extend(bag.problems)
    info.topics = {name: (t.type_name, t.message_count) for name, t in bag.topics.items()}
    meta = bag.metadata.get(METADATA_NAME, {})
    ours = bool(meta)
    notes: list[str] = []
    parameters = _recorded_parameters(meta, notes)
    info.source = str(meta.get('source', ''))[:200]
    info.scene = str(meta.get('scene', ''))[:200]
    if not info.topics and info.problems:
        raise AnalysisError(f'{path}: nothing readable ({info.problems[0]})')
    picked = _pick_topics(info.topics, namespace, _yaml(meta.get('topics')))
    keys = {name: key for key, name in picked.items()}
    js_data: list[bytes] = []
    js_log: list[int] = []
    events: list[tuple[str, int, int, bytes]] = []
    setpoint: list[tuple[float, float]] = []   # a controller-kit run's set point (sim time)
    if info.topics.get(SETPOINT_TOPIC, ('',))[0] == 'std_msgs/msg/Float64':
        keys[SETPOINT_TOPIC] = 'setpoint'
    try:
        for m in read_messages(path, topics=list(keys)):
            key = keys[m.topic]
            if key == 'setpoint':
                value = _event_value(key, m.data)
                if value is not None:
                    setpoint.append(((m.publish_time_ns if ours else m.log_time_ns) * 1e-9,
                                     value))
            elif key == 'joint_states':
                js_data.append(m.data)
                js_log.append(m.log_time_ns)
            elif key in ('clutch_engaged', 'crank_length_cmd', 'load_torque_cmd',
                         'joint_commands', 'clutch_states'):
                events.append((key, m.log_time_ns, m.publish_time_ns, m.data))
    except RecordingReadError as exc:
        # the summary's scan reported the same damage; keep the reader's wording once
        if not any(p in str(exc) for p in info.problems):
            info.problems.append(str(exc))
    if not js_data:
        why = '; '.join(info.problems) if info.problems else 'no joint_states messages'
        raise AnalysisError(f'{path}: nothing to analyse ({why})')
    decoded, stamps, pos, vel, eff, crank, problems, rockers = _decode_joint_states(js_data)
    info.problems.extend(problems)
    good = decoded & _finite_samples(stamps, pos, vel, eff)
    skipped = int(np.count_nonzero(decoded & ~good))
    if skipped:
        info.problems.append(f'{skipped} joint_states sample(s) with non-finite values or a '
                             'negative stamp skipped')
    samples = _Samples(stamps[good], np.asarray(js_log, dtype=np.int64)[good], pos[good],
                       vel[good], eff[good], crank[good],
                       None if rockers is None else [r[good] for r in rockers])
    changes = []
    if ours:
        for name, record in bag.metadata_records:   # one record per live change
            if name == PARAMETER_CHANGE_NAME:
                change = _yaml(record.get('parameters', ''))
                try:
                    changes.append((int(record.get('time_ns', 0)),
                                    change if isinstance(change, dict) else {}))
                except ValueError:
                    pass
    traces = _split_runs(path, samples, events, parameters, ours, info, changes)
    for trace in traces:
        trace.notes[:0] = notes
        # the set point in force over the run: the last value before it and the changes in it
        inside = [p for p in setpoint if trace.t[0] < p[0] <= trace.t[-1]]
        before = [p for p in setpoint if p[0] <= trace.t[0]]
        trace.setpoint = before[-1:] + inside
    return traces, info


def _event_value(key: str, data: bytes) -> float | None:
    """The value of a clutch_engaged (Bool) or command (Float64) message; None if the bytes
    are not one (or a command is not finite: the node refuses those)."""
    if len(data) < 5 or data[1] not in (0, 1):
        return None
    if key == 'clutch_engaged':
        return float(data[4] != 0) if data[4] in (0, 1) else None
    if len(data) < 12:
        return None
    value = I.float64_value(data)
    return value if math.isfinite(value) else None


def _clutch_set(data: bytes, rockers: list[np.ndarray] | None
                ) -> tuple[float, tuple[float, ...]] | None:
    """(stamp [s], each clutch's position: 1 engaged) of a clutch_states message; None for
    bytes that are not one of this machine (N = the recorded rockers)."""
    if rockers is None:
        return None
    try:
        ns, _, names, position, _, _ = I.parse_joint_state_cdr(data)
    except ValueError:
        return None
    n = rockers[0].shape[1]
    if len(position) != n or len(names) != n or not all(v in (0.0, 1.0) for v in position):
        return None
    return ns * 1e-9, tuple(position)


def _path_trace(rockers: list[np.ndarray], t0: float,
                clutch_sets: list[tuple[float, tuple[float, ...]]], exact: bool) -> PathTrace:
    """Each path's signals of one run and each clutch's switches: a change of its state from
    one clutch_states message to the next, at the later one's stamp (a switch message carries
    the switch's own time; without it, the period's message places it ≤ one period late)."""
    n = rockers[0].shape[1]
    ordered = sorted(clutch_sets, key=lambda c: c[0])
    head = [c for c in ordered if c[0] <= t0 + 1e-12]
    state = list(head[-1][1]) if head else None
    rest = ordered[len(head):]
    if state is None and rest:
        state = list(rest[0][1])
    switch_t: list[list[float]] = [[] for _ in range(n)]
    switch_on: list[list[bool]] = [[] for _ in range(n)]
    initial = None if state is None else tuple(v == 1.0 for v in state)
    for ts, values in rest:
        for k in range(n):
            if values[k] != state[k]:
                switch_t[k].append(ts)
                switch_on[k].append(values[k] == 1.0)
        state = list(values)
    return PathTrace(rockers[0], rockers[1], rockers[2],
                     [np.asarray(v, dtype=float) for v in switch_t],
                     [np.asarray(v, dtype=bool) for v in switch_on], initial, exact)


@dataclass
class _Samples:
    """Decoded joint_states samples in file order (arrays of one length)."""

    stamps: np.ndarray        # int64 [ns]
    log: np.ndarray           # int64 log times [ns]
    pos: np.ndarray
    vel: np.ndarray
    eff: np.ndarray
    crank: np.ndarray
    rockers: list[np.ndarray] | None = None   # N ≥ 2: position, velocity, effort (m, N)

    def take(self, keep: np.ndarray) -> _Samples:
        return _Samples(self.stamps[keep], self.log[keep], self.pos[keep], self.vel[keep],
                        self.eff[keep], self.crank[keep],
                        None if self.rockers is None else [r[keep] for r in self.rockers])


#: live parameter changes that act as a command does (analysis: a step like the command's)
LIVE_COMMANDS = {'load.torque': 'load_torque_cmd', 'linkage.crank_length': 'crank_length_cmd'}


def _finite(value: Any) -> float | None:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


def _refused(key: str, value: float, params: dict | None) -> bool:
    """Whether the node refused this command, by the checks it makes on the parameters in force
    (a crank length outside [0, Grashof bound): physics.linkage.check_crank_length; a load
    beyond limits.load_torque); False when the recording has no parameters."""
    if not params:
        return False
    try:
        if key == 'crank_length_cmd':
            check_crank_length(value, float(params['linkage.rocker_length']),
                               float(params['linkage.coupler_length']),
                               float(params['linkage.pivot_distance']))
            return False
        return abs(value) > float(params['limits.load_torque'])
    except GrashofError:
        return True
    except (KeyError, TypeError, ValueError):
        return False


def _split_runs(path: str, samples: _Samples, events: list, parameters: dict | None,
                ours: bool, info: RecordingInfo, changes: list) -> list[Trace]:
    """Cut the samples into runs where the stamp goes back; attach events by log time."""
    stamps = samples.stamps
    # a repeated stamp is a duplicate sample (e.g. paused and stepped): drop it, do not cut
    dup = np.flatnonzero(np.diff(stamps) == 0) + 1
    if len(dup):
        keep = np.ones(len(stamps), bool)
        keep[dup] = False
        samples = samples.take(keep)
        stamps = samples.stamps
    steps = np.diff(stamps)
    cuts = np.flatnonzero(steps < 0) + 1
    gaps = set()
    if info.problems and np.any(steps > 0):
        # a damaged file's skipped chunk leaves a hole in the samples: the crank may turn
        # several times across it. The intact stretches on either side are analysed apart
        typical = float(np.median(steps[steps > 0]))
        gaps = set((np.flatnonzero(steps > GAP_FACTOR * typical) + 1).tolist())
        cuts = np.union1d(cuts, sorted(gaps)).astype(int)
    bounds = [0, *cuts.tolist(), len(stamps)]
    if len(bounds) - 1 > MAX_RUNS:
        info.problems.append(f'simulation time goes back {len(cuts)} times: not the recording '
                             f'of a node; only the first {MAX_RUNS} runs are analysed')
        bounds = bounds[:MAX_RUNS + 1]
    # events in log-time order, so each run's events are one slice (searchsorted)
    order = np.argsort(np.array([e[1] for e in events], dtype=np.int64), kind='stable')
    events = [events[i] for i in order]
    ev_log = np.array([e[1] for e in events], dtype=np.int64)
    traces = []
    for r in range(len(bounds) - 1):
        lo, hi = bounds[r], bounds[r + 1]
        if hi - lo < 2:
            continue
        first_log = samples.log[lo]
        next_log = samples.log[hi] if hi < len(samples.log) else None
        t = stamps[lo:hi] * 1e-9
        start = int(np.searchsorted(ev_log, first_log, 'left')) if r else 0
        stop = int(np.searchsorted(ev_log, next_log, 'left')) if next_log is not None \
            else len(events)
        initial = None
        clutch_sets: list[tuple[float, tuple[float, ...]]] = []
        for key, _, _, data in reversed(events[:start] if r else []):
            if key == 'clutch_states' and not clutch_sets:   # the set in force at the start
                state = _clutch_set(data, samples.rockers)
                if state is not None:
                    clutch_sets.append((-math.inf, state[1]))
            if key == 'clutch_engaged':
                value = _event_value(key, data)
                initial = None if value is None else bool(value)
                break
        switch_t, switch_on, commands = [], [], []
        run_log = samples.log[lo:hi]
        # the parameters in force at the run's start: the scene's and every live change logged
        # before it (a reset keeps them); a change of the load or the crank inside the run acts
        # as that command does
        in_force = dict(parameters) if parameters else parameters
        inside = []
        for ns, change in changes:
            if ns < first_log:
                if in_force is not None:
                    in_force.update(change)
            elif next_log is None or ns < next_log:
                inside.append((ns, change))
                for name, key in LIVE_COMMANDS.items():
                    value = _finite(change.get(name))
                    if value is not None:
                        commands.append(Command(float(np.interp(ns, run_log, t)), key, value))
        refused = 0
        for key, lt, pt, data in events[start:max(start, stop)]:
            if key == 'clutch_states':   # (stamped: simulation time whoever recorded it)
                state = _clutch_set(data, samples.rockers)
                if state is not None:
                    clutch_sets.append(state)
                continue
            if key == 'joint_commands':   # topic_based_ros2_control's crank-length command
                key, value = 'crank_length_cmd', I.joint_command_crank_length(data)
            else:
                value = _event_value(key, data)
            if value is None:
                continue
            if key != 'clutch_engaged' and _refused(key, value, in_force):
                refused += 1   # recorded as received; the node did not apply it
                continue
            if ours:
                ts = pt * 1e-9  # our recorder keeps the simulation time in publish_time
            else:   # ros2 bag record: map the log time onto simulation time via joint_states
                ts = float(np.interp(lt, run_log, t))
            if key == 'clutch_engaged':
                switch_t.append(ts)
                switch_on.append(bool(value))
            else:
                commands.append(Command(ts, key, value))
        switch_t_arr = np.asarray(switch_t, dtype=float)
        switch_on_arr = np.asarray(switch_on, dtype=bool)
        order = np.argsort(switch_t_arr, kind='stable')
        switch_t_arr, switch_on_arr = switch_t_arr[order], switch_on_arr[order]
        # events at or before the first sample set the initial state (start-up, reset)
        head = switch_t_arr <= t[0] + 1e-12
        if np.any(head):
            initial = bool(switch_on_arr[head][-1])
            switch_t_arr, switch_on_arr = switch_t_arr[~head], switch_on_arr[~head]
        notes = []
        if lo in gaps:
            notes.append(f'samples lost before this part (a damaged chunk of the file was '
                         f'skipped): none from t = {stamps[lo - 1] * 1e-9:.6f} s to '
                         f'{t[0]:.6f} s')
        if refused:
            notes.append(f'{refused} command(s) outside the node\'s limits (refused by it) left '
                         f'out')
        if initial is None and len(switch_on_arr):
            initial = not switch_on_arr[0]
            notes.append('initial clutch state inferred from the first switch')
        elif initial is None:
            notes.append('no clutch_engaged messages: clutch metrics unavailable')
        pos_r = samples.pos[lo:hi]
        crank = samples.crank[lo:hi]
        paths = None
        if samples.rockers is not None:
            paths = _path_trace([r[lo:hi] for r in samples.rockers], t[0], clutch_sets, ours)
            if paths.initial is None:
                notes.append('no clutch_states messages: per-path clutch switches unavailable')
        trace = Trace(path, 'mcap', t, pos_r, samples.vel[lo:hi], samples.eff[lo:hi],
                      pos_r[:, 2] - pos_r[:, 3], crank.copy(), switch_t_arr,
                      switch_on_arr, initial, ours, sorted(commands, key=lambda c: c.t),
                      in_force, 'recording' if parameters else '',
                      [(ns * 1e-9, ch) for ns, ch in inside],
                      info.scene, len(traces), notes,
                      'recorded' if np.any(np.isfinite(crank)) else '', paths=paths)
        traces.append(trace)
    if not traces:
        raise AnalysisError(f'{path}: fewer than 2 samples in every run')
    return traces
