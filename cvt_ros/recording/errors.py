"""Typed errors of :mod:`cvt_ros.recording`.

Everything raised on purpose derives from :class:`RecordingError`, so a caller that only wants to
log and carry on (the simulation node) can catch one type.
"""

from __future__ import annotations


class RecordingError(Exception):
    """A recording could not be created or written (bad path, disk full, I/O error)."""


class MessageDefinitionError(RecordingError, LookupError):
    """A message type's definition (``.msg``) or type hash (``.json``) could not be found/read."""


class LogTimeError(RecordingError, ValueError):
    """A log time went backwards (or was negative); rosbag2 tools expect monotonic log times."""


class RecordingReadError(RecordingError):
    """A recording is truncated, corrupt or not an MCAP file.

    Raised *after* everything readable was delivered. Attributes:

    ``path``
        The file.
    ``offset``
        Byte offset of the first problem (where reading stopped being reliable).
    ``problems``
        Human-readable descriptions of every problem found, in file order.
    ``messages_read``
        Messages delivered before the error was raised.
    """

    def __init__(self, path: str, problems: list[str], offset: int | None = None,
                 messages_read: int = 0):
        self.path = str(path)
        self.problems = list(problems)
        self.offset = offset
        self.messages_read = messages_read
        first = self.problems[0] if self.problems else 'unknown problem'
        more = f' (+{len(self.problems) - 1} more)' if len(self.problems) > 1 else ''
        where = f' at byte {offset}' if offset is not None else ''
        super().__init__(f'{self.path}: {first}{where}{more}; '
                         f'{messages_read} message(s) were readable')


class OutputError(RecordingError):
    """An output file cannot be written (no such directory, a directory, an input of the
    command, disk full); the text names the path and the reason. Nothing partial is left."""


class RecordingReadWarning(UserWarning):
    """Issued instead of :class:`RecordingReadError` when reading with ``strict=False``."""


class ReplayError(RecordingError):
    """A recording cannot be replayed (not readable, unknown topics, no installed types)."""
