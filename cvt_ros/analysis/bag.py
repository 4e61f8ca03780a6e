"""An MCAP recording (ours, or ``ros2 bag record`` of the node's topics) into runs.

``joint_states`` messages are decoded in one numpy gather when they share a layout; the clutch
switches and commands are attached to the run whose log-time span holds them, on the
simulation-time axis (our recorder keeps a message's simulation time in ``publish_time``; for
other recorders the log time is mapped onto simulation time through the joint_states stamps).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from .. import interface as I
from .errors import AnalysisError
from .trace import Command, RecordingInfo, Trace

__all__ = ['load_mcap']


def _jointstate_layout(data: bytes) -> tuple[list[int], list[int], int] | None:
    """(joint order, byte offsets of the position/velocity/effort doubles, count) of one
    JointState CDR message; None if it is not one of this node."""
    try:
        values, names = I.decode_joint_state_cdr(data)
    except ValueError:
        return None
    cur = I._Cursor(data)
    cur.pos = 12
    cur.string()
    for _ in range(cur.u32()):
        cur.string()
    offsets = []
    count = len(names)
    for _ in range(3):
        n = cur.u32()
        if n != count:
            return None
        cur.align(8)
        offsets.append(cur.pos)
        cur.pos += 8 * n
    return I.joint_order(names), offsets, count


def _decode_joint_states(datas: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray, list[str]]:
    """Decode many JointState messages: (stamp_ns (m,), pos, vel, eff (m, 4)), problems.

    Messages with the layout of the first are decoded in one numpy gather; others one by one.
    """
    m = len(datas)
    stamps = np.zeros(m, dtype=np.int64)
    out = [np.full((m, 4), np.nan) for _ in range(3)]
    problems: list[str] = []
    if not m:
        return stamps, out[0], out[1], out[2], problems
    layout = None
    for data in datas:
        layout = _jointstate_layout(data)
        if layout is not None:
            break
    if layout is None:
        raise AnalysisError('joint_states messages do not carry the joints '
                            f'{", ".join(I.JOINTS)}')
    order, offsets, count = layout
    size = offsets[2] + 8 * count
    lengths = np.fromiter((len(d) for d in datas), dtype=np.int64, count=m)
    fast = np.flatnonzero(lengths == size)
    if len(fast):
        buf = np.frombuffer(b''.join(datas[i] for i in fast), dtype=np.uint8).reshape(-1, size)
        sec = buf[:, 4:8].copy().view('<i4')[:, 0].astype(np.int64)
        nsec = buf[:, 8:12].copy().view('<u4')[:, 0].astype(np.int64)
        stamps[fast] = sec * 1_000_000_000 + nsec
        for k, off in enumerate(offsets):
            block = buf[:, off:off + 8 * count].copy().view('<f8')
            out[k][fast] = block[:, order]
    slow = np.flatnonzero(lengths != size)
    bad = 0
    for i in slow:
        try:
            values, _ = I.decode_joint_state_cdr(datas[i])
        except ValueError:
            bad += 1
            stamps[i] = -1
            continue
        stamps[i] = values.stamp_ns
        out[0][i], out[1][i], out[2][i] = values.position, values.velocity, values.effort
    if bad:
        problems.append(f'{bad} joint_states message(s) could not be decoded and were skipped')
    return stamps, out[0], out[1], out[2], problems


def _pick_topics(topics: Mapping[str, tuple[str, int]], namespace: str | None,
                 recorded: Mapping[str, str] | None) -> dict[str, str]:
    """Interface key -> topic name in this recording."""
    if recorded and namespace is None and recorded.get('joint_states') in topics:
        return {k: v for k, v in recorded.items() if v in topics}
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
            raise AnalysisError(f'several JointState topics ({", ".join(sorted(js))}); choose '
                                'one with --namespace')
        js = named
    joint_states = js[0]
    ns = joint_states[:-len(I.JOINT_STATES)] if joint_states.endswith(I.JOINT_STATES) else '/'
    picked = {'joint_states': joint_states}
    for key, spec in I.TOPICS.items():
        if key == 'joint_states':
            continue
        name = I.resolve_topic(spec.name, ns)
        if name in topics and topics[name][0] == spec.type_name:
            picked[key] = name
    return picked


def _yaml(text: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return None


def load_mcap(path: str, *, namespace: str | None = None
              ) -> tuple[list[Trace], RecordingInfo]:
    """Read an MCAP recording (ours, or ``ros2 bag record`` of the node's topics)."""
    from ..recording import RecordingReadError, read_messages, summary
    from ..recording.recorder import METADATA_NAME, PARAMETER_CHANGE_NAME

    info = RecordingInfo(path, 'mcap')
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            bag = summary(path)
    except RecordingReadError as exc:
        raise AnalysisError(str(exc)) from None
    info.problems.extend(bag.problems)
    info.topics = {name: (t.type_name, t.message_count) for name, t in bag.topics.items()}
    meta = bag.metadata.get(METADATA_NAME, {})
    parameters = _yaml(meta['parameters']) if 'parameters' in meta else None
    recorded_topics = _yaml(meta['topics']) if 'topics' in meta else None
    ours = bool(meta)
    info.source = meta.get('source', '')
    info.scene = meta.get('scene', '')
    if not info.topics and info.problems:
        raise AnalysisError(f'{path}: nothing readable ({info.problems[0]})')
    picked = _pick_topics(info.topics, namespace, recorded_topics
                          if isinstance(recorded_topics, dict) else None)
    keys = {name: key for key, name in picked.items()}
    js_data: list[bytes] = []
    js_log: list[int] = []
    events: list[tuple[str, int, int, bytes]] = []
    try:
        for m in read_messages(path, topics=list(keys)):
            key = keys[m.topic]
            if key == 'joint_states':
                js_data.append(m.data)
                js_log.append(m.log_time_ns)
            elif key in ('clutch_engaged', 'crank_length_cmd', 'load_torque_cmd'):
                events.append((key, m.log_time_ns, m.publish_time_ns, m.data))
    except RecordingReadError as exc:
        # the summary's scan reported the same damage; keep the reader's wording once
        if not any(p in str(exc) for p in info.problems):
            info.problems.append(str(exc))
    if not js_data:
        why = '; '.join(info.problems) if info.problems else 'no joint_states messages'
        raise AnalysisError(f'{path}: nothing to analyse ({why})')
    stamps, pos, vel, eff, problems = _decode_joint_states(js_data)
    info.problems.extend(problems)
    good = stamps >= 0
    stamps, pos, vel, eff = stamps[good], pos[good], vel[good], eff[good]
    log = np.asarray(js_log, dtype=np.int64)[good]
    changes = []
    if ours:
        for name, record in bag.metadata.items():
            if name == PARAMETER_CHANGE_NAME:  # summary keeps one per name: the last
                changes.append((int(record.get('time_ns', 0)), _yaml(record.get('parameters',
                                                                                 '')) or {}))
    return _split_runs(path, stamps, log, pos, vel, eff, events, parameters, ours,
                       info, changes), info


def _event_value(key: str, data: bytes) -> float | None:
    try:
        if key == 'clutch_engaged':
            return float(data[4] != 0)
        return float(np.frombuffer(data, dtype='<f8', count=1, offset=4)[0])
    except (IndexError, ValueError):
        return None


def _split_runs(path: str, stamps: np.ndarray, log: np.ndarray, pos: np.ndarray,
                vel: np.ndarray, eff: np.ndarray, events: list, parameters: Any, ours: bool,
                info: RecordingInfo, changes: list) -> list[Trace]:
    """Cut the samples into runs where the stamp goes back; attach events by log time."""
    cuts = np.flatnonzero(np.diff(stamps) <= 0) + 1
    # a repeated stamp is a duplicate sample (e.g. paused and stepped): drop it, do not cut
    dup = cuts[stamps[cuts] == stamps[cuts - 1]]
    if len(dup):
        keep = np.ones(len(stamps), bool)
        keep[dup] = False
        stamps, log, pos, vel, eff = stamps[keep], log[keep], pos[keep], vel[keep], eff[keep]
        cuts = np.flatnonzero(np.diff(stamps) < 0) + 1
    bounds = [0, *cuts.tolist(), len(stamps)]
    params = parameters if isinstance(parameters, dict) else None
    ev_log = np.array([e[1] for e in events], dtype=np.int64)
    traces = []
    for r in range(len(bounds) - 1):
        lo, hi = bounds[r], bounds[r + 1]
        if hi - lo < 2:
            continue
        first_log = log[lo]
        next_log = log[hi] if hi < len(log) else None
        t = stamps[lo:hi] * 1e-9
        if next_log is None:
            in_run = ev_log >= first_log if r else np.ones(len(events), bool)
        else:
            in_run = ((ev_log >= first_log) if r else True) & (ev_log < next_log)
        before = ev_log < first_log if r else np.zeros(len(events), bool)
        switch_t, switch_on, commands = [], [], []
        initial = None
        for j in np.flatnonzero(before):
            key, _, _, data = events[j]
            if key == 'clutch_engaged':
                value = _event_value(key, data)
                initial = None if value is None else bool(value)
        for j in np.flatnonzero(in_run):
            key, lt, pt, data = events[j]
            value = _event_value(key, data)
            if value is None:
                continue
            if ours:
                ts = pt * 1e-9  # our recorder keeps the simulation time in publish_time
            else:   # ros2 bag record: map the log time onto simulation time via joint_states
                ts = float(np.interp(lt, log[lo:hi], t))
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
        if initial is None and len(switch_on_arr):
            initial = not switch_on_arr[0]
            notes.append('initial clutch state inferred from the first switch')
        elif initial is None:
            notes.append('no clutch_engaged messages: clutch metrics unavailable')
        pos_r = pos[lo:hi]
        trace = Trace(path, 'mcap', t, pos_r, vel[lo:hi], eff[lo:hi],
                      pos_r[:, 2] - pos_r[:, 3], np.full(hi - lo, np.nan), switch_t_arr,
                      switch_on_arr, initial, ours, sorted(commands, key=lambda c: c.t),
                      params, 'recording' if params else '',
                      [(ns * 1e-9, ch) for ns, ch in changes if first_log <= ns
                       and (next_log is None or ns < next_log)],
                      info.scene, len(traces), notes)
        traces.append(trace)
    if not traces:
        raise AnalysisError(f'{path}: fewer than 2 samples in every run')
    return traces
