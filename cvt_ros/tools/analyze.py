"""Offline analysis of a recording (MCAP of the node or of ``cvt-sim run``, or a ``cvt-sim`` CSV).

Loading (:func:`load`) turns the file into :class:`Trace` objects, one per *run* (a run ends where
simulation time goes back: a ``~/reset`` of the node). Sample arrays come from ``joint_states``
(or the CSV rows); clutch switches from ``clutch_engaged`` at their exact times (a CSV has only
the sampled ``engaged`` column: a switch is placed half-way between the two samples); commands
from ``crank_length_cmd`` / ``load_torque_cmd``; scene parameters from the file's ``cvt_ros``
metadata record (or ``--scene``).

Metrics (:func:`analyze_trace`), per crank cycle and per run. A crank cycle is one turn of the
crank between successive crossings of φ1 = 2πk (k integer: the crank along the frame line
O1→O2), located on the cubic Hermite interpolant of (φ1, ω1); only complete cycles count.
Over a window [ta, tb] (one cycle, all cycles of a run, or the last quarter of them):

* ratio i = Δφ4 / Δφ1 (= mean ω4 / mean ω1);
* output speed ripple = (max ω4 − min ω4) / mean ω4 (n/a while |i| < 1e-3: neutral crank);
* torsion twist θ = φ3 − φ4: peak (max θ) and time mean;
* peak clutch torque Tc,max and the **dynamic load factor** K = Tc,max / mean Tc (mean over the
  whole window, engaged or not: the torque the clutch transmits on average);
* engaged fraction = time engaged / window length (exact from the switch times);
* switches per cycle (engage + release; grazing contacts are not switches);
* motor power P1 = ∫M1·ω1 dt / T, output power P4 = ∫M4·ω4 dt / T (the power taken by the load),
  efficiency η = ∫M4·ω4 / ∫M1·ω1 (n/a while |i| < 1e-3 or the motor does no work). The model
  is lossless except shaft damping (and the rare plastic engagement at start-up), so η < 1 in
  steady state only by damping and by the change of stored energy over the window;
* energy residual (per run, over the whole sampled span): ΔE − (W1 − W4 − Wd) with stored energy
  E = ½ΣJk·ωk² + ½c·θ² (inertias, stiffness, damping from the scene parameters), W1 = ∫M1ω1,
  W4 = ∫M4ω4, Wd = ∫kd·(ω3 − ω4)². Integrals are trapezoidal over the samples, so the residual
  measures the sampling (O(Δt²), at the clutch switches O(Δt)) more than the solver; the
  crank-length actuator's work is not recorded (flagged when the crank length moved).

Integrals and means use the piecewise-linear interpolant of the samples, integrated exactly
between the (interpolated) cycle boundaries.

The library raises :class:`AnalysisError` (nothing usable) and records read problems in
``Trace.problems``; :func:`command` prints and returns the exit code.
"""

from __future__ import annotations

import csv
import math
import os
import sys
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import interface as I

__all__ = ['AnalysisError', 'Command', 'CycleTable', 'RunAnalysis', 'Trace', 'analyze_trace',
           'command', 'crank_length_from_angles', 'load', 'load_csv', 'load_mcap']

TWO_PI = 2.0 * math.pi
#: Below this |ratio| the output is not driven (neutral crank): ripple and efficiency are n/a.
DRIVEN_RATIO = 1e-3
#: Per-cycle metrics, in table order, with units.
CYCLE_FIELDS = (
    ('cycle', '-'), ('t_start', 's'), ('period', 's'), ('crank_speed', 'rad/s'),
    ('ratio', '-'), ('output_speed', 'rad/s'), ('ripple', '-'), ('twist_peak', 'rad'),
    ('twist_mean', 'rad'), ('clutch_torque_peak', 'N*m'), ('clutch_torque_mean', 'N*m'),
    ('load_factor', '-'), ('engaged_fraction', '-'), ('switches', '-'), ('motor_power', 'W'),
    ('output_power', 'W'), ('efficiency', '-'), ('crank_length', 'm'), ('load_torque', 'N*m'),
)


class AnalysisError(Exception):
    """Nothing analysable in the input (not a recording of this node, unreadable, no samples)."""


@dataclass(frozen=True)
class Command:
    """A command the node received: simulation time [s], interface key, value."""

    t: float
    key: str
    value: float


