"""Recording simulations to MCAP (cvt_ros.recording.recorder, cvt_ros.interface, `run --mcap`).

Files are opened by two independent readers — ``mcap.reader.make_reader`` and
``rosbags.highlevel.AnyReader`` (which builds its types only from the definitions embedded in the
file) — and compared with what the simulation produced. Crash safety is tested with real
signals on a child process that records in real time, as the node does.
"""
import json
import math
import signal
import struct
import subprocess
import sys

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rclpy.serialization import deserialize_message, serialize_message
from recording_helpers import child_env, progress_until, wait_on_disk
from rosbags.highlevel import AnyReader
from rosbags.rosbag2.metadata import parse_qos
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64

from cvt_ros import interface as I
from cvt_ros.bench.recording import benchmark
from cvt_ros.recording import (
    RecordingError,
    RecordingReadWarning,
    message_definition_text,
    read_messages,
    summary,
    type_description_hash,
)
from cvt_ros.recording._cdr import cdr_size
from cvt_ros.recording.recorder import (
    METADATA_NAME,
    SELF_CHECK_NAME,
    SimulationRecorder,
    write_run,
)
from cvt_ros.solver.offline import run_scene
from cvt_ros.solver.output import COL

CLI = [sys.executable, '-m', 'cvt_ros']
#: every topic of the node's interface, as the recorder registers them (resolved in '/')
TYPES = {I.resolve_topic(spec.name, '/'): spec.type_name for spec in I.TOPICS.values()}
QOS_KEYS = ['history', 'depth', 'reliability', 'durability', 'deadline', 'lifespan',
            'liveliness', 'liveliness_lease_duration', 'avoid_ros_namespace_conventions']


@pytest.fixture(scope='module')
def paper_run(tmp_path_factory):
    """The paper scene, 0.6 s at 1 ms, recorded in-process: (path, result)."""
    path = tmp_path_factory.mktemp('rec') / 'paper.mcap'
    sim, result = run_scene('paper', 0.6, sample_dt=1e-3)
    count, error = write_run(path, sim, result, scene='paper')
    assert error is None and count > 1200
    return path, result


# ---------------------------------------------------------------------------------- interface
def test_interface_matches_the_node():
    """The node and the recorder name joints, topics and QoS from the one interface module."""
    from cvt_ros.device import node

    assert node.JOINTS[:4] == I.JOINTS
    pairs = {'joint_states': I.joint_states_qos(), 'clutch_engaged': I.clutch_qos(),
             'clock': I.clock_qos(), 'diagnostics': I.diagnostics_qos(),
             'crank_length_cmd': I.command_qos(), 'load_torque_cmd': I.command_qos()}
    for key, profile in pairs.items():
        assert I.qos_profile(key) == profile, key
    assert {k: v for k, v in I.resolved_topics('/line1').items() if k in pairs} == {
        'joint_states': '/line1/joint_states', 'clutch_engaged': '/line1/clutch_engaged',
        'clock': '/clock', 'diagnostics': '/diagnostics',
        'crank_length_cmd': '/line1/crank_length_cmd',
        'load_torque_cmd': '/line1/load_torque_cmd'}


