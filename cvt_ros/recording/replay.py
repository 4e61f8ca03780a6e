"""Publish a recording back onto its ROS 2 topics (``cvt-sim replay FILE``; no rosbag2 needed).

Every recorded topic gets a publisher of its recorded type with the **recorded QoS** (parsed from
the channel's ``offered_qos_profiles``, adapted as ``ros2 bag play`` does: reliable only if every
offered profile is reliable, transient local (latched) only if every one is), so
``clutch_engaged`` stays latched (volatile topics get a history of at least 1000, the publisher's
own buffer, so a fast replay does not outrun a reliable subscriber). Messages go out in file
order, each at its log time relative to the first, scaled by ``--rate`` (2 = twice as fast), as
the recorded CDR bytes (no decoding).

``/clock``: if the recording has ``/clock`` (and ``--topics`` keeps it), those messages are
replayed; otherwise the player publishes ``/clock`` itself with each message's log time (before
the message), unless ``--no-clock``. ``--loop`` starts over at the end (simulation time jumps
back, as with ``ros2 bag play --loop``). ``--delay`` waits before the first message so that
subscribers can connect (DDS discovery); ``--wait-for-subscribers`` first waits until at least
one subscriber, and every subscriber the ROS graph knows of on the replayed topics, is
matched. Setting ``stop`` (the command sets it on Ctrl-C/SIGTERM) ends the replay cleanly. A
damaged file is replayed as far as it can be read; the problems are returned with the counts.

rclpy is imported only inside the functions: this module imports without ROS.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from .. import interface as I
from .errors import ReplayError

__all__ = ['ReplayError', 'qos_from_offered', 'replay']

CLOCK_TOPIC = '/clock'
MIN_VOLATILE_DEPTH = 1000
ACK_TIMEOUT = 2.0  # [s] at the end: wait this long at most for reliable subscribers to ack
_RELIABILITY = {'reliable': 'reliable', 'best_effort': 'best_effort', '1': 'reliable',
                '2': 'best_effort'}
_DURABILITY = {'transient_local': 'transient_local', 'volatile': 'volatile',
               '1': 'transient_local', '2': 'volatile'}


def qos_from_offered(text: str, default: Mapping[str, Any] | None = None):
    """rclpy QoSProfile for a publisher replaying a channel with ``offered_qos_profiles``
    ``text`` (rosbag2 YAML). Unparseable text gives ``default`` (or keep last 10, reliable,
    volatile)."""
    import yaml
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    base = dict(default or {'depth': 10, 'reliability': 'reliable', 'durability': 'volatile'})
    try:
        profiles = yaml.safe_load(text) if text else None
    except yaml.YAMLError:
        profiles = None
    if isinstance(profiles, list) and profiles and all(isinstance(p, dict) for p in profiles):
        rel = [_RELIABILITY.get(str(p.get('reliability', '')).lower()) for p in profiles]
        dur = [_DURABILITY.get(str(p.get('durability', '')).lower()) for p in profiles]
        depths = [p.get('depth') for p in profiles if isinstance(p.get('depth'), int)]
        if all(rel):
            base['reliability'] = 'reliable' if all(r == 'reliable' for r in rel) \
                else 'best_effort'
        if all(dur):
            base['durability'] = 'transient_local' if all(d == 'transient_local' for d in dur) \
                else 'volatile'
        if depths and max(depths) > 0:
            base['depth'] = max(depths)
    if base['durability'] == 'volatile':
        # history depth is the publisher's own buffer, not part of QoS matching: a deeper one
        # keeps a reliable subscriber from losing samples when the replay runs faster than the
        # node did. Latched topics keep their depth (it is what a late subscriber receives).
        base['depth'] = max(int(base['depth']), MIN_VOLATILE_DEPTH)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=int(base['depth']),
        reliability=ReliabilityPolicy.RELIABLE if base['reliability'] == 'reliable'
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if base['durability'] == 'transient_local'
        else DurabilityPolicy.VOLATILE)


def _subscribers_matched(node: Any, publishers: Mapping[str, Any]) -> bool:
    """At least one subscriber matched, and every subscription the ROS graph knows of on the
    replayed topics matched by our publisher (DDS discovery done for them)."""
    matched = 0
    for name, pub in publishers.items():
        count = pub.get_subscription_count()
        if count < node.count_subscribers(name):
            return False
        matched += count
    return matched > 0


def replay(path: str, *, rate: float = 1.0, topics: Iterable[str] | None = None,
           loop: bool = False, clock: bool = True, delay: float = 1.0,
           wait_for_subscribers: bool = False,
           stop: threading.Event | None = None, log: Callable[[str], None] = print,
           context: Any = None) -> dict[str, Any]:
    """Publish the recording; returns {'published': n, 'per_topic': {...}, 'problems': [...],
    'interrupted': bool}. Needs rclpy; creates its own node on ``context`` (rclpy must be
    initialised for it). Raises :class:`ReplayError` for an unusable recording."""
    import rclpy
    from rclpy.duration import Duration
    from rosgraph_msgs.msg import Clock

    from .definitions import message_class
    from .errors import MessageDefinitionError, RecordingReadError
    from .reader import read_messages, summary

    if not rate > 0:
        raise ReplayError(f'--rate must be positive, got {rate!r}')
    stop = stop or threading.Event()
    try:
        bag = summary(path)
    except RecordingReadError as exc:
        raise ReplayError(str(exc)) from None
    available = {name: t for name, t in bag.topics.items()}
    if not available and bag.problems:
        raise ReplayError(f'{path}: nothing readable ({bag.problems[0]})')
    if topics:
        wanted = list(dict.fromkeys(topics))
        unknown = [t for t in wanted if t not in available]
        if unknown:
            raise ReplayError(f'topic(s) {", ".join(unknown)} not in the recording; it has '
                              f'{", ".join(sorted(available)) or "no topics"}')
    else:
        wanted = sorted(available)
    node = rclpy.create_node('cvt_replay', context=context, start_parameter_services=False)
    publishers: dict[str, Any] = {}
    skipped = []
    try:
        for name in wanted:
            topic = available[name]
            if topic.message_encoding != 'cdr':
                skipped.append(f'{name} ({topic.message_encoding} encoding)')
                continue
            try:
                cls = message_class(topic.type_name)
            except MessageDefinitionError:
                skipped.append(f'{name[:80]} (type {topic.type_name[:80]} not installed)')
                continue
            key = I.topic_key(name)
            default = I.QOS.get(key) if key else None
            publishers[name] = node.create_publisher(
                cls, name, qos_from_offered(topic.offered_qos_profiles, default))
        if skipped:
            log(f'skipping {", ".join(skipped)}')
        if not publishers:
            raise ReplayError('nothing to replay: no topic with an installed message type')
        clock_pub = None
        if clock and CLOCK_TOPIC not in publishers:
            clock_pub = node.create_publisher(Clock, CLOCK_TOPIC, I.clock_qos())
        duration = bag.duration_ns * 1e-9
        log(f'replaying {path}: {sum(available[t].message_count for t in publishers)} messages '
            f'on {len(publishers)} topics, {duration:.3f} s at rate {rate:g}'
            + (' (looping)' if loop else '')
            + ('; publishing /clock from the log times' if clock_pub else ''))
        if wait_for_subscribers:
            log('waiting for subscribers (Ctrl-C to stop)')
            while not stop.is_set() and not _subscribers_matched(node, publishers):
                stop.wait(0.02)
        if delay > 0:
            stop.wait(delay)
        per_topic = dict.fromkeys(publishers, 0)
        problems: list[str] = []
        published = 0
        clock_msg = Clock()
        while not stop.is_set():
            wall0 = time.monotonic()
            first = None
            last_clock = None
            try:
                for m in read_messages(path, topics=list(publishers)):
                    if first is None:
                        first = m.log_time_ns
                    due = wall0 + (m.log_time_ns - first) * 1e-9 / rate
                    remaining = due - time.monotonic()
                    if remaining > 0 and stop.wait(remaining):
                        break
                    if stop.is_set():
                        break
                    if clock_pub is not None and m.log_time_ns != last_clock:
                        I.set_stamp(clock_msg.clock, m.log_time_ns)
                        clock_pub.publish(clock_msg)
                        last_clock = m.log_time_ns
                    publishers[m.topic].publish(m.data)
                    per_topic[m.topic] += 1
                    published += 1
            except RecordingReadError as exc:
                problems.append(str(exc))
                break
            if not loop or first is None:
                break
        # let reliable subscribers receive the last messages before the publishers go away
        deadline = time.monotonic() + ACK_TIMEOUT
        for pub in publishers.values():
            remaining = deadline - time.monotonic()
            if remaining <= 0 or stop.is_set():
                break
            pub.wait_for_all_acked(Duration(nanoseconds=int(remaining * 1e9)))
        return {'published': published, 'per_topic': per_topic, 'problems': problems,
                'interrupted': stop.is_set()}
    finally:
        node.destroy_node()
