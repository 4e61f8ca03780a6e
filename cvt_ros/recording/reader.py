"""Tolerant reading and recovery of rosbag2 MCAP recordings.

:func:`read_messages` walks the file record by record (never trusting the summary), so a file
cut short by a crash, or with a damaged chunk, still yields every message in the intact part.
Damage is reported after the readable messages as :class:`RecordingReadError` (or, with
``strict=False``, a :class:`RecordingReadWarning`); mcap/struct exceptions never escape.
A chunk whose CRC does not match is skipped and reading continues with the next record as long
as the record framing is intact.

:func:`summary` uses the file's summary section when it is intact (fast, like ``ros2 bag
info``) and falls back to a scan. :func:`recover` rewrites the readable part into a finished
file.
"""

from __future__ import annotations

import importlib
import io
import os
import struct
import warnings
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

from .errors import MessageDefinitionError, RecordingReadError, RecordingReadWarning

__all__ = ['BagMessage', 'BagSummary', 'TopicSummary', 'read_messages', 'recover', 'summary']

_MAGIC = b'\x89MCAP0\r\n'
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_STATISTICS, _OP_METADATA, _OP_DATA_END = 0x0B, 0x0C, 0x0F
_OP_NAMES = {1: 'Header', 2: 'Footer', 3: 'Schema', 4: 'Channel', 5: 'Message', 6: 'Chunk',
             7: 'MessageIndex', 8: 'ChunkIndex', 9: 'Attachment', 10: 'AttachmentIndex',
             11: 'Statistics', 12: 'Metadata', 13: 'MetadataIndex', 14: 'SummaryOffset',
             15: 'DataEnd'}
_MSG_HEAD = struct.Struct('<HIQQ')
_REC_HEAD = struct.Struct('<BQ')


@lru_cache(maxsize=256)
def _message_class(type_name: str) -> type:
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3:
        raise MessageDefinitionError(f'invalid message type name {type_name!r}')
    try:
        module = importlib.import_module(f'{parts[0]}.{parts[1]}')
        return getattr(module, parts[2])
    except (ImportError, AttributeError) as exc:
        raise MessageDefinitionError(
            f'message type {type_name!r} is not available in this Python environment') from exc


@dataclass(frozen=True)
class BagMessage:
    """One recorded message: times in int64 ns, ``data`` the serialized (CDR) bytes."""

    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes = field(repr=False)
    sequence: int = 0
    message_encoding: str = 'cdr'

    def message(self) -> Any:
        """Deserialize ``data`` into an rclpy message (imports rclpy and the message package)."""
        if self.message_encoding != 'cdr':
            raise MessageDefinitionError(
                f'cannot deserialize {self.message_encoding!r} messages on {self.topic!r}')
        from rclpy.serialization import deserialize_message

        return deserialize_message(self.data, _message_class(self.type_name))


@dataclass(frozen=True)
class TopicSummary:
    """Per-topic facts of a recording."""

    topic: str
    type_name: str
    message_count: int
    message_encoding: str = 'cdr'
    offered_qos_profiles: str = ''
    type_hash: str = ''


@dataclass(frozen=True)
class BagSummary:
    """What :func:`summary` found. Times in int64 ns; ``None`` if there are no messages.

    ``complete`` is True when the file ends with a valid footer; ``problems`` lists what was
    wrong otherwise (empty for a good file).
    """

    path: str
    profile: str
    library: str
    message_count: int
    start_time_ns: int | None
    end_time_ns: int | None
    topics: dict[str, TopicSummary]
    metadata: dict[str, dict[str, str]]
    complete: bool
    problems: tuple[str, ...] = ()

    @property
    def duration_ns(self) -> int:
        """End minus start log time (0 for an empty recording)."""
        if self.start_time_ns is None or self.end_time_ns is None:
            return 0
        return self.end_time_ns - self.start_time_ns


