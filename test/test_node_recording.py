"""The node records what it publishes and receives (record.path) into a rosbag2-compatible MCAP,
read back by two independent readers; SIGINT finalizes the file, SIGKILL loses nothing already
on disk (chunks close at least every 0.5 s: test_recording.test_idle_data_is_flushed_by_time)."""
import signal

from mcap.reader import make_reader
from node_harness import NodeProcess, Probe, domain_id, wait_for
from recording_helpers import wait_on_disk
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from cvt_ros.analysis.bag import load_mcap
from cvt_ros.recording import read_messages, recover
from cvt_ros.recording import summary as summary_of


def run_node(tmp_path, stop_signal, commands=True, until_on_disk=False):
    """Run the node recording in fast mode; returns (path, exit code, output, the stamp [ns] of
    the last sample received before the stop signal). ``until_on_disk``: the signal waits until
    the running node's file holds that sample (a handshake with the recorder, not a sleep: a busy
    machine only takes longer)."""
    path = tmp_path / 'run.mcap'
    domain = domain_id()
    mark = None
    with NodeProcess(domain, ['-p', f'record.path:={path}', '-p', 'time_mode:=fast',
                              '-p', 'publish_rate:=1000.0']) as proc:
        probe = Probe(domain)
        try:
            joints = probe.subscribe(JointState, 'joint_states')
            assert wait_for(lambda: len(joints) > 200, 180.0), proc.output()
            if commands:
                crank = probe.publisher(Float64, 'crank_length_cmd')
                assert wait_for(lambda: crank.get_subscription_count() > 0, 10.0)
                crank.publish(Float64(data=0.05))
                crank.publish(Float64(data=float('nan')))   # refused, but still recorded
                crank.publish(Float64(data=0.2))            # beyond Grashof: refused too
                result = probe.set_parameters('/cvt_sim', **{'load.torque': 9.0})[0]
                assert result.successful, result.reason
            assert wait_for(lambda: len(joints) > 2500, 60.0), proc.output()
            last = joints.last()
            mark = last.header.stamp.sec * 10**9 + last.header.stamp.nanosec
            if until_on_disk:   # the node keeps running and recording meanwhile
                written = wait_on_disk(path, '/joint_states', lambda messages: messages and
                                       messages[-1].log_time_ns >= mark)
                assert written and written[-1].log_time_ns >= mark, (
                    f'sample {mark} ns not on disk after 120 s', proc.output())
        finally:
            probe.close()
        code, _ = proc.stop(stop_signal)
        return path, code, proc.output(), mark


def test_sigint_leaves_a_complete_bag_that_independent_readers_accept(tmp_path):
    path, code, output, _ = run_node(tmp_path, signal.SIGINT)
    assert code == 0, output
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert reader.get_header().profile == 'ros2'
        topics = {c.topic: c for c in summary.channels.values()}
        for name in ('/joint_states', '/clutch_engaged', '/clock', '/crank_length_cmd'):
            assert name in topics
            assert topics[name].message_encoding == 'cdr'
            assert topics[name].metadata['topic_type_hash'].startswith('RIHS01_')
        counts = {topics_by_id.topic: n for topics_by_id, n in
                  ((summary.channels[cid], n)
                   for cid, n in summary.statistics.channel_message_counts.items())}
        assert counts['/joint_states'] > 2000
        assert counts['/crank_length_cmd'] == 3
    with AnyReader([path]) as reader:
        stamps = []
        for conn, log_ns, raw in reader.messages(
                connections=[c for c in reader.connections if c.topic == '/joint_states']):
            msg = reader.deserialize(raw, conn.msgtype)
            stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
            assert log_ns == stamps[-1]   # log time = simulation time of the sample
            assert list(msg.name) == ['crank', 'rocker', 'clutch_output', 'output_shaft',
                                      'crank_length']
    assert all(b - a == 1_000_000 for a, b in zip(stamps, stamps[1:], strict=False))
    # the live change is in the recording (a metadata record at its simulation time), and the
    # analysis takes it as the load command it is; the refused commands are left out
    changes = [m for name, m in summary_of(path).metadata_records
               if name == 'cvt_ros.parameter_change']
    assert len(changes) == 1 and 'load.torque: 9.0' in changes[0]['parameters'], changes
    (trace,), _ = load_mcap(str(path))
    assert sorted((c.key, c.value) for c in trace.commands) == [('crank_length_cmd', 0.05),
                                                               ('load_torque_cmd', 9.0)]
    assert any('1 command(s) outside the node' in note for note in trace.notes), trace.notes
    switches = [m for m in read_messages(path, ['/clutch_engaged'])]
    assert len(switches) > 10
    values = [m.message().data for m in switches]
    assert all(a != b for a, b in zip(values[1:], values[2:], strict=False))  # alternating


def test_sigkill_loses_nothing_already_on_disk(tmp_path):
    path, code, output, mark = run_node(tmp_path, signal.SIGKILL, commands=False,
                                        until_on_disk=True)
    assert code == -signal.SIGKILL, output
    fixed = tmp_path / 'fixed.mcap'
    n = recover(path, fixed)
    stamps = [m.log_time_ns for m in read_messages(fixed, ['/joint_states'])]
    assert n > 0
    # everything the running node had put on disk survives the kill, without gaps from the start
    assert mark in stamps
    assert stamps[:stamps.index(mark) + 1] == [1_000_000 * k for k in
                                               range(stamps.index(mark) + 1)]