def test_fast_cdr_encoders_decode_like_rclpy_messages():
    row = np.random.default_rng(3).normal(size=len(COL)) * 1e3
    row[COL['t']] = 12.345678901
    for names in (I.JOINTS, ['line1_' + j for j in I.JOINTS]):
        msg = I.joint_state_from_row(row, names=names)
        data = I.joint_state_cdr(row, names=names)
        assert len(data) == cdr_size(msg)
        assert deserialize_message(data, JointState) == msg
        assert msg.header.stamp.sec == 12 and msg.header.stamp.nanosec == 345678901
        values, got_names = I.decode_joint_state_cdr(data)
        assert got_names == list(names)
        assert values == I.decode_joint_state(msg)
        assert values.position == tuple(row[[COL[c] for c in I.POSITION_COLUMNS]])
        assert values.effort == tuple(row[[COL[c] for c in I.EFFORT_COLUMNS]])
        assert values.twist == row[COL['phi3']] - row[COL['phi4']]
    assert deserialize_message(I.clock_cdr(5_000_000_001), Clock) == I.clock_msg(5_000_000_001)
    assert deserialize_message(I.bool_cdr(True), Bool) == I.clutch_msg(True)
    assert deserialize_message(I.float64_cdr(0.04), Float64) == I.command_msg(0.04)
    # the node's raw command subscriptions: what rclpy serializes, and the other byte order
    for value in (0.04, -1e300, math.inf):
        assert I.float64_value(serialize_message(Float64(data=value))) == value
    assert I.float64_value(b'\x00\x00\x00\x00' + struct.pack('>d', 0.07)) == 0.07
    assert math.isnan(I.float64_value(I.float64_cdr(math.nan)))
    with pytest.raises(ValueError, match='not a std_msgs/Float64'):
        I.float64_value(I.float64_cdr(0.04)[:11])
    with pytest.raises(ValueError, match='joints'):
        I.decode_joint_state_cdr(I.joint_state_cdr(row, names=['a', 'b', 'c', 'd']))


def test_stream_decoder_reads_what_rclpy_reads():
    """JointStateDecoder (the dds harness's raw samples): its one-struct fast path and its
    general parser agree with rclpy's message, also when the layout changes under it."""
    rng = np.random.default_rng(7)
    decoder = I.JointStateDecoder()
    streams = [(I.JOINTS, ''), (I.JOINTS, ''), (['x_' + j for j in I.JOINTS], 'base'),
               (I.DEVICE_JOINTS, ''), (I.DEVICE_JOINTS, '')]
    for names, frame in streams:
        msg = JointState(name=list(names), position=rng.normal(size=len(names)).tolist(),
                         velocity=rng.normal(size=len(names)).tolist(),
                         effort=rng.normal(size=len(names)).tolist())
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(rng.integers(0, 2**31)), 999_999_999
        msg.header.frame_id = frame
        data = serialize_message(msg)
        ns, position, velocity, effort = decoder.decode(data)
        assert ns == msg.header.stamp.sec * 1_000_000_000 + 999_999_999
        assert I.joint_state_stamp_ns(data) == ns
        assert decoder.names == list(names)
        assert (position, velocity, effort) == (tuple(msg.position), tuple(msg.velocity),
                                                tuple(msg.effort))
    partial = JointState(name=['a', 'b'], position=[1.0, 2.0])   # no velocity, no effort
    assert decoder.decode(serialize_message(partial))[1:] == ((1.0, 2.0), (), ())
    with pytest.raises(ValueError):
        decoder.decode(b'\x00\x01\x00\x00' + b'\xff' * 20)