@dataclass
class Trace:
    """One run of a recording: samples on the simulation-time axis and the events in it.

    Arrays have n rows; (n, 4) arrays are in joint order J1..J4. NaN marks what the source does
    not carry (e.g. motor torque in a ``cvt-sim run`` CSV).
    """

    source: str
    kind: str                       # 'mcap' | 'csv'
    t: np.ndarray                   # [s]
    phi: np.ndarray                 # (n, 4) [rad]
    omega: np.ndarray               # (n, 4) [rad/s]
    effort: np.ndarray              # (n, 4) [N*m]: M1, Tc, Ts, M4
    twist: np.ndarray               # [rad]
    crank_length: np.ndarray        # [m] (NaN if unknown)
    switch_t: np.ndarray            # [s] clutch switch times
    switch_engaged: np.ndarray      # state after each switch
    initial_engaged: bool | None    # state at t[0]; None if unknown
    switches_exact: bool            # True: event times; False: located between samples
    commands: list[Command] = field(default_factory=list)
    parameters: dict[str, Any] | None = None
    parameters_origin: str = ''
    parameter_changes: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    scene: str = ''
    run_index: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.t)

    def engaged_at(self, t: np.ndarray) -> np.ndarray:
        """Clutch state (0/1, NaN if unknown) at times ``t``: the state after the last switch
        at or before t."""
        t = np.asarray(t, dtype=float)
        if self.initial_engaged is None:
            return np.full(t.shape, np.nan)
        states = np.concatenate([[float(self.initial_engaged)],
                                 self.switch_engaged.astype(float)])
        return states[np.searchsorted(self.switch_t, t, side='right')]

    def engaged_time(self, t: np.ndarray) -> np.ndarray:
        """∫ engaged dτ from t[0] to each of ``t`` [s] (exact for the step function)."""
        t = np.asarray(t, dtype=float)
        if self.initial_engaged is None:
            return np.full(t.shape, np.nan)
        t0 = self.t[0]
        sw = self.switch_t
        keep = sw > t0
        sw, st = sw[keep], self.switch_engaged[keep].astype(float)
        knots = np.concatenate([[t0], sw])
        states = np.concatenate([[float(self.initial_engaged)], st])
        cum = np.concatenate([[0.0], np.cumsum(states[:-1] * np.diff(knots))])
        i = np.clip(np.searchsorted(knots, t, side='right') - 1, 0, len(knots) - 1)
        return cum[i] + states[i] * (t - knots[i])


@dataclass
class RecordingInfo:
    """What :func:`load` found besides the runs."""

    path: str
    kind: str
    problems: list[str] = field(default_factory=list)
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    source: str = ''
    scene: str = ''


# ---------------------------------------------------------------------------------- loading
def load(path: str, *, scene: str | None = None, namespace: str | None = None
         ) -> tuple[list[Trace], RecordingInfo]:
    """Read an MCAP recording or a cvt-sim CSV into runs. ``scene`` (name or path) supplies the
    parameters when the file has none (or overrides them). Raises :class:`AnalysisError` when
    nothing can be read; read problems of a damaged file are in ``RecordingInfo.problems``."""
    if not os.path.exists(path):
        raise AnalysisError(f'{path}: no such file')
    if os.path.isdir(path):
        raise AnalysisError(f'{path}: is a directory, not a recording')
    with open(path, 'rb') as f:
        head = f.read(8)
    if head == b'\x89MCAP0\r\n':
        traces, info = load_mcap(path, namespace=namespace)
    elif head[:1] in (b'\x89', b'\x00') or not head:
        raise AnalysisError(f'{path}: not an MCAP recording or a CSV file'
                            if head else f'{path}: empty file')
    else:
        traces, info = load_csv(path)
    if scene:
        from ..scene import load_scene

        values = load_scene(scene)
        for trace in traces:
            trace.parameters = values
            trace.parameters_origin = f'--scene {scene}'
            trace.scene = trace.scene or scene
    for trace in traces:
        _fill_crank_length(trace)
        _fill_motor_torque(trace)
        if (trace.parameters or {}).get('model.fidelity') == 'averaged':
            trace.notes.append('model.fidelity averaged: ripple, twist, clutch torque and '
                               'switches are not modelled (mean motion only)')
    return traces, info


def _fill_crank_length(trace: Trace) -> None:
    if np.all(np.isnan(trace.crank_length)) and trace.parameters:
        p = trace.parameters
        try:
            trace.crank_length = crank_length_from_angles(
                trace.phi[:, 0], trace.phi[:, 1], p['linkage.rocker_length'],
                p['linkage.coupler_length'], p['linkage.pivot_distance'],
                p['linkage.assembly_mode'])
        except (KeyError, TypeError, ValueError):
            pass


def _fill_motor_torque(trace: Trace) -> None:
    """A CSV has no motor torque; with scene parameters the torque law gives it."""
    if not np.all(np.isnan(trace.effort[:, 0])) or not trace.parameters:
        return
    p = trace.parameters
    model = p.get('motor.model')
    w1 = trace.omega[:, 0]
    if model == 'induction':
        w0, mk, sk = p['motor.synchronous_speed'], p['motor.breakdown_torque'], \
            p['motor.breakdown_slip']
        s = (w0 - w1) / w0
        trace.effort[:, 0] = 2.0 * mk * sk * s / (s * s + sk * sk)  # Kloss (physics.md §5)
        trace.notes.append('motor torque computed from ω1 by the scene\'s torque law')
    elif model == 'constant_torque':
        trace.effort[:, 0] = p['motor.torque']
        trace.notes.append('motor torque from the scene (constant)')


