"""Does a byte string hold one message of a given ROS 2 type? A structural CDR check against the
``ros2msg`` definition that rosbag2 stores as the channel's schema (:mod:`.definitions`).

Used where no CRC vouches for a message (a record outside the chunks, a chunk without a CRC): a
record that is not a CDR message of its channel's type was not recorded on that channel (a
MessageIndex whose opcode a bit flip turned into Message's parses as a message with plausible
times, but its bytes are index entries, not a JointState). The walk follows the CDR rules of
:mod:`._cdr` (4-byte encapsulation header; primitives aligned to their size, at most 8, from the
end of the header; strings ``uint32`` length with the NUL, which must be there; sequences a
``uint32`` count; ``bool`` 0 or 1; a message without fields one byte) and must end within the
last 4-byte alignment of the data. Every count is checked against the bytes left before it is
used, so hostile counts cost nothing. Types the check does not model (``wstring``, IDL schemas)
pass: the check only ever refuses what cannot be right.
"""

from __future__ import annotations

import re
import struct
from functools import lru_cache

__all__ = ['MessageShape', 'cdr_matches', 'message_shape']

_SIZES = {'bool': 1, 'byte': 1, 'char': 1, 'uint8': 1, 'int8': 1, 'uint16': 2, 'int16': 2,
          'uint32': 4, 'int32': 4, 'float32': 4, 'uint64': 8, 'int64': 8, 'float64': 8}
_SECTION = re.compile(r'^={80}\n(?:MSG: )?([A-Za-z0-9_/]+)\n', re.MULTILINE)
_FIELD = re.compile(r'^\s*([A-Za-z0-9_/]+(?:<=\d+)?)(\[(<=)?(\d*)\])?\s+([A-Za-z0-9_]+)\s*(=)?')
_U32 = struct.Struct('<I')
_U32_BE = struct.Struct('>I')


class _Unmodelled(Exception):
    """A type the check does not model: the message passes."""


class MessageShape:
    """The fields of one message type: (kind, element, array) per field, kind in
    'prim' (element = size), 'bool', 'string', 'msg' (element = MessageShape), array =
    None | ('fixed', n) | ('seq', bound or None)."""

    def __init__(self, name: str):
        self.name = name
        self.fields: list[tuple[str, object, tuple[str, int | None] | None]] = []


def _short_name(name: str) -> str:
    parts = name.split('/')
    return f'{parts[0]}/{parts[-1]}' if len(parts) >= 2 else name


@lru_cache(maxsize=128)
def message_shape(type_name: str, definition: str) -> MessageShape | None:
    """The shape of ``type_name`` from a rosbag2 concatenated definition; None if the text
    is not a parseable ``ros2msg`` definition (the check then passes everything)."""
    sections = {}
    marks = list(_SECTION.finditer(definition))
    sections[_short_name(type_name)] = definition[:marks[0].start()] if marks else definition
    for i, mark in enumerate(marks):
        end = marks[i + 1].start() if i + 1 < len(marks) else len(definition)
        sections[_short_name(mark.group(1))] = definition[mark.end():end]
    shapes: dict[str, MessageShape] = {}
    try:
        return _build(_short_name(type_name), sections, shapes, set())
    except _Unmodelled:
        return None


def _build(name: str, sections: dict[str, str], shapes: dict[str, MessageShape],
           building: set[str]) -> MessageShape:
    if name in shapes:
        return shapes[name]
    if name in building or len(building) > 32 or name not in sections:
        raise _Unmodelled(name)  # a type that contains itself, too deep, or not defined
    building.add(name)
    shape = MessageShape(name)
    package = name.split('/')[0]
    for line in sections[name].splitlines():
        line = line.split('#', 1)[0]
        if not line.strip():
            continue
        match = _FIELD.match(line)
        if match is None:
            raise _Unmodelled(line)
        type_text, array, bounded, count, _, constant = match.groups()
        if constant:
            continue
        base = type_text.split('<=')[0]
        if base in _SIZES:
            kind, element = ('bool', 1) if base == 'bool' else ('prim', _SIZES[base])
        elif base == 'string':
            kind, element = 'string', None
        elif base == 'wstring':
            raise _Unmodelled(base)
        else:
            full = 'std_msgs/Header' if base == 'Header' else base
            if '/' not in full:
                full = f'{package}/{full}'
            kind, element = 'msg', _build(_short_name(full), sections, shapes, building)
        shape_array = None
        if array is not None:
            if count and not bounded:
                shape_array = ('fixed', int(count))
            else:
                shape_array = ('seq', int(count) if count else None)
        shape.fields.append((kind, element, shape_array))
    building.discard(name)
    shapes[name] = shape
    return shape


def cdr_matches(data: bytes, shape: MessageShape | None) -> bool:
    """True when ``data`` is (or may be) one CDR message of ``shape`` (None: unknown type)."""
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        return False
    if shape is None:
        return True
    walker = _Walker(data, data[1] == 1)
    try:
        walker.message(shape)
    except (_Bad, struct.error, IndexError, RecursionError):
        return False
    return len(data) - walker.pos < 4 and walker.pos <= len(data)


class _Bad(Exception):
    pass


class _Walker:
    __slots__ = ('data', 'little', 'pos', 'u32')

    def __init__(self, data: bytes, little: bool):
        self.data = data
        self.little = little
        self.pos = 4
        self.u32 = _U32 if little else _U32_BE

    def align(self, size: int) -> None:
        self.pos += (-(self.pos - 4)) % size

    def take(self, size: int) -> int:
        start = self.pos
        self.pos += size
        if self.pos > len(self.data):
            raise _Bad('past the end')
        return start

    def count(self) -> int:
        self.align(4)
        (n,) = self.u32.unpack_from(self.data, self.take(4))
        if n > len(self.data) - self.pos:  # every element takes at least one byte
            raise _Bad('count larger than the bytes left')
        return n

    def element(self, kind: str, element: object) -> None:
        if kind == 'prim':
            self.align(min(int(element), 8))
            self.take(int(element))
        elif kind == 'bool':
            if self.data[self.take(1)] > 1:
                raise _Bad('bool not 0 or 1')
        elif kind == 'string':
            n = self.count()
            if n == 0 or self.data[self.take(n) + n - 1] != 0:
                raise _Bad('string without its NUL')
        else:
            self.message(element)  # type: ignore[arg-type]

    def message(self, shape: MessageShape) -> None:
        if not shape.fields:
            self.take(1)  # rosidl's structure_needs_at_least_one_member
            return
        for kind, element, array in shape.fields:
            if array is None:
                self.element(kind, element)
                continue
            if array[0] == 'fixed':
                n = array[1]
                if kind != 'prim' and n > len(self.data) - self.pos:
                    raise _Bad('array longer than the bytes left')
            else:
                n = self.count()
                if array[1] is not None and n > array[1]:
                    raise _Bad('sequence longer than its bound')
            if kind == 'prim':
                if n:
                    self.align(min(int(element), 8))
                    self.take(n * int(element))
            else:
                for _ in range(int(n)):
                    self.element(kind, element)
