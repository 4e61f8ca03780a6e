"""Minimal YAML emitter that reproduces yaml-cpp's ``YAML::Dump`` block style.

rosbag2 serialises QoS profiles and bag metadata with yaml-cpp; emitting the same layout (two-space
indents, sequences indented under their key, empty containers as ``[]``/``{}`` on the next line,
``~`` for null, ``""`` for empty strings, no trailing newline) keeps our files byte-compatible
with what ``ros2 bag record`` produces. Only the value types rosbag2 uses are supported.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence

__all__ = ['RawBlock', 'dump']


class RawBlock(str):
    """Already-rendered block YAML, embedded as a nested node (re-indented) by :func:`dump`."""


_PLAIN = re.compile(r'[A-Za-z_/][A-Za-z0-9_./\-]*(?: [A-Za-z0-9_./\-]+)*')
_RESERVED = frozenset({'true', 'false', 'yes', 'no', 'on', 'off', 'y', 'n', 'null', '~'})


def _scalar(value: object) -> str:
    if value is None:
        return '~'
    if value is True:
        return 'true'
    if value is False:
        return 'false'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    text = str(value)
    if _PLAIN.fullmatch(text) and text.lower() not in _RESERVED:
        return text
    # JSON escapes are valid in YAML double-quoted scalars.
    return json.dumps(text, ensure_ascii=False)


def _is_node(value: object) -> bool:
    return isinstance(value, (RawBlock, Mapping)) or (
        isinstance(value, Sequence) and not isinstance(value, (str, bytes)))


def _lines(value: object, indent: int) -> list[str]:
    pad = ' ' * indent
    if isinstance(value, RawBlock):
        text = str(value).strip('\n')
        if not text.strip():
            return [pad + '[]']
        return [pad + line if line else line for line in text.split('\n')]
    if isinstance(value, Mapping):
        if not value:
            return [pad + '{}']
        out = []
        for key, item in value.items():
            if _is_node(item):
                out.append(f'{pad}{_scalar(str(key))}:')
                out.extend(_lines(item, indent + 2))
            else:
                out.append(f'{pad}{_scalar(str(key))}: {_scalar(item)}')
        return out
    if _is_node(value):
        items = list(value)  # type: ignore[call-overload]
        if not items:
            return [pad + '[]']
        out = []
        for item in items:
            if _is_node(item):
                sub = _lines(item, indent + 2)
                out.append(pad + '- ' + sub[0][indent + 2:])
                out.extend(sub[1:])
            else:
                out.append(f'{pad}- {_scalar(item)}')
        return out
    return [pad + _scalar(value)]


def dump(value: object) -> str:
    """Render ``value`` (dict / list / str / int / bool / None / RawBlock) like yaml-cpp."""
    return '\n'.join(_lines(value, 0))
