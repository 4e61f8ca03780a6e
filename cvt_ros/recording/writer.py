"""Crash-tolerant rosbag2-compatible MCAP writer.

The file is what ``ros2 bag record -s mcap`` (Jazzy) writes: profile ``ros2``, one ``ros2msg``
schema per type, ``cdr`` channels carrying ``offered_qos_profiles`` and ``topic_type_hash``
metadata, a summary (chunk + message indexes, statistics) and a ``rosbag2`` metadata record whose
``serialized_metadata`` is the bag metadata YAML. ``ros2 bag play/info file.mcap`` accept it.

Design: :meth:`BagWriter.write` only serializes the message and appends it to a queue; one
background thread owns the ``mcap`` writer and the file and does all I/O. So ``write`` never
blocks on the disk, and a signal handler (which Python always runs in the main thread) can never
interrupt the MCAP bookkeeping half-way: :meth:`BagWriter.finish` just queues a "finish" and
waits for the thread. If the process exits without ``finish()`` (exception, ``sys.exit`` from a
handler), an ``atexit`` hook finishes the file.

Crash safety: messages go into small chunks (64 KiB by default) and the thread closes the current
chunk and hands it to the OS once the oldest unwritten message is ``0.75 * flush_interval`` old
(it polls every ``flush_interval / 4``), so after SIGKILL everything written more than
``flush_interval`` earlier sits in complete, CRC-checked chunks; :func:`cvt_ros.recording.recover`
turns such a file into a finished one. That protects against a process crash, not a power cut:
only ``finish()`` fsyncs.

Errors: a bad path raises :class:`RecordingError` from the constructor. An I/O error later (disk
full...) is raised as :class:`RecordingError` once, by the next call of ``write``/``add_topic``/
``flush``/``finish``; the writer is then *failed*: further calls return without raising and
:attr:`BagWriter.failed` / :attr:`BagWriter.error` tell what happened.
"""

from __future__ import annotations

import atexit
import errno
import os
import queue
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from . import _yaml
from ._cdr import cdr_size
from .definitions import get_message_definition, normalize_type_name, type_name_of
from .errors import LogTimeError, MessageDefinitionError, RecordingError
from .qos import offered_qos_profiles_yaml

__all__ = ['BagWriter', 'DEFAULT_CHUNK_SIZE', 'ROS_DISTRO', 'METADATA_VERSION']

#: Default chunk size in bytes: small, so little is lost in a crash (rosbag2 uses 768 KiB).
DEFAULT_CHUNK_SIZE = 64 * 1024
#: rosbag2 bag metadata version written by Jazzy.
METADATA_VERSION = 9
#: ``ros_distro`` written into the bag metadata.
ROS_DISTRO = 'jazzy'

_OPEN, _CLOSED, _FAILED = 'open', 'closed', 'failed'
_RECORD_OVERHEAD = 31  # opcode + length + message header bytes (9 + 22)
_DONE_POLL_S = 0.002   # finish() looks this often whether the writer thread is done
# Queue commands (first tuple element).
_MSG, _SCHEMA, _CHANNEL, _METADATA, _FLUSH, _FINISH = range(6)


@dataclass
class _Topic:
    name: str
    type_name: str
    channel_id: int
    serialization_format: str
    qos_yaml: str
    type_hash: str
    count: int = 0  # messages written; only the writer thread changes it


def _finish_at_exit(ref: weakref.ReferenceType[BagWriter]) -> None:
    writer = ref()
    if writer is not None:
        try:
            writer.finish()
        except RecordingError:
            pass  # already reported (or nobody left to report it to)


