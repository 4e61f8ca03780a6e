"""The pytest plugin as a user meets it: a test file of a few lines, run by pytest."""
import subprocess
import sys
import textwrap

USER_TESTS = '''
import pytest


class Stubborn:
    """A controller that never moves the crank."""

    def __call__(self, m):
        return None


def test_reference_controller_rejects_the_load_step(cvt_device):
    run = cvt_device.run('conveyor_load_step', duration=6.0)
    assert cvt_device.backend == 'lockstep' and run.backend == 'lockstep'
    assert run.ok, run.error
    assert run.metrics['max_deviation'] < 1.0


def test_a_stubborn_controller_misses_the_set_point(cvt_device):
    run = cvt_device.run('conveyor_setpoint_steps', controller=Stubborn(), duration=5.0)
    assert run.steps[1]['steady_state_error'] > 10.0


@pytest.mark.cvt_backend('offline')
def test_marker_picks_the_back_end(cvt_device):
    run = cvt_device.run('conveyor_load_step', controller=lambda m: float('nan'), duration=1.0)
    assert run.backend == 'offline'
    assert not run.ok and 'not a finite crank length' in run.error
'''


def test_a_user_test_file_runs_with_the_plugin(tmp_path):
    (tmp_path / 'test_user.py').write_text(textwrap.dedent(USER_TESTS))
    env = {'PYTEST_DISABLE_PLUGIN_AUTOLOAD': '1'}
    import os
    env = dict(os.environ, **env)
    done = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'cvt_ros.testing.plugin',
                           '-p', 'no:cacheprovider', str(tmp_path)], capture_output=True,
                          text=True, timeout=600, cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stdout + done.stderr
    assert '3 passed' in done.stdout
    other = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'cvt_ros.testing.plugin',
                            '-p', 'no:cacheprovider', '--cvt-backend', 'offline', '-k',
                            'load_step', str(tmp_path)], capture_output=True, text=True,
                           timeout=600, cwd=tmp_path, env=env)
    assert other.returncode == 1 and '1 failed' in other.stdout and "'offline'" in other.stdout


def test_plugin_names_the_harness_back_ends():
    from cvt_ros.scenario import BACKENDS
    from cvt_ros.testing.plugin import BACKENDS as PLUGIN_BACKENDS
    assert PLUGIN_BACKENDS == BACKENDS
