"""ROS domain ids handed out machine-wide, so that test runs, benchmarks and demos started at the
same time on one machine (several developers, CI) never share a DDS domain.

A domain is held by an exclusive ``flock`` on ``<tmp>/cvt_ros-ros-domains/<id>.lock``. The kernel
drops the lock when the last process that holds the open file ends, by any means (exit, crash,
SIGKILL): no lock goes stale, and no pid needs checking. A child process that inherits the lock's
descriptor (``subprocess.Popen(..., pass_fds=[lease.fd])``) keeps the domain held after its parent
died, so a node orphaned by a killed test run never shares a domain with the next run.

Which ids: ROS 2 on Linux allows 0–101 and 215–232 (docs.ros.org, "The ROS_DOMAIN_ID"); the
project keeps 0–20 and 215–232 for developers' ad-hoc runs (one range per room), so programs that
allocate use 21–101. No rclpy here.
"""
import errno
import fcntl
import os
import tempfile
import time
from pathlib import Path

#: Domains that programs allocate (tests, benchmarks, demos). Ad-hoc ranges stay outside.
ALLOCATED_DOMAINS = tuple(range(21, 102))
#: Where the lock files live (one per domain id, shared by every user of the machine).
LOCK_DIR = Path(tempfile.gettempdir()) / 'cvt_ros-ros-domains'
POLL_S = 0.2   # all domains taken: look again this often


class DomainsExhausted(RuntimeError):
    """Every candidate domain stayed held for the whole timeout."""


class DomainLease:
    """One held domain: ``domain`` (the id), ``fd`` (the locked descriptor; pass it to children
    that should keep the domain held). ``release()`` (or leaving the ``with`` block) frees it;
    so does the end of every process holding ``fd``."""

    def __init__(self, domain, fd):
        self.domain = domain
        self.fd = fd

    def release(self):
        if self.fd is not None:
            os.close(self.fd)   # the lock goes with the last descriptor of this open file
            self.fd = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()

    def __repr__(self):
        return f"DomainLease(domain={self.domain}, held={self.fd is not None})"


def _lock_dir():
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    try:   # every user of the machine must be able to add lock files (sticky, like /tmp)
        if LOCK_DIR.stat().st_uid == os.getuid():
            LOCK_DIR.chmod(0o1777)
    except OSError:
        pass
    return LOCK_DIR


def try_acquire(domain):
    """Hold ``domain`` if no other process does; a DomainLease, or None when it is taken."""
    path = _lock_dir() / f"{domain}.lock"
    # read-only is enough for flock, so a lock file made by another user works too
    fd = os.open(path, os.O_RDONLY | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return None
        raise
    return DomainLease(domain, fd)


_next = [os.getpid()]   # where this process looks first: spreads concurrent runs apart


def acquire(candidates=ALLOCATED_DOMAINS, timeout=120.0):
    """Hold a free domain out of ``candidates``; waits up to ``timeout`` [s] when all are held.

    Successive calls in one process start their search at successive ids, and processes start at
    their pid's place in the list, so runs that start together rarely contend for one lock.
    Raises DomainsExhausted after ``timeout``.
    """
    candidates = tuple(candidates)
    if not candidates:
        raise ValueError('no candidate domains')
    end = time.monotonic() + timeout
    while True:
        start = _next[0]
        for i in range(len(candidates)):
            domain = candidates[(start + i) % len(candidates)]
            lease = try_acquire(domain)
            if lease is not None:
                _next[0] = start + i + 1
                return lease
        if time.monotonic() > end:
            raise DomainsExhausted(
                f"all {len(candidates)} ROS domains {candidates[0]}–{candidates[-1]} are held by "
                f"other processes (lock files in {LOCK_DIR}); wait for runs to end")
        time.sleep(POLL_S)


__all__ = ['ALLOCATED_DOMAINS', 'DomainLease', 'DomainsExhausted', 'LOCK_DIR', 'acquire',
           'try_acquire']