class BagWriter:
    """Write a single rosbag2-compatible ``.mcap`` file.

    ``path``: the ``.mcap`` file to create (its directory must exist). It must not exist unless
    ``overwrite=True`` (like ``ros2 bag record``, we refuse to clobber a recording).
    ``chunk_size``: bytes of messages per chunk; smaller loses less on a crash.
    ``flush_interval``: seconds; data is on disk (in complete chunks) at most this long after
    :meth:`write` returned. ``None`` disables time-based flushing (chunks close by size only).
    ``library``: free-form MCAP header library string.
    ``clamp_log_time``: if true, a log time earlier than the previous one is raised to it instead
    of raising :class:`LogTimeError`.
    ``custom_data``: string map stored as ``custom_data`` in the bag metadata.

    Log times are int64 nanoseconds (ROS time of reception, usually ``node.get_clock().now()``)
    and must be non-decreasing: rosbag2's player and our crash recovery rely on file order being
    time order. All methods are thread-safe; usable as a context manager (``finish()`` on exit).
    """

    def __init__(self, path: str | os.PathLike[str], *, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 flush_interval: float | None = 1.0, library: str = 'cvt_ros',
                 overwrite: bool = False, clamp_log_time: bool = False,
                 custom_data: Mapping[str, str] | None = None):
        from mcap.writer import CompressionType, Writer

        if int(chunk_size) <= 0:
            raise ValueError(f'chunk_size must be positive, got {chunk_size!r}')
        if flush_interval is not None and not flush_interval > 0:
            raise ValueError(f'flush_interval must be positive or None, got {flush_interval!r}')
        self._path = os.fspath(path)
        self._chunk_size = int(chunk_size)
        self._flush_after = None if flush_interval is None else 0.75 * flush_interval
        self._poll = None if flush_interval is None else flush_interval / 4
        self._clamp = bool(clamp_log_time)
        self._custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        # Producer side (any thread), guarded by _lock.
        self._lock = threading.RLock()
        self._queue: deque[tuple] = deque()  # append/popleft are atomic: no lock for the thread
        self._wake = _Wake()
        self._done = threading.Event()  # set when the writer thread has exited
        self._state = _OPEN
        self._finish_requested = False
        self._error: RecordingError | None = None
        self._error_reported = False
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[tuple[str, str, bytes], int] = {}
        self._class_types: dict[type, str] = {}
        self._next_schema_id = 1
        self._next_channel_id = 1
        self._bytes_since_wake = 0
        self._dirty_since: float | None = None  # monotonic time of the oldest unflushed message
        self._last_log_time = 0
        # Writer-thread side.
        self._channels: dict[int, _Topic] = {}
        self._message_count = 0
        self._start_ns: int | None = None
        self._end_ns = 0
        try:
            self._file = open(self._path, 'wb' if overwrite else 'xb')
        except FileExistsError as exc:
            raise RecordingError(f'cannot create recording {self._path}: file exists '
                                 '(pass overwrite=True to replace it)') from exc
        except OSError as exc:
            raise RecordingError(
                f'cannot create recording {self._path}: {exc.strerror or exc}') from exc
        try:
            self._mcap = Writer(self._file, chunk_size=self._chunk_size,
                                compression=CompressionType.NONE)
            self._mcap.start(profile='ros2', library=library)
            self._file.flush()  # surface an unwritable target (e.g. a full disk) right away
        except OSError as exc:
            self._state = _FAILED
            self._close_quietly()
            raise RecordingError(
                f'cannot write recording {self._path}: {exc.strerror or exc}') from exc
        self._thread = threading.Thread(target=self._run, name='BagWriter', daemon=True)
        self._thread.start()
        self._atexit = _make_atexit_hook(self)
        atexit.register(self._atexit)

    # ------------------------------------------------------------------ properties
    @property
    def path(self) -> str:
        """The file being written."""
        return self._path

    @property
    def failed(self) -> bool:
        """True once an I/O error stopped the recording (see :attr:`error`)."""
        return self._state == _FAILED

    @property
    def error(self) -> RecordingError | None:
        """The error that stopped the recording, if any."""
        return self._error

    @property
    def closed(self) -> bool:
        """True after :meth:`finish` has completed, or after a failure."""
        return self._state != _OPEN

    @property
    def message_count(self) -> int:
        """Messages in the file so far (lags :meth:`write` until the thread catches up)."""
        return self._message_count

    @property
    def topics(self) -> dict[str, str]:
        """Registered topics -> type names."""
        return {t.name: t.type_name for t in list(self._topics.values())}

    # ------------------------------------------------------------------ public API
    def add_topic(self, topic: str, type_name: str | type, qos: Any = None) -> int:
        """Register ``topic`` with message type ``type_name`` and return its channel id.

        ``type_name`` is ``'pkg/msg/Type'`` (or a message class); ``qos`` is the publisher's
        QoS (rclpy ``QoSProfile``, dict or list of them; ``None`` = rclpy default, see
        :mod:`cvt_ros.recording.qos`). The schema is stored once per type. Registering the same
        topic again with the same type returns the existing id. Raises
        :class:`MessageDefinitionError` if the type's definition is not installed. On a failed
        or closed writer nothing is registered and 0 is returned.
        """
        if isinstance(type_name, type):
            type_name = type_name_of(type_name)
        full_type = normalize_type_name(type_name)
        existing = self._topics.get(topic)
        if existing is not None:
            if existing.type_name != full_type:
                raise ValueError(f'topic {topic!r} already has type {existing.type_name}, '
                                 f'not {full_type}')
            return existing.channel_id
        if not isinstance(topic, str) or not topic:
            raise ValueError(f'invalid topic name {topic!r}')
        definition = get_message_definition(full_type)
        qos_yaml = offered_qos_profiles_yaml(qos)
        return self._add_channel(
            topic, full_type, definition.encoding, definition.text.encode('utf-8'), 'cdr',
            {'offered_qos_profiles': qos_yaml, 'topic_type_hash': definition.type_hash})

    def write(self, topic: str, message: Any, log_time_ns: int,
              publish_time_ns: int | None = None) -> bool:
        """Queue one message for writing; return True if it was accepted.

        ``message`` is an rclpy message (serialized with ``rclpy.serialization``, cut to its
        exact CDR length, see :mod:`cvt_ros.recording._cdr`) or serialized CDR ``bytes`` (written
        as given). ``log_time_ns``: reception time, int64 ns, non-decreasing.
        ``publish_time_ns`` defaults to ``log_time_ns``. Never blocks on I/O. Returns False
        without raising when the writer is closed or failed (an I/O error is raised once as
        :class:`RecordingError`).
        """
        if self._state != _OPEN or self._finish_requested:
            self._raise_unreported()
            return False
        entry = self._topics.get(topic)
        if entry is None:
            raise ValueError(f'unknown topic {topic!r}; call add_topic() first')
        data = self._serialize(entry, message)
        log = int(log_time_ns)
        publish = log if publish_time_ns is None else int(publish_time_ns)
        if log < 0 or publish < 0:
            raise LogTimeError(f'negative time on {topic!r}: log {log}, publish {publish} ns')
        with self._lock:
            if self._state != _OPEN or self._finish_requested:
                self._raise_unreported()
                return False
            if log < self._last_log_time:
                if not self._clamp:
                    raise LogTimeError(
                        f'log time went backwards on {topic!r}: {log} ns < previous '
                        f'{self._last_log_time} ns (log times must be non-decreasing; '
                        'use clamp_log_time=True to clamp)')
                log = self._last_log_time
            self._enqueue((_MSG, entry, log, publish, data), len(data) + _RECORD_OVERHEAD)
            self._last_log_time = log
        return True

    def flush(self) -> None:
        """Close the current chunk and hand everything written so far to the OS (blocks)."""
        done = threading.Event()
        with self._lock:
            if self._state != _OPEN or self._finish_requested:
                self._raise_unreported()
                return
            self._queue.append((_FLUSH, done))
            self._wake.set()
        while not done.wait(0.1) and not self._done.is_set():
            pass
        self._raise_unreported()

    def finish(self) -> None:
        """Write the summary and the rosbag2 metadata, fsync and close. Idempotent.

        Blocks until the file is complete. Safe to call from a signal handler. On a failed
        writer it returns at once (raising the failure if it has not been reported yet).
        """
        with self._lock:
            if not self._finish_requested and self._state == _OPEN:
                # queued before it is marked: a handler landing in between queues its own
                # (a second FINISH is never read) instead of waiting for one never queued
                self._queue.append((_FINISH,))
                self._finish_requested = True
                self._wake.set()
        while not self._done.is_set():   # polled: Event.wait() holds a plain lock a handler
            time.sleep(_DONE_POLL_S)     # landing inside it would wait on forever
        atexit.unregister(self._atexit)
        self._raise_unreported()

    def close(self) -> None:
        """Alias of :meth:`finish`."""
        self.finish()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.finish()

    def bag_metadata(self) -> dict[str, Any]:
        """The rosbag2 bag metadata (version 9) of what is in the file so far, as a dict."""
        base = os.path.basename(self._path)
        start = self._start_ns if self._start_ns is not None else 0
        duration = self._end_ns - start if self._start_ns is not None else 0
        count = self._message_count
        return {
            'version': METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': [
                {
                    'topic_metadata': {
                        'name': t.name,
                        'type': t.type_name,
                        'serialization_format': t.serialization_format,
                        'offered_qos_profiles': _yaml.RawBlock(t.qos_yaml),
                        'type_description_hash': t.type_hash,
                    },
                    'message_count': t.count,
                }
                for t in list(self._channels.values())
            ],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [base],
            'files': [{
                'path': base,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': duration},
                'message_count': count,
            }],
            'custom_data': dict(self._custom_data) or None,
            'ros_distro': ROS_DISTRO,
        }

    def bag_metadata_yaml(self) -> str:
        """:meth:`bag_metadata` as rosbag2 serialises it (yaml-cpp ``Dump``, no root key)."""
        return _yaml.dump(self.bag_metadata())

    # ------------------------------------------------------------------ producer internals
    def _enqueue(self, command: tuple, size: int) -> None:
        """Append under _lock; wake the thread when a chunk's worth is waiting."""
        self._queue.append(command)
        if self._dirty_since is None:
            self._dirty_since = time.monotonic()
        self._bytes_since_wake += size
        if self._bytes_since_wake >= self._chunk_size:
            self._bytes_since_wake = 0
            self._wake.set()

    def _serialize(self, entry: _Topic, message: Any) -> bytes:
        if isinstance(message, (bytes, bytearray, memoryview)):
            return bytes(message)
        cls = type(message)
        msg_type = self._class_types.get(cls)
        if msg_type is None:
            try:
                msg_type = type_name_of(cls)
            except MessageDefinitionError as exc:
                raise TypeError(f'cannot record {cls!r} on {entry.name!r}: pass an rclpy '
                                'message or serialized bytes') from exc
            self._class_types[cls] = msg_type
        if msg_type != entry.type_name:
            raise TypeError(f'topic {entry.name!r} has type {entry.type_name}, got {msg_type}')
        from rclpy.serialization import serialize_message

        data = serialize_message(message)
        size = cdr_size(message)  # rclpy's buffer ends with the RMW's size-estimate slack
        return data[:size] if size is not None and size <= len(data) else data

    def _add_channel(self, topic: str, type_name: str, schema_encoding: str, schema_data: bytes,
                     message_encoding: str, metadata: Mapping[str, str]) -> int:
        """Queue schema (deduplicated) and channel registration; used by add_topic and recover.

        Ids are assigned here in the order the mcap writer will assign them (1, 2, ...).
        """
        with self._lock:
            if self._state != _OPEN or self._finish_requested:
                self._raise_unreported()
                return 0
            existing = self._topics.get(topic)
            if existing is not None and existing.type_name == type_name:
                return existing.channel_id
            key = (type_name, schema_encoding, schema_data)
            schema_id = self._schema_ids.get(key)
            if schema_id is None:
                schema_id = self._next_schema_id
                self._next_schema_id += 1
                self._schema_ids[key] = schema_id
                self._queue.append((_SCHEMA, schema_id, type_name, schema_encoding, schema_data))
            channel_id = self._next_channel_id
            self._next_channel_id += 1
            entry = _Topic(topic, type_name, channel_id, message_encoding,
                           metadata.get('offered_qos_profiles', ''),
                           metadata.get('topic_type_hash', ''))
            self._queue.append((_CHANNEL, entry, schema_id, dict(metadata)))
            self._topics[topic] = entry
            return channel_id

    def _write_raw(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int,
                   sequence: int | None = None) -> None:
        """Queue without the monotonic check (recovery copies times and sequence numbers as
        found)."""
        with self._lock:
            if self._state == _OPEN and not self._finish_requested:
                command = (_MSG, self._topics[topic], log_time_ns, publish_time_ns, data)
                if sequence is not None:
                    command += (int(sequence) & 0xFFFFFFFF,)
                self._enqueue(command, len(data) + _RECORD_OVERHEAD)

    def _add_metadata_raw(self, name: str, data: Mapping[str, str]) -> None:
        with self._lock:
            if self._state == _OPEN and not self._finish_requested:
                self._queue.append((_METADATA, name, dict(data)))

    def _raise_unreported(self) -> None:
        if self._state != _FAILED or self._error_reported:
            return
        with self._lock:
            if not self._error_reported and self._error is not None:
                self._error_reported = True
                raise self._error

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        try:
            while self._state == _OPEN:
                self._wake.wait(self._poll)
                self._process()
        except Exception as exc:  # noqa: BLE001 - any failure stops the recording, reported once
            self._fail(exc)
        finally:
            if self._state == _OPEN:  # defensive: never leave waiters hanging
                self._state = _FAILED
            self._queue.clear()
            self._done.set()

    def _process(self) -> None:
        """Write everything queued; close the chunk if a flush is due; finish if asked."""
        flush = False
        since = self._dirty_since
        if since is not None and self._flush_after is not None and \
                time.monotonic() - since >= self._flush_after:
            flush = True
            self._dirty_since = None  # reset *before* draining: later messages set it again
        flushed: list[threading.Event] = []
        finish = False
        queue, mcap = self._queue, self._mcap
        # Take only what is queued now, so a busy producer cannot keep us from flushing.
        for _ in range(len(queue)):
            command = queue.popleft()
            kind = command[0]
            if kind == _MSG:
                _, entry, log, publish, data, *sequence = command
                entry.count += 1
                self._message_count += 1
                if self._start_ns is None or log < self._start_ns:
                    self._start_ns = log
                if log > self._end_ns:
                    self._end_ns = log
                mcap.add_message(entry.channel_id, log, data, publish,
                                 sequence=sequence[0] if sequence else entry.count & 0xFFFFFFFF)
            elif kind == _SCHEMA:
                _, schema_id, name, encoding, data = command
                if mcap.register_schema(name, encoding, data) != schema_id:
                    raise RuntimeError('internal error: schema id mismatch')
            elif kind == _CHANNEL:
                _, entry, schema_id, metadata = command
                if mcap.register_channel(entry.name, entry.serialization_format, schema_id,
                                         metadata) != entry.channel_id:
                    raise RuntimeError('internal error: channel id mismatch')
                self._channels[entry.channel_id] = entry
            elif kind == _METADATA:
                mcap.add_metadata(command[1], command[2])
            elif kind == _FLUSH:
                flush = True
                flushed.append(command[1])
            elif kind == _FINISH:
                finish = True
                break
        if finish:
            mcap.add_metadata('rosbag2', {'serialized_metadata': self.bag_metadata_yaml()})
            mcap.finish()
            self._file.flush()
            try:
                os.fsync(self._file.fileno())
            except OSError as exc:
                if exc.errno not in (errno.EINVAL, errno.EOPNOTSUPP):  # not a regular file
                    raise
            self._file.close()
            self._state = _CLOSED
        elif flush:
            mcap.flush()  # close the chunk, write it and its message index, flush the file
        for event in flushed:
            event.set()
        if queue:
            self._wake.set()

    def _fail(self, exc: BaseException) -> None:
        reason = getattr(exc, 'strerror', None) or str(exc) or type(exc).__name__
        error = RecordingError(
            f'recording to {self._path} stopped: {reason}; later messages are dropped')
        error.__cause__ = exc
        self._error = error
        self._state = _FAILED
        self._close_quietly()

    def _close_quietly(self) -> None:
        try:
            self._file.close()  # closes the descriptor even if flushing the buffer fails
        except (OSError, ValueError):
            pass


class _Wake:
    """Wakes the writer thread; any thread, and a signal handler, may call :meth:`set`.

    Not a threading.Event: its set() holds a plain lock, and a signal handler that calls
    finish() while the main thread is inside write()'s wake-up would wait for that lock forever.
    queue.SimpleQueue's put() is reentrant (C, documented safe in signal handlers)."""

    def __init__(self) -> None:
        self._tokens: queue.SimpleQueue[None] = queue.SimpleQueue()

    def set(self) -> None:
        self._tokens.put(None)

    def wait(self, timeout: float | None) -> None:
        """Until set() or ``timeout`` [s]; one pass of the thread serves every set() so far."""
        try:
            self._tokens.get(timeout=timeout)
        except queue.Empty:
            return
        while True:
            try:
                self._tokens.get_nowait()
            except queue.Empty:
                return


def _make_atexit_hook(writer: BagWriter) -> Callable[[], None]:
    """An exit hook that holds the writer only weakly (a finished writer can be collected)."""
    ref = weakref.ref(writer)

    def hook() -> None:
        _finish_at_exit(ref)
    return hook
