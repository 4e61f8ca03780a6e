"""Campaigns on a real Dask LocalCluster (two single-threaded worker processes, shared by the
module): the same table as one process, resume, failures that do not stop the campaign, a
worker killed by PID mid-campaign (its case reruns elsewhere, nothing lost or duplicated), and
``cvt-sim sweep --scheduler`` against this cluster."""
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import dask
import pyarrow.parquet as pq
import pytest

from cvt_ros.sweep import build_tasks, load_campaign, run_case
from cvt_ros.sweep.cluster import open_cluster, run_campaign

TESTS = Path(__file__).resolve().parent


@pytest.fixture(scope='module')
def cluster():
    # workers import the test controllers (sweep_controllers.py); a case that kills its worker
    # is given up after 2 deaths instead of 4 (each costs a worker restart)
    path = os.environ.get('PYTHONPATH')
    os.environ['PYTHONPATH'] = os.pathsep.join(filter(None, [str(TESTS), path]))
    try:
        with dask.config.set({'distributed.scheduler.allowed-failures': 1}):
            handle = open_cluster(workers=2, dashboard=':0')
    finally:
        if path is None:
            del os.environ['PYTHONPATH']
        else:
            os.environ['PYTHONPATH'] = path
    with handle:
        yield handle


def campaign_file(tmp_path, text, name='c.yaml'):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return load_campaign(path)


def comparable(rows):
    """Rows without their wall time, NaN as text (NaN == NaN is False)."""
    return [{k: 'NaN' if isinstance(v, float) and math.isnan(v) else v
             for k, v in r.items() if k != 'wall_time'} for r in rows]


MIXED = """\
    scene: conveyor
    duration: 2.0
    overrides: {solver.method: rk4, solver.fixed_step: 0.05, shaft.stiffness: 2.0e4}
    cases:
      - {solver.refine_step: auto, load.torque: 4.0}
      - {solver.refine_step: 'off', load.torque: 4.0}
      - {solver.refine_step: auto, load.torque: 8.0}
      - {solver.refine_step: auto, load.torque: 12.0}
      - {solver.refine_step: 'off', load.torque: 12.0}
      - {solver.refine_step: auto, load.torque: 16.0}
    metrics: [mean_ratio, efficiency, peak_clutch_torque, switches_per_second, energy_residual]
    """


def _sigint_ignored():
    import signal
    return signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_local_workers_ignore_ctrl_c_and_this_process_does_not(cluster):
    """Ctrl-C reaches the whole process group: the client stops the campaign (exit 130, the
    table merged) and closes the cluster; workers that took SIGINT too printed ~30 lines of
    KeyboardInterrupt tracebacks first. Ours ignore it (an existing cluster's are left alone)."""
    assert set(cluster.client.run(_sigint_ignored).values()) == {True}
    assert not _sigint_ignored()   # the client's own Ctrl-C still works


def test_same_table_as_one_process_and_failures_do_not_stop_it(tmp_path, cluster):
    campaign = campaign_file(tmp_path, MIXED)
    events = []
    run = run_campaign(campaign, tmp_path / 'out', cluster,
                       on_event=lambda kind, info: events.append((kind, info)))
    assert run.total == run.ran == 6 and run.failed == 2 and run.skipped == 0
    assert events[0] == ('start', {'total': 6, 'skipped': 0, 'todo': 6})
    assert sorted(info['case'] for kind, info in events[1:]) == list(range(6))
    rows = pq.read_table(tmp_path / 'out' / 'results.parquet').to_pylist()
    assert [r['case'] for r in rows] == list(range(6))
    assert [r['failure'] for r in rows] == ['', 'diverged', '', '', 'diverged', '']
    serial = [run_case(t) for t in build_tasks(campaign)]   # one worker: this process
    differ = [(r['case'], k, r[k], s[k]) for r, s in zip(comparable(rows), comparable(serial),
                                                          strict=True) for k in r if r[k] != s[k]]
    assert not differ                                         # bit for bit, NaN where NaN
    # rerun: nothing left to do; --retry-failed reruns just the failed two
    again = run_campaign(campaign, tmp_path / 'out', cluster)
    assert again.ran == 0 and again.skipped == 6 and comparable(again.rows) == comparable(rows)
    retried = run_campaign(campaign, tmp_path / 'out', cluster, retry_failed=True)
    assert retried.ran == 2 and comparable(retried.rows) == comparable(rows)