def crank_length_from_angles(phi1: np.ndarray, phi2: np.ndarray, b: float, d: float, h: float,
                             sigma: float = 1.0) -> np.ndarray:
    """The crank length a [m] that puts the rocker at φ2 for crank angle φ1 (paper eq. 1
    solved for a): a² − 2a·(h·cos φ1 + b·cos(φ1 − φ2)) + b² + h² − d² + 2bh·cos φ2 = 0.

    A root counts if it lies in [0, Grashof bound] and its closed-form rocker angle (assembly
    mode σ) is φ2. Where both roots count, the one nearer the median of the unambiguous samples
    is taken. NaN where no root fits (a recording of another geometry)."""
    from ..physics.linkage import grashof_bound

    phi1 = np.asarray(phi1, dtype=float)
    phi2 = np.asarray(phi2, dtype=float)
    bound = grashof_bound(b, d, h)
    B = h * np.cos(phi1) + b * np.cos(phi1 - phi2)
    C = b * b + h * h - d * d + 2.0 * b * h * np.cos(phi2)
    root = np.sqrt(np.maximum(B * B - C, 0.0))
    roots, ok = [], []
    for a in (B - root, B + root):
        c1 = np.cos(phi1)
        p = 2.0 * b * h - 2.0 * a * b * c1
        q = -2.0 * a * b * np.sin(phi1)
        r = -(a * a + b * b + h * h - d * d) + 2.0 * a * h * c1
        with np.errstate(invalid='ignore', divide='ignore'):
            phi2_a = np.arctan2(q, p) + sigma * np.arccos(np.clip(r / np.hypot(p, q), -1, 1))
        err = np.abs(np.angle(np.exp(1j * (phi2_a - phi2))))
        roots.append(np.clip(a, 0.0, None))
        ok.append((a >= -1e-9) & (a <= bound + 1e-9) & (err < 1e-6))
    lo, hi = roots
    only_lo, only_hi, both = ok[0] & ~ok[1], ok[1] & ~ok[0], ok[0] & ok[1]
    out = np.where(only_lo, lo, np.where(only_hi, hi, np.nan))
    if np.any(both):
        # the crank length moves slowly: take the root nearer the nearest unambiguous sample
        known = np.flatnonzero(np.isfinite(out))
        amb = np.flatnonzero(both)
        if len(known):
            j = np.clip(np.searchsorted(known, amb), 1, len(known)) - 1
            j_next = np.minimum(j + 1, len(known) - 1)
            nearer = np.where(np.abs(known[j_next] - amb) < np.abs(known[j] - amb), j_next, j)
            ref = out[known[nearer]]
        else:
            ref = np.full(len(amb), 0.5 * bound)
        out[amb] = np.where(np.abs(lo[amb] - ref) <= np.abs(hi[amb] - ref), lo[amb], hi[amb])
    return out


# .................................................................................. MCAP
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
    from .record import METADATA_NAME, PARAMETER_CHANGE_NAME

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


# .................................................................................. CSV
_CSV_REQUIRED = ('t', 'phi1', 'phi2', 'phi3', 'phi4', 'omega1', 'omega2', 'omega3', 'omega4')


def load_csv(path: str) -> tuple[list[Trace], RecordingInfo]:
    """Read a CSV of ``cvt-sim run --csv`` or ``cvt-sim export`` (tolerates a cut-off end)."""
    info = RecordingInfo(path, 'csv')
    try:
        with open(path, newline='', encoding='utf-8') as f:
            text = f.read()
    except (OSError, UnicodeDecodeError) as exc:
        raise AnalysisError(f'{path}: cannot read: {exc}') from None
    lines = text.splitlines()
    if not lines:
        raise AnalysisError(f'{path}: empty file')
    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    missing = [c for c in _CSV_REQUIRED if c not in header]
    if missing:
        raise AnalysisError(f'{path}: not a cvt-sim CSV (missing columns {", ".join(missing)})')
    width = len(header)
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        cells = line.split(',')
        if len(cells) != width:
            info.problems.append(f'line {number}: {len(cells)} fields instead of {width} '
                                 '(file cut off?); reading stopped there')
            break
        try:
            rows.append([float(c) if c.strip() else math.nan for c in cells])
        except ValueError:
            info.problems.append(f'line {number}: not a number; reading stopped there')
            break
    if not text.endswith('\n') and rows and not info.problems:
        info.problems.append('the last line has no line end (file cut off?)')
    if len(rows) < 2:
        raise AnalysisError(f'{path}: fewer than 2 sample rows'
                            + (f' ({info.problems[0]})' if info.problems else ''))
    data = np.asarray(rows)
    col = {name: data[:, i] for i, name in enumerate(header)}
    n = len(data)

    def get(name: str) -> np.ndarray:
        return col[name] if name in col else np.full(n, np.nan)

    t = col['t']
    cuts = np.flatnonzero(np.diff(t) < 0) + 1
    bounds = [0, *cuts.tolist(), n]
    traces = []
    for r in range(len(bounds) - 1):
        s = slice(bounds[r], bounds[r + 1])
        if bounds[r + 1] - bounds[r] < 2:
            continue
        tt = t[s]
        engaged = get('engaged')[s]
        initial = None if np.isnan(engaged[0]) else bool(engaged[0] > 0.5)
        on = engaged > 0.5
        change = np.flatnonzero(on[1:] != on[:-1])
        sw_t = 0.5 * (tt[change] + tt[change + 1])
        sw_on = on[change + 1]
        phi = np.column_stack([get(c)[s] for c in I.POSITION_COLUMNS])
        twist = get('twist')[s]
        if np.all(np.isnan(twist)):
            twist = phi[:, 2] - phi[:, 3]
        trace = Trace(path, 'csv', tt, phi,
                      np.column_stack([get(c)[s] for c in I.VELOCITY_COLUMNS]),
                      np.column_stack([get(c)[s] for c in I.EFFORT_COLUMNS]),
                      twist, get('crank_length')[s].copy(), sw_t, sw_on, initial, False,
                      run_index=len(traces))
        if initial is None:
            trace.notes.append('no engaged column: clutch metrics unavailable')
        traces.append(trace)
    return traces, info