class _Scan:
    """Record-by-record walk of an MCAP file that notes problems instead of raising."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = os.fspath(path)
        try:
            self._file = open(self.path, 'rb')
            self.size = os.fstat(self._file.fileno()).st_size
        except OSError as exc:
            raise RecordingReadError(self.path, [f'cannot open: {exc.strerror or exc}']) from exc
        self.problems: list[str] = []
        self.problem_offset: int | None = None
        self.header: Any = None
        self.schemas: dict[int, Any] = {}
        self.channels: dict[int, Any] = {}
        self.metadata: list[Any] = []
        self.statistics: Any = None
        self.complete = False
        self.reached_data_end = False

    def close(self) -> None:
        self._file.close()

    def _problem(self, offset: int, text: str) -> None:
        if self.problem_offset is None:
            self.problem_offset = offset
        self.problems.append(text)

    def records(self) -> Iterator[tuple[str, Any]]:
        """Yield ('schema'|'channel'|'metadata', record) and ('message', tuple) in file order."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Channel, Header, Metadata, Schema, Statistics

        def stream(body: bytes | memoryview) -> ReadDataStream:
            return ReadDataStream(io.BytesIO(body))

        f = self._file
        magic = f.read(8)
        if magic != _MAGIC:
            what = 'empty file' if not magic else 'not an MCAP file (bad magic bytes)'
            self._problem(0, what)
            return
        pos = 8
        in_summary = False
        while True:
            head = f.read(9)
            if len(head) < 9:
                if in_summary:
                    self._problem(pos, 'file ends inside the summary section (all messages '
                                  'were read, the index is incomplete)')
                else:
                    self._problem(pos, 'file ends without a summary/footer (recording was not '
                                  'finished; it may have crashed)' if not head else
                                  'file ends inside a record header (truncated)')
                return
            op, length = _REC_HEAD.unpack(head)
            name = _OP_NAMES.get(op, f'opcode 0x{op:02x}')
            if op == 0 or (0x10 <= op < 0x80):
                self._problem(pos, f'invalid record opcode 0x{op:02x} (corrupt data)')
                return
            available = self.size - pos - 9
            if length > available:
                self._problem(pos, f'file ends inside a {name} record ({length} bytes declared, '
                              f'{max(available, 0)} present): truncated')
                return
            if pos == 8 and op != _OP_HEADER:
                self._problem(pos, f'first record is {name}, not Header (corrupt file)')
                return
            body = f.read(length)
            if len(body) < length:  # file shrank while reading
                self._problem(pos, f'file ends inside a {name} record: truncated')
                return
            start, pos = pos, pos + 9 + length
            try:
                if op == _OP_HEADER:
                    self.header = Header.read(stream(body))
                elif op == _OP_MESSAGE and not in_summary:
                    yield 'message', self._message(body)
                elif op == _OP_CHUNK and not in_summary:
                    yield from self._chunk(body, start, stream, Schema, Channel)
                elif op == _OP_SCHEMA:
                    schema = Schema.read(stream(body))
                    if not in_summary or schema.id not in self.schemas:
                        self.schemas[schema.id] = schema
                        yield 'schema', schema
                elif op == _OP_CHANNEL:
                    channel = Channel.read(stream(body))
                    if not in_summary or channel.id not in self.channels:
                        self.channels[channel.id] = channel
                        yield 'channel', channel
                elif op == _OP_METADATA:
                    record = Metadata.read(stream(body))
                    self.metadata.append(record)
                    yield 'metadata', record
                elif op == _OP_STATISTICS:
                    self.statistics = Statistics.read(stream(body))
                elif op == _OP_DATA_END:
                    in_summary = True
                    self.reached_data_end = True
                elif op == _OP_FOOTER:
                    tail = f.read(8)
                    if tail != _MAGIC:
                        self._problem(pos, 'missing closing magic after the footer (truncated)')
                    else:
                        self.complete = True
                    return
            except Exception as exc:  # noqa: BLE001 - any parse failure means a damaged record
                self._problem(start, f'damaged {name} record skipped ({type(exc).__name__}: '
                              f'{exc})')

    @staticmethod
    def _message(body: bytes | memoryview) -> tuple[int, int, int, int, bytes]:
        if len(body) < _MSG_HEAD.size:
            raise ValueError('message record too short')
        channel_id, sequence, log_time, publish_time = _MSG_HEAD.unpack_from(body, 0)
        return channel_id, sequence, log_time, publish_time, bytes(body[_MSG_HEAD.size:])

    def _chunk(self, body: bytes, start: int, stream: Any, schema_cls: Any,
               channel_cls: Any) -> Iterator[tuple[str, Any]]:
        from mcap.records import Chunk
        from mcap.stream_reader import get_chunk_data_stream

        chunk = Chunk.read(stream(body))
        data_stream, size = get_chunk_data_stream(chunk, validate_crc=False)
        data = data_stream.read(size) if size else b''
        if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
            self._problem(start, 'chunk CRC mismatch: damaged chunk skipped')
            return
        view = memoryview(data)
        i, n = 0, len(data)
        while i < n:
            if n - i < 9:
                raise ValueError('chunk ends inside a record header')
            op, length = _REC_HEAD.unpack_from(view, i)
            i += 9
            if length > n - i:
                raise ValueError('chunk record overruns the chunk')
            rec = view[i:i + length]
            i += length
            if op == _OP_MESSAGE:
                yield 'message', self._message(rec)
            elif op == _OP_SCHEMA:
                schema = schema_cls.read(stream(bytes(rec)))
                self.schemas[schema.id] = schema
                yield 'schema', schema
            elif op == _OP_CHANNEL:
                channel = channel_cls.read(stream(bytes(rec)))
                self.channels[channel.id] = channel
                yield 'channel', channel


