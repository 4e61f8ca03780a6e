"""Machine-wide ROS domain allocation (cvt_ros.device.domains): concurrent processes never get
the same domain, a dead holder frees it, a child that inherited the lock keeps it held."""
import os
import signal
import subprocess
import sys

import pytest

from cvt_ros.device import domains

# lock names outside every real range (no DDS is used here): no run waits for these, and this
# test waits for none
CANDIDATES = (9001, 9002, 9003)

HOLDER = """
import sys
from cvt_ros.device import domains
lease = domains.acquire({candidates!r}, timeout=0)
print(lease.domain, flush=True)
sys.stdin.read()   # hold until stdin closes
"""


def holder(candidates=CANDIDATES):
    proc = subprocess.Popen([sys.executable, '-c', HOLDER.format(candidates=candidates)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    assert line.strip(), 'the holder did not report a domain'
    return proc, int(line)


def free(candidates=CANDIDATES):
    """The candidates no one holds now (held ones are skipped, free ones released again)."""
    out = []
    for d in candidates:
        lease = domains.try_acquire(d)
        if lease is not None:
            out.append(d)
            lease.release()
    return out


def test_concurrent_processes_get_distinct_domains():
    a, da = holder()
    b, db = holder()
    try:
        assert da != db and {da, db} <= set(CANDIDATES)
        with domains.acquire(CANDIDATES, timeout=0) as lease:
            assert lease.domain not in (da, db)
            with pytest.raises(domains.DomainsExhausted, match='9001–9003'):
                domains.acquire(CANDIDATES, timeout=0)
    finally:
        for p in (a, b):
            p.stdin.close()
            p.wait(10)
    assert free() == list(CANDIDATES)


def test_a_killed_holder_frees_its_domain():
    proc, domain = holder()
    assert domain not in free()
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    assert domain in free()


def test_a_child_with_the_lock_keeps_the_domain_after_its_parent():
    lease = domains.acquire(CANDIDATES, timeout=0)
    child = subprocess.Popen([sys.executable, '-c', 'import sys; sys.stdin.read()'],
                             stdin=subprocess.PIPE, pass_fds=[lease.fd])
    try:
        lease.release()                      # the parent lets go ...
        assert lease.domain not in free()    # ... the child still holds it
    finally:
        child.stdin.close()
        child.wait(10)
    assert lease.domain in free()


def test_the_allocated_range_leaves_the_ad_hoc_ranges_out():
    ids = set(domains.ALLOCATED_DOMAINS)
    assert ids == set(range(21, 102))
    assert not ids & (set(range(0, 21)) | set(range(215, 233)))
    assert os.environ['ROS_DOMAIN_ID'] in {str(d) for d in ids}   # conftest's session domain