# ---------------------------------------------------------------------------------- metrics
def _hermite(s: np.ndarray, h: np.ndarray, p0: np.ndarray, p1: np.ndarray, m0: np.ndarray,
             m1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Hermite value and d/ds on [0, 1] (h: interval length, m: slopes per unit time)."""
    s2, s3 = s * s, s * s * s
    value = ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * m0
             + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * m1)
    slope = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * h * m0
             + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * h * m1)
    return value, slope


def cycle_boundaries(t: np.ndarray, phi1: np.ndarray, omega1: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Crossings of φ1 = 2πk: (times, sample index i with t[i] ≤ tb < t[i+1], fraction s in
    [0, 1), k). Only forward crossings of a new, higher k count."""
    k = np.floor(phi1 / TWO_PI)
    running = np.maximum.accumulate(k)
    idx = np.flatnonzero(running[1:] > running[:-1])
    if len(idx) and np.any(running[idx + 1] - running[idx] > 1):
        raise AnalysisError('the crank turns more than once between two samples: the sample '
                            'interval is too coarse to split crank cycles')
    kk = running[idx + 1]
    target = kk * TWO_PI
    h = t[idx + 1] - t[idx]
    p0, p1 = phi1[idx], phi1[idx + 1]
    m0, m1 = omega1[idx], omega1[idx + 1]
    with np.errstate(invalid='ignore', divide='ignore'):
        s = np.clip((target - p0) / (p1 - p0), 0.0, 1.0)
    for _ in range(6):
        value, slope = _hermite(s, h, p0, p1, m0, m1)
        with np.errstate(invalid='ignore', divide='ignore'):
            step = np.where(slope > 0, (value - target) / slope, 0.0)
        s = np.clip(s - step, 0.0, 1.0)
    return t[idx] + s * h, idx, s, kk


class _Integrator:
    """Exact integrals of the piecewise-linear interpolant of samples f(t)."""

    def __init__(self, t: np.ndarray):
        self.t = t
        self.h = np.diff(t)

    def cumulative(self, f: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * self.h)])

    def at(self, F: np.ndarray, f: np.ndarray, idx: np.ndarray, s: np.ndarray) -> np.ndarray:
        """∫ from t[0] to t[idx] + s·h[idx]."""
        idx = np.minimum(idx, len(self.h) - 1)
        h = self.h[idx]
        tau = s * h
        return F[idx] + f[idx] * tau + (f[idx + 1] - f[idx]) * tau * tau / (2.0 * h)


def _lerp(f: np.ndarray, idx: np.ndarray, s: np.ndarray) -> np.ndarray:
    idx = np.minimum(idx, len(f) - 2)
    return f[idx] + s * (f[idx + 1] - f[idx])


def _window_extrema(f: np.ndarray, lo: np.ndarray, hi: np.ndarray, fa: np.ndarray,
                    fb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """max/min of samples lo..hi (inclusive; may be empty when hi < lo) and the ends fa, fb."""
    mx = np.maximum(fa, fb)
    mn = np.minimum(fa, fb)
    nonempty = hi >= lo
    if np.any(nonempty):
        starts = lo[nonempty]
        ends = hi[nonempty] + 1
        # reduceat over [start, next start) — build explicit index ranges for safety
        seg_max = np.array([np.max(f[a:b]) for a, b in zip(starts, ends, strict=True)])
        seg_min = np.array([np.min(f[a:b]) for a, b in zip(starts, ends, strict=True)])
        mx[nonempty] = np.maximum(mx[nonempty], seg_max)
        mn[nonempty] = np.minimum(mn[nonempty], seg_min)
    return mx, mn


@dataclass
class CycleTable:
    """Per-cycle metrics: one array per name of ``CYCLE_FIELDS`` (length = complete cycles)."""

    values: dict[str, np.ndarray]
    t_end: np.ndarray

    def __len__(self) -> int:
        return len(self.values['cycle'])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]

    def rows(self) -> list[dict[str, float]]:
        return [{k: float(v[i]) for k, v in self.values.items()} for i in range(len(self))]


@dataclass
class StepResponse:
    """The response of the cycle-mean ratio and output speed to one command."""

    command: Command
    previous: float
    ratio_before: float
    ratio_after: float
    speed_before: float
    speed_after: float
    rise_time: float        # 10 → 90 % of the ratio change [s] after the command (NaN: n/a)
    settling_time: float    # into a ±2 % band of the change, for good [s] (NaN: not settled)
    window_end: float


@dataclass
class RunAnalysis:
    """Everything :func:`analyze_trace` computes for one run."""

    trace: Trace
    cycles: CycleTable
    boundaries: np.ndarray
    summary: dict[str, dict[str, float]]    # 'all' / 'last_quarter' -> metric -> value
    energy: dict[str, Any]
    steps: list[StepResponse]


