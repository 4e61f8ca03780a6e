"""YAML input files (scenes, scenarios, campaigns), read so that a bad file is one clear error.

A file a person wrote is small, UTF-8 and shallow. Anything else is refused with a message that
names the file and the problem, before it can cost memory or time: a file larger than
``MAX_BYTES``, not a regular file (a directory, a FIFO, /dev/zero), bytes that are not UTF-8,
nesting deeper than ``MAX_DEPTH`` (PyYAML's composer recurses: 3000 levels end in a
RecursionError), and anchors/aliases (a "billion laughs" alias bomb expands to gigabytes once
walked; a parameter file has no use for them).
"""
import os
import stat
from pathlib import Path

import yaml

MAX_BYTES = 1 << 20     # 1 MiB: the largest shipped scene is < 2 KiB
MAX_DEPTH = 32          # maps/lists inside each other


class InputFileError(ValueError):
    """An input file that cannot be used; the message names the file and the reason."""


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader without aliases and with a nesting limit."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(
                None, None, f"alias *{event.anchor} is not allowed in an input file (write the "
                            f"value out)", event.start_mark)
        self._depth = getattr(self, '_depth', 0) + 1
        try:
            if self._depth > MAX_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"nested deeper than {MAX_DEPTH} levels",
                    self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def read_text(path, error=InputFileError, limit=MAX_BYTES, kind='a YAML file'):
    """The text of a UTF-8 regular file of at most ``limit`` bytes, or ``error`` (a subclass of
    InputFileError, or any exception class taking a message). A FIFO, a device (/dev/zero) or a
    directory is refused before it is opened: no read that blocks or never ends."""
    path = Path(path)
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{_shown(path)}: not a regular file")
        if info.st_size > limit:
            raise error(f"{_shown(path)}: {info.st_size} bytes, larger than an input file may be "
                        f"({limit} bytes)")
        with open(path, 'rb') as f:
            data = f.read(limit + 1)
    except (OSError, ValueError) as exc:   # (ValueError: a NUL byte in the name)
        if isinstance(exc, error):
            raise
        raise error(f"{_shown(path)}: cannot read: {getattr(exc, 'strerror', None) or exc}"
                    ) from None
    if len(data) > limit:
        raise error(f"{_shown(path)}: larger than an input file may be ({limit} bytes)")
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise error(f"{_shown(path)}: not UTF-8 text (byte {exc.start}: "
                    f"{data[exc.start:exc.start + 1]!r}); is it {kind}?") from None


def read_yaml(path, error=InputFileError):
    """The document of a YAML input file (plain maps, lists, scalars), or ``error``."""
    text = read_text(path, error)
    try:
        return yaml.load(text, Loader=_StrictLoader)   # noqa: S506 — a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None


def numbers_in(node, text_keys=()):
    """``node`` with its number-like texts as floats: YAML 1.1 (PyYAML) reads 1e-3 and 1.0e5 (no
    sign, or no dot) as text, ROS's parser and a person as numbers. Values under ``text_keys``
    (names, paths, descriptions) stay as they are."""
    if isinstance(node, dict):
        return {k: v if k in text_keys else numbers_in(v, text_keys) for k, v in node.items()}
    if isinstance(node, list):
        return [numbers_in(v, text_keys) for v in node]
    if isinstance(node, str):
        try:
            value = float(node)
        except ValueError:
            return node
        if value == value:   # (not 'nan': text stays text)
            return value
    return node


def parse_value(text):
    """A value given on a command line, read as YAML (``.inf``, ``1e-3``, ``constant_torque``);
    text that is not a YAML scalar or a small collection stays text."""
    try:
        return yaml.load(text, Loader=_StrictLoader) if text.strip() else ''  # noqa: S506
    except yaml.YAMLError:
        return text


def _shown(path, limit=120):
    """A path for a message: a 4 KiB file name is cut, not printed whole."""
    text = os.fspath(path)
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters)"


def is_file(path):
    """Path.is_file() that answers False for names the OS refuses (too long, NUL bytes)."""
    try:
        return Path(path).is_file()
    except (OSError, ValueError):
        return False


__all__ = ['InputFileError', 'MAX_BYTES', 'MAX_DEPTH', 'is_file', 'numbers_in', 'parse_value',
           'read_text', 'read_yaml']