def _schema_name(scan: _Scan, channel: Any) -> str:
    schema = scan.schemas.get(channel.schema_id)
    return schema.name if schema is not None else ''


def read_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None, *,
                  strict: bool = True) -> Iterator[BagMessage]:
    """Yield the messages of an MCAP recording in file order (= log-time order for our files).

    ``topics`` restricts to those topic names. Every readable message is yielded even if the
    file is truncated or damaged; afterwards the problem is raised as
    :class:`RecordingReadError` (``strict=True``) or issued as :class:`RecordingReadWarning`.
    A file that cannot be opened raises :class:`RecordingReadError` immediately.
    """
    if isinstance(topics, str):
        topics = [topics]
    wanted = None if topics is None else set(topics)
    scan = _Scan(path)
    count = 0
    unknown_channels: set[int] = set()
    try:
        for kind, record in scan.records():
            if kind != 'message':
                continue
            channel_id, sequence, log_time, publish_time, data = record
            channel = scan.channels.get(channel_id)
            if channel is None:
                if channel_id not in unknown_channels:
                    unknown_channels.add(channel_id)
                    scan._problem(-1, f'messages on unknown channel {channel_id} skipped')
                continue
            if wanted is not None and channel.topic not in wanted:
                continue
            count += 1
            yield BagMessage(channel.topic, _schema_name(scan, channel), log_time, publish_time,
                             data, sequence, channel.message_encoding)
    finally:
        scan.close()
    if scan.problems:
        offset = scan.problem_offset if scan.problem_offset is not None and \
            scan.problem_offset >= 0 else None
        error = RecordingReadError(scan.path, scan.problems, offset, count)
        if strict:
            raise error
        warnings.warn(str(error), RecordingReadWarning, stacklevel=2)


def _summary_from_index(path: str) -> BagSummary | None:
    """Build the summary from an intact summary section; None if there is none."""
    from mcap.reader import SeekingReader

    with open(path, 'rb') as f:
        reader = SeekingReader(f, validate_crcs=True)
        header = reader.get_header()
        index = reader.get_summary()
        if index is None or index.statistics is None:
            return None
        stats = index.statistics
        topics: dict[str, TopicSummary] = {}
        for channel_id, channel in index.channels.items():
            schema = index.schemas.get(channel.schema_id)
            count = stats.channel_message_counts.get(channel_id, 0)
            previous = topics.get(channel.topic)
            if previous is not None:
                count += previous.message_count
            topics[channel.topic] = TopicSummary(
                channel.topic, schema.name if schema else '', count, channel.message_encoding,
                channel.metadata.get('offered_qos_profiles', ''),
                channel.metadata.get('topic_type_hash', ''))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    empty = stats.message_count == 0
    return BagSummary(path, header.profile, header.library, stats.message_count,
                      None if empty else stats.message_start_time,
                      None if empty else stats.message_end_time, topics, metadata, True)


