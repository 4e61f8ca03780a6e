"""Output files of a command, written completely or not at all, and never onto an input.

:class:`OutputFiles` checks every target before the work starts (:meth:`~OutputFiles.check`: not
an input of the command, not a directory, its directory exists and is writable, no two outputs
on one file), then hands out temporary files next to the targets (:meth:`~OutputFiles.open`,
:meth:`~OutputFiles.temp_path`). :meth:`~OutputFiles.commit` renames them all into place;
an error (disk full, quota, I/O) or an exception discards them all, so a failed command leaves
no partial file behind and an existing file is never half overwritten. Special files (a
character device such as ``/dev/full`` or ``/dev/null``, a FIFO, ``/dev/stdout``) are written
directly: they cannot be renamed onto.

Every problem is an :class:`~cvt_ros.recording.errors.OutputError` whose text names the path
and the reason.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from collections.abc import Callable, Iterable
from typing import IO, Any, TypeVar

from .errors import OutputError

__all__ = ['OutputFiles', 'same_file']

_T = TypeVar('_T')


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """True when ``a`` and ``b`` name the same existing file (links included) or the same
    path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _special(path: str) -> bool:
    """An existing file that is not a regular file or directory (device, FIFO, socket)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _new_file_mode(target: str) -> int:
    """The mode a file created by ``open`` would get (an existing target keeps its own)."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _reason(exc: OSError) -> str:
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return f'{exc.strerror} (disk full or file too large)'
    return exc.strerror or str(exc)


def _probe(folder: str, path: str) -> None:
    """Create and remove a file in ``folder``: what os.access cannot tell (root on a read-only
    or virtual file system such as /proc) shows before the work, not after it."""
    try:
        fd, temp = tempfile.mkstemp(prefix='.cvt-probe-', dir=folder)
    except OSError as exc:
        raise OutputError(f'{path}: cannot write in {folder}: {_reason(exc)}') from None
    os.close(fd)
    os.unlink(temp)


