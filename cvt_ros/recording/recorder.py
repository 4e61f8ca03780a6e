"""Recording a simulation to a rosbag2-compatible MCAP file: one class for the node and the CLI.

:class:`SimulationRecorder` writes what the node publishes (``joint_states``, ``clutch_engaged``,
``/clock``, ``/diagnostics``) and what it receives (``crank_length_cmd``, ``load_torque_cmd``)
with their ROS types, QoS and type hashes (:mod:`cvt_ros.interface`), through
:class:`cvt_ros.recording.BagWriter` (background I/O thread, small chunks flushed every
``flush_interval``, summary and ``rosbag2`` metadata on :meth:`~SimulationRecorder.close`).

Times: every message is logged at the **simulation time** it belongs to (a sample: its stamp; a
clutch switch: the exact event time; a command: the simulation time when it was received).
MCAP log times must not go backwards, so the recorder keeps them monotonic:

* a message slightly older than the last one (a command received by the executor thread while
  the loop thread already wrote a switch of the next period) is logged at the last log time; its
  ``publish_time`` keeps the true simulation time;
* after a reset (simulation time back to 0: :meth:`~SimulationRecorder.mark_reset`, or detected
  when a ``joint_states`` stamp goes backwards) log times continue from the last one (a new
  *epoch*: log time = simulation time + offset); ``publish_time`` and the message stamps keep the
  simulation time. Without resets log time == publish time == simulation time.

The scene parameters go into the file right at the start, as an MCAP metadata record
``cvt_ros`` (keys ``format``, ``source``, ``scene``, ``parameters`` (YAML map of dotted names),
``joint_names``, ``topics`` (YAML map key → topic), ``created``), so analysis can compute
energies years later, and so that they survive a crash. Live parameter changes can be appended
as ``cvt_ros.parameter_change`` records (:meth:`~SimulationRecorder.record_parameters`).

Errors never stop the simulation: a path that cannot be created raises
:class:`~cvt_ros.recording.RecordingError` from the constructor (the caller logs it and runs
without recording); an I/O error later (disk full) is reported once through ``on_error`` (default:
one line on stderr) and the recorder drops everything after it (:attr:`failed`, :attr:`error`).

The node's hook is :meth:`~SimulationRecorder.write` (``write(topic, msg, t_ns)``, the
``BagWriter`` signature), plus :meth:`~SimulationRecorder.mark_reset` on ``~/reset``;
``cvt-sim run --mcap`` uses :func:`write_run`. ``python -m cvt_ros.bench.recording`` measures the
cost per message.
"""

from __future__ import annotations

import datetime
import math
import os
import sys
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from .. import interface as I
from ..solver.output import COL
from .errors import RecordingError
from .writer import DEFAULT_CHUNK_SIZE, BagWriter

__all__ = ['FORMAT', 'METADATA_NAME', 'PARAMETER_CHANGE_NAME', 'SELF_CHECK_NAME',
           'SimulationRecorder', 'check_target', 'record_run', 'write_run']

#: Value of the ``format`` key of the ``cvt_ros`` metadata record.
FORMAT = 'cvt_ros recording 1'
#: Name of the metadata record with the scene parameters.
METADATA_NAME = 'cvt_ros'
#: Name of the metadata records of live parameter changes.
PARAMETER_CHANGE_NAME = 'cvt_ros.parameter_change'
#: Name of the metadata record of the solver's self-check (Simulator.self_check(), at the end).
SELF_CHECK_NAME = 'cvt_ros.solver_check'
#: Data is on disk (in complete chunks) at most this long after it was written [s].
FLUSH_INTERVAL = 0.5


def _ensure_ament_prefix() -> None:
    """Message definitions are looked up in the ament index; in a plain venv whose ROS wheels
    installed ``share/`` under ``sys.prefix``, point AMENT_PREFIX_PATH there if it is unset."""
    if not os.environ.get('AMENT_PREFIX_PATH') and os.path.isdir(
            os.path.join(sys.prefix, 'share', 'ament_index')):
        os.environ['AMENT_PREFIX_PATH'] = sys.prefix


