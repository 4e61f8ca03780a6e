"""recover and the readers let through only messages that were recorded (issue 14): every
message is checked against its chunk (CRC, time range), its channel and its schema, and what
is skipped is reported. The damaged files here are made byte by byte from real recordings."""
import io
import struct
import zlib

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from cvt_ros.recording import (
    RecordingReadError,
    read_messages,
    recover_file,
    summary,
)
from cvt_ros.recording.cdr_check import cdr_matches, message_shape
from cvt_ros.recording.recorder import SimulationRecorder
from cvt_ros.scene import load_scene
from cvt_ros.solver.simulator import Simulator

OP_MESSAGE, OP_CHUNK, OP_MESSAGE_INDEX = 5, 6, 7


def records(data):
    """(opcode, offset, length) of the top-level records of an MCAP file."""
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = struct.unpack_from('<BQ', data, pos)
        out.append((op, pos, length))
        if op == 2:   # footer
            break
        pos += 9 + length
    return out


def messages_of(path):
    """Every message as (topic, log time, publish time, sequence, bytes), read by mcap."""
    with open(path, 'rb') as f:
        return [(ch.topic, m.log_time, m.publish_time, m.sequence, bytes(m.data))
                for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def ours(path):
    return [(m.topic, m.log_time_ns, m.publish_time_ns, m.sequence, m.data)
            for m in read_messages(path, strict=False)]


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """0.3 s of the paper scene at 1 ms, in small chunks (so there are many)."""
    path = tmp_path_factory.mktemp('integrity') / 'r.mcap'
    sim = Simulator(load_scene('paper'))
    with SimulationRecorder(path, parameters=sim.values, scene='paper', chunk_size=4096,
                            flush_interval=None) as rec:
        rec.record_clutch_state(sim.engaged, 0.0)
        for _ in range(300):
            for sw in sim.advance(1e-3):
                rec.record_switch(sw)
            rec.record_sample(sim.sample())
            rec.record_clock(sim.t)
    return path


def damaged(recording, tmp_path, edit):
    data = bytearray(recording.read_bytes())
    edit(data)
    out = tmp_path / 'damaged.mcap'
    out.write_bytes(bytes(data))
    return out


def test_a_message_index_turned_into_a_message_is_not_recovered(recording, tmp_path):
    """The tester's case: one bit turns a MessageIndex opcode (7) into Message's (5); the
    record parses as a JointState-sized message with plausible times."""
    original = messages_of(recording)
    data = recording.read_bytes()
    index = [r for r in records(data) if r[0] == OP_MESSAGE_INDEX]
    assert len(index) > 10
    for _, pos, _ in index[:5]:
        bad = damaged(recording, tmp_path, lambda d, pos=pos: d.__setitem__(pos, OP_MESSAGE))
        result = recover_file(bad, tmp_path / 'out.mcap', overwrite=True)
        got = messages_of(tmp_path / 'out.mcap')
        assert result.messages == len(got) == len(original)
        assert got == original                          # nothing fabricated, nothing lost
        assert result.skipped == 1
        assert any('outside the chunks of a chunked file' in p for p in result.problems)
        assert ours(bad) == [(t, lt, pt, s, d) for t, lt, pt, s, d in original]


def test_a_chunk_whose_crc_was_zeroed_is_not_trusted(recording, tmp_path):
    data = recording.read_bytes()
    chunks = [r for r in records(data) if r[0] == OP_CHUNK]
    pos = chunks[3][1]
    crc_at = pos + 9 + 24            # after message start/end time and uncompressed size

    def edit(d):
        d[crc_at:crc_at + 4] = b'\0\0\0\0'
        d[pos + 9 + 40 + 100] ^= 0x10          # and a bit of its records changed
    bad = damaged(recording, tmp_path, edit)
    result = recover_file(bad, tmp_path / 'out.mcap')
    got = messages_of(tmp_path / 'out.mcap')
    original = messages_of(recording)
    assert set(got) < set(original) and len(got) == result.messages
    assert any('without a CRC' in p for p in result.problems)


def test_channels_lost_with_a_damaged_chunk_come_from_the_summary(recording, tmp_path):
    """The first chunk holds the schemas and channels: damaged, its messages are lost, but
    every later chunk's messages are recovered with the summary's channel definitions."""
    data = recording.read_bytes()
    first = [r for r in records(data) if r[0] == OP_CHUNK][0]
    bad = damaged(recording, tmp_path, lambda d: d.__setitem__(
        first[1] + 9 + 60, d[first[1] + 9 + 60] ^ 0xFF))
    result = recover_file(bad, tmp_path / 'out.mcap')
    got = messages_of(tmp_path / 'out.mcap')
    original = messages_of(recording)
    assert set(got) <= set(original)
    assert len(got) == result.messages > 0.9 * len(original)
    assert any('CRC mismatch' in p for p in result.problems)
    info = summary(tmp_path / 'out.mcap')
    assert info.topics['/joint_states'].type_name == 'sensor_msgs/msg/JointState'


def _mcap(path, chunked, records_, compression=CompressionType.NONE):
    """A small MCAP with Float64 and JointState channels written by the mcap library."""
    from cvt_ros.recording import message_definition_text
    with open(path, 'wb') as f:
        w = Writer(f, use_chunking=chunked, compression=compression)
        w.start(profile='ros2')
        schemas = {t: w.register_schema(t, 'ros2msg', message_definition_text(t).encode())
                   for t in ('std_msgs/msg/Float64', 'sensor_msgs/msg/JointState')}
        channels = {'/x': w.register_channel('/x', 'cdr', schemas['std_msgs/msg/Float64']),
                    '/js': w.register_channel('/js', 'cdr',
                                              schemas['sensor_msgs/msg/JointState'])}
        for i, (topic, data) in enumerate(records_):
            w.add_message(channels[topic], log_time=i, publish_time=i, data=data, sequence=i)
        w.finish()


def _float64(x):
    return b'\x00\x01\x00\x00' + struct.pack('<d', x)


def test_unchunked_files_check_each_message_against_its_schema(tmp_path):
    import numpy as np

    from cvt_ros import interface as I
    row = np.arange(20, dtype=float)
    good = [('/x', _float64(1.5)), ('/js', I.joint_state_cdr(row)), ('/x', _float64(2.5))]
    path = tmp_path / 'flat.mcap'
    _mcap(path, False, good + [('/x', b'\x01\x02\x03\x04' + bytes(8)),     # no CDR header
                               ('/js', I.joint_state_cdr(row)[:-8]),       # cut short
                               ('/x', _float64(3.5) + bytes(8))])          # 8 bytes too many
    result = recover_file(path, tmp_path / 'out.mcap')
    assert [d for *_, d in messages_of(tmp_path / 'out.mcap')] == [d for _, d in good]
    assert result.skipped == 3 and len(result.problems) == 3
    with pytest.raises(RecordingReadError, match='skipped'):
        list(read_messages(path))


@pytest.mark.parametrize('compression', [CompressionType.LZ4, CompressionType.ZSTD])
def test_a_compressed_chunk_cannot_inflate_past_its_declared_size(tmp_path, compression):
    path = tmp_path / 'c.mcap'
    _mcap(path, True, [('/x', _float64(i)) for i in range(50)], compression)
    assert len(ours(path)) == 50
    data = bytearray(path.read_bytes())
    chunk = [r for r in records(data) if r[0] == OP_CHUNK][0]
    size_at = chunk[1] + 9 + 16
    for declared in (8, 300 << 20, 2 ** 63):
        data[size_at:size_at + 8] = struct.pack('<Q', declared)
        bad = tmp_path / 'bomb.mcap'
        bad.write_bytes(bytes(data))
        with pytest.raises(RecordingReadError) as info:
            list(read_messages(bad))
        assert 'declares' in str(info.value) or 'holds' in str(info.value)


def test_cdr_check_against_the_recorded_definitions(recording):
    with open(recording, 'rb') as f:
        reader = make_reader(f)
        s = reader.get_summary()
        shapes = {cid: message_shape(s.schemas[c.schema_id].name,
                                     s.schemas[c.schema_id].data.decode())
                  for cid, c in s.channels.items()}
        count = 0
        for _, channel, m in reader.iter_messages():
            shape = shapes[channel.id]
            assert shape is not None and cdr_matches(m.data, shape)
            for cut in (1, 4, len(m.data) // 2):
                assert not cdr_matches(m.data[:-cut], shape) or channel.topic == '/clock'
            count += 1
    assert count > 600
    shape = message_shape('std_msgs/msg/Bool', 'bool data\n')
    assert cdr_matches(b'\x00\x01\x00\x00\x01', shape)
    assert not cdr_matches(b'\x00\x01\x00\x00\x02', shape)      # a bool is 0 or 1
    # a type that contains itself, or a hostile count, never loops
    assert message_shape('a/A', 'A child\n') is None
    js = message_shape('x/J', 'string[] names\n')
    assert not cdr_matches(b'\x00\x01\x00\x00\xff\xff\xff\xff', js)


def test_crc_of_a_good_recording_and_zlib_agree(recording):
    """The chunk CRCs the checks rely on are really there in our recordings."""
    data = recording.read_bytes()
    for op, pos, _ in records(data):
        if op == OP_CHUNK:
            start, end, size, crc = struct.unpack_from('<QQQI', data, pos + 9)
            assert crc != 0
            comp_len = struct.unpack_from('<I', data, pos + 9 + 28)[0]
            body = data[pos + 9 + 32 + comp_len:]
            (n,) = struct.unpack_from('<Q', body, 0)
            assert zlib.crc32(body[8:8 + n]) == crc and n == size
    assert io.BytesIO(data).read(8) == b'\x89MCAP0\r\n'
