"""`cvt-sim analyze` of a real node recording (issue 13): the node stores its scene and full
parameter set, the actual crank length it publishes is read back, and the whole-run figures
(start-up included) equal what an independent reader (rosbags) finds in the same file."""
import signal

import numpy as np
import yaml
from node_harness import NodeProcess, Probe, domain_id, wait_for
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from cvt_ros import interface as I
from cvt_ros.analysis import analyze_trace, load
from cvt_ros.recording import summary
from cvt_ros.recording.recorder import METADATA_NAME


def test_node_recording_analysed_against_an_independent_reader(tmp_path):
    path = tmp_path / 'node.mcap'
    domain = domain_id()
    with NodeProcess(domain, ['-p', f'record.path:={path}', '-p', 'time_mode:=fast',
                              '-p', 'publish_rate:=1000.0'], args=['--scene', 'paper']) as proc:
        probe = Probe(domain)
        try:
            joints = probe.subscribe(JointState, 'joint_states')
            assert wait_for(lambda: len(joints) > 300, 180.0), proc.output()
            crank = probe.publisher(Float64, 'crank_length_cmd')
            assert wait_for(lambda: crank.get_subscription_count() > 0, 10.0)
            crank.publish(Float64(data=0.04))
            # wait for the command's effect, not for a number of samples: delivery to a reader
            # that has only just matched may wait for a heartbeat, and a fast node on a fast
            # machine publishes thousands of samples meanwhile (it once ended the run first)
            crank_at = I.DEVICE_JOINTS.index(I.ACTUATOR_JOINT)
            assert wait_for(lambda: (m := joints.last()) is not None
                            and m.position[crank_at] > 0.0301, 120.0), proc.output()
            assert wait_for(lambda: len(joints) > 2500, 120.0), proc.output()
        finally:
            probe.close()
        code, _ = proc.stop(signal.SIGINT)
    assert code == 0, proc.output()

    meta = summary(path).metadata[METADATA_NAME]
    assert meta['scene'] == 'paper'
    recorded = yaml.safe_load(meta['parameters'])
    assert recorded['time_mode'] == 'fast' and recorded['publish_rate'] == 1000.0
    assert recorded['inertia.output'] == 0.5 and 'solver.method' in recorded

    # the truth, read with rosbags (types from the file's own definitions)
    efforts, names, stamps, crank_lengths = [], None, [], []
    switches = 0
    with AnyReader([path]) as reader:
        for connection, _, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            if connection.topic == '/joint_states':
                names = list(msg.name)
                stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
                efforts.append(list(msg.effort))
                crank_lengths.append(msg.position[names.index(I.ACTUATOR_JOINT)])
            elif connection.topic == '/clutch_engaged':
                switches += 1
    assert names == list(I.DEVICE_JOINTS) and stamps[0] == 0        # from the start-up on
    efforts = np.array(efforts)

    (trace,), info = load(str(path))
    assert not info.problems and info.scene == 'paper'
    assert trace.crank_length_source == 'recorded'
    assert np.array_equal(trace.crank_length, crank_lengths)
    assert trace.crank_length[-1] > 0.03                       # the command moved it
    result = analyze_trace(trace)
    whole = result.whole_run
    assert whole['clutch_torque_peak'] == efforts[:, 1].max()   # start-up included
    assert whole['motor_torque_peak'] == efforts[:, 0].max()
    # clutch_engaged: the state at start-up, then one message per switch
    assert whole['switches'] == switches - 1
    assert [c.value for c in trace.commands] == [0.04]
