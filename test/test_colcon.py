"""The package builds with colcon in a Jazzy-style workspace and its executables run.

`colcon build` (colcon-common-extensions from PyPI, AMENT_PREFIX_PATH at the venv holding the ROS 2
wheels) installs lib/cvt_ros/<executable>, which is what `ros2 run cvt_ros <executable>` starts.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
IGNORE = shutil.ignore_patterns('.venv', '.git', 'build', 'install', 'log', '__pycache__', '*.nbi',
                                '*.nbc', '.pytest_cache', '.hypothesis', '.ruff_cache', 'out')


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    ws = tmp_path_factory.mktemp('jazzy_ws')
    shutil.copytree(ROOT, ws / 'src' / 'cvt_ros', ignore=IGNORE)
    colcon = Path(sys.executable).with_name('colcon')
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix)
    proc = subprocess.run([str(colcon), 'build'], cwd=ws, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return ws


def sourced(ws, command):
    """Run ``command`` in bash after sourcing the workspace like a ROS user does."""
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix)
    env.pop('PYTHONPATH', None)
    return subprocess.run(['bash', '-c', f'source install/setup.bash && {command}'], cwd=ws,
                          env=env, capture_output=True, text=True, timeout=300)


def test_colcon_installs_the_ament_python_layout(workspace):
    prefix = workspace / 'install' / 'cvt_ros'
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'cvt_ros').exists()
    assert (prefix / 'share' / 'cvt_ros' / 'package.xml').exists()
    assert (prefix / 'share' / 'cvt_ros' / 'config' / 'scenes' / 'paper.yaml').exists()
    exes = sorted(p.name for p in (prefix / 'lib' / 'cvt_ros').iterdir())
    assert 'cvt-sim' in exes


def test_installed_executables_run(workspace):
    lib = workspace / 'install' / 'cvt_ros' / 'lib' / 'cvt_ros'
    for exe in sorted(lib.iterdir()):
        proc = sourced(workspace, f'"{exe}" --help')
        assert proc.returncode == 0, (exe.name, proc.stderr)
        assert 'usage' in proc.stdout.lower(), exe.name


def test_installed_package_finds_its_scenes_from_anywhere(workspace):
    """The installed cvt-sim, started from /, reads the paper scene from the install space's
    share/ (the scene as `cvt-sim run paper` takes it; `params` does not compile the kernels of
    the installed copy: that would be a second fresh compilation in the suite, ~1 min)."""
    exe = workspace / 'install' / 'cvt_ros' / 'lib' / 'cvt_ros' / 'cvt-sim'
    proc = sourced(workspace, f'cd / && "{exe}" params --scene paper '
                              f'&& "{sys.executable}" -c "import cvt_ros; print(cvt_ros.__file__)"')
    assert proc.returncode == 0, proc.stderr
    share = workspace / 'install' / 'cvt_ros' / 'share' / 'cvt_ros' / 'config' / 'scenes'
    assert f'# values: scene {share / "paper.yaml"}' in proc.stdout
    assert str(workspace / 'install') in proc.stdout   # the installed copy, not the source tree