def parameters_yaml(values: Mapping[str, Any]) -> str:
    """Scene parameters (dotted name → value) as YAML (``.inf`` for a rigid shaft)."""
    import yaml

    plain = {str(k): (v.item() if hasattr(v, 'item') else v) for k, v in values.items()}
    return yaml.safe_dump(plain, sort_keys=True, default_flow_style=False)


def _stderr_error(exc: Exception) -> None:
    print(f'cvt_ros recording: error: {exc}', file=sys.stderr, flush=True)


class SimulationRecorder:
    """Record one simulation run to ``path`` (an ``.mcap`` file).

    ``namespace``: the node's namespace (topic names resolve in it; offline runs use '/').
    ``topic_names``: interface key → fully qualified topic name, overriding ``namespace`` (the
    node passes its resolved names, remappings included). Keys are those of
    :data:`cvt_ros.interface.TOPICS`.
    ``joint_names``: the joint names J1..J4 in joint_states (the node's ``joint_prefix``
    applied; with N ≥ 2 paths one rocker per path, ``interface.joint_names``);
    :meth:`record_sample` adds the actuator joint (``crank_length`` with the same prefix), as
    the node publishes it.
    ``parameters``: validated scene values (dotted name → value), stored in the ``cvt_ros``
    metadata record; their ``paths.count`` (default 1) is the machine's N: N ≥ 2 registers
    ``clutch_states`` too; ``scene``: the scene's name or path; ``source``: who recorded.
    ``extra_topics``: more (topic, type, qos) to register, for :meth:`write`.
    ``on_error``: called once with the :class:`RecordingError` that stopped the recording.
    ``overwrite``, ``chunk_size``, ``flush_interval``: see :class:`BagWriter`.

    Raises :class:`RecordingError` if the file cannot be created (existing file without
    ``overwrite``, missing directory, unwritable, disk full). Thread-safe.
    """

    def __init__(self, path: str | os.PathLike[str], *, namespace: str = '/',
                 topic_names: Mapping[str, str] | None = None,
                 joint_names: Iterable[str] = I.JOINTS,
                 parameters: Mapping[str, Any] | None = None, scene: str = '',
                 source: str = 'cvt_ros', extra_topics: Iterable[tuple[str, Any, Any]] = (),
                 on_error: Callable[[Exception], None] | None = _stderr_error,
                 overwrite: bool = False, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 flush_interval: float | None = FLUSH_INTERVAL):
        _ensure_ament_prefix()
        self.n_paths = n = int((parameters or {}).get('paths.count', 1))
        names = I.resolved_topics(namespace, n)
        names.update(topic_names or {})
        self.topics: dict[str, str] = names
        self.joint_names = tuple(joint_names)
        if len(self.joint_names) == 4 and n > 1 and tuple(joint_names) == I.JOINTS:
            self.joint_names = I.joint_names(n)   # (the default names, for N paths)
        prefix = self.joint_names[0][:-len(I.JOINTS[0])] \
            if self.joint_names[0].endswith(I.JOINTS[0]) else ''
        if self.joint_names != I.joint_names(n, prefix):
            raise ValueError(f'joint_names must name the {n + 3} joints of {n} path(s), '
                             f'{", ".join(I.joint_names(n, prefix))}; got {self.joint_names!r}')
        self._layout = I.SampleLayout(n, prefix)
        self._sample_names = self._layout.names
        self._on_error = on_error
        self._lock = threading.Lock()
        self._error: Exception | None = None
        self._offset_ns = 0           # log time − simulation time in the present epoch
        self._last_log_ns = 0
        self._last_sample_ns: int | None = None
        self._reset_pending = False
        self._count = 0
        scene = str(scene)
        custom = {'cvt_ros.format': FORMAT, 'cvt_ros.source': source}
        if scene:
            custom['cvt_ros.scene'] = scene
        self._writer = BagWriter(path, chunk_size=chunk_size, flush_interval=flush_interval,
                                 overwrite=overwrite, clamp_log_time=True, custom_data=custom)
        try:
            for key, spec in I.topics_for(n).items():
                self._writer.add_topic(names[key], spec.type_name, qos=I.QOS[key])
            for topic, type_name, qos in extra_topics:
                self._writer.add_topic(topic, type_name, qos=qos)
            import yaml

            record = {
                'format': FORMAT,
                'source': source,
                'scene': scene,
                'parameters': parameters_yaml(parameters or {}),
                'joint_names': ','.join(self._sample_names),
                'topics': yaml.safe_dump(dict(names), sort_keys=True),
                'created': datetime.datetime.now(datetime.UTC).isoformat(
                    timespec='seconds'),
            }
            self._add_metadata(METADATA_NAME, record)
        except Exception:
            self._writer.finish()
            raise

    # ------------------------------------------------------------------ state
    @property
    def path(self) -> str:
        return self._writer.path

    @property
    def failed(self) -> bool:
        """True once an I/O error stopped the recording."""
        return self._error is not None or self._writer.failed

    @property
    def error(self) -> Exception | None:
        """The error that stopped the recording (None while all is well)."""
        return self._error or self._writer.error

    @property
    def closed(self) -> bool:
        return self._writer.closed

    @property
    def message_count(self) -> int:
        """Messages accepted so far (the file catches up within ``flush_interval``)."""
        return self._count

    # ------------------------------------------------------------------ generic hook
    def write(self, topic: str, msg: Any, t_ns: int) -> bool:
        """Record ``msg`` (rclpy message or CDR bytes) on ``topic`` (a registered, fully
        qualified name) at simulation time ``t_ns``; the node's ``_hand_to_recorder`` hook.
        Returns False if the recording has stopped. Never raises for I/O problems."""
        return self._write(topic, msg, int(t_ns), topic == self.topics['joint_states'])

    def mark_reset(self) -> None:
        """Simulation time restarts (``~/reset``): the next message opens a new epoch."""
        with self._lock:
            self._reset_pending = True

    def _write(self, topic: str, data: Any, t_ns: int, is_sample: bool = False) -> bool:
        if self._error is not None:
            return False
        with self._lock:
            last = self._last_sample_ns
            went_back = last is not None and t_ns < last
            if is_sample and went_back:
                self._reset_pending = True
            # a pending reset opens the new epoch with the first message that is earlier than
            # the old epoch's last sample: a command stamped just before the reset (with that
            # sample's time) still belongs to the old epoch
            if self._reset_pending and (went_back or last is None):
                self._reset_pending = False
                self._offset_ns = self._last_log_ns - t_ns
                self._last_sample_ns = None
            if is_sample:
                self._last_sample_ns = t_ns
            log = max(t_ns + self._offset_ns, self._last_log_ns)
            self._last_log_ns = log
            try:
                ok = self._writer.write(topic, data, log, t_ns)
            except RecordingError as exc:
                self._fail(exc)
                return False
            if ok:
                self._count += 1
        if not ok and self._writer.failed and self._error is None:
            self._fail(self._writer.error or RecordingError('recording stopped'))
        return ok

    def _fail(self, exc: Exception) -> None:
        self._error = exc
        if self._on_error is not None:
            try:
                self._on_error(exc)
            except Exception:  # noqa: BLE001 - a broken logger must not stop the simulation
                pass

    def _add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        # BagWriter has no public add_metadata yet; its recover() path uses this one.
        self._writer._add_metadata_raw(name, {str(k): str(v) for k, v in data.items()})

    # ------------------------------------------------------------------ typed recording
    def record_sample(self, row: Any, crank_rate: float = math.nan) -> bool:
        """A sample row (``cvt_ros.solver.output.path_columns(n_paths)``): joint_states
        stamped with its time, J1..J4 and the actuator joint (position = the actual crank length,
        velocity = ``crank_rate`` [m/s], effort NaN: not modelled), the node's layout, and with
        N ≥ 2 paths clutch_states; no /clock (see :meth:`record_clock`)."""
        ns = I.stamp_ns(row[0])
        data = self._layout.joint_states(row, crank_rate, ns)
        if self.n_paths > 1 and not self._write(self.topics['clutch_states'],
                                                self._layout.clutch_states(row, ns), ns):
            return False
        return self._write(self.topics['joint_states'], data, ns, True)

    def record_clock(self, t: float) -> bool:
        """/clock at simulation time ``t`` [s]."""
        ns = I.stamp_ns(t)
        return self._write(self.topics['clock'], I.clock_cdr(ns), ns)

    def record_clutch_state(self, engaged: bool, t: float) -> bool:
        """clutch_engaged = ``engaged`` at simulation time ``t`` [s] (start-up, reset)."""
        return self._write(self.topics['clutch_engaged'], I.bool_cdr(engaged), I.stamp_ns(t))

    def record_switch(self, switch: Any) -> bool:
        """A ``ClutchSwitch`` at its exact event time; grazing contacts are not switches. N ≥ 2
        paths: a switching instant (``solver.clutch_sets.SetChange``): the engaged set on
        clutch_states, and clutch_engaged where "any clutch engaged" changed."""
        if getattr(switch, 'kind', '') == 'graze':
            return False
        if self.n_paths > 1:
            ok = self.record_clutch_set(switch.after, switch.t)
            if ok and switch.any_changed:
                ok = self.record_clutch_state(switch.engaged, switch.t)
            return ok
        return self.record_clutch_state(switch.engaged, switch.t)

    def record_clutch_set(self, mask: int, t: float) -> bool:
        """clutch_states (N ≥ 2) of a switch at ``t`` [s]: the engaged set ``mask`` (bit k − 1
        = path k), positions only."""
        ns = I.stamp_ns(t)
        return self._write(self.topics['clutch_states'], self._layout.clutch_switch(mask, ns), ns)

    def record_command(self, topic: str, value: Any, t_receive: float) -> bool:
        """A command received at simulation time ``t_receive`` [s]. ``topic``: interface key
        ('crank_length_cmd', 'load_torque_cmd') or the topic name; ``value``: float or Float64."""
        name = self.topics.get(topic, topic)
        if name not in (self.topics['crank_length_cmd'], self.topics['load_torque_cmd']):
            raise ValueError(f'{topic!r} is not a command topic of this recording '
                             f"({self.topics['crank_length_cmd']}, "
                             f"{self.topics['load_torque_cmd']})")
        data = getattr(value, 'data', value)
        return self._write(name, I.float64_cdr(data), I.stamp_ns(t_receive))

    def record_diagnostics(self, msg: Any, t: float) -> bool:
        """A diagnostic_msgs/DiagnosticArray at simulation time ``t`` [s]."""
        return self._write(self.topics['diagnostics'], msg, I.stamp_ns(t))

    def record_parameters(self, changes: Mapping[str, Any], t: float) -> None:
        """Live parameter changes at simulation time ``t`` [s] (metadata record)."""
        if self._error is None:
            self._add_metadata(PARAMETER_CHANGE_NAME, {
                'time_ns': str(I.stamp_ns(t) + self._offset_ns),
                'parameters': parameters_yaml(changes)})

    def record_self_check(self, check: Mapping[str, Any]) -> None:
        """The solver's self-check (``Simulator.self_check()``: method and step, possibly missed
        clutch events) as a metadata record: whoever reads the file later sees whether the run
        that made it may have missed an event (docs/solver.md)."""
        if self._error is None and check:
            self._add_metadata(SELF_CHECK_NAME, {k: '' if v is None else v
                                                 for k, v in check.items()})

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Finish the file (summary, statistics, rosbag2 metadata, fsync). Idempotent; safe in
        a signal handler. An I/O error is reported through ``on_error``, not raised."""
        try:
            self._writer.finish()
        except RecordingError as exc:
            if self._error is None:
                self._fail(exc)

    finish = close

    def __enter__(self) -> SimulationRecorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def record_run(recorder: SimulationRecorder, result: Any, *, clock: bool = True) -> int:
    """Write a finished ``Simulator.run`` result: the clutch state at the first sample, then every
    sample (joint_states and /clock) and every clutch switch at its event time, in time order
    (a switch before a sample of the same nanosecond, as the node publishes). Returns the number
    of messages written (stops early if the recording failed)."""
    samples = result.samples
    switches = [s for s in result.switches if s.kind != 'graze']
    if len(samples) == 0:
        return 0
    import numpy as np

    n = recorder.n_paths
    count = 0
    if n > 1:   # one switching instant at a time, from the engaged set at the first sample
        from ..solver.clutch_sets import path_masks, set_changes
        engaged = list(result.columns).index('engaged_1')
        mask = path_masks(samples[0, engaged:engaged + n])
        if not recorder.record_clutch_set(mask, float(samples[0, COL['t']])):
            return 0
        count = 1
        switches = set_changes(switches, mask)[0]

    # the actuator moves at a constant rate between its corners: differences of the samples
    a, t = samples[:, COL['crank_length']], samples[:, COL['t']]
    rates = np.gradient(a, t) if len(samples) > 1 else np.zeros(len(samples))

    t0 = float(samples[0, COL['t']])
    count += int(recorder.record_clutch_state(bool(samples[0, COL['engaged']]), t0))
    per_sample = 2 if n > 1 else 1   # joint_states (and clutch_states)
    k = 0
    for row, rate in zip(samples, rates, strict=True):
        ns = I.stamp_ns(row[0])
        while k < len(switches) and I.stamp_ns(switches[k].t) <= ns:
            count += recorder.record_switch(switches[k])
            k += 1
        if not recorder.record_sample(row, float(rate)):
            return count
        count += per_sample
        if clock:
            count += recorder.record_clock(row[0])
    for switch in switches[k:]:  # after the last sample (duration not a multiple of the grid)
        count += recorder.record_switch(switch)
    diagnostics = getattr(result, 'diagnostics', {})
    recorder.record_self_check({k: diagnostics[k] for k in SELF_CHECK_KEYS if k in diagnostics})
    return count


#: The keys of a run's diagnostics that make its self-check record (Simulator.self_check()).
SELF_CHECK_KEYS = ('solver', 'possible_missed_events', 'first_possible_missed_event_s',
                   'stray_samples', 'first_stray_sample_s')


def check_target(path: str | os.PathLike[str], overwrite: bool = False) -> None:
    """Raise :class:`RecordingError` now if ``path`` cannot become a new recording (exists
    without ``overwrite``, no such directory, a directory, not writable): before a long run."""
    path = os.fspath(path)
    where = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise RecordingError(f'cannot create recording {path}: it is a directory')
    if os.path.exists(path) and not overwrite:
        raise RecordingError(f'cannot create recording {path}: file exists (use --overwrite to '
                             'replace it)')
    if not os.path.isdir(where):
        raise RecordingError(f'cannot create recording {path}: no such directory {where}')
    if not os.access(where if not os.path.exists(path) else path, os.W_OK):
        raise RecordingError(f'cannot create recording {path}: permission denied')


class _SignalsFinish:
    """While active (main thread only), SIGTERM raises SystemExit(128 + SIGTERM) so that the
    ``with`` blocks around a recording finish the file; SIGINT already raises KeyboardInterrupt."""

    def __enter__(self) -> _SignalsFinish:
        import signal

        self._previous = None
        if threading.current_thread() is threading.main_thread():
            def handler(signum: int, frame: Any) -> None:
                raise SystemExit(128 + signum)
            self._previous = signal.signal(signal.SIGTERM, handler)
        return self

    def __exit__(self, *exc_info: object) -> None:
        import signal

        if self._previous is not None:
            signal.signal(signal.SIGTERM, self._previous)


def write_run(path: str | os.PathLike[str], sim: Any, result: Any, *, scene: str = '',
              overwrite: bool = False, source: str = 'cvt-sim run') -> tuple[int, Exception | None]:
    """``cvt-sim run --mcap``: record a finished run with its scene parameters.

    Returns (messages written, the error that stopped the recording or None). SIGINT / SIGTERM
    while writing leave a finished file with what was written so far."""
    errors: list[Exception] = []
    try:
        recorder = SimulationRecorder(path, parameters=sim.values, scene=scene, source=source,
                                      overwrite=overwrite, on_error=errors.append)
    except RecordingError as exc:
        return 0, exc
    with _SignalsFinish(), recorder:
        count = record_run(recorder, result)
    return count, (errors[0] if errors else None)
