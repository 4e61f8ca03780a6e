"""Shared by the recording and analysis tests: the environment of a child process and waiting for
a child's own progress reports (so that a slow machine only takes longer)."""
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CLI = [sys.executable, '-m', 'cvt_ros']


def child_env():
    """This environment for a child process: the package importable, the ROS wheels' share/
    found, unbuffered output, plots without a display."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(ROOT), env.get('PYTHONPATH')]))
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    env['PYTHONUNBUFFERED'] = '1'
    env['MPLBACKEND'] = 'Agg'
    return env


def progress_until(proc, done, timeout=120.0):
    """Read a child's progress lines of two integers until ``done(first, latest)`` holds (or
    the child stops printing them); returns the pairs read."""
    progress = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        fields = proc.stdout.readline().split()
        if len(fields) != 2:
            break
        progress.append((int(fields[0]), int(fields[1])))
        if done(progress[0], progress[-1]):
            break
    return progress
