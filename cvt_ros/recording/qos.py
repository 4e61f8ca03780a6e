"""QoS profiles -> rosbag2 ``offered_qos_profiles`` YAML (metadata version 9, ROS 2 Jazzy).

rosbag2 (``rosbag2_storage/src/rosbag2_storage/qos.cpp``) writes a YAML *sequence* of maps with
the keys, in order: ``history, depth, reliability, durability, deadline{sec,nsec},
lifespan{sec,nsec}, liveliness, liveliness_lease_duration{sec,nsec},
avoid_ros_namespace_conventions``. Since metadata version 9 the policies are strings
(``rmw_qos_*_policy_to_str``: ``keep_last``, ``reliable``, ``transient_local``, ``automatic``...).

``ros2 bag record`` stores what the RMW *reports* for the live publisher, so we do the same
resolution here:

* durations that are unspecified (0) or infinite become ``RMW_DURATION_INFINITE``
  (``sec: 9223372036, nsec: 854775807``), the value Fast DDS reports;
* ``system_default`` / ``best_available`` policies become the value a publisher ends up with
  (``keep_last``, ``reliable``, ``volatile`` / ``transient_local``, ``automatic``).

Input is an rclpy ``QoSProfile`` (rclpy is never imported here: attributes are read duck-typed)
or a plain dict with the same keys (missing keys take rclpy's default publisher profile: keep
last 10, reliable, volatile). Policy values may be strings (any case), rclpy enums or the rmw
integer values; durations may be integer nanoseconds, ``{'sec': s, 'nsec': ns}`` or anything with
a ``nanoseconds`` attribute (rclpy ``Duration``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from . import _yaml

__all__ = [
    'DURATION_INFINITE',
    'offered_qos_profiles_yaml',
    'qos_profile_dict',
]

#: ``RMW_DURATION_INFINITE`` as rosbag2 writes it (``{sec, nsec}``; total 2**63 - 1 ns).
DURATION_INFINITE = {'sec': 9223372036, 'nsec': 854775807}
_INFINITE_NS = 2**63 - 1
# RMW_QOS_DEADLINE_BEST_AVAILABLE etc. are INT64_MAX - 1 ns; treat anything that large as infinite.
_INFINITE_THRESHOLD_NS = 2**63 - 2

# rmw enum values (rmw/types.h, Jazzy) -> rmw_qos_*_policy_to_str() names.
_HISTORY = {0: 'system_default', 1: 'keep_last', 2: 'keep_all', 3: 'unknown'}
_RELIABILITY = {0: 'system_default', 1: 'reliable', 2: 'best_effort', 3: 'unknown',
                4: 'best_available'}
_DURABILITY = {0: 'system_default', 1: 'transient_local', 2: 'volatile', 3: 'unknown',
               4: 'best_available'}
_LIVELINESS = {0: 'system_default', 1: 'automatic', 3: 'manual_by_topic', 4: 'unknown',
               5: 'best_available'}
# What the RMW reports for a publisher created with system_default / best_available.
_RESOLVED = {
    'history': {'system_default': 'keep_last'},
    'reliability': {'system_default': 'reliable', 'best_available': 'reliable'},
    'durability': {'system_default': 'volatile', 'best_available': 'transient_local'},
    'liveliness': {'system_default': 'automatic', 'best_available': 'automatic'},
}
_DEFAULTS: dict[str, Any] = {
    'history': 'keep_last', 'depth': 10, 'reliability': 'reliable', 'durability': 'volatile',
    'deadline': 0, 'lifespan': 0, 'liveliness': 'system_default', 'liveliness_lease_duration': 0,
    'avoid_ros_namespace_conventions': False,
}
_POLICIES = {'history': _HISTORY, 'reliability': _RELIABILITY, 'durability': _DURABILITY,
             'liveliness': _LIVELINESS}
_KEYS = ('history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan', 'liveliness',
         'liveliness_lease_duration', 'avoid_ros_namespace_conventions')


def _policy(key: str, value: Any) -> str:
    table = _POLICIES[key]
    if isinstance(value, str):
        name = value.strip().lower()
    elif hasattr(value, 'name') and isinstance(value.name, str):
        name = value.name.lower()  # rclpy enum member (QoSReliabilityPolicy.RELIABLE)
    elif isinstance(value, int) and not isinstance(value, bool):
        name = table.get(int(value), '')
    else:
        name = ''
    if name not in table.values():
        raise ValueError(f'invalid QoS {key} {value!r}; expected one of {sorted(table.values())}')
    return _RESOLVED.get(key, {}).get(name, name)


def _duration(key: str, value: Any) -> dict[str, int]:
    if isinstance(value, Mapping):
        try:
            ns = int(value['sec']) * 1_000_000_000 + int(value['nsec'])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f'invalid QoS {key} {value!r}; expected {{sec, nsec}}') from exc
    elif hasattr(value, 'nanoseconds'):
        ns = int(value.nanoseconds)
    elif isinstance(value, int) and not isinstance(value, bool):
        ns = value
    else:
        raise ValueError(f'invalid QoS {key} {value!r}; expected integer nanoseconds, '
                         '{sec, nsec} or an rclpy Duration')
    if ns < 0:
        raise ValueError(f'invalid QoS {key} {value!r}: negative duration')
    if ns == 0 or ns >= _INFINITE_THRESHOLD_NS:
        return dict(DURATION_INFINITE)
    return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}


def qos_profile_dict(qos: Any = None) -> dict[str, Any]:
    """One profile as the ordered map rosbag2 serialises (``None`` = rclpy default publisher)."""
    if qos is None:
        source: Mapping[str, Any] = {}
    elif isinstance(qos, Mapping):
        unknown = set(qos) - set(_KEYS)
        if unknown:
            raise ValueError(f'unknown QoS keys {sorted(unknown)}; known: {list(_KEYS)}')
        source = qos
    elif all(hasattr(qos, k) for k in ('history', 'depth', 'reliability', 'durability')):
        source = {k: getattr(qos, k) for k in _KEYS if hasattr(qos, k)}
    else:
        raise ValueError(f'cannot interpret {qos!r} as a QoS profile')
    values = {k: source.get(k, _DEFAULTS[k]) for k in _KEYS}
    depth = values['depth']
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise ValueError(f'invalid QoS depth {depth!r}; expected a non-negative integer')
    return {
        'history': _policy('history', values['history']),
        'depth': int(depth),
        'reliability': _policy('reliability', values['reliability']),
        'durability': _policy('durability', values['durability']),
        'deadline': _duration('deadline', values['deadline']),
        'lifespan': _duration('lifespan', values['lifespan']),
        'liveliness': _policy('liveliness', values['liveliness']),
        'liveliness_lease_duration': _duration('liveliness_lease_duration',
                                               values['liveliness_lease_duration']),
        'avoid_ros_namespace_conventions': bool(values['avoid_ros_namespace_conventions']),
    }


def offered_qos_profiles_yaml(qos: Any = None) -> str:
    """rosbag2 ``offered_qos_profiles`` string for one profile or a list of profiles.

    ``None`` means one rclpy default publisher profile. The text is what yaml-cpp's
    ``YAML::Dump`` produces for rosbag2's node (block style, no trailing newline); an empty
    list gives ``[]``.
    """
    if qos is None or isinstance(qos, Mapping) or not isinstance(qos, (list, tuple)):
        profiles = [qos_profile_dict(qos)]
    else:
        profiles = [qos_profile_dict(p) for p in qos]
    return _yaml.dump(profiles)
