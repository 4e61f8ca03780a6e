"""Exact CDR size of an rclpy message.

``rclpy.serialization.serialize_message`` (rmw_fastrtps, Jazzy) returns a buffer whose length is
the RMW's size *estimate*, so it usually ends with a few uninitialised bytes after the real CDR
data. DDS subscribers ignore them, but strict readers (rosbags: "CDR message size mismatch")
reject such records, and ``ros2 bag record`` never stores them (it records what arrives on the
wire). :func:`cdr_size` computes the true length so the writer can cut the tail off.

Layout rules (plain CDR / XCDR1 as used by ROS 2): 4-byte encapsulation header, then fields in
order, each primitive aligned to its size (max 8) relative to the end of the header; strings are
``uint32`` length (including the NUL) + UTF-8 bytes + NUL; sequences are a ``uint32`` count
followed by the elements (primitive elements are aligned only if there is at least one); fixed
arrays have no count; a message without fields is one ``uint8``. Types whose wire size we do not
model (``wstring``, ``wchar``, ``long double``) make :func:`cdr_size` return ``None``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ['cdr_size']

_PRIMITIVE_SIZES = {
    'boolean': 1, 'octet': 1, 'char': 1, 'uint8': 1, 'int8': 1, 'uint16': 2, 'int16': 2,
    'uint32': 4, 'int32': 4, 'float': 4, 'uint64': 8, 'int64': 8, 'double': 8,
}

_Sizer = Callable[[Any, int], int]  # (value, offset) -> offset after the value


class _Unsupported(Exception):
    pass


def _align(offset: int, size: int) -> int:
    return (offset + size - 1) & -size


def _string(value: str, offset: int) -> int:
    return _align(offset, 4) + 4 + len(value.encode('utf-8')) + 1


def _element_sizer(slot_type: Any) -> tuple[_Sizer | None, int]:
    """Sizer of one element; for primitives return (None, size) so arrays can be sized fast."""
    kind = type(slot_type).__name__
    if kind == 'BasicType':
        size = _PRIMITIVE_SIZES.get(slot_type.typename)
        if size is None:
            raise _Unsupported(slot_type.typename)
        return None, size
    if kind in ('UnboundedString', 'BoundedString'):
        return _string, 0
    if kind == 'NamespacedType':
        return _message_sizer(slot_type), 0
    raise _Unsupported(kind)


def _message_sizer(namespaced_type: Any) -> _Sizer:
    # The Python class is only needed for its SLOT_TYPES; values come from the instance.
    def sizer(value: Any, offset: int) -> int:
        return _class_sizer(type(value))(value, offset)
    return sizer


def _field_sizer(name: str, slot_type: Any) -> _Sizer:
    kind = type(slot_type).__name__
    if kind in ('UnboundedSequence', 'BoundedSequence', 'Array'):
        is_array = kind == 'Array'
        sub, prim = _element_sizer(slot_type.value_type)

        def seq(msg: Any, offset: int) -> int:
            items = getattr(msg, name)
            if not is_array:
                offset = _align(offset, 4) + 4
            count = len(items)
            if sub is None:
                return _align(offset, prim) + count * prim if count else offset
            for item in items:
                offset = sub(item, offset)
            return offset
        return seq
    sub, prim = _element_sizer(slot_type)
    if sub is None:
        return lambda msg, offset: _align(offset, prim) + prim
    return lambda msg, offset: sub(getattr(msg, name), offset)


_CLASS_SIZERS: dict[type, _Sizer | None] = {}


def _class_sizer(cls: type) -> _Sizer:
    cached = _CLASS_SIZERS.get(cls, False)
    if cached is None:
        raise _Unsupported(cls.__name__)
    if cached is not False:
        return cached  # type: ignore[return-value]
    try:
        names = list(cls.get_fields_and_field_types())
        fields = [_field_sizer(n, t) for n, t in zip(names, cls.SLOT_TYPES, strict=True)]
    except (_Unsupported, AttributeError):
        _CLASS_SIZERS[cls] = None
        raise _Unsupported(cls.__name__) from None
    if not fields:
        def sizer(msg: Any, offset: int) -> int:
            return offset + 1  # rosidl adds "uint8 structure_needs_at_least_one_member"
    else:
        def sizer(msg: Any, offset: int) -> int:
            for field in fields:
                offset = field(msg, offset)
            return offset
    _CLASS_SIZERS[cls] = sizer
    return sizer


def cdr_size(message: Any) -> int | None:
    """Serialized length of ``message`` including the 4-byte header; None if not modelled."""
    try:
        return 4 + _class_sizer(type(message))(message, 0)
    except _Unsupported:
        return None
