"""Test environment: ROS wheels found through the venv, DDS kept on this host and per run.

Each pytest process holds a ROS domain of its own for its whole life, allocated machine-wide
(``cvt_ros.device.domains``: a lock per domain id, released when the process ends, however it
ends), so concurrent runs on one machine (several developers, CI) never see each other; its
subprocesses inherit ROS_DOMAIN_ID. Tests that start nodes take a further domain each
(``node_harness.domain_id``). An exported ROS_DOMAIN_ID of an ad-hoc session is not used.
"""
import os
import signal
import sys

from cvt_ros.device import domains

# Tests stop their children with SIGINT (Ctrl-C) and check that files are finished. A suite started
# in the background by a script (``./run.sh test &``) inherits SIGINT *ignored*, and so would every
# child it starts: give this process, and through it the children, the default disposition.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
_SESSION_DOMAIN = domains.acquire()
os.environ['ROS_DOMAIN_ID'] = str(_SESSION_DOMAIN.domain)