class OutputFiles:
    """The output files of one command. ``inputs``: files the command reads (never written).

    Use as a context manager: leaving it normally commits, an exception discards::

        with OutputFiles(inputs=[recording]) as out:
            out.check(csv_path)              # before the work: refuse a bad target early
            ...
            with out.open(csv_path, 'w') as f:
                f.write(...)
    """

    def __init__(self, inputs: Iterable[str | os.PathLike[str]] = ()):
        self.inputs = [os.fspath(p) for p in inputs]
        self._targets: list[str] = []
        self._pending: list[tuple[str, str]] = []       # (temporary, target)
        self._created_dirs: list[str] = []
        self._direct: set[str] = set()

    # ------------------------------------------------------------------ checks
    def check(self, path: str | os.PathLike[str], *, directory: bool = False,
              overwrite: bool = True, suffixes: Iterable[str] = ()) -> str:
        """Refuse ``path`` now if it cannot become an output; returns it as a str.
        ``overwrite`` False: an existing file is refused (the user's, until --overwrite says
        otherwise); ``suffixes``: the file's format follows its suffix, one of these."""
        path = os.fspath(path)
        what = 'directory' if directory else 'file'
        if not path:
            raise OutputError(f'empty output {what} name')
        if '\0' in path:
            raise OutputError(f'{path!r}: a file name cannot hold a NUL byte')
        suffixes = tuple(suffixes)
        if suffixes and not directory and not path.lower().endswith(suffixes):
            if os.path.isdir(path):
                raise OutputError(f'{path}: is a directory; name a file in it, e.g. '
                                  f'{os.path.join(path, "run" + suffixes[0])}')
            raise OutputError(f'{path}: the format follows the suffix: name a '
                              f'{", ".join(suffixes)} file')
        for source in self.inputs:
            if same_file(path, source):
                raise OutputError(f'{path}: is an input of this command; refusing to write '
                                  'onto it')
        for other in self._targets:
            if same_file(path, other) and not directory:
                raise OutputError(f'{path}: named for two outputs')
        where = os.path.dirname(os.path.abspath(path))
        if directory:
            if os.path.exists(path) and not os.path.isdir(path):
                raise OutputError(f'{path}: exists and is not a directory')
        elif os.path.isdir(path):
            raise OutputError(f'{path}: is a directory, not a file')
        elif not overwrite and os.path.lexists(path) and not _special(path):
            raise OutputError(f'{path}: exists (use --overwrite to replace it)')
        if not os.path.isdir(where):
            raise OutputError(f'{path}: no such directory {where}')
        if not os.access(where, os.W_OK | os.X_OK) and not _special(path):
            raise OutputError(f'{path}: permission denied (directory {where})')
        if len(os.path.basename(path).encode()) > 255:
            raise OutputError(f'{path[:60]}…: file name longer than 255 bytes')
        if not directory and not _special(path):
            _probe(where, path)
        if not directory:
            self._targets.append(path)
        return path

    # ------------------------------------------------------------------ writing
    def temp_path(self, path: str | os.PathLike[str]) -> str:
        """A new, empty temporary file next to ``path`` that :meth:`commit` renames onto it
        (``path`` itself for a special file); for writers that want a path."""
        path = self.check(path) if os.fspath(path) not in self._targets else os.fspath(path)
        if _special(path):
            self._direct.add(path)
            return path
        folder, name = os.path.split(os.path.abspath(path))
        try:
            fd, temp = tempfile.mkstemp(prefix=f'.{name[:200]}.', suffix='.part', dir=folder)
        except OSError as exc:
            raise OutputError(f'cannot write {path}: {_reason(exc)}') from None
        try:
            os.fchmod(fd, _new_file_mode(path))  # mkstemp makes 0600 files
        finally:
            os.close(fd)
        self._pending.append((temp, path))
        return temp

    def open(self, path: str | os.PathLike[str], mode: str = 'w', **kwargs: Any) -> IO[Any]:
        """An open file for ``path`` (text modes default to UTF-8 and newline='')."""
        target = self.temp_path(path)
        if 'b' not in mode:
            kwargs.setdefault('encoding', 'utf-8')
            kwargs.setdefault('newline', '')
        try:
            return open(target, mode, **kwargs)  # noqa: SIM115 - the caller closes it
        except OSError as exc:
            raise OutputError(f'cannot write {path}: {_reason(exc)}') from None

    def write(self, path: str | os.PathLike[str], produce: Callable[[IO[Any]], _T],
              mode: str = 'w', **kwargs: Any) -> _T:
        """Open ``path`` (:meth:`open`), let ``produce(file)`` write it, flush it to the disk and
        close it; an I/O error (disk full …) becomes an :class:`OutputError`. Returns what
        ``produce`` returns."""
        f = self.open(path, mode, **kwargs)
        try:
            with f:
                result = produce(f)
                f.flush()
                if not _special(f.name):
                    os.fsync(f.fileno())
        except OSError as exc:
            raise self.error(os.fspath(path), exc) from None
        return result

    def directory(self, path: str | os.PathLike[str]) -> str:
        """Create the output directory ``path`` if missing (its parent must exist); a directory
        created here is removed again if the outputs are discarded."""
        path = self.check(path, directory=True)
        if not os.path.isdir(path):
            try:
                os.mkdir(path)
            except OSError as exc:
                raise OutputError(f'cannot create directory {path}: {_reason(exc)}') from None
            self._created_dirs.append(path)
        return path

    def error(self, path: str, exc: OSError) -> OutputError:
        """The OutputError for an OSError while writing ``path``."""
        return OutputError(f'cannot write {path}: {_reason(exc)}')

    # ------------------------------------------------------------------ end
    def commit(self) -> None:
        """Move every written file into place."""
        while self._pending:
            temp, target = self._pending[0]
            try:
                os.replace(temp, target)
            except OSError as exc:
                self.discard()
                raise OutputError(f'cannot write {target}: {_reason(exc)}') from None
            self._pending.pop(0)
        self._created_dirs = []

    def discard(self) -> None:
        """Remove every temporary file (and directory created here); targets stay untouched."""
        pending, self._pending = self._pending, []
        for temp, _ in pending:
            try:
                os.unlink(temp)
            except OSError:
                pass
        for folder in reversed(self._created_dirs):
            try:
                os.rmdir(folder)
            except OSError:
                pass
        self._created_dirs = []

    def __enter__(self) -> OutputFiles:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()
