"""Tolerant reading and recovery of rosbag2 MCAP recordings.

:func:`read_messages` walks the file record by record (never trusting the summary), so a file
cut short by a crash, or with a damaged chunk, still yields every message in the intact part.
Damage is reported after the readable messages as :class:`RecordingReadError` (or, with
``strict=False``, a :class:`RecordingReadWarning`); mcap/struct exceptions never escape.
A chunk whose CRC does not match is skipped and reading continues with the next record as long
as the record framing is intact.

:func:`summary` uses the file's summary section when it is intact (fast, like ``ros2 bag
info``) and falls back to a scan. :func:`~cvt_ros.recording.recover.recover` rewrites the
readable part into a finished file.

Only messages that were recorded get through. A first pass over the record headers learns the
file's structure; then each message is checked against its context: a CRC-verified chunk vouches
for its messages; in a file whose messages live in chunks, a Message record outside them is
damage (a MessageIndex or other record whose opcode a bit flip turned into Message's), and so is
a chunk without a CRC among chunks that carry one; a message no CRC vouches for must lie in its
chunk's time range and be a CDR message of its channel's schema (:mod:`.cdr_check`). Channels
lost with a damaged chunk come from the summary section when its CRC checks out. Chunks are
inflated to at most their declared size (≤ :data:`MAX_CHUNK_BYTES`), so a hostile file costs
no more memory than that. Everything skipped is reported.
"""

from __future__ import annotations

import io
import os
import struct
import warnings
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from .errors import MessageDefinitionError, RecordingReadError, RecordingReadWarning

__all__ = ['MAX_CHUNK_BYTES', 'BagMessage', 'BagSummary', 'TopicSummary', 'read_messages',
           'summary']

_MAGIC = b'\x89MCAP0\r\n'
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_STATISTICS, _OP_METADATA, _OP_DATA_END = 0x0B, 0x0C, 0x0F
_OP_NAMES = {1: 'Header', 2: 'Footer', 3: 'Schema', 4: 'Channel', 5: 'Message', 6: 'Chunk',
             7: 'MessageIndex', 8: 'ChunkIndex', 9: 'Attachment', 10: 'AttachmentIndex',
             11: 'Statistics', 12: 'Metadata', 13: 'MetadataIndex', 14: 'SummaryOffset',
             15: 'DataEnd'}
_MSG_HEAD = struct.Struct('<HIQQ')
_REC_HEAD = struct.Struct('<BQ')


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

        from .definitions import message_class

        return deserialize_message(self.data, message_class(self.type_name))


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
    wrong otherwise (empty for a good file). ``metadata``: the last record of each name;
    ``metadata_records``: every metadata record as (name, map), in file order (a name may
    repeat: one ``cvt_ros.parameter_change`` per live change).
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
    metadata_records: tuple[tuple[str, dict[str, str]], ...] = ()

    @property
    def duration_ns(self) -> int:
        """End minus start log time (0 for an empty recording)."""
        if self.start_time_ns is None or self.end_time_ns is None:
            return 0
        return self.end_time_ns - self.start_time_ns


#: A chunk may declare at most this many uncompressed bytes (ours hold 64 KiB, rosbag2's
#: ~1 MiB): a hostile size would otherwise be allocated, or a small compressed chunk inflated.
MAX_CHUNK_BYTES = 256 << 20
#: Problems kept word for word; more are counted.
MAX_PROBLEMS = 50
_CHUNK_HEAD = struct.Struct('<QQQI')       # message start/end time, uncompressed size, CRC
_FOOTER = struct.Struct('<BQQQI')          # opcode, length, summary start, offsets start, CRC


@dataclass
class _Structure:
    """What a first, header-only pass over the file tells about the records before any is
    trusted: whether messages live in chunks and whether chunks carry CRCs (then a message
    outside a chunk, or a chunk without a CRC, can only be damage), and the schemas and
    channels of a summary section whose CRC checks out (context for chunks whose own
    definitions were lost)."""

    chunks: int = 0
    chunks_with_crc: int = 0
    summary_schemas: dict[int, Any] = field(default_factory=dict)
    summary_channels: dict[int, Any] = field(default_factory=dict)


