"""Test environment: ROS wheels found through the venv, DDS kept on this host and per run.

Each pytest run gets its own ROS_DOMAIN_ID (from its pid) so parallel runs on one machine do not
see each other; subprocesses inherit it. Tests that start several node processes may still pick
a different id of their own.
"""
import os
import sys

os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
