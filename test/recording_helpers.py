"""Shared by the recording and analysis tests: the environment of a child process, waiting for
a child's own progress reports and for its file to hold what it wrote (so that a slow machine
only takes longer)."""
import os
import sys
import time
import warnings
from pathlib import Path

from cvt_ros.recording import RecordingReadWarning, read_messages

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


def on_disk(path, topic):
    """The messages of ``topic`` in the complete chunks of a file a live writer still writes."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RecordingReadWarning)
        return list(read_messages(path, [topic], strict=False))


def wait_on_disk(path, topic, enough, timeout=120.0):
    """Poll a file being written until ``enough(messages of topic)`` holds: a handshake with the
    writer's background flush (chunks close at least every flush_interval of wall time, but a
    busy machine may starve the writer's thread). Returns the last list read."""
    deadline = time.monotonic() + timeout
    while True:
        messages = on_disk(path, topic)
        if enough(messages) or time.monotonic() > deadline:
            return messages
        time.sleep(0.1)