def _structure(f: Any, size: int) -> _Structure:
    out = _Structure()
    pos = 8
    summary_at = None      # where the walk found the summary section (after DataEnd)
    f.seek(pos)
    while pos + 9 <= size:
        head = f.read(9)
        if len(head) < 9:
            break
        op, length = _REC_HEAD.unpack(head)
        if op == 0 or 0x10 <= op < 0x80 or length > size - pos - 9:
            break
        if op == _OP_CHUNK and length >= _CHUNK_HEAD.size and summary_at is None:
            out.chunks += 1
            out.chunks_with_crc += _CHUNK_HEAD.unpack(f.read(_CHUNK_HEAD.size))[3] != 0
        elif op == _OP_DATA_END:
            summary_at = pos + 9 + length
        elif op == _OP_FOOTER:
            break
        pos += 9 + length
        f.seek(pos)
    _summary_context(f, size, out, summary_at)
    return out


def _summary_context(f: Any, size: int, out: _Structure, summary_at: int | None) -> None:
    """Schemas and channels of the summary section, if its CRC (in the footer) checks out.
    The section is where the walk found it (bytes inserted or cut before it move it, they do
    not change it), else where the footer says."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Schema

    if size < 8 + _FOOTER.size + 8:
        return
    footer_at = size - 8 - _FOOTER.size
    f.seek(footer_at)
    tail = f.read(_FOOTER.size + 8)
    if tail[-8:] != _MAGIC:
        return
    op, length, start, _, crc = _FOOTER.unpack(tail[:_FOOTER.size])
    if op != _OP_FOOTER or crc == 0:
        return
    for begin in dict.fromkeys((summary_at, start)):
        if begin is None or not 8 < begin <= footer_at:
            continue
        f.seek(begin)
        covered = f.read(footer_at + 1 + 8 + 8 + 8 - begin)
        if zlib.crc32(covered) == crc:
            break
    else:
        return
    i, end = 0, footer_at - begin
    while i + 9 <= end:
        rop, rlen = _REC_HEAD.unpack_from(covered, i)
        body = covered[i + 9:i + 9 + rlen]
        i += 9 + rlen
        try:
            if rop == _OP_SCHEMA:
                schema = Schema.read(ReadDataStream(io.BytesIO(body)))
                out.summary_schemas[schema.id] = schema
            elif rop == _OP_CHANNEL:
                channel = Channel.read(ReadDataStream(io.BytesIO(body)))
                out.summary_channels[channel.id] = channel
        except Exception:  # noqa: BLE001 - a summary that does not parse gives no context
            return


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """A chunk's records, inflated to at most ``size`` bytes (ValueError otherwise)."""
    if size > MAX_CHUNK_BYTES:
        raise ValueError(f'chunk declares {size} uncompressed bytes (more than '
                         f'{MAX_CHUNK_BYTES >> 20} MiB)')
    if compression == '':
        out = data
    elif compression == 'zstd':
        import zstandard

        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data))
        out = reader.read(size + 1)
    elif compression == 'lz4':
        import lz4.frame

        out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
    else:
        raise ValueError(f'unknown chunk compression {compression[:20]!r}')
    if len(out) != size:
        raise ValueError(f'chunk holds {len(out)} bytes, {size} declared')
    return bytes(out)