# ---------------------------------------------------------------------------------- the file
def test_run_recording_read_by_mcap_reader(paper_run):
    path, result = paper_run
    switches = [s for s in result.switches if s.kind != 'graze']
    n = len(result.samples)
    with path.open('rb') as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_header().profile == 'ros2'
        index = reader.get_summary()
        by_topic = {c.topic: c for c in index.channels.values()}
        assert set(by_topic) == set(TYPES)
        for topic, channel in by_topic.items():
            schema = index.schemas[channel.schema_id]
            assert (schema.name, schema.encoding) == (TYPES[topic], 'ros2msg')
            assert schema.data.decode() == message_definition_text(TYPES[topic])
            assert channel.message_encoding == 'cdr'
            assert channel.metadata['topic_type_hash'] == type_description_hash(TYPES[topic])
            qos = yaml.safe_load(channel.metadata['offered_qos_profiles'])
            assert list(qos[0]) == QOS_KEYS
            parse_qos(qos)  # rosbags' own rosbag2 QoS parser accepts it
            key = I.topic_key(topic)
            for k in ('history', 'depth', 'reliability', 'durability'):
                assert qos[0][k] == I.QOS[key][k]
        stats = index.statistics
        counts = {by_topic_id.topic: stats.channel_message_counts.get(cid, 0)
                  for cid, by_topic_id in index.channels.items()}
        assert counts == dict(dict.fromkeys(TYPES, 0), **{
            '/joint_states': n, '/clock': n, '/clutch_engaged': len(switches) + 1})
        assert index.chunk_indexes and all(ci.message_index_offsets
                                           for ci in index.chunk_indexes)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        messages = [(c.topic, m.log_time, m.publish_time, m.data)
                    for _, c, m in reader.iter_messages(log_time_order=False)]
    assert set(metadata) == {METADATA_NAME, SELF_CHECK_NAME, 'rosbag2'}
    # the run's solver self-check (issue 32): no possibly missed clutch event in this run
    check = metadata[SELF_CHECK_NAME]
    assert check['possible_missed_events'] == '0' and check['stray_samples'] == '0'
    assert check['solver'].startswith('dopri5')
    meta = metadata[METADATA_NAME]
    params = yaml.safe_load(meta['parameters'])
    assert params['inertia.output'] == 0.5 and params['linkage.crank_length'] == 0.03
    assert meta['scene'] == 'paper' and meta['joint_names'] == ','.join(I.DEVICE_JOINTS)
    bag = yaml.safe_load(metadata['rosbag2']['serialized_metadata'])
    assert bag['message_count'] == len(messages) and bag['custom_data']['cvt_ros.scene'] == 'paper'
    logs = [m[1] for m in messages]
    assert logs == sorted(logs)                      # monotonic, in file order
    assert all(m[1] == m[2] for m in messages)       # no reset: log time == simulation time
    # clutch: the state at t = 0, then every switch at its exact event time
    clutch = [(m[1], deserialize_message(m[3], Bool).data) for m in messages
              if m[0] == '/clutch_engaged']
    assert clutch[0] == (0, bool(result.samples[0, COL['engaged']]))
    assert clutch[1:] == [(round(s.t * 1e9), s.engaged) for s in switches]
    # each switch sits between the samples around it, as the node publishes it
    order = [m[0] for m in messages]
    first_switch = order.index('/clutch_engaged', 1)
    assert messages[first_switch - 1][1] <= messages[first_switch][1] <= \
        messages[first_switch + 1][1]
    js = [deserialize_message(m[3], JointState) for m in messages if m[0] == '/joint_states']
    for msg, row in zip(js, result.samples, strict=True):
        assert I.time_to_ns(msg.header.stamp) == round(row[COL['t']] * 1e9)
        assert list(msg.name) == list(I.DEVICE_JOINTS)      # J1..J4 and the actuator, as the node
        assert list(msg.position) == list(row[[COL[c] for c in I.POSITION_COLUMNS]]) + [
            row[COL['crank_length']]]
        assert list(msg.velocity)[:4] == list(row[[COL[c] for c in I.VELOCITY_COLUMNS]])
        assert abs(msg.velocity[4]) < 1e-12                  # the crank length does not move
        assert list(msg.effort)[:4] == list(row[[COL[c] for c in I.EFFORT_COLUMNS]])
    clocks = [I.time_to_ns(deserialize_message(m[3], Clock).clock) for m in messages
              if m[0] == '/clock']
    assert clocks == [round(t * 1e9) for t in result.samples[:, COL['t']]]


