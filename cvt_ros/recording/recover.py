"""Recover a crashed (unfinished) or damaged recording into a new, finished MCAP file.

The source is read by the checking scan of :mod:`.reader`, so the output holds only messages
that were recorded (each vouched for by its chunk's CRC or checked against its chunk, channel
and schema), with their times and sequence numbers unchanged, and what was skipped is reported
(:class:`Recovery`). Schemas, channels (with their metadata) and metadata records are copied;
the ``rosbag2`` metadata record is regenerated for what was recovered (its ``custom_data`` is
kept). The output is written next to its target and renamed into place at the end
(:class:`~.outputs.OutputFiles`): a failure (disk full) leaves no partial file, and the source
is never the target.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

from .errors import OutputError, RecordingError, RecordingReadError
from .outputs import OutputFiles
from .reader import _Scan

__all__ = ['Recovery', 'recover', 'recover_file']


@dataclass
class Recovery:
    """What :func:`recover_file` did: messages copied, message records skipped because they
    did not check out, and every problem found in the source (file order)."""

    path: str
    messages: int = 0
    skipped: int = 0
    problems: list[str] = field(default_factory=list)


def _custom_data(serialized: str) -> dict[str, str] | None:
    """``custom_data`` of a rosbag2 metadata record (strict YAML: no aliases)."""
    from ..yaml_file import parse_value

    data = parse_value(serialized) if isinstance(serialized, str) else None
    custom = data.get('custom_data') if isinstance(data, dict) else None
    return {str(k): str(v) for k, v in custom.items()} if isinstance(custom, dict) else None


def recover_file(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
                 overwrite: bool = False) -> Recovery:
    """Copy every message of ``src`` that checks out into a new, finished MCAP ``dst``.

    Raises :class:`RecordingReadError` if ``src`` is not an MCAP file (no header),
    :class:`OutputError` if ``dst`` is ``src``, exists without ``overwrite`` or cannot be
    written (then nothing is left at ``dst``)."""
    from .writer import BagWriter

    src, dst = os.fspath(src), os.fspath(dst)
    outputs = OutputFiles(inputs=[src])
    outputs.check(dst)
    if os.path.lexists(dst) and not overwrite and os.path.isfile(dst):
        raise OutputError(f'{dst}: file exists (use --overwrite to replace it)')
    scan = _Scan(src)
    writer: BagWriter | None = None
    result = Recovery(dst)
    try:
        with outputs:
            for kind, record, message in scan.messages():
                if writer is None:
                    if scan.header is None:
                        break
                    writer = _open_writer(outputs, dst, scan.header)
                _copy(writer, scan, kind, record, message, result)
            if writer is None and scan.header is not None:
                writer = _open_writer(outputs, dst, scan.header)
            if writer is None:
                raise RecordingReadError(scan.path, scan.problems or ['no MCAP header'],
                                         scan.problem_offset)
            writer.finish()
            if writer.failed:
                raise OutputError(f'cannot write {dst}: {writer.error}')
    except RecordingError as exc:
        if writer is not None and not writer.closed:
            writer.finish()
        if isinstance(exc, (OutputError, RecordingReadError)):
            raise
        raise OutputError(f'cannot write {dst}: {exc}') from None
    finally:
        scan.close()
    error = scan.error(result.messages)
    result.problems = list(error.problems) if error is not None else []
    result.skipped = scan.skipped
    return result


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str], *,
            overwrite: bool = False) -> int:
    """:func:`recover_file`, returning the number of messages recovered."""
    return recover_file(src, dst, overwrite=overwrite).messages


def _open_writer(outputs: OutputFiles, dst: str, header: Any) -> Any:
    from .writer import BagWriter

    return BagWriter(outputs.temp_path(dst), overwrite=True, flush_interval=None,
                     library=str(header.library or 'cvt_ros')[:200])


def _add_channel(writer: Any, scan: _Scan, channel: Any) -> None:
    schema = scan.schemas.get(channel.schema_id)
    writer._add_channel(channel.topic, schema.name if schema else '',
                        schema.encoding if schema else '', bytes(schema.data) if schema else b'',
                        channel.message_encoding, channel.metadata)


def _copy(writer: Any, scan: _Scan, kind: str, record: Any, message: tuple,
          result: Recovery) -> None:
    if kind == 'channel':
        _add_channel(writer, scan, record)
    elif kind == 'message':
        channel = record
        if channel.topic not in writer.topics:  # a channel known from the summary only
            _add_channel(writer, scan, channel)
        _, sequence, log_time, publish_time, data = message
        writer._write_raw(channel.topic, data, log_time, publish_time, sequence)
        result.messages += 1
    elif kind == 'metadata':
        if record.name == 'rosbag2':
            custom = _custom_data(record.metadata.get('serialized_metadata', ''))
            if custom:
                writer._custom_data = custom
        else:
            writer._add_metadata_raw(record.name, record.metadata)