class _Scan:
    """Record-by-record walk of an MCAP file that notes problems instead of raising, and lets
    through only messages that check out (:meth:`records`)."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = os.fspath(path)
        try:
            self._file = open(self.path, 'rb')
            self.size = os.fstat(self._file.fileno()).st_size
        except OSError as exc:
            raise RecordingReadError(self.path, [f'cannot open: {exc.strerror or exc}']) from exc
        self.problems: list[str] = []
        self.more_problems = 0
        self.problem_offset: int | None = None
        self.header: Any = None
        self.schemas: dict[int, Any] = {}
        self.channels: dict[int, Any] = {}
        self.metadata: list[Any] = []
        self.statistics: Any = None
        self.complete = False
        self.reached_data_end = False
        self.skipped = 0                   # message records that did not check out
        self._shapes: dict[int, Any] = {}
        self._unknown_channels: set[int] = set()
        try:
            self.structure = _structure(self._file, self.size) if self.size >= 8 \
                else _Structure()
            self._file.seek(0)
        except OSError as exc:
            self._file.close()
            raise RecordingReadError(self.path, [f'cannot read: {exc.strerror or exc}']) from exc

    def close(self) -> None:
        self._file.close()

    def _problem(self, offset: int, text: str) -> None:
        if self.problem_offset is None and offset >= 0:
            self.problem_offset = offset
        if len(self.problems) < MAX_PROBLEMS:
            self.problems.append(text)
        else:
            self.more_problems += 1

    def _skip(self, offset: int, text: str) -> None:
        self.skipped += 1
        self._problem(offset, text)

    # ------------------------------------------------------------------ context checks
    def channel(self, channel_id: int) -> Any:
        """The channel of an id: from the file, or from the intact summary; None if unknown."""
        channel = self.channels.get(channel_id)
        if channel is None:
            channel = self.structure.summary_channels.get(channel_id)
            if channel is not None:
                self.channels[channel_id] = channel
                schema = self.structure.summary_schemas.get(channel.schema_id)
                if schema is not None and channel.schema_id not in self.schemas:
                    self.schemas[channel.schema_id] = schema
        return channel

    def _shape(self, channel: Any) -> Any:
        from .cdr_check import message_shape

        if channel.id not in self._shapes:
            schema = self.schemas.get(channel.schema_id)
            shape = None
            if schema is not None and schema.encoding == 'ros2msg':
                try:
                    shape = message_shape(schema.name, bytes(schema.data).decode('utf-8'))
                except UnicodeDecodeError:
                    shape = None
            self._shapes[channel.id] = shape
        return self._shapes[channel.id]

    def _unverified_ok(self, record: tuple, offset: int, where: str,
                       times: tuple[int, int] | None = None) -> bool:
        """A message no CRC vouches for: its channel must be known, its log time inside its
        chunk's range, its bytes a message of the channel's type (:mod:`.cdr_check`)."""
        from .cdr_check import cdr_matches

        channel_id, _, log_time, _, data = record
        channel = self.channel(channel_id)
        if channel is None:
            return True  # reported once as an unknown channel by the reader
        if times is not None and not times[0] <= log_time <= times[1]:
            self._skip(offset, f'a message {where} whose log time is outside its chunk\'s '
                               'time range skipped (damaged)')
            return False
        if channel.message_encoding == 'cdr' and not cdr_matches(data, self._shape(channel)):
            self._skip(offset, f'a record {where} that is no {_schema_name(self, channel) or "CDR"}'
                               f' message of {channel.topic[:80]} skipped (damaged)')
            return False
        return True

    # ------------------------------------------------------------------ walk
    def records(self) -> Iterator[tuple[str, Any]]:
        """Yield ('schema'|'channel'|'metadata', record) and ('message', tuple) in file order;
        messages only if they check out against their context."""
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
        chunked = self.structure.chunks > 0
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
                    record = self._message(body)
                    if chunked:
                        self._skip(start, 'a Message record outside the chunks of a chunked '
                                          'file skipped (a damaged record, not a recorded '
                                          'message)')
                    elif self._unverified_ok(record, start, 'outside any chunk'):
                        yield 'message', record
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
                              f'{str(exc)[:200]})')

    @staticmethod
    def _message(body: bytes | memoryview) -> tuple[int, int, int, int, bytes]:
        if len(body) < _MSG_HEAD.size:
            raise ValueError('message record too short')
        channel_id, sequence, log_time, publish_time = _MSG_HEAD.unpack_from(body, 0)
        return channel_id, sequence, log_time, publish_time, bytes(body[_MSG_HEAD.size:])

    def _chunk(self, body: bytes, start: int, stream: Any, schema_cls: Any,
               channel_cls: Any) -> Iterator[tuple[str, Any]]:
        from mcap.records import Chunk

        chunk = Chunk.read(stream(body))
        data = _decompress(chunk.compression, bytes(chunk.data), chunk.uncompressed_size)
        if chunk.uncompressed_crc:
            if zlib.crc32(data) != chunk.uncompressed_crc:
                self._problem(start, 'chunk CRC mismatch: damaged chunk skipped')
                return
            verified = True
        elif self.structure.chunks_with_crc:
            self._problem(start, 'a chunk without a CRC in a file whose chunks carry CRCs '
                                 'skipped (damaged: it cannot be verified)')
            return
        else:
            verified = False
        times = (chunk.message_start_time, chunk.message_end_time)
        view = memoryview(data)
        i, n = 0, len(data)
        records: list[tuple[str, Any]] = []
        while i < n:  # the whole chunk parses before any of it is used
            if n - i < 9:
                raise ValueError('chunk ends inside a record header')
            op, length = _REC_HEAD.unpack_from(view, i)
            i += 9
            if length > n - i:
                raise ValueError('chunk record overruns the chunk')
            rec = view[i:i + length]
            i += length
            if op == _OP_MESSAGE:
                records.append(('message', self._message(rec)))
            elif op == _OP_SCHEMA:
                records.append(('schema', schema_cls.read(stream(bytes(rec)))))
            elif op == _OP_CHANNEL:
                records.append(('channel', channel_cls.read(stream(bytes(rec)))))
        for kind, record in records:
            if kind == 'schema':
                self.schemas[record.id] = record
            elif kind == 'channel':
                self.channels[record.id] = record
            elif not verified and not self._unverified_ok(record, start, 'in a chunk without '
                                                          'a CRC', times):
                continue
            yield kind, record

    def messages(self) -> Iterator[tuple[str, Any, tuple[int, int, int, int, bytes]]]:
        """('message', channel, record) for every message that checks out and whose channel
        is known (messages on an unknown channel are reported once per channel and skipped),
        and (kind, record, ()) for the schema, channel and metadata records, in file order."""
        for kind, record in self.records():
            if kind != 'message':
                yield kind, record, ()
                continue
            channel = self.channel(record[0])
            if channel is None:
                self.skipped += 1
                if record[0] not in self._unknown_channels:
                    self._unknown_channels.add(record[0])
                    self._problem(-1, f'messages on unknown channel {record[0]} skipped')
                continue
            yield kind, channel, record

    def error(self, messages_read: int) -> RecordingReadError | None:
        """The problems found as one error (None for a good file)."""
        if not self.problems:
            return None
        problems = self.problems + ([f'{self.more_problems} more problem(s)']
                                    if self.more_problems else [])
        return RecordingReadError(self.path, problems, self.problem_offset, messages_read)


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
    try:
        for kind, channel, record in scan.messages():
            if kind != 'message' or (wanted is not None and channel.topic not in wanted):
                continue
            _, sequence, log_time, publish_time, data = record
            count += 1
            yield BagMessage(channel.topic, _schema_name(scan, channel), log_time, publish_time,
                             data, sequence, channel.message_encoding)
    finally:
        scan.close()
    error = scan.error(count)
    if error is not None:
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
        records = tuple((m.name, dict(m.metadata)) for m in reader.iter_metadata())
    empty = stats.message_count == 0
    return BagSummary(path, header.profile, header.library, stats.message_count,
                      None if empty else stats.message_start_time,
                      None if empty else stats.message_end_time, topics, dict(records), True,
                      metadata_records=records)


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
        for kind, channel, record in scan.messages():
            if kind == 'message':
                log_time = record[2]
                counts[channel.id] = counts.get(channel.id, 0) + 1
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
    records = tuple((m.name, dict(m.metadata)) for m in scan.metadata)
    error = scan.error(sum(counts.values()))
    return BagSummary(scan.path, scan.header.profile, scan.header.library, sum(counts.values()),
                      start, end, topics, dict(records), scan.complete and not scan.problems,
                      tuple(error.problems) if error is not None else (),
                      metadata_records=records)