def _window_metrics(cy: CycleTable, sel: slice, totals: dict[str, np.ndarray]) -> dict:
    """Aggregate the cycles ``sel`` (whole cycles: sums of the per-cycle integrals)."""
    T = float(np.sum(totals['T'][sel]))
    if not len(cy['cycle'][sel]) or T <= 0:
        return {}
    n = len(cy['cycle'][sel])
    out = {
        'cycles': float(n),
        't_start': float(cy['t_start'][sel][0]),
        't_end': float(cy.t_end[sel][-1]),
        'ratio': float(np.sum(totals['dphi4'][sel]) / (TWO_PI * n)),
        'crank_speed': TWO_PI * n / T,
        'output_speed': float(np.sum(totals['dphi4'][sel]) / T),
        'ripple': float(np.nanmean(cy['ripple'][sel])) if np.any(np.isfinite(
            cy['ripple'][sel])) else math.nan,
        'ripple_max': float(np.nanmax(cy['ripple'][sel])) if np.any(np.isfinite(
            cy['ripple'][sel])) else math.nan,
        'twist_peak': float(np.max(cy['twist_peak'][sel])),
        'twist_mean': float(np.sum(totals['twist'][sel]) / T),
        'clutch_torque_peak': float(np.max(cy['clutch_torque_peak'][sel])),
        'clutch_torque_mean': float(np.sum(totals['tc'][sel]) / T),
        'engaged_fraction': float(np.sum(totals['engaged'][sel]) / T),
        'switches_per_cycle': float(np.sum(cy['switches'][sel]) / n),
        'motor_power': float(np.sum(totals['w1'][sel]) / T),
        'output_power': float(np.sum(totals['w4'][sel]) / T),
    }
    with np.errstate(invalid='ignore', divide='ignore'):
        out['load_factor'] = out['clutch_torque_peak'] / out['clutch_torque_mean'] \
            if out['clutch_torque_mean'] > 0 else math.nan
        w1 = float(np.sum(totals['w1'][sel]))
        out['efficiency'] = float(np.sum(totals['w4'][sel])) / w1 \
            if w1 > 0 and abs(out['ratio']) >= DRIVEN_RATIO else math.nan
    if abs(out['ratio']) < DRIVEN_RATIO:
        out['ripple'] = out['ripple_max'] = math.nan
    return out


def energy_balance(trace: Trace) -> dict[str, Any]:
    """Energy residual over the whole run from the samples and the scene parameters."""
    p = trace.parameters
    if not p:
        return {'available': False, 'reason': 'no scene parameters in the recording (give '
                                              '--scene)'}
    if np.all(np.isnan(trace.effort[:, 0])):
        return {'available': False, 'reason': 'no motor torque in the input (a cvt-sim run CSV '
                                              'with a constant_speed motor, or no --scene)'}
    try:
        J = [float(p[k]) for k in ('inertia.motor', 'inertia.rocker', 'inertia.clutch_driven',
                                   'inertia.output')]
        c = float(p['shaft.stiffness'])
        kd = float(p['shaft.damping'])
    except (KeyError, TypeError, ValueError) as exc:
        return {'available': False, 'reason': f'scene parameters incomplete ({exc})'}
    changed = [k for _, ch in trace.parameter_changes for k in ch
               if k.startswith(('inertia.', 'shaft.', 'motor.', 'model.'))]
    if changed:
        return {'available': False, 'reason': f'parameters changed live ({", ".join(changed)})'}
    fidelity = p.get('model.fidelity', 'full')
    if fidelity == 'averaged':
        return {'available': False, 'reason': 'model.fidelity averaged: the mean-motion model '
                                              'has no cycle-resolved energy'}
    if fidelity == 'rigid_shaft':
        c = math.inf
    t, w, th = trace.t, trace.omega, trace.twist
    m1, m4 = trace.effort[:, 0], trace.effort[:, 3]
    rigid = not math.isfinite(c)
    w3 = w[:, 3] if rigid else w[:, 2]
    energy = 0.5 * (J[0] * w[:, 0] ** 2 + J[1] * w[:, 1] ** 2 + J[2] * w3 ** 2
                    + J[3] * w[:, 3] ** 2)
    if not rigid:
        energy = energy + 0.5 * c * th ** 2
    integ = _Integrator(t)
    w_motor = float(integ.cumulative(m1 * w[:, 0])[-1])
    w_load = float(integ.cumulative(m4 * w[:, 3])[-1])
    w_damp = 0.0 if rigid else float(integ.cumulative(kd * (w3 - w[:, 3]) ** 2)[-1])
    stored = float(energy[-1] - energy[0])
    residual = stored - (w_motor - w_load - w_damp)
    scale = abs(w_motor) + abs(w_load) + abs(w_damp)
    notes = []
    a = trace.crank_length[np.isfinite(trace.crank_length)]
    if len(a) and np.ptp(a) > 1e-7 or any(c.key == 'crank_length_cmd' for c in trace.commands):
        notes.append('the crank length moved: the actuator work is not recorded and is in the '
                     'residual')
    if trace.t[0] < 1e-9:
        notes.append('includes the plastic engagement at t = 0, if any')
    return {'available': True, 'work_motor': w_motor, 'work_load': w_load,
            'dissipated_damping': w_damp, 'stored': stored, 'residual': residual,
            'relative_residual': abs(residual) / scale if scale > 0 else abs(residual),
            'span': (float(t[0]), float(t[-1])), 'notes': notes}


