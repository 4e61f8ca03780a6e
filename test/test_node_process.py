"""The node as a process (issue 3): scene files as params files, refusal of a bad scene, and a
clean shutdown on SIGINT and SIGTERM within 2 s."""
import os
import signal
import sys
from pathlib import Path

import pytest
from node_harness import SCENES, NodeProcess, Probe, domain_id, wait_for
from sensor_msgs.msg import JointState

from cvt_ros.scene import load_scene

SHUTDOWN_S = 2.0


def console_script():
    """The `cvt_node` console script next to this interpreter (pip install -e . puts it there)."""
    path = os.path.join(os.path.dirname(sys.executable), 'cvt_node')
    return [path] if os.access(path, os.X_OK) else None


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_signal_shuts_down_cleanly(sig):
    domain = domain_id()
    command = console_script() if sig == signal.SIGINT else None
    with NodeProcess(domain, command=command) as proc:
        probe = Probe(domain)
        try:
            joints = probe.subscribe(JointState, 'joint_states')
            assert wait_for(lambda: len(joints) > 50, 180.0), proc.output()
        finally:
            probe.close()
        code, seconds = proc.stop(sig, timeout=10.0)
        output = proc.output()
    assert code == 0, output
    assert seconds < SHUTDOWN_S, (seconds, output)
    assert 'Traceback' not in output, output


def _loading_rclpy(pid):
    """The process has begun to import rclpy (its extension is mapped): main() is running."""
    try:
        return '_rclpy_pybind11' in Path(f'/proc/{pid}/maps').read_text()
    except OSError:
        return False


@pytest.mark.parametrize('moment', ['imports', 'ready'])
def test_sigint_during_start_up_is_a_clean_stop(moment):
    """SIGINT is how a node is stopped (Ctrl-C, ros2 launch), also while it starts: while it
    imports rclpy and loads its kernels, and right after "ready" (before the executor spins)."""
    domain = domain_id()
    with NodeProcess(domain, command=console_script()) as proc:
        if moment == 'imports':
            assert wait_for(lambda: _loading_rclpy(proc.proc.pid) or not proc.alive(), 60.0)
        else:
            assert wait_for(lambda: 'cvt_sim ready' in proc.output() or not proc.alive(),
                            180.0), proc.output()
        code, _ = proc.stop(signal.SIGINT, timeout=30.0)
        output = proc.output()
    assert code == 0, output
    assert 'Traceback' not in output, output


def test_scene_file_sets_the_parameters_as_offline():
    """--params-file config/scenes/paper.yaml, the node in a namespace (the shipped scenes' key
    /**/cvt_sim applies in any): the node's parameters are the scene's values as the offline
    loader reads them; started in lockstep, its solver is the offline one too (dopri5: rk4 is
    its default only when it starts in realtime)."""
    domain = domain_id()
    path = os.path.join(SCENES, 'paper.yaml')
    with NodeProcess(domain, ['--params-file', path, '-p', 'time_mode:=lockstep',
                              '-r', '__ns:=/line1']) as proc:
        probe = Probe(domain)
        try:
            assert wait_for(lambda: probe.node.count_publishers('/line1/joint_states') > 0,
                            180.0), proc.output()
            expected = load_scene(path)
            names = ['linkage.crank_length', 'inertia.output', 'shaft.stiffness',
                     'motor.breakdown_torque', 'load.torque', 'solver.method', 'time_mode']
            got = probe.get_parameters('/line1/cvt_sim', names)
            assert got == {n: expected[n] if n != 'time_mode' else 'lockstep' for n in names}
        finally:
            probe.close()
        code, seconds = proc.stop(signal.SIGTERM)
        assert code == 0 and seconds < SHUTDOWN_S, proc.output()


def test_scene_with_infinite_stiffness_and_integers(tmp_path):
    """.inf (rigid shaft) and integer values for double parameters are taken from a scene."""
    scene = tmp_path / 'rigid.yaml'
    scene.write_text('cvt_sim:\n  ros__parameters:\n    shaft:\n      stiffness: .inf\n'
                     '    load:\n      torque: 6\n')
    domain = domain_id()
    with NodeProcess(domain, ['--params-file', str(scene), '-p', 'time_mode:=lockstep']) as proc:
        probe = Probe(domain)
        try:
            assert wait_for(lambda: probe.node.count_publishers('/joint_states') > 0, 180.0), \
                proc.output()
            got = probe.get_parameters('/cvt_sim', ['shaft.stiffness', 'load.torque'])
            assert got == {'shaft.stiffness': float('inf'), 'load.torque': 6.0}
        finally:
            probe.close()
        assert proc.stop(signal.SIGINT)[0] == 0, proc.output()


def test_params_file_that_misses_the_node_is_refused_at_start(tmp_path):
    """ROS skips a params file whose top key does not name the node without a word (`cvt_sim:`
    is the root namespace's node only): the node would run the defaults, so it stops instead."""
    scene = tmp_path / 'mixer_root.yaml'
    scene.write_text('cvt_sim:\n  ros__parameters:\n    load:\n      torque: 6.0\n')
    domain = domain_id()
    with NodeProcess(domain, ['--params-file', str(scene), '-r', '__ns:=/line1']) as proc:
        assert wait_for(lambda: not proc.alive(), 180.0)
        output = proc.output()
        assert proc.proc.returncode == 2, output
    assert (f"{scene}: no top key applies to this node, /line1/cvt_sim (the file's keys: "
            "cvt_sim)") in output and "'/**/cvt_sim:'" in output, output
    assert 'Traceback' not in output, output


def test_invalid_scene_is_refused_at_start():
    domain = domain_id()
    with NodeProcess(domain, ['-p', 'linkage.crank_length:=0.15']) as proc:
        assert wait_for(lambda: not proc.alive(), 180.0)
        output = proc.output()
        assert proc.proc.returncode == 2, output
    assert 'linkage.crank_length' in output and '0.15' in output and '0.1' in output, output


def test_unknown_parameter_is_refused_at_start_naming_the_closest():
    domain = domain_id()
    with NodeProcess(domain, ['-p', 'time_mod:=fast']) as proc:
        assert wait_for(lambda: not proc.alive(), 180.0)
        output = proc.output()
        assert proc.proc.returncode == 2, output
    assert 'unknown parameter time_mod (did you mean time_mode?)' in output, output
    assert 'Traceback' not in output, output


def test_bad_disturbance_file_is_refused_at_start(tmp_path):
    path = tmp_path / 'load.csv'
    path.write_text('t,load_torque\n0,8\n1.5,inf\n')
    domain = domain_id()
    with NodeProcess(domain, ['-p', f'disturbance.file:={path}']) as proc:
        assert wait_for(lambda: not proc.alive(), 180.0)
        output = proc.output()
        assert proc.proc.returncode == 2, output
    assert f"disturbance.file: {path}:3: load_torque 'inf' is not a finite number" in output, \
        output
    assert 'Traceback' not in output, output