def summary(path: str | os.PathLike[str]) -> BagSummary:
    """Topics, types, counts and time range of a recording.

    Uses the summary section when present; otherwise (crashed or damaged file) scans the file
    and reports what it could read, with ``complete=False`` and the ``problems`` found. Raises
    :class:`RecordingReadError` only if the file cannot be opened or is not MCAP at all.
    """
    path = os.fspath(path)
    try:
        fast = _summary_from_index(path)
    except Exception:  # noqa: BLE001 - damaged or missing summary: fall back to a scan
        fast = None
    if fast is not None:
        return fast
    scan = _Scan(path)
    counts: dict[int, int] = {}
    start: int | None = None
    end: int | None = None
    try:
        for kind, record in scan.records():
            if kind == 'message':
                channel_id, _, log_time, _, _ = record
                counts[channel_id] = counts.get(channel_id, 0) + 1
                start = log_time if start is None else min(start, log_time)
                end = log_time if end is None else max(end, log_time)
    finally:
        scan.close()
    if scan.header is None:
        raise RecordingReadError(scan.path, scan.problems or ['no MCAP header'],
                                 scan.problem_offset)
    topics: dict[str, TopicSummary] = {}
    for channel_id, channel in scan.channels.items():
        count = counts.get(channel_id, 0) + (
            topics[channel.topic].message_count if channel.topic in topics else 0)
        topics[channel.topic] = TopicSummary(
            channel.topic, _schema_name(scan, channel), count, channel.message_encoding,
            channel.metadata.get('offered_qos_profiles', ''),
            channel.metadata.get('topic_type_hash', ''))
    metadata = {m.name: dict(m.metadata) for m in scan.metadata}
    return BagSummary(scan.path, scan.header.profile, scan.header.library, sum(counts.values()),
                      start, end, topics, metadata, scan.complete and not scan.problems,
                      tuple(scan.problems))


def _custom_data(serialized: str) -> dict[str, str] | None:
    try:
        import yaml

        data = yaml.safe_load(serialized)
        custom = data.get('custom_data') if isinstance(data, dict) else None
        return {str(k): str(v) for k, v in custom.items()} if isinstance(custom, dict) else None
    except Exception:  # noqa: BLE001 - custom data is a nicety; a damaged record is ignored
        return None


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
            overwrite: bool = False) -> int:
    """Copy everything readable from ``src`` into a new, finished MCAP ``dst``.

    Schemas, channels (with their metadata), messages (times and sequence numbers unchanged)
    and metadata records are copied; the ``rosbag2`` metadata record is regenerated for what was
    recovered (``custom_data`` is kept). Returns the number of messages recovered. Raises
    :class:`RecordingReadError` if ``src`` is not an MCAP file and
    :class:`~cvt_ros.recording.RecordingError` if ``dst`` cannot be written.
    """
    from .writer import BagWriter

    src, dst = os.fspath(src), os.fspath(dst)
    if os.path.abspath(src) == os.path.abspath(dst):
        raise ValueError('recover() needs a destination different from the source')
    scan = _Scan(src)
    writer: BagWriter | None = None
    channel_topics: dict[int, str] = {}
    count = 0
    try:
        for kind, record in scan.records():
            if writer is None:
                if scan.header is None:
                    break
                writer = BagWriter(dst, overwrite=overwrite, flush_interval=None,
                                   library=scan.header.library or 'cvt_ros')
            if kind == 'channel':
                schema = scan.schemas.get(record.schema_id)
                writer._add_channel(
                    record.topic, schema.name if schema else '',
                    schema.encoding if schema else '', bytes(schema.data) if schema else b'',
                    record.message_encoding, record.metadata)
                channel_topics[record.id] = record.topic
            elif kind == 'message':
                channel_id, _, log_time, publish_time, data = record
                topic = channel_topics.get(channel_id)
                if topic is not None:
                    writer._write_raw(topic, data, log_time, publish_time)
                    count += 1
            elif kind == 'metadata':
                if record.name == 'rosbag2':
                    custom = _custom_data(record.metadata.get('serialized_metadata', ''))
                    if custom:
                        writer._custom_data = custom
                else:
                    writer._add_metadata_raw(record.name, record.metadata)
        if writer is None and scan.header is not None:
            writer = BagWriter(dst, overwrite=overwrite, flush_interval=None,
                               library=scan.header.library or 'cvt_ros')
        if writer is None:
            raise RecordingReadError(scan.path, scan.problems or ['no MCAP header'],
                                     scan.problem_offset)
        writer.finish()
    finally:
        scan.close()
        if writer is not None and not writer.closed:
            writer.finish()
    return count