def test_a_grown_campaign_runs_only_its_new_cases(tmp_path, cluster):
    small = campaign_file(tmp_path, """\
        scene: conveyor
        duration: 1.0
        vary: {load.torque: [2.0, 6.0]}
        """)
    first = run_campaign(small, tmp_path / 'out', cluster)
    grown = campaign_file(tmp_path, """\
        scene: conveyor
        duration: 1.0
        vary: {load.torque: [0.0, 2.0, 4.0, 6.0]}
        """)
    second = run_campaign(grown, tmp_path / 'out', cluster)
    assert second.ran == 2 and second.skipped == 2
    assert [r['load.torque'] for r in second.rows] == [0.0, 2.0, 4.0, 6.0]
    assert [r['case'] for r in second.rows] == [0, 1, 2, 3]
    assert comparable([second.rows[1], second.rows[3]]) == comparable(
        [dict(r, case=r['case'] * 2 + 1) for r in first.rows])


def test_a_worker_killed_mid_campaign_loses_nothing(tmp_path, cluster):
    # cases of ~0.5-1 s each: the kill lands while a case runs (a case that finished just before
    # would still have to be in the table once, which is what is checked)
    campaign = campaign_file(tmp_path, """\
        scene: conveyor
        duration: 40.0
        sample_dt: 0.002
        vary: {load.torque: [2.0, 4.0, 6.0, 8.0, 10.0, 12.0]}
        metrics: [mean_ratio, switches_per_second]
        """)
    client = cluster.client
    killed = {}

    def kill_one(kind, info):
        if kind != 'case' or killed:
            return
        busy = {w: keys for w, keys in client.processing().items() if keys}
        worker, keys = next(iter(busy.items()))
        pid = client.run(os.getpid, workers=[worker])[worker]
        os.kill(pid, signal.SIGKILL)
        killed.update(pid=pid, worker=worker, case=int(sorted(keys)[0].split('-')[2]))

    run = run_campaign(campaign, tmp_path / 'out', cluster, on_event=kill_one)
    assert killed, 'no worker was killed'
    rows = run.rows
    assert [r['case'] for r in rows] == list(range(6))          # each case once, none lost
    assert len({r['case_id'] for r in rows}) == 6
    assert all(r['status'] == 'ok' for r in rows), [r['error'] for r in rows]
    assert rows[killed['case']]['switches_per_second'] > 40     # the killed case ran again
    assert killed['pid'] not in client.run(os.getpid).values()  # ...on another worker process
    client.wait_for_workers(2, timeout=300)                     # the nanny restarted it


def test_a_case_that_kills_its_worker_every_time_is_recorded_and_the_rest_run(tmp_path,
                                                                            cluster):
    campaign = campaign_file(tmp_path, """\
        scenario: conveyor_load_step
        duration: 0.5
        controller: sweep_controllers:crashing
        vary: {load.viscous: [0.0, 0.01, 0.02, 0.03, 0.1, 0.04, 0.05, 0.06]}
        """)
    run = run_campaign(campaign, tmp_path / 'out', cluster)
    assert [r['case'] for r in run.rows] == list(range(8))
    failed = [r for r in run.rows if r['status'] != 'ok']
    assert [(r['case'], r['failure']) for r in failed] == [(4, 'killed')]
    assert 'its worker process died every time it ran this case' in failed[0]['error']
    assert 'on 2 different workers' in failed[0]['error']   # Dask's own account
    cluster.client.wait_for_workers(2, timeout=300)


def test_cli_on_an_existing_cluster(tmp_path, cluster):
    path = tmp_path / 'c.yaml'
    path.write_text('scene: conveyor\nduration: 1.0\nvary: {load.torque: [3.0, 5.0]}\n')
    out = tmp_path / 'out'
    cmd = [sys.executable, '-m', 'cvt_ros', 'sweep', str(path), '--out', str(out),
           '--scheduler', cluster.address, '--quiet']
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert f"{cluster.address}: 2 workers, 2 threads; dashboard http" in proc.stderr
    assert '2 cases: 2 ok, 0 failed' in proc.stdout
    assert (out / 'summary.png').read_bytes()[:4] == b'\x89PNG'
    assert (out / 'campaign.yaml').read_text() == path.read_text()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and 'resuming: 2 of 2 cases' in proc.stderr