def test_run_recording_read_by_rosbags(paper_run):
    path, result = paper_run
    switches = [s for s in result.switches if s.kind != 'graze']
    with AnyReader([path]) as reader:
        counts = dict(dict.fromkeys(TYPES, 0), **{
            '/joint_states': len(result.samples), '/clock': len(result.samples),
            '/clutch_engaged': len(switches) + 1})
        assert {c.topic: (c.msgtype, c.msgcount) for c in reader.connections} == {
            topic: (TYPES[topic], count) for topic, count in counts.items()}
        got = [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
    js = [(t, m) for topic, t, m in got if topic == '/joint_states']
    assert len(js) == len(result.samples)
    for (t, msg), row in zip(js, result.samples, strict=True):
        assert t == round(row[COL['t']] * 1e9) == I.time_to_ns(msg.header.stamp)
        assert list(msg.name) == list(I.DEVICE_JOINTS)
        values = I.decode_joint_state(msg)   # the decoder takes rosbags objects too
        assert values.position == tuple(row[[COL[c] for c in I.POSITION_COLUMNS]])
        assert values.velocity == tuple(row[[COL[c] for c in I.VELOCITY_COLUMNS]])
        assert values.effort == tuple(row[[COL[c] for c in I.EFFORT_COLUMNS]])
    clutch = [(t, m.data) for topic, t, m in got if topic == '/clutch_engaged']
    assert clutch[1:] == [(round(s.t * 1e9), s.engaged) for s in switches]


def test_cli_run_mcap_and_target_errors(tmp_path):
    out = tmp_path / 'cli.mcap'
    proc = subprocess.run([*CLI, 'run', 'paper', '--duration', '0.2', '--mcap', str(out)],
                          capture_output=True, text=True, timeout=120, env=child_env())
    assert proc.returncode == 0, proc.stderr
    assert f'messages → {out}' in proc.stdout
    info = summary(out)
    assert info.complete and info.topics['/joint_states'].message_count == 201
    for args, fragment in (
            ([str(out)], 'file exists (use --overwrite'),
            ([str(tmp_path / 'no' / 'dir.mcap')], 'no such directory'),
            ([str(tmp_path)], 'is a directory')):
        bad = subprocess.run([*CLI, 'run', 'paper', '--duration', '0.1', '--mcap', *args],
                             capture_output=True, text=True, timeout=120, env=child_env())
        assert bad.returncode == 2 and fragment in bad.stderr, bad.stderr
        assert 'Traceback' not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    again = subprocess.run([*CLI, 'run', 'paper', '--duration', '0.1', '--mcap', str(out),
                            '--overwrite'], capture_output=True, text=True, timeout=120,
                           env=child_env())
    assert again.returncode == 0 and summary(out).topics['/clock'].message_count == 101


# ---------------------------------------------------------------------------------- the node's hook
def test_node_hook_keeps_log_times_monotonic_across_resets(tmp_path):
    """write(topic, msg, t_ns) as the node calls it: rclpy messages, a command trailing a switch
    written by the other thread, and a ~/reset that sends simulation time back to 0."""
    path = tmp_path / 'node.mcap'
    rec = SimulationRecorder(path, namespace='/line1', source='cvt_sim node',
                             joint_names=['l1_' + j for j in I.JOINTS])
    topics = rec.topics
    assert topics['joint_states'] == '/line1/joint_states' and topics['clock'] == '/clock'
    row = np.zeros(len(COL))
    js = JointState()

    def sample(t):
        row[COL['t']] = t
        row[COL['phi1']] = 100.0 * t
        I.joint_state_from_row(row, names=['l1_' + j for j in I.JOINTS], msg=js)
        rec.write(topics['joint_states'], js, I.stamp_ns(t))

    rec.write(topics['clutch_engaged'], I.clutch_msg(False), 0)
    for k in range(11):
        sample(k * 0.1)
    rec.write(topics['clutch_engaged'], I.clutch_msg(True), I.stamp_ns(1.05))
    rec.write(topics['crank_length_cmd'], I.command_msg(0.04), I.stamp_ns(1.0))  # trails
    sample(1.1)
    rec.mark_reset()
    # a command the executor stamped with the last sample just before the reset: old epoch
    rec.write(topics['load_torque_cmd'], I.command_msg(2.0), I.stamp_ns(1.1))
    rec.write(topics['clutch_engaged'], I.clutch_msg(False), 0)
    for k in range(4):
        sample(k * 0.1)
    rec.write(topics['load_torque_cmd'], I.command_msg(3.0), I.stamp_ns(0.3))
    sample(0.4)
    rec.close()
    got = list(read_messages(path))
    logs = [m.log_time_ns for m in got]
    assert logs == sorted(logs)
    assert [m.publish_time_ns for m in got if m.topic == '/line1/joint_states'] == \
        [I.stamp_ns(k * 0.1) for k in range(12)] + [I.stamp_ns(k * 0.1) for k in range(5)]
    command = next(m for m in got if m.topic == '/line1/crank_length_cmd')
    assert command.publish_time_ns == I.stamp_ns(1.0) and command.log_time_ns == I.stamp_ns(1.05)
    after = [m for m in got if m.log_time_ns >= I.stamp_ns(1.1)]
    assert [m.topic for m in after[:3]] == ['/line1/joint_states', '/line1/load_torque_cmd',
                                            '/line1/clutch_engaged']
    assert after[1].log_time_ns == after[2].log_time_ns == I.stamp_ns(1.1)
    assert after[2].publish_time_ns == 0
    # the second epoch continues from the last log time: 1.1 s + its simulation time
    last = [m for m in got if m.topic == '/line1/joint_states'][-1]
    assert last.log_time_ns == I.stamp_ns(1.1) + I.stamp_ns(0.4)
    assert summary(path).topics['/line1/load_torque_cmd'].message_count == 2


def test_recorder_reports_io_errors_once_and_the_simulation_goes_on(tmp_path):
    with pytest.raises(RecordingError, match='No such file'):
        SimulationRecorder(tmp_path / 'missing' / 'x.mcap')
    (tmp_path / 'exists.mcap').write_bytes(b'keep')
    with pytest.raises(RecordingError, match='file exists'):
        SimulationRecorder(tmp_path / 'exists.mcap')
    child = '''
import json, resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (40_000, 40_000))
from cvt_ros.scene import load_scene
from cvt_ros.solver.simulator import Simulator
from cvt_ros.recording.recorder import SimulationRecorder
errors = []
sim = Simulator(load_scene('paper'))
rec = SimulationRecorder(sys.argv[1], parameters=sim.values, on_error=errors.append,
                         chunk_size=4096, flush_interval=None)
def step():
    for sw in sim.advance(1e-3):
        rec.record_switch(sw)
    return rec.record_sample(sim.sample())
accepted = steps = 0
while not rec.failed and steps < 100_000:   # the writer thread meets the limit at its pace
    accepted += step()
    steps += 1
after = sum(step() for _ in range(500))     # the simulation goes on, nothing more is taken
rec.close()
print(json.dumps({'t': sim.t, 'errors': [str(e) for e in errors], 'failed': rec.failed,
                  'accepted': accepted, 'steps': steps, 'after': after}))
'''
    proc = subprocess.run([sys.executable, '-c', child, str(tmp_path / 'full.mcap')],
                          capture_output=True, text=True, timeout=120, env=child_env())
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out['failed'] and out['steps'] < 100_000
    assert math.isclose(out['t'], (out['steps'] + 500) * 1e-3)
    assert len(out['errors']) == 1 and 'File too large' in out['errors'][0]
    assert out['accepted'] > 50 and out['after'] == 0
    with pytest.warns(RecordingReadWarning, match='truncated'):
        readable = list(read_messages(tmp_path / 'full.mcap', strict=False))
    assert len(readable) > 50


# ---------------------------------------------------------------------------------- signals
LIVE_CHILD = '''
import signal, sys, time
from cvt_ros.scene import load_scene
from cvt_ros.solver.simulator import Simulator
from cvt_ros.recording.recorder import SimulationRecorder
sim = Simulator(load_scene('paper'))
rec = SimulationRecorder(sys.argv[1], parameters=sim.values, scene='paper', source='live test')
def finish(signum, frame):
    rec.close()
    print('finished', rec.message_count, flush=True)
    sys.exit(0)
if sys.argv[2] == 'handler':
    signal.signal(signal.SIGTERM, finish)
    signal.signal(signal.SIGINT, finish)
rec.record_clutch_state(sim.engaged, 0.0)
rec.record_sample(sim.sample())
print('ready', flush=True)
dt, k, wall0 = 1e-3, 0, time.monotonic()
try:
    with rec:
        while True:  # real time, 1 kHz, as the node's loop
            for sw in sim.advance(dt):
                rec.record_switch(sw)
            rec.record_sample(sim.sample())
            rec.record_clock(sim.t)
            k += 1
            if k % 50 == 0:
                print(f'{round(sim.t * 1e9)} {time.monotonic_ns()}', flush=True)
            pause = wall0 + k * dt - time.monotonic()
            if pause > 0:
                time.sleep(pause)
except KeyboardInterrupt:
    print('finished', rec.message_count, flush=True)
'''


def _progress_until(proc, sim_ns, wall_ns):
    """Until the live child (printing simulation ns, monotonic ns) has run ``sim_ns`` of
    simulated time over at least ``wall_ns`` of wall time."""
    return progress_until(proc, lambda first, last: last[0] >= sim_ns and
                          last[1] - first[1] >= wall_ns)


def _start_live(path, mode):
    proc = subprocess.Popen([sys.executable, '-c', LIVE_CHILD, str(path), mode], env=child_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if line.strip() != 'ready':
        proc.kill()
        raise AssertionError(f'child did not start: {line!r} {proc.stderr.read()}')
    return proc


@pytest.mark.parametrize('signum, mode', [(signal.SIGTERM, 'handler'),
                                          (signal.SIGINT, 'with')])
def test_signal_finishes_a_valid_file(tmp_path, signum, mode):
    path = tmp_path / 'signalled.mcap'
    proc = _start_live(path, mode)
    _progress_until(proc, 400_000_000, 0)
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    written = int(out.split()[-1])
    info = summary(path)
    assert info.complete and not info.problems and info.message_count == written
    with AnyReader([path]) as reader:  # strict second reader
        assert sum(c.msgcount for c in reader.connections) == written
    samples = [m for m in read_messages(path, '/joint_states')]  # strict: raises if damaged
    assert len(samples) > 300
    stamps = [m.log_time_ns for m in samples]
    assert stamps == [k * 1_000_000 for k in range(len(stamps))]


def test_sigkill_loses_nothing_already_on_disk_and_recovers(tmp_path):
    path = tmp_path / 'killed.mcap'
    proc = _start_live(path, 'handler')
    progress = _progress_until(proc, 1_600_000_000, 2_000_000_000)
    must = progress[-1][0]   # the child's latest sample: kill once its file holds it
    wait_on_disk(path, '/joint_states', lambda messages: messages and
                 messages[-1].log_time_ns >= must)
    proc.kill()
    out, _ = proc.communicate(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    fixed = tmp_path / 'killed.recovered.mcap'
    proc = subprocess.run([*CLI, 'recover', str(path)], capture_output=True, text=True,
                          timeout=60, env=child_env())
    assert proc.returncode == 0, proc.stderr
    assert f'→ {fixed}' in proc.stdout and '/joint_states' in proc.stdout
    info = summary(fixed)
    assert info.complete and not info.problems
    assert METADATA_NAME in info.metadata  # the scene parameters were on disk from the start
    stamps = [m.log_time_ns for m in read_messages(fixed, '/joint_states')]
    assert stamps == [k * 1_000_000 for k in range(len(stamps))]
    assert stamps[-1] >= must
    with AnyReader([fixed]) as reader:
        assert {c.topic: c.msgcount for c in reader.connections}['/joint_states'] == len(stamps)


# ---------------------------------------------------------------------------------- cost
def test_benchmark_reports_the_cost_per_message():
    result = benchmark(2000)
    assert 0 < result['sample_us'] < 200 and 0 < result['clock_us'] < 200
    assert 0 < result['rclpy_joint_state_us'] < 500 and 150 < result['bytes_per_sample'] < 600
