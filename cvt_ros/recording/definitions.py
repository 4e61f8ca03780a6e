"""Message definitions (MCAP schemas) and type hashes, exactly as rosbag2 (Jazzy) records them.

rosbag2's ``LocalMessageDefinitionSource`` stores, per message type, the type's ``.msg`` file
verbatim followed by every dependency's ``.msg`` (depth-first, each once), each introduced by::

    "\\n" + "=" * 80 + "\\n" + "MSG: pkg/Type\\n"

Dependencies are found with rosbag2's own regular expression over the text and visited in sorted
order (rosbag2 keeps them in a ``std::set``), so the schema bytes match ``ros2 bag record``'s.
Primitive types (including bounded ``string<=N`` and ``wstring``) have no definition; arrays
(``T[]``, ``T[N]``, ``T[<=N]``), constants and default values need no special handling because
only the leading type token of each line matters. A bare ``Header`` (ROS 1 shorthand) resolves to
``std_msgs/Header`` when the package has no ``Header`` of its own.

The type hash (``RIHS01_<sha256 hex>``, rosbag2's ``topic_type_hash``) comes from the
``share/<pkg>/msg/<Type>.json`` file that rosidl installs next to the ``.msg``.

Files are found with ``ament_index_python`` (``AMENT_PREFIX_PATH``); nothing here imports rclpy.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from functools import lru_cache

from .errors import MessageDefinitionError

__all__ = [
    'MessageDefinition',
    'get_message_definition',
    'message_class',
    'message_definition_text',
    'normalize_type_name',
    'type_description_hash',
    'type_name_of',
]

#: Schema encoding rosbag2 uses for ``.msg`` based definitions.
SCHEMA_ENCODING = 'ros2msg'

# rosbag2_cpp local_message_definition_source.cpp: MSG_FIELD_TYPE_REGEX and PRIMITIVE_TYPES.
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16', 'int32',
    'uint32', 'int64', 'uint64', 'string',
    'wstring',  # not in rosbag2's list (it would fall back to IDL); a primitive in rosidl.
})
_NAME = r'[a-zA-Z][a-zA-Z0-9_]*'
_TYPE_2 = re.compile(rf'({_NAME})/({_NAME})')
_TYPE_3 = re.compile(rf'({_NAME})/({_NAME})/({_NAME})')
_DELIMITER = '=' * 80 + '\n'
_MAX_DEPTH = 50  # guards against cyclic definitions (rosbag2 has the same kind of limit)


@dataclass(frozen=True)
class MessageDefinition:
    """What a rosbag2 MCAP stores about a message type.

    ``type_name`` is the full name (``sensor_msgs/msg/JointState``), ``encoding`` the schema
    encoding (``ros2msg``), ``text`` the concatenated definition and ``type_hash`` the
    ``RIHS01_...`` hash ('' when the package installed no ``.json``).
    """

    type_name: str
    encoding: str
    text: str
    type_hash: str


def _split(type_name: str) -> tuple[str, str, str]:
    if not isinstance(type_name, str):
        raise MessageDefinitionError(f'message type name must be a str, got {type_name!r}')
    match = _TYPE_3.fullmatch(type_name)
    if match:
        return match.group(1), match.group(2), match.group(3)
    match = _TYPE_2.fullmatch(type_name)
    if match:
        return match.group(1), 'msg', match.group(2)
    raise MessageDefinitionError(
        f'invalid message type name {type_name!r}; expected "pkg/msg/Type" or "pkg/Type"')


def normalize_type_name(type_name: str) -> str:
    """``'std_msgs/Bool'`` or ``'std_msgs/msg/Bool'`` -> ``'std_msgs/msg/Bool'``."""
    pkg, ns, name = _split(type_name)
    if ns != 'msg':
        raise MessageDefinitionError(
            f'{type_name!r} is not a message type (only "msg" interfaces can be recorded)')
    return f'{pkg}/{ns}/{name}'


def type_name_of(message_or_class: object) -> str:
    """Full type name of an rclpy message instance or class (``'sensor_msgs/msg/JointState'``)."""
    cls = message_or_class if isinstance(message_or_class, type) else type(message_or_class)
    module = getattr(cls, '__module__', '') or ''
    parts = module.split('.')
    if len(parts) < 2 or parts[1] != 'msg' or not hasattr(cls, '_TYPE_SUPPORT'):
        raise MessageDefinitionError(f'{cls!r} is not a generated ROS 2 message class')
    return f'{parts[0]}/msg/{cls.__name__}'


@lru_cache(maxsize=256)
def message_class(type_name: str) -> type:
    """The installed rclpy class of message type ``type_name`` (``pkg/msg/Type`` or
    ``pkg/Type``). A name read from a recording is looked up in the ament index first, so a
    hostile name never imports an arbitrary module. Raises :class:`MessageDefinitionError`."""
    import importlib

    pkg, _, name = _split(normalize_type_name(type_name))
    if _read_interface_file(pkg, 'msg', name, '.msg') is None:
        raise MessageDefinitionError(f'message type {type_name!r} is not installed (no '
                                     f'{pkg}/msg/{name}.msg in the ament index)')
    try:
        cls = getattr(importlib.import_module(f'{pkg}.msg'), name)
    except (ImportError, AttributeError) as exc:
        raise MessageDefinitionError(
            f'message type {type_name!r} is not available in this Python environment') from exc
    if not isinstance(cls, type) or not hasattr(cls, '_TYPE_SUPPORT'):
        raise MessageDefinitionError(f'{type_name!r} is not a generated ROS 2 message class')
    return cls


def _share_dir(pkg: str, wanted: str) -> str:
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
    except ImportError as exc:  # pragma: no cover - ament_index_python ships with rclpy
        raise MessageDefinitionError(
            f'cannot look up {wanted}: ament_index_python is not installed') from exc
    try:
        return get_package_share_directory(pkg)
    except (PackageNotFoundError, LookupError, ValueError) as exc:
        prefix = os.environ.get('AMENT_PREFIX_PATH', '')
        raise MessageDefinitionError(
            f'cannot find {wanted}: package {pkg!r} is not in the ament index '
            f'(AMENT_PREFIX_PATH={prefix!r})') from exc


def _read_interface_file(pkg: str, ns: str, name: str, ext: str) -> str | None:
    path = os.path.join(_share_dir(pkg, f'{pkg}/{ns}/{name}'), ns, name + ext)
    try:
        with open(path, 'rb') as f:  # binary: keep the text byte-exact (no newline translation)
            return f.read().decode('utf-8')
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as exc:
        raise MessageDefinitionError(f'cannot read {path}: {exc}') from exc


def _dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for match in _FIELD_TYPE.finditer(text):
        token = match.group(1)
        if token in _PRIMITIVES:
            continue
        if token == 'Header' and _read_interface_file(package, 'msg', 'Header', '.msg') is None:
            token = 'std_msgs/Header'  # ROS 1 style shorthand
        deps.add(token if '/' in token else f'{package}/{token}')
    return sorted(deps)


def _load_msg(ident: str) -> tuple[str, str]:
    """Return (package, text) of a type like 'pkg/Type' or 'pkg/msg/Type'."""
    pkg, ns, name = _split(ident)
    text = _read_interface_file(pkg, ns, name, '.msg')
    if text is None:
        raise MessageDefinitionError(f'no .msg definition found for {ident!r}')
    return pkg, text


@lru_cache(maxsize=256)
def _full_text(type_name: str, _prefix_path: str) -> str:
    seen: set[str] = set()

    def append(ident: str, depth: int) -> str:
        if depth <= 0:
            raise MessageDefinitionError(
                f'definition of {type_name!r} nests deeper than {_MAX_DEPTH} levels')
        pkg, text = _load_msg(ident)
        result = text
        for dep in _dependencies(text, pkg):
            if dep not in seen:
                seen.add(dep)
                result += '\n' + _DELIMITER + f'MSG: {dep}\n' + append(dep, depth - 1)
        return result

    return append(type_name, _MAX_DEPTH)


def message_definition_text(type_name: str) -> str:
    """The ``ros2msg`` schema text rosbag2 stores for ``type_name``.

    Raises :class:`MessageDefinitionError` if the type or one of its dependencies has no
    ``.msg`` file in the ament index.
    """
    full = normalize_type_name(type_name)
    return _full_text(full, os.environ.get('AMENT_PREFIX_PATH', ''))


@lru_cache(maxsize=256)
def _hash(type_name: str, _prefix_path: str) -> str | None:
    pkg, ns, name = _split(type_name)
    raw = _read_interface_file(pkg, ns, name, '.json')
    if raw is None:
        return None
    try:
        entries = json.loads(raw)['type_hashes']
        for entry in entries:
            if entry['type_name'] == type_name:
                return str(entry['hash_string'])
    except (ValueError, KeyError, TypeError) as exc:
        raise MessageDefinitionError(
            f'malformed type description file for {type_name!r}: {exc!r}') from exc
    raise MessageDefinitionError(f'type description file of {type_name!r} lists no hash for it')


def type_description_hash(type_name: str) -> str:
    """``RIHS01_<hex>`` hash of ``type_name`` (from ``share/<pkg>/msg/<Type>.json``).

    Raises :class:`MessageDefinitionError` if the ``.json`` file is missing or malformed.
    """
    full = normalize_type_name(type_name)
    value = _hash(full, os.environ.get('AMENT_PREFIX_PATH', ''))
    if value is None:
        raise MessageDefinitionError(f'no type description (.json) installed for {full!r}')
    return value


def get_message_definition(type_name: str) -> MessageDefinition:
    """Schema text and type hash of ``type_name``; the hash is '' if no ``.json`` is installed."""
    full = normalize_type_name(type_name)
    prefix = os.environ.get('AMENT_PREFIX_PATH', '')
    text = _full_text(full, prefix)
    return MessageDefinition(full, SCHEMA_ENCODING, text, _hash(full, prefix) or '')