def analyze_trace(trace: Trace) -> RunAnalysis:
    """Split one run into crank cycles and compute the metrics (see the module docstring)."""
    t = trace.t
    if np.any(np.diff(t) <= 0):
        raise AnalysisError('sample times are not increasing')
    phi1, w1 = trace.phi[:, 0], trace.omega[:, 0]
    tb, idx, s, _ = cycle_boundaries(t, phi1, w1)
    n_cyc = max(len(tb) - 1, 0)
    integ = _Integrator(t)
    h = np.diff(t)

    def at(f: np.ndarray) -> np.ndarray:
        return integ.at(integ.cumulative(f), f, idx, s)

    phi4_b = _hermite(s, h[np.minimum(idx, len(h) - 1)], trace.phi[idx, 3],
                      trace.phi[np.minimum(idx + 1, len(t) - 1), 3], trace.omega[idx, 3],
                      trace.omega[np.minimum(idx + 1, len(t) - 1), 3])[0]
    T = np.diff(tb)
    a, b = slice(0, n_cyc), slice(1, n_cyc + 1)
    dphi4 = np.diff(phi4_b)
    m1, tc, m4 = trace.effort[:, 0], trace.effort[:, 1], trace.effort[:, 3]
    w4 = trace.omega[:, 3]
    twist_int = np.diff(at(trace.twist))
    tc_int = np.diff(at(tc))
    w1_int = np.diff(at(m1 * w1))
    w4_int = np.diff(at(m4 * w4))
    m4_int = np.diff(at(m4))
    a_int = np.diff(at(trace.crank_length))
    engaged_int = np.diff(trace.engaged_time(tb))
    # samples strictly inside each cycle: idx[k] + 1 .. idx[k + 1]
    lo, hi = idx[a] + 1, idx[b]
    w4_b = _lerp(w4, idx, s)
    th_b = _lerp(trace.twist, idx, s)
    tc_b = _lerp(tc, idx, s)
    w4_max, w4_min = _window_extrema(w4, lo, hi, w4_b[a], w4_b[b])
    th_max, _ = _window_extrema(trace.twist, lo, hi, th_b[a], th_b[b])
    tc_max, _ = _window_extrema(tc, lo, hi, tc_b[a], tc_b[b])
    sw = np.searchsorted(trace.switch_t, tb, side='left')
    switches = np.diff(sw).astype(float) if trace.initial_engaged is not None \
        else np.full(n_cyc, np.nan)
    with np.errstate(invalid='ignore', divide='ignore'):
        out_speed = dphi4 / T
        values = {
            'cycle': np.arange(n_cyc, dtype=float),
            't_start': tb[a],
            'period': T,
            'crank_speed': TWO_PI / T,
            'ratio': dphi4 / TWO_PI,
            'output_speed': out_speed,
            'ripple': (w4_max - w4_min) / out_speed,
            'twist_peak': th_max,
            'twist_mean': twist_int / T,
            'clutch_torque_peak': tc_max,
            'clutch_torque_mean': tc_int / T,
            'load_factor': np.where(tc_int > 0, tc_max / (tc_int / T), np.nan),
            'engaged_fraction': engaged_int / T,
            'switches': switches,
            'motor_power': w1_int / T,
            'output_power': w4_int / T,
            'efficiency': w4_int / w1_int,
            'crank_length': a_int / T,
            'load_torque': m4_int / T,
        }
    idle = (np.abs(values['ratio']) < DRIVEN_RATIO) | ~(w1_int > 0)
    values['efficiency'] = np.where(idle, np.nan, values['efficiency'])
    values['ripple'] = np.where(np.abs(values['ratio']) < DRIVEN_RATIO, np.nan, values['ripple'])
    cycles = CycleTable(values, tb[b])
    totals = {'T': T, 'dphi4': dphi4, 'twist': twist_int, 'tc': tc_int, 'engaged': engaged_int,
              'w1': w1_int, 'w4': w4_int}
    summary = {}
    if n_cyc:
        summary['all'] = _window_metrics(cycles, slice(0, n_cyc), totals)
        q = max(1, n_cyc // 4)
        summary['last_quarter'] = _window_metrics(cycles, slice(n_cyc - q, n_cyc), totals)
    analysis = RunAnalysis(trace, cycles, tb, summary, energy_balance(trace), [])
    analysis.steps = step_responses(analysis)
    return analysis


def _initial_value(trace: Trace, key: str) -> float:
    p = trace.parameters or {}
    name = {'crank_length_cmd': 'linkage.crank_length', 'load_torque_cmd': 'load.torque'}[key]
    try:
        return float(p[name])
    except (KeyError, TypeError, ValueError):
        return math.nan


def step_responses(analysis: RunAnalysis) -> list[StepResponse]:
    """Rise and settling time of the cycle-mean ratio after each command (window: until the
    next command or the end of the run)."""
    trace, cy = analysis.trace, analysis.cycles
    if not len(cy):
        return []
    mid = cy['t_start'] + 0.5 * cy['period']
    ratio, speed = cy['ratio'], cy['output_speed']
    out = []
    last = {key: _initial_value(trace, key) for key in ('crank_length_cmd', 'load_torque_cmd')}
    commands = trace.commands
    for j, cmd in enumerate(commands):
        previous = last[cmd.key]
        last[cmd.key] = cmd.value
        end = commands[j + 1].t if j + 1 < len(commands) else float(trace.t[-1])
        before = np.flatnonzero(cy.t_end <= cmd.t)[-5:]
        after = np.flatnonzero((cy['t_start'] >= cmd.t) & (cy.t_end <= end))
        rb = float(np.mean(ratio[before])) if len(before) else math.nan
        sb = float(np.mean(speed[before])) if len(before) else math.nan
        if len(after) >= 6:
            ra = float(np.mean(ratio[after[-3:]]))
            sa = float(np.mean(speed[after[-3:]]))
        else:
            ra = sa = math.nan
        rise = settle = math.nan
        change = ra - rb
        noise = float(np.std(ratio[before])) if len(before) > 1 else 0.0
        significant = math.isfinite(change) and abs(change) > max(5.0 * noise, 1e-4 * abs(ra))
        if len(after) >= 6 and significant:
            frac = (ratio[after] - rb) / change
            t_mid = mid[after]
            outside = np.flatnonzero(np.abs(frac - 1.0) > 0.02)
            if not len(outside):
                settle = float(cy['t_start'][after[0]] - cmd.t)
            elif outside[-1] < len(after) - 3:  # in the band for the last 3 cycles at least
                settle = float(cy.t_end[after[outside[-1]]] - cmd.t)
            i10 = np.flatnonzero(frac >= 0.1)
            i90 = np.flatnonzero(frac >= 0.9)
            if math.isfinite(settle) and len(i10) and len(i90):  # final value known
                rise = float(t_mid[i90[0]] - t_mid[i10[0]])
        out.append(StepResponse(cmd, previous, rb, ra, sb, sa, rise, settle, end))
    return out


# ---------------------------------------------------------------------------------- report
_SUMMARY_ROWS = (
    ('cycles', 'complete crank cycles', '{:.0f}'),
    ('crank_speed', 'mean crank speed ω1 [rad/s]', '{:.4f}'),
    ('output_speed', 'mean output speed ω4 [rad/s]', '{:.4f}'),
    ('ratio', 'mean ratio i = ω4/ω1', '{:.6f}'),
    ('ripple', 'output speed ripple (max−min)/mean', '{:.4%}'),
    ('twist_peak', 'peak torsion twist [rad]', '{:.6f}'),
    ('twist_mean', 'mean torsion twist [rad]', '{:.6f}'),
    ('clutch_torque_peak', 'peak clutch torque [N·m]', '{:.4f}'),
    ('clutch_torque_mean', 'mean clutch torque [N·m]', '{:.4f}'),
    ('load_factor', 'dynamic load factor peak/mean', '{:.4f}'),
    ('engaged_fraction', 'engaged fraction of the cycle', '{:.4%}'),
    ('switches_per_cycle', 'clutch switches per cycle', '{:.3f}'),
    ('motor_power', 'motor power [W]', '{:.4f}'),
    ('output_power', 'output (load) power [W]', '{:.4f}'),
    ('efficiency', 'efficiency P4/P1', '{:.4%}'),
)


def _fmt(template: str, value: float) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return 'n/a'
    return template.format(value)


def format_run(analysis: RunAnalysis, cycles_shown: int | None = 10) -> str:
    """The printed report of one run."""
    tr = analysis.trace
    lines = []
    span = f'{tr.t[0]:.6g}–{tr.t[-1]:.6g} s'
    lines.append(f'run {tr.run_index + 1}: {tr.n} samples, {span}, '
                 f'{len(tr.switch_t)} clutch switches, {len(tr.commands)} commands'
                 + (f' (parameters: {tr.parameters_origin})' if tr.parameters_origin else
                    ' (no scene parameters)'))
    for note in tr.notes:
        lines.append(f'  note: {note}')
    s = analysis.summary
    if not s:
        lines.append('  no complete crank cycle: cycle metrics need at least two crossings of '
                     'φ1 = 2πk')
    else:
        allw, last = s['all'], s['last_quarter']
        lines.append(f"  {'per run':38s} {'all cycles':>14s} {'last quarter':>14s}")
        lines.append(f"  {'window [s]':38s} {allw['t_start']:>6.3f}–{allw['t_end']:<7.3f} "
                     f"{last['t_start']:>6.3f}–{last['t_end']:<7.3f}")
        for key, label, template in _SUMMARY_ROWS:
            lines.append(f'  {label:38s} {_fmt(template, allw.get(key)):>14s} '
                         f'{_fmt(template, last.get(key)):>14s}')
    e = analysis.energy
    if e.get('available'):
        lines.append(f"  energy residual                        {e['residual']:.4e} J = "
                     f"{e['relative_residual']:.2e} of the work (motor {e['work_motor']:.4f} J,"
                     f" load {e['work_load']:.4f} J, damping {e['dissipated_damping']:.4f} J, "
                     f"stored {e['stored']:+.4f} J; trapezoidal over the samples)")
        for note in e['notes']:
            lines.append(f'    ({note})')
    else:
        lines.append(f"  energy residual                        unavailable: {e['reason']}")
    cy = analysis.cycles
    if len(cy) and cycles_shown != 0:
        shown = range(len(cy)) if cycles_shown is None else \
            range(max(0, len(cy) - cycles_shown), len(cy))
        if cycles_shown is not None and len(cy) > cycles_shown:
            lines.append(f'  per cycle (last {cycles_shown} of {len(cy)}; --cycles all for '
                         'every one):')
        else:
            lines.append('  per cycle:')
        lines.append('  ' + ' '.join(f'{h:>9s}' for h in (
            'cycle', 't0 [s]', 'T [ms]', 'i', 'ripple', 'θmax', 'θmean', 'Tc,max',
            'K', 'engaged', 'switches', 'P1 [W]', 'η')))
        for i in shown:
            v = {k: float(cy[k][i]) for k, _ in CYCLE_FIELDS}
            lines.append('  ' + ' '.join(cell.rjust(9) for cell in [
                f"{v['cycle'] + 1:9.0f}", f"{v['t_start']:9.4f}", f"{v['period'] * 1e3:9.3f}",
                f"{v['ratio']:9.5f}", _fmt('{:9.3%}', v['ripple']),
                f"{v['twist_peak']:9.5f}", f"{v['twist_mean']:9.5f}",
                f"{v['clutch_torque_peak']:9.3f}", _fmt('{:9.4f}', v['load_factor']),
                _fmt('{:9.3%}', v['engaged_fraction']), _fmt('{:9.0f}', v['switches']),
                _fmt('{:9.3f}', v['motor_power']), _fmt('{:9.3%}', v['efficiency'])]))
    for step in analysis.steps:
        c = step.command
        what = 'crank length' if c.key == 'crank_length_cmd' else 'load torque'
        unit = 'm' if c.key == 'crank_length_cmd' else 'N·m'
        lines.append(
            f'  step at t = {c.t:.4f} s: {what} {_fmt("{:g}", step.previous)} → {c.value:g} '
            f'{unit}: ratio {_fmt("{:.5f}", step.ratio_before)} → '
            f'{_fmt("{:.5f}", step.ratio_after)}, ω4 {_fmt("{:.3f}", step.speed_before)} → '
            f'{_fmt("{:.3f}", step.speed_after)} rad/s, rise (10–90 %) '
            f'{_fmt("{:.3f} s", step.rise_time)}, settling (±2 %) '
            f'{_fmt("{:.3f} s", step.settling_time)}')
    return '\n'.join(lines)


def write_cycles_csv(path: str, analyses: Sequence[RunAnalysis]) -> int:
    """All per-cycle metrics of all runs (a ``run`` column first)."""
    count = 0
    with open(path, 'w', newline='', encoding='utf-8') as f:
        writer = csv.writer(f)
        writer.writerow(['run'] + [f'{name} [{unit}]' if unit != '-' else name
                                   for name, unit in CYCLE_FIELDS])
        for analysis in analyses:
            for row in analysis.cycles.rows():
                writer.writerow([analysis.trace.run_index + 1]
                                + ['' if not math.isfinite(row[k]) else f'{row[k]:.10g}'
                                   for k, _ in CYCLE_FIELDS])
                count += 1
    return count


def to_json(analyses: Sequence[RunAnalysis], info: RecordingInfo) -> dict[str, Any]:
    """Machine-readable results (NaN → null)."""
    def clean(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if isinstance(value, (float, np.floating)):
            return float(value) if math.isfinite(value) else None
        if isinstance(value, np.integer):
            return int(value)
        return value

    runs = []
    for a in analyses:
        runs.append({
            'run': a.trace.run_index + 1, 'samples': a.trace.n,
            't_first': a.trace.t[0], 't_last': a.trace.t[-1],
            'switches': len(a.trace.switch_t), 'summary': a.summary,
            'energy': {k: v for k, v in a.energy.items()},
            'cycles': a.cycles.rows(),
            'steps': [{'t': s.command.t, 'topic': s.command.key, 'value': s.command.value,
                       'previous': s.previous, 'ratio_before': s.ratio_before,
                       'ratio_after': s.ratio_after, 'output_speed_before': s.speed_before,
                       'output_speed_after': s.speed_after, 'rise_time': s.rise_time,
                       'settling_time': s.settling_time} for s in a.steps],
        })
    return clean({'path': info.path, 'kind': info.kind, 'source': info.source,
                  'scene': info.scene, 'problems': info.problems, 'runs': runs})


# ---------------------------------------------------------------------------------- command
def _parse_cycles(text: str) -> int | None:
    return None if text == 'all' else int(text)


def command(args: Any) -> int:
    """``cvt-sim analyze``: 0 = all read, 1 = damaged file (partial results printed), 2 = nothing
    usable."""
    try:
        traces, info = load(args.file, scene=args.scene, namespace=args.namespace)
    except AnalysisError as exc:
        print(f'cvt-sim analyze: error: {exc}', file=sys.stderr)
        return 2
    analyses = []
    for trace in traces:
        try:
            analyses.append(analyze_trace(trace))
        except AnalysisError as exc:
            print(f'cvt-sim analyze: error: run {trace.run_index + 1}: {exc}', file=sys.stderr)
            return 2
    head = f'recording        {info.path} ({info.kind}'
    if info.source:
        head += f', {info.source}'
    if info.scene:
        head += f', scene {info.scene}'
    print(head + ')')
    if info.topics:
        print('topics           ' + ', '.join(f'{name} ({count})'
                                              for name, (_, count) in sorted(info.topics.items())))
    if len(analyses) > 1:
        print(f'runs             {len(analyses)} (simulation time went back: ~/reset)')
    try:
        cycles = _parse_cycles(args.cycles)
    except ValueError:
        print(f'cvt-sim analyze: error: --cycles expects a number or "all", got {args.cycles!r}',
              file=sys.stderr)
        return 2
    for analysis in analyses:
        print(format_run(analysis, cycles))
    if args.cycles_csv:
        n = write_cycles_csv(args.cycles_csv, analyses)
        print(f'per-cycle table  {n} rows → {args.cycles_csv}')
    if args.json:
        import json

        with open(args.json, 'w', encoding='utf-8') as f:
            json.dump(to_json(analyses, info), f, indent=1)
        print(f'json             → {args.json}')
    if args.plots:
        from .plots import plot_all

        try:
            files = plot_all(analyses, args.plots)
        except OSError as exc:
            print(f'cvt-sim analyze: error: cannot write plots to {args.plots}: {exc}',
                  file=sys.stderr)
            return 2
        print(f'plots            {len(files)} PNG files → {args.plots}')
    if info.problems:
        print(f'cvt-sim analyze: error: {args.file}: {info.problems[0]}'
              + (f' (+{len(info.problems) - 1} more)' if len(info.problems) > 1 else '')
              + '; the results above cover the readable part', file=sys.stderr)
        return 1
    return 0

