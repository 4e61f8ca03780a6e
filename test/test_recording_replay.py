"""`cvt-sim replay`: a recording back onto ROS 2 topics, received by a separate rclpy process.

The subscriber takes the messages as serialized bytes (``raw=True``); they are compared with the
recording after deserialization (DDS pads a payload to 4 bytes, so a 5-byte Bool arrives as 8).
"""
import json
import signal
import subprocess
import sys
import time

import pytest
from node_harness import domain_id, ros_env
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64

from cvt_ros.recording import read_messages
from cvt_ros.recording.recorder import SimulationRecorder
from cvt_ros.scene import load_scene
from cvt_ros.solver.simulator import Simulator

CLI = [sys.executable, '-m', 'cvt_ros']
TYPES = {'/joint_states': JointState, '/clutch_engaged': Bool, '/clock': Clock,
         '/crank_length_cmd': Float64, '/load_torque_cmd': Float64}


def _decode(topic, hexes):
    return [deserialize_message(bytes.fromhex(h), TYPES[topic]) for h in hexes]


def _messages(topic, recorded):
    return [m.message() for m in recorded.get(topic, [])]


def _same(messages):
    """Messages as comparable text (the actuator joint's effort is NaN, and NaN != NaN)."""
    return [repr(m) for m in messages]

SUBSCRIBER = '''
import json, sys, time
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
out, expect, timeout = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
rclpy.init()
node = rclpy.create_node('replay_probe')
types = {'/joint_states': JointState, '/clutch_engaged': Bool, '/clock': Clock,
         '/crank_length_cmd': Float64, '/load_torque_cmd': Float64}
got = {topic: [] for topic in types}
for topic, cls in types.items():
    qos = QoSProfile(depth=10000)
    if topic == '/clock':
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    if topic == '/clutch_engaged':
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    node.create_subscription(cls, topic, lambda data, topic=topic: got[topic].append(data.hex()),
                             qos, raw=True)
print('ready', flush=True)
end = time.monotonic() + timeout
got['clutch_qos'] = None
while time.monotonic() < end and len(got['/joint_states']) < expect:
    rclpy.spin_once(node, timeout_sec=0.05)
    if got['clutch_qos'] is None and got['/joint_states']:  # the player is running: its QoS
        got['clutch_qos'] = [[p.qos_profile.durability.name, p.qos_profile.reliability.name]
                             for p in node.get_publishers_info_by_topic('/clutch_engaged')]
settle = time.monotonic() + 0.3
while time.monotonic() < settle:
    rclpy.spin_once(node, timeout_sec=0.05)
with open(out, 'w') as f:
    json.dump(got, f)
'''


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """0.4 s of the paper scene at 1 ms with two commands, recorded as the node would."""
    path = tmp_path_factory.mktemp('replay') / 'replay.mcap'
    sim = Simulator(load_scene('paper'))
    with SimulationRecorder(path, parameters=sim.values, scene='paper', source='test') as rec:
        rec.record_clutch_state(sim.engaged, 0.0)
        rec.record_sample(sim.sample())
        rec.record_clock(0.0)
        for i in range(400):
            if i in (150, 300):
                rec.record_command('crank_length_cmd', 0.03 + i * 1e-5, sim.t)
                sim.command_crank_length(0.03 + i * 1e-5)
            for sw in sim.advance(1e-3):
                rec.record_switch(sw)
            rec.record_sample(sim.sample())
            rec.record_clock(sim.t)
    return path


def _recorded(path):
    out = {}
    for m in read_messages(path):
        out.setdefault(m.topic, []).append(m)
    return out


def _start_subscriber(env, out, expect, timeout=30.0):
    proc = subprocess.Popen([sys.executable, '-c', SUBSCRIBER, str(out), str(expect),
                             str(timeout)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    # Fast DDS may print its own log lines first (shared-memory port files of a busy machine)
    for _ in range(50):
        line = proc.stdout.readline()
        if not line or line.strip() == 'ready':
            break
    assert line.strip() == 'ready', proc.stderr.read()
    return proc


def test_replay_is_received_with_the_same_content_and_order(recording, tmp_path):
    env = ros_env(domain_id())
    recorded = _recorded(recording)
    n_js = len(recorded['/joint_states'])
    sub = _start_subscriber(env, tmp_path / 'got.json', n_js)
    replay = subprocess.run([*CLI, 'replay', str(recording), '--rate', '1',
                             '--wait-for-subscribers', '--delay', '0.5'],
                            env=env, capture_output=True, text=True, timeout=60)
    assert replay.returncode == 0, replay.stderr
    assert f'published {sum(len(v) for v in recorded.values())} messages' in replay.stdout
    sub.communicate(timeout=40)
    got = json.loads((tmp_path / 'got.json').read_text())
    for topic in ('/joint_states', '/clutch_engaged', '/crank_length_cmd'):
        assert _same(_decode(topic, got[topic])) == _same(_messages(topic, recorded)), topic
    assert len(got['/crank_length_cmd']) == 2
    clock = _messages('/clock', recorded)
    received = _decode('/clock', got['/clock'])
    assert len(received) >= 0.95 * len(clock)            # best effort, as the node offers it
    it = iter(clock)
    assert all(c in it for c in received)                # in order, nothing invented
    # the recorded QoS (the graph carries no depth): clutch_engaged stays latched
    assert got['clutch_qos'] == [['TRANSIENT_LOCAL', 'RELIABLE']]


def test_replay_topic_filter_own_clock_loop_and_ctrl_c(recording, tmp_path):
    env = ros_env(domain_id())
    recorded = _recorded(recording)
    replay = subprocess.Popen([*CLI, 'replay', str(recording), '--topics', '/joint_states',
                               '/clutch_engaged', '--loop', '--rate', '1', '--delay', '0'],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    try:
        sub = _start_subscriber(env, tmp_path / 'got.json', 600, timeout=20)
        sub.communicate(timeout=40)
        time.sleep(0.2)
        replay.send_signal(signal.SIGINT)
        out, err = replay.communicate(timeout=20)
    finally:
        if replay.poll() is None:
            replay.kill()
    assert replay.returncode == 0, err
    assert 'Traceback' not in err and 'interrupted: published' in out
    assert 'publishing /clock from the log times' in out
    got = json.loads((tmp_path / 'got.json').read_text())
    assert got['/crank_length_cmd'] == []                 # filtered out
    js = _same(_messages('/joint_states', recorded))
    received = _same(_decode('/joint_states', got['/joint_states']))
    assert len(received) >= 600
    # looping: the recording's sequence, again and again, from wherever the subscriber joined
    start = js.index(received[0])
    assert received == [js[(start + i) % len(js)] for i in range(len(received))]
    # /clock made by the player from the log times: the times of the recorded messages
    log_times = {m.log_time_ns for t in ('/joint_states', '/clutch_engaged')
                 for m in recorded[t]}
    clock = [c.clock.sec * 10**9 + c.clock.nanosec for c in _decode('/clock', got['/clock'])]
    assert len(clock) > 300 and set(clock) <= log_times


def test_replay_errors_are_one_line(recording, tmp_path):
    env = ros_env(domain_id())
    proc = subprocess.run([*CLI, 'replay', str(recording), '--topics', '/nope', '--delay', '0'],
                          env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and 'not in the recording' in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(recording.read_bytes()[:int(recording.stat().st_size * 0.7)])
    proc = subprocess.run([*CLI, 'replay', str(cut), '--rate', '50', '--delay', '0'],
                          env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and 'done: published' in proc.stdout
    assert 'truncated' in proc.stderr and 'Traceback' not in proc.stderr
