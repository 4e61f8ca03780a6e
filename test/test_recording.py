"""Tests of cvt_ros.recording: rosbag2-compatible MCAP writing, tolerant reading, recovery.

Real rclpy messages and real processes/signals; files are checked with independent readers
(``mcap.reader.make_reader`` and ``rosbags.highlevel.AnyReader``, which builds its types only from
the definitions embedded in the file).
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import textwrap
import threading
import time
import warnings
from pathlib import Path

import pytest
import yaml
from recording_helpers import child_env, on_disk, progress_until, wait_on_disk

# The ROS 2 wheels install share/<pkg> into the venv; ament_index looks there (the Makefile sets
# this too).
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from lifecycle_msgs.msg import State  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor  # noqa: E402
from rclpy.duration import Duration  # noqa: E402
from rclpy.qos import (  # noqa: E402
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from rmw_dds_common.msg import Gid, NodeEntitiesInfo  # noqa: E402
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.rosbag2.metadata import parse_qos  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Bool, Float64  # noqa: E402

from cvt_ros.recording import (  # noqa: E402
    BagWriter,
    LogTimeError,
    MessageDefinitionError,
    RecordingError,
    RecordingReadError,
    RecordingReadWarning,
    get_message_definition,
    message_definition_text,
    offered_qos_profiles_yaml,
    qos_profile_dict,
    read_messages,
    recover,
    summary,
    type_description_hash,
)

ROOT = Path(__file__).resolve().parents[1]
SHARE = Path(sys.prefix) / 'share'
INFINITE = {'sec': 9223372036, 'nsec': 854775807}
QOS_KEYS = ['history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
            'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions']
SEP = '\n' + '=' * 80 + '\n'
T0 = 1_700_000_000_000_000_000  # ns


def _msg_file(pkg: str, name: str) -> str:
    return (SHARE / pkg / 'msg' / f'{name}.msg').read_bytes().decode()


def _json_hash(type_name: str) -> str:
    pkg, _, name = type_name.split('/')
    data = json.loads((SHARE / pkg / 'msg' / f'{name}.json').read_text())
    return next(e['hash_string'] for e in data['type_hashes'] if e['type_name'] == type_name)


def _stamp(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


# ------------------------------------------------------------------ a sample recording
TOPICS = {
    '/joint_states': ('sensor_msgs/msg/JointState', None),
    '/cvt/engaged': ('std_msgs/msg/Bool',
                     QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)),
    '/cvt/ratio': ('std_msgs/msg/Float64', QoSProfile(depth=10)),
    '/clock': ('rosgraph_msgs/msg/Clock', qos_profile_sensor_data),
    '/diagnostics': ('diagnostic_msgs/msg/DiagnosticArray', {'depth': 5}),
}


def _sample_messages() -> list[tuple[str, object, int, int]]:
    """(topic, message, log_time_ns, publish_time_ns), log times non-decreasing."""
    out = []
    for i in range(60):
        t = T0 + i * 1_000_000
        js = JointState(name=['input', 'output'], position=[0.1 * i, 0.05 * i],
                        velocity=[1.0, 0.5], effort=[] if i % 2 else [2.0, 4.0])
        js.header.stamp = _stamp(t)
        js.header.frame_id = 'cvt'
        out.append(('/joint_states', js, t, t - 500))
        out.append(('/cvt/ratio', Float64(data=0.5 + i / 100), t, t))
        out.append(('/clock', Clock(clock=_stamp(t)), t, t))
        if i % 20 == 0:
            out.append(('/cvt/engaged', Bool(data=i != 20), t + 1, t + 1))
        if i % 15 == 0:
            status = DiagnosticStatus(level=bytes([i % 3]), name='cvt: slip', message=f'ok {i}',
                                      hardware_id='sim',
                                      values=[KeyValue(key='ratio', value=str(i)),
                                              KeyValue(key='temp', value='40')])
            diag = DiagnosticArray(status=[status, DiagnosticStatus(name='empty')])
            diag.header.stamp = _stamp(t)
            out.append(('/diagnostics', diag, t + 2, t + 2))
    return sorted(out, key=lambda m: m[2])


@pytest.fixture(scope='module')
def sample_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list]:
    path = tmp_path_factory.mktemp('bag') / 'sample.mcap'
    messages = _sample_messages()
    with BagWriter(path, custom_data={'scene': 'ramp test'}) as writer:
        for topic, (type_name, qos) in TOPICS.items():
            assert writer.add_topic(topic, type_name, qos) > 0
        for topic, msg, log_time, publish_time in messages:
            assert writer.write(topic, msg, log_time, publish_time)
    return path, messages


# ------------------------------------------------------------------ definitions
def test_import_does_not_load_rclpy() -> None:
    code = ('import sys, cvt_ros.recording as r; '
            'assert "rclpy" not in sys.modules and "mcap" not in sys.modules; '
            'r.message_definition_text("std_msgs/msg/Bool"); '
            'assert "rclpy" not in sys.modules')
    subprocess.run([sys.executable, '-c', code], env=child_env(), check=True, timeout=60)


def test_joint_state_schema_text_is_rosbag2_concatenation() -> None:
    text = message_definition_text('sensor_msgs/msg/JointState')
    joint_state = _msg_file('sensor_msgs', 'JointState')
    assert text.startswith(joint_state)
    assert text.count('MSG: std_msgs/Header\n') == 1
    assert text.count('MSG: builtin_interfaces/Time\n') == 1
    assert text == (joint_state
                    + SEP + 'MSG: std_msgs/Header\n' + _msg_file('std_msgs', 'Header')
                    + SEP + 'MSG: builtin_interfaces/Time\n' + _msg_file('builtin_interfaces',
                                                                         'Time'))
    # Short and full type names are the same type.
    assert message_definition_text('sensor_msgs/JointState') == text


def test_schema_dependencies_depth_first_sorted_each_once() -> None:
    text = message_definition_text('diagnostic_msgs/msg/DiagnosticArray')
    headers = [line for line in text.split('\n') if line.startswith('MSG: ')]
    # rosbag2 keeps each message's dependencies in a std::set (sorted), then recurses.
    assert headers == ['MSG: diagnostic_msgs/DiagnosticStatus', 'MSG: diagnostic_msgs/KeyValue',
                       'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    assert text.split(SEP)[2] == 'MSG: diagnostic_msgs/KeyValue\n' + _msg_file(
        'diagnostic_msgs', 'KeyValue')
    # Bounded sequences of messages, defaults, bounded strings, constants.
    text = message_definition_text('rcl_interfaces/msg/ParameterDescriptor')
    assert [line for line in text.split('\n') if line.startswith('MSG: ')] == [
        'MSG: rcl_interfaces/FloatingPointRange', 'MSG: rcl_interfaces/IntegerRange']
    text = message_definition_text('rmw_dds_common/msg/NodeEntitiesInfo')
    assert [line for line in text.split('\n') if line.startswith('MSG: ')] == [
        'MSG: rmw_dds_common/Gid']
    assert message_definition_text('lifecycle_msgs/msg/State') == _msg_file('lifecycle_msgs',
                                                                            'State')


def test_type_hash_matches_installed_json() -> None:
    for type_name, _ in TOPICS.values():
        assert type_description_hash(type_name) == _json_hash(type_name)
        assert type_description_hash(type_name).startswith('RIHS01_')
    definition = get_message_definition('std_msgs/Bool')
    assert (definition.type_name, definition.encoding) == ('std_msgs/msg/Bool', 'ros2msg')
    assert definition.type_hash == _json_hash('std_msgs/msg/Bool')


def _fake_package(prefix: Path, files: dict[str, str], json_for: tuple[str, ...] = ()) -> None:
    (prefix / 'share/ament_index/resource_index/packages').mkdir(parents=True)
    (prefix / 'share/ament_index/resource_index/packages/cvt_fake_msgs').write_text('')
    msg_dir = prefix / 'share/cvt_fake_msgs/msg'
    msg_dir.mkdir(parents=True)
    for name, text in files.items():
        (msg_dir / f'{name}.msg').write_bytes(text.encode())
    for name in json_for:
        (msg_dir / f'{name}.json').write_text(json.dumps({'type_hashes': [
            {'type_name': f'cvt_fake_msgs/msg/{name}', 'hash_string': 'RIHS01_' + 'ab' * 32}]}))


def test_schema_of_hand_written_package(tmp_path: Path,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    thing = textwrap.dedent('''\
        # Header shorthand, constants, defaults, all array kinds, primitives incl. wstring
        Header header
        int32 LIMIT=5
        string GREETING = "hi there"
        float64 gain 1.5
        int32[3] fixed [1, 2, 3]
        int32[<=4] bounded
        wstring wide
        string<=8 short_name
        byte b
        char c
        Part[] parts
        cvt_fake_msgs/Part[2] two_parts
        builtin_interfaces/Duration elapsed  # trailing comment
        ''')
    part = 'uint8 id\nbuiltin_interfaces/Time when\n'
    _fake_package(tmp_path, {'Thing': thing, 'Part': part}, json_for=('Part',))
    monkeypatch.setenv('AMENT_PREFIX_PATH', f'{tmp_path}{os.pathsep}{sys.prefix}')
    text = message_definition_text('cvt_fake_msgs/msg/Thing')
    assert text == (thing
                    + SEP + 'MSG: builtin_interfaces/Duration\n'
                    + _msg_file('builtin_interfaces', 'Duration')
                    + SEP + 'MSG: cvt_fake_msgs/Part\n' + part
                    + SEP + 'MSG: builtin_interfaces/Time\n'
                    + _msg_file('builtin_interfaces', 'Time')
                    + SEP + 'MSG: std_msgs/Header\n' + _msg_file('std_msgs', 'Header'))
    # Time is shared by Part and Header but stored once.
    assert text.count('MSG: builtin_interfaces/Time') == 1
    assert get_message_definition('cvt_fake_msgs/msg/Thing').type_hash == ''
    assert type_description_hash('cvt_fake_msgs/msg/Part') == 'RIHS01_' + 'ab' * 32
    with pytest.raises(MessageDefinitionError, match='no type description'):
        type_description_hash('cvt_fake_msgs/msg/Thing')


@pytest.mark.parametrize('type_name, pattern', [
    ('no_such_pkg/msg/Foo', 'not in the ament index'),
    ('std_msgs/msg/NoSuchType', 'no .msg definition'),
    ('std_msgs', 'invalid message type name'),
    ('std_msgs/msg/Bool/extra', 'invalid message type name'),
    ('std_srvs/srv/Trigger', 'not a message type'),
])
def test_definition_errors_are_typed(type_name: str, pattern: str) -> None:
    with pytest.raises(MessageDefinitionError, match=pattern) as info:
        message_definition_text(type_name)
    assert isinstance(info.value, RecordingError)


# ------------------------------------------------------------------ QoS
def test_qos_yaml_matches_rosbag2_layout() -> None:
    text = offered_qos_profiles_yaml(QoSProfile(depth=1,
                                                durability=DurabilityPolicy.TRANSIENT_LOCAL))
    assert text == textwrap.dedent('''\
        - history: keep_last
          depth: 1
          reliability: reliable
          durability: transient_local
          deadline:
            sec: 9223372036
            nsec: 854775807
          lifespan:
            sec: 9223372036
            nsec: 854775807
          liveliness: automatic
          liveliness_lease_duration:
            sec: 9223372036
            nsec: 854775807
          avoid_ros_namespace_conventions: false''')


def test_qos_inputs_and_errors() -> None:
    profile = qos_profile_dict({'reliability': 'BEST_EFFORT', 'depth': 5,
                                'deadline': 1_500_000_000, 'lifespan': {'sec': 2, 'nsec': 3},
                                'durability': 1, 'history': 'keep_all'})
    assert list(profile) == QOS_KEYS
    assert profile['reliability'] == 'best_effort'
    assert profile['durability'] == 'transient_local'
    assert profile['history'] == 'keep_all'
    assert profile['deadline'] == {'sec': 1, 'nsec': 500_000_000}
    assert profile['lifespan'] == {'sec': 2, 'nsec': 3}
    assert profile['liveliness_lease_duration'] == INFINITE
    rclpy_profile = QoSProfile(depth=3, reliability=ReliabilityPolicy.BEST_AVAILABLE,
                               lifespan=Duration(seconds=2))
    assert qos_profile_dict(rclpy_profile)['lifespan'] == {'sec': 2, 'nsec': 0}
    assert qos_profile_dict(rclpy_profile)['reliability'] == 'reliable'  # as a publisher gets
    two = yaml.safe_load(offered_qos_profiles_yaml([None, qos_profile_sensor_data]))
    assert [p['reliability'] for p in two] == ['reliable', 'best_effort']
    assert offered_qos_profiles_yaml([]) == '[]'
    # rosbags' own parser reads our text (another consumer of the format).
    parsed = parse_qos(offered_qos_profiles_yaml(qos_profile_sensor_data))
    assert parsed[0].depth == 5 and parsed[0].reliability.name == 'BEST_EFFORT'
    assert parsed[0].deadline.sec == INFINITE['sec']
    for bad in ({'reliability': 'sometimes'}, {'depth': -1}, {'deadline': 'soon'},
                {'colour': 'red'}, 'reliable'):
        with pytest.raises(ValueError):
            qos_profile_dict(bad)


# ------------------------------------------------------------------ full round trip
def test_written_bag_read_with_mcap_reader(sample_bag: tuple[Path, list]) -> None:
    path, messages = sample_bag
    counts = {topic: sum(1 for m in messages if m[0] == topic) for topic in TOPICS}
    with path.open('rb') as f:
        reader = make_reader(f, validate_crcs=True)
        header = reader.get_header()
        assert header.profile == 'ros2'
        assert header.library == 'cvt_ros'
        index = reader.get_summary()
        assert index is not None and index.statistics is not None
        schemas = {s.name: s for s in index.schemas.values()}
        assert set(schemas) == {t for t, _ in TOPICS.values()}
        for name, schema in schemas.items():
            assert schema.encoding == 'ros2msg'
            assert schema.data.decode() == message_definition_text(name)
        assert schemas['sensor_msgs/msg/JointState'].data.decode().startswith(
            _msg_file('sensor_msgs', 'JointState'))
        by_topic = {c.topic: c for c in index.channels.values()}
        assert set(by_topic) == set(TOPICS)
        for topic, channel in by_topic.items():
            type_name = TOPICS[topic][0]
            assert channel.message_encoding == 'cdr'
            assert index.schemas[channel.schema_id].name == type_name
            assert set(channel.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
            assert channel.metadata['topic_type_hash'] == _json_hash(type_name)
            qos = yaml.safe_load(channel.metadata['offered_qos_profiles'])
            assert isinstance(qos, list) and len(qos) == 1 and list(qos[0]) == QOS_KEYS
            for key in ('deadline', 'lifespan', 'liveliness_lease_duration'):
                assert qos[0][key] == INFINITE
            assert qos[0]['liveliness'] == 'automatic'
            assert qos[0]['avoid_ros_namespace_conventions'] is False
        engaged = yaml.safe_load(by_topic['/cvt/engaged'].metadata['offered_qos_profiles'])[0]
        assert (engaged['history'], engaged['depth'], engaged['reliability'],
                engaged['durability']) == ('keep_last', 1, 'reliable', 'transient_local')
        clock = yaml.safe_load(by_topic['/clock'].metadata['offered_qos_profiles'])[0]
        assert (clock['reliability'], clock['durability'], clock['depth']) == (
            'best_effort', 'volatile', 5)
        stats = index.statistics
        assert stats.message_count == len(messages)
        assert stats.schema_count == 5 and stats.channel_count == 5
        assert stats.message_start_time == messages[0][2]
        assert stats.message_end_time == messages[-1][2]
        assert stats.chunk_count >= 1 and index.chunk_indexes
        assert all(ci.message_index_offsets for ci in index.chunk_indexes)
        assert {by_id.topic: stats.channel_message_counts[cid]
                for cid, by_id in index.channels.items()} == counts
        read = [(c.topic, m.log_time, m.publish_time,
                 deserialize_message(m.data, type(messages[i][1])))
                for i, (_, c, m) in enumerate(reader.iter_messages(log_time_order=False))]
        assert read == [(t, lt, pt, msg) for t, msg, lt, pt in messages]
        metadata = list(reader.iter_metadata())
    assert [m.name for m in metadata] == ['rosbag2']
    serialized = metadata[0].metadata['serialized_metadata']
    info = yaml.safe_load(serialized)
    assert list(info) == ['version', 'storage_identifier', 'duration', 'starting_time',
                          'message_count', 'topics_with_message_count', 'compression_format',
                          'compression_mode', 'relative_file_paths', 'files', 'custom_data',
                          'ros_distro']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['ros_distro'] == 'jazzy'
    assert info['message_count'] == len(messages)
    assert info['starting_time'] == {'nanoseconds_since_epoch': messages[0][2]}
    assert info['duration'] == {'nanoseconds': messages[-1][2] - messages[0][2]}
    assert info['compression_format'] == '' and info['compression_mode'] == ''
    assert info['relative_file_paths'] == [path.name]
    assert info['files'] == [{'path': path.name, 'starting_time': info['starting_time'],
                              'duration': info['duration'], 'message_count': len(messages)}]
    assert info['custom_data'] == {'scene': 'ramp test'}
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert {name: t['message_count'] for name, t in topics.items()} == counts
    for name, entry in topics.items():
        meta = entry['topic_metadata']
        assert list(meta) == ['name', 'type', 'serialization_format', 'offered_qos_profiles',
                              'type_description_hash']
        assert meta['type'] == TOPICS[name][0] and meta['serialization_format'] == 'cdr'
        assert meta['type_description_hash'] == _json_hash(meta['type'])
        # Version 9: a nested YAML list with string policies, not a string.
        assert meta['offered_qos_profiles'] == yaml.safe_load(
            by_topic[name].metadata['offered_qos_profiles'])
    assert 'compression_format: ""\n' in serialized and 'ros_distro: jazzy' in serialized


def test_written_bag_read_with_rosbags(sample_bag: tuple[Path, list]) -> None:
    path, messages = sample_bag
    with AnyReader([path]) as reader:
        assert {c.topic: (c.msgtype, c.msgcount) for c in reader.connections} == {
            topic: (type_name, sum(1 for m in messages if m[0] == topic))
            for topic, (type_name, _) in TOPICS.items()}
        decoded = [(c.topic, t, reader.deserialize(raw, c.msgtype))
                   for c, t, raw in reader.messages()]
    assert [(topic, t) for topic, t, _ in decoded] == [(m[0], m[2]) for m in messages]
    for (topic, _, got), (_, want, _, _) in zip(decoded, messages, strict=True):
        if topic == '/joint_states':
            assert got.name == want.name and got.header.frame_id == 'cvt'
            assert list(got.position) == list(want.position)
            assert list(got.effort) == list(want.effort)
            assert got.header.stamp.nanosec == want.header.stamp.nanosec
        elif topic == '/clock':
            assert (got.clock.sec, got.clock.nanosec) == (want.clock.sec, want.clock.nanosec)
        elif topic == '/diagnostics':
            assert [s.name for s in got.status] == ['cvt: slip', 'empty']
            assert [(v.key, v.value) for v in got.status[0].values] == [
                (v.key, v.value) for v in want.status[0].values]
            assert got.status[0].level == want.status[0].level[0]
        else:
            assert got.data == want.data


def test_written_bag_read_with_own_reader(sample_bag: tuple[Path, list]) -> None:
    path, messages = sample_bag
    got = list(read_messages(path))
    assert [(m.topic, m.type_name, m.log_time_ns, m.publish_time_ns, m.message())
            for m in got] == [(t, TOPICS[t][0], lt, pt, msg) for t, msg, lt, pt in messages]
    ratio = list(read_messages(path, topics='/cvt/ratio'))
    assert [m.message().data for m in ratio] == [m[1].data for m in messages
                                                  if m[0] == '/cvt/ratio']
    info = summary(path)
    assert info.complete and not info.problems
    assert (info.profile, info.message_count) == ('ros2', len(messages))
    assert (info.start_time_ns, info.end_time_ns) == (messages[0][2], messages[-1][2])
    assert info.duration_ns == messages[-1][2] - messages[0][2]
    assert {t: (s.type_name, s.message_count) for t, s in info.topics.items()} == {
        t: (ty, sum(1 for m in messages if m[0] == t)) for t, (ty, _) in TOPICS.items()}
    assert info.topics['/cvt/engaged'].type_hash == _json_hash('std_msgs/msg/Bool')
    assert 'serialized_metadata' in info.metadata['rosbag2']


def test_schema_edge_cases_round_trip_through_rosbags(tmp_path: Path) -> None:
    """Bounded sequences, defaults, bounded strings and constants decode from our schemas."""
    path = tmp_path / 'edge.mcap'
    descriptor = ParameterDescriptor(name='gain', type=3, description='d', read_only=True,
                                     floating_point_range=[FloatingPointRange(
                                         from_value=0.0, to_value=2.0, step=0.5)])
    entities = NodeEntitiesInfo(node_namespace='/', node_name='sim',
                                reader_gid_seq=[Gid(data=list(range(16)))])
    with BagWriter(path) as writer:
        writer.add_topic('/descriptor', ParameterDescriptor)
        writer.add_topic('/entities', NodeEntitiesInfo)
        writer.add_topic('/state', State)
        writer.write('/descriptor', descriptor, T0)
        writer.write('/entities', entities, T0 + 1)
        writer.write('/state', State(id=State.PRIMARY_STATE_ACTIVE, label='active'), T0 + 2)
    with AnyReader([path]) as reader:
        got = {c.topic: reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()}
    assert got['/descriptor'].floating_point_range[0].to_value == 2.0
    assert got['/descriptor'].read_only is True
    assert list(got['/entities'].reader_gid_seq[0].data) == list(range(16))
    assert (got['/state'].id, got['/state'].label) == (3, 'active')
    assert got['/state'].PRIMARY_STATE_ACTIVE == 3


# ------------------------------------------------------------------ writer behaviour
def test_log_time_must_not_go_backwards(tmp_path: Path) -> None:
    path = tmp_path / 'mono.mcap'
    with BagWriter(path) as writer:
        writer.add_topic('/x', Float64)
        assert writer.write('/x', Float64(data=1.0), 10)
        assert writer.write('/x', Float64(data=2.0), 10)  # equal is fine
        with pytest.raises(LogTimeError, match='backwards') as info:
            writer.write('/x', Float64(data=3.0), 9)
        assert isinstance(info.value, RecordingError) and not writer.failed
        with pytest.raises(LogTimeError, match='negative'):
            writer.write('/x', Float64(data=3.0), -1)
        assert writer.write('/x', Float64(data=4.0), 11)
    assert [(m.log_time_ns, m.message().data) for m in read_messages(path)] == [
        (10, 1.0), (10, 2.0), (11, 4.0)]
    clamped = tmp_path / 'clamp.mcap'
    with BagWriter(clamped, clamp_log_time=True) as writer:
        writer.add_topic('/x', Float64)
        writer.write('/x', Float64(data=1.0), 100)
        writer.write('/x', Float64(data=2.0), 50, publish_time_ns=50)
    assert [(m.log_time_ns, m.publish_time_ns) for m in read_messages(clamped)] == [
        (100, 100), (100, 50)]


def test_unwritable_paths_raise_recording_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match='No such file or directory'):
        BagWriter(tmp_path / 'missing-dir' / 'x.mcap')
    with pytest.raises(RecordingError, match='cannot create'):
        BagWriter(tmp_path)  # a directory
    existing = tmp_path / 'exists.mcap'
    existing.write_bytes(b'keep me')
    with pytest.raises(RecordingError, match='file exists'):
        BagWriter(existing)
    assert existing.read_bytes() == b'keep me'
    if Path('/dev/full').exists():
        with pytest.raises(RecordingError, match='No space left'):
            BagWriter('/dev/full', overwrite=True)


def test_writer_api_contract(tmp_path: Path) -> None:
    path = tmp_path / 'api.mcap'
    writer = BagWriter(path)
    channel = writer.add_topic('/x', 'std_msgs/msg/Float64')
    assert writer.add_topic('/x', 'std_msgs/Float64') == channel
    assert writer.add_topic('/y', 'std_msgs/msg/Float64') != channel
    with pytest.raises(ValueError, match='already has type'):
        writer.add_topic('/x', 'std_msgs/msg/Bool')
    with pytest.raises(ValueError, match='unknown topic'):
        writer.write('/nope', Float64(), 1)
    with pytest.raises(TypeError, match='has type std_msgs/msg/Float64'):
        writer.write('/x', Bool(), 1)
    raw = serialize_message(Float64(data=2.5))[:12]
    assert writer.write('/y', raw, 5)  # bytes are written as given
    assert writer.topics == {'/x': 'std_msgs/msg/Float64', '/y': 'std_msgs/msg/Float64'}
    writer.finish()
    writer.finish()  # idempotent
    assert writer.closed and not writer.failed and writer.error is None
    assert writer.write('/y', raw, 6) is False  # closed: dropped, no exception
    assert writer.add_topic('/z', 'std_msgs/msg/Bool') == 0
    assert [m.message().data for m in read_messages(path)] == [2.5]


def test_idle_data_is_flushed_by_time(tmp_path: Path) -> None:
    path = tmp_path / 'idle.mcap'
    writer = BagWriter(path, flush_interval=0.2)
    writer.add_topic('/x', Float64)
    for i in range(5):
        writer.write('/x', Float64(data=float(i)), T0 + i)
    # no more writes: only the background flush can put them on disk (polled, so that a busy
    # machine only takes longer)
    deadline = time.monotonic() + 30
    on_disk: list[float] = []
    while time.monotonic() < deadline and len(on_disk) < 5:
        time.sleep(0.05)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RecordingReadWarning)
            on_disk = [m.message().data for m in read_messages(path, strict=False)]
    assert on_disk == [0.0, 1.0, 2.0, 3.0, 4.0]
    with pytest.warns(RecordingReadWarning, match='not finished'):
        list(read_messages(path, strict=False))
    writer.finish()
    assert summary(path).complete


DISK_FULL_CHILD = '''
import json, resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # get EFBIG instead of being killed
resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))
from cvt_ros.recording import BagWriter, RecordingError
from std_msgs.msg import Float64
writer = BagWriter(sys.argv[1], chunk_size=4096, flush_interval=None)
writer.add_topic('/count', 'std_msgs/msg/Float64')
raised, dropped, first, message = 0, 0, None, ''
# write until the writer's thread hits the size limit and write() says so (when that happens
# depends on when the thread gets to run: on a busy machine many messages later), then 1000 more
i = 0
while (first is None or i < first + 1000) and i < 5_000_000:
    try:
        if not writer.write('/count', Float64(data=float(i)), 1000 + i):
            dropped += 1
    except RecordingError as exc:
        raised, first, message = raised + 1, i, str(exc)
    i += 1
finish = 'ok'
try:
    writer.finish()
except RecordingError:
    finish = 'raised'
print(json.dumps({'raised': raised, 'first': first, 'dropped': dropped, 'message': message,
                  'failed': writer.failed, 'error': str(writer.error), 'finish': finish,
                  'written': i}))
'''


def test_disk_full_fails_once_then_drops_quietly(tmp_path: Path) -> None:
    path = tmp_path / 'full.mcap'
    proc = subprocess.run([sys.executable, '-c', DISK_FULL_CHILD, str(path)], env=child_env(),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result['raised'] == 1 and result['failed'] and result['finish'] == 'ok'
    assert 'File too large' in result['message'] and result['error'] == result['message']
    assert result['dropped'] == result['written'] - result['first'] - 1 == 999
    with pytest.raises(RecordingReadError, match='truncated'):
        list(read_messages(path))
    good = [m.message().data for m in read_messages(path, strict=False)]
    assert good == [float(i) for i in range(len(good))] and len(good) > 100
    assert recover(path, tmp_path / 'full-recovered.mcap') == len(good)


# ------------------------------------------------------------------ damaged files
@pytest.fixture(scope='module')
def chunky_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list, list]:
    """Many small chunks.

    Returns (path, [(topic, log_time, data)], [(chunk start, chunk end, messages up to its end)]).
    """
    path = tmp_path_factory.mktemp('chunky') / 'chunky.mcap'
    with BagWriter(path, chunk_size=1500, flush_interval=None) as writer:
        writer.add_topic('/x', Float64)
        writer.add_topic('/joint_states', JointState)
        for i in range(400):
            writer.write('/x', Float64(data=float(i)), T0 + i)
            if i % 4 == 0:
                writer.write('/joint_states', JointState(name=['a'], position=[float(i)]),
                             T0 + i)
    originals = [(m.topic, m.log_time_ns, m.data) for m in read_messages(path)]
    with path.open('rb') as f:
        index = make_reader(f).get_summary()
    data = path.read_bytes()
    bounds = []
    for ci in sorted(index.chunk_indexes, key=lambda ci: ci.chunk_start_offset):
        end = ci.chunk_start_offset + ci.chunk_length
        cut = path.with_name('count.mcap')
        cut.write_bytes(data[:end])
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RecordingReadWarning)
            bounds.append((ci.chunk_start_offset, end,
                           len(list(read_messages(cut, strict=False)))))
        cut.unlink()
    assert len(bounds) > 5 and bounds[-1][2] == len(originals)
    return path, originals, bounds


def _read_all(path: Path) -> tuple[list, RecordingReadError | None]:
    got: list = []
    try:
        for m in read_messages(path):
            got.append((m.topic, m.log_time_ns, m.data))
    except RecordingReadError as exc:
        return got, exc
    return got, None


def test_truncated_files_yield_prefix_and_recover(chunky_bag: tuple[Path, list, list],
                                                  tmp_path: Path) -> None:
    path, originals, bounds = chunky_bag
    data = path.read_bytes()
    size = len(data)
    header_end = 17 + struct.unpack_from('<Q', data, 9)[0]
    cuts = [8, 9, 30, bounds[0][0], bounds[0][0] + 20, bounds[2][1], bounds[2][1] + 5,
            bounds[len(bounds) // 2][1] - 1, bounds[-2][1], bounds[-1][0] + 3, size - 30,
            size - 1]
    for cut in cuts:
        damaged = tmp_path / f'cut-{cut}.mcap'
        damaged.write_bytes(data[:cut])
        got, error = _read_all(damaged)
        assert error is not None, cut
        assert got == originals[:len(got)], cut  # a clean prefix, nothing invented
        assert error.messages_read == len(got)
        assert 'truncated' in str(error) or 'not finished' in str(error) or \
            'summary' in str(error), str(error)
        complete_chunks = [n for start, end, n in bounds if end <= cut]
        assert len(got) >= (complete_chunks[-1] if complete_chunks else 0), cut
        fixed = tmp_path / f'fixed-{cut}.mcap'
        if cut < header_end:  # not even the MCAP header survived: nothing to summarise
            assert got == []
            with pytest.raises(RecordingReadError):
                summary(damaged)
            with pytest.raises(RecordingReadError):
                recover(damaged, fixed)
            continue
        info = summary(damaged)
        assert not info.complete and info.problems and info.message_count == len(got)
        assert recover(damaged, fixed) == len(got)
        recovered, error = _read_all(fixed)
        assert error is None and recovered == got
        with fixed.open('rb') as f:
            index = make_reader(f, validate_crcs=True).get_summary()
            assert index is not None and index.statistics.message_count == len(got)


def test_recover_complete_file_copies_everything(sample_bag: tuple[Path, list],
                                                 tmp_path: Path) -> None:
    path, messages = sample_bag
    out = tmp_path / 'copy.mcap'
    assert recover(path, out) == len(messages)
    assert [(m.topic, m.log_time_ns, m.data) for m in read_messages(out)] == [
        (m.topic, m.log_time_ns, m.data) for m in read_messages(path)]
    original, copy = summary(path), summary(out)
    assert copy.topics == original.topics
    info = yaml.safe_load(copy.metadata['rosbag2']['serialized_metadata'])
    assert info['custom_data'] == {'scene': 'ramp test'}
    assert info['message_count'] == len(messages)
    with pytest.raises(RecordingError, match='file exists'):
        recover(path, out)


@pytest.mark.parametrize('content', [b'', b'\x89MCAP', b'not an mcap file at all' * 10,
                                     bytes(range(256)) * 4])
def test_garbage_files_give_clear_errors(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / 'garbage.mcap'
    path.write_bytes(content)
    got, error = _read_all(path)
    assert got == [] and error is not None
    assert 'not an MCAP file' in str(error) or 'empty file' in str(error)
    with pytest.warns(RecordingReadWarning):
        assert list(read_messages(path, strict=False)) == []
    with pytest.raises(RecordingReadError):
        summary(path)
    with pytest.raises(RecordingReadError):
        recover(path, tmp_path / 'out.mcap')
    with pytest.raises(RecordingReadError, match='cannot open'):
        list(read_messages(tmp_path / 'does-not-exist.mcap'))


def test_corrupt_chunk_is_skipped_and_reported(chunky_bag: tuple[Path, list, list],
                                               tmp_path: Path) -> None:
    path, originals, bounds = chunky_bag
    data = bytearray(path.read_bytes())
    start, end, count_through = bounds[3]
    lost = count_through - bounds[2][2]
    data[end - 5] ^= 0xFF  # inside the chunk's message data; the CRC no longer matches
    damaged = tmp_path / 'corrupt.mcap'
    damaged.write_bytes(bytes(data))
    got, error = _read_all(damaged)
    assert error is not None and 'CRC' in str(error)
    assert len(got) == len(originals) - lost
    assert got == originals[:bounds[2][2]] + originals[count_through:]
    assert recover(damaged, tmp_path / 'corrupt-fixed.mcap') == len(got)


# ------------------------------------------------------------------ crashes and signals
CRASH_CHILD = '''
import sys, time
from cvt_ros.recording import BagWriter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
writer = BagWriter(sys.argv[1])
writer.add_topic('/count', 'std_msgs/msg/Float64')
writer.add_topic('/joint_states', JointState)
print('ready', flush=True)
i, next_t = 0, time.monotonic()
while True:
    now = time.time_ns()
    writer.write('/count', Float64(data=float(i)), now)
    js = JointState(name=['in', 'out'], position=[float(i), 0.5 * i])
    js.header.stamp.sec, js.header.stamp.nanosec = divmod(now, 1_000_000_000)
    writer.write('/joint_states', js, now)
    if i % 50 == 0:
        print(i, now, flush=True)
    i += 1
    next_t += 0.001
    time.sleep(max(0.0, next_t - time.monotonic()))
'''


def _start(code: str, *args: object) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, '-c', code, *map(str, args)], env=child_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if line.strip() != 'ready':
        proc.kill()
        raise AssertionError(f'child did not start: {line!r} {proc.stderr.read()}')
    return proc


def test_sigkill_loses_nothing_already_on_disk(tmp_path: Path) -> None:
    path = tmp_path / 'killed.mcap'
    proc = _start(CRASH_CHILD, path)
    # once the child has recorded ≥ 1500 messages over ≥ 2 s (its own report), wait until its
    # file holds them (the background flush: a handshake, so a busy machine only takes longer),
    # then kill it while it goes on writing, so the signal lands anywhere inside write()
    progress = progress_until(proc, lambda first, last: last[0] >= 1500 and
                              last[1] - first[1] >= 2_000_000_000)
    must_have = progress[-1][0] + 1
    wait_on_disk(path, '/count', lambda messages: len(messages) >= must_have)
    proc.kill()
    out, _ = proc.communicate(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    progress += [(int(a), int(b)) for a, b in (line.split() for line in out.splitlines())]
    assert progress and progress[-1][0] >= 1500, progress[-3:]
    got, error = _read_all(path)
    assert error is not None and 'not finished' in str(error)
    counts = [m.message().data for m in on_disk(path, '/count')]
    assert counts == [float(i) for i in range(len(counts))]
    assert len(counts) >= must_have, f'{must_have} messages not on disk after 120 s'
    fixed = tmp_path / 'recovered.mcap'
    assert recover(path, fixed) == len(got)
    info = summary(fixed)
    assert info.complete and info.topics['/count'].message_count == len(counts)
    assert info.topics['/joint_states'].message_count >= must_have
    last = [m for m in read_messages(fixed, ['/joint_states'])][-1].message()
    assert last.position[0] == len(counts) - 1 or last.position[0] == len(counts) - 2


SIGNAL_CHILD = '''
import signal, sys
from cvt_ros.recording import BagWriter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
writer = BagWriter(sys.argv[1], chunk_size=8192)
def finish_and_exit(signum, frame):
    writer.finish()
    print('finished', writer.message_count, flush=True)
    sys.exit(0)
if sys.argv[2] == 'handler':
    signal.signal(signal.SIGTERM, finish_and_exit)
    signal.signal(signal.SIGINT, finish_and_exit)
writer.add_topic('/count', Float64)
writer.add_topic('/joint_states', JointState)
print('ready', flush=True)
i = 0
try:
    with writer:  # as fast as possible, so the signal lands anywhere inside write()
        while True:
            writer.write('/count', Float64(data=float(i)), 1000 + i)
            writer.write('/joint_states', JointState(name=['a'], position=[float(i)]), 1000 + i)
            i += 1
            if i == 1000:
                print('running', flush=True)
except KeyboardInterrupt:
    print('finished', writer.message_count, flush=True)
'''


@pytest.mark.parametrize('signum, mode', [(signal.SIGTERM, 'handler'),
                                          (signal.SIGINT, 'handler'),
                                          (signal.SIGINT, 'with')])
def test_signal_handler_finish_leaves_complete_file(tmp_path: Path, signum: int,
                                                    mode: str) -> None:
    path = tmp_path / 'signalled.mcap'
    proc = _start(SIGNAL_CHILD, path, mode)
    assert proc.stdout.readline().strip() == 'running'   # 1000 messages written: signal now
    time.sleep(0.05)
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    written = int(out.split()[-1])
    assert written > 1000
    with path.open('rb') as f:
        reader = make_reader(f, validate_crcs=True)
        index = reader.get_summary()
        assert index is not None and index.statistics.message_count == written
        info = yaml.safe_load(next(iter(reader.iter_metadata())).metadata['serialized_metadata'])
    assert info['message_count'] == written
    got = list(read_messages(path))  # strict: raises if anything is wrong
    assert len(got) == written
    counts = [m.message().data for m in got if m.topic == '/count']
    assert counts == [float(i) for i in range(len(counts))]


EXIT_CHILD = '''
import sys
from cvt_ros.recording import BagWriter
from std_msgs.msg import Float64
writer = BagWriter(sys.argv[1])
writer.add_topic('/count', Float64)
for i in range(500):
    writer.write('/count', Float64(data=float(i)), 1000 + i)
if sys.argv[2] == 'raise':
    raise RuntimeError('simulated crash of the node (not of the process)')
'''


@pytest.mark.parametrize('ending', ['return', 'raise'])
def test_exit_without_finish_still_completes_file(tmp_path: Path, ending: str) -> None:
    path = tmp_path / 'forgotten.mcap'
    proc = subprocess.run([sys.executable, '-c', EXIT_CHILD, str(path), ending],
                          env=child_env(), capture_output=True, text=True, timeout=60)
    assert proc.returncode == (0 if ending == 'return' else 1), proc.stderr
    info = summary(path)  # the atexit hook finished the file
    assert info.complete and info.message_count == 500
    assert [m.message().data for m in read_messages(path)] == [float(i) for i in range(500)]


@pytest.mark.parametrize('interrupted', ['write', 'finish'])
def test_finish_from_a_handler_anywhere_inside_write_cannot_deadlock(tmp_path: Path,
                                                                     interrupted: str) -> None:
    """Python runs a signal handler between any two bytecodes of the main thread, so a handler
    that calls finish() may land anywhere inside write(), its wake-up of the writer thread
    included, or inside a finish() under way. (That wake-up was a threading.Event, whose set()
    holds a plain lock: finish() waking the thread again from inside it hung the process, once
    in a CI run.) The handler is simulated here at every line the call executes, by a tracer,
    in a thread of its own."""
    def interrupted_at(k: int, path: Path) -> int:
        writer = BagWriter(path, chunk_size=1, flush_interval=None)   # every write wakes it
        writer.add_topic('/x', Float64)
        writer.write('/x', Float64(data=0.0), 1)
        lines = 0

        def handler_at_line_k(frame, event, arg):
            nonlocal lines
            if event == 'line':
                lines += 1
                if lines == k:
                    sys.settrace(None)
                    writer.finish()
            return handler_at_line_k
        sys.settrace(handler_at_line_k)
        if interrupted == 'write':
            writer.write('/x', Float64(data=1.0), 2)
        else:
            writer.finish()
        sys.settrace(None)
        writer.finish()
        return lines

    k = 1
    while True:
        result: list[int] = []
        path = tmp_path / f'at_{k}.mcap'
        thread = threading.Thread(target=lambda k=k, path=path, result=result:
                                  result.append(interrupted_at(k, path)), daemon=True)
        thread.start()
        thread.join(30)
        assert not thread.is_alive(), f'finish() at line {k} of {interrupted}() never returned'
        assert summary(path).complete
        if result[0] < k:   # the call has fewer lines: every one was tried
            break
        k += 1
    assert k > 5
