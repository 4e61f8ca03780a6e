"""``cvt-sim bench sweep`` (``./run.sh bench sweep``): a campaign of short cases on Dask
LocalClusters of 1 and 2 single-threaded workers — the speed-up, the scheduling overhead per
case and the workers' memory over the campaign — printed, and with ``--write BENCHMARKS.md``
put there (section "Sweeps").

Method. The same campaign (``--cases`` cases of the conveyor scene, ``--duration`` s simulated
each, the load torque varied) runs on a 1-worker cluster, a 2-worker cluster, and the 1-worker
cluster again (a shared machine's load drifts: the speed-up is taken against the mean of the two
1-worker runs). Each run starts from an empty output folder, after the workers are up and have
loaded the kernels; its wall time is :func:`cvt_ros.sweep.cluster.run_campaign`'s, table writes
included. Scheduling overhead per case = (wall × workers − Σ case wall time) / cases: the time a
worker was not inside a case. The client process's CPU time (client and, for a LocalCluster,
the scheduler) is what the orchestration takes from the cores the workers share. Memory: every
worker's RSS after warm-up and after each of ``--rounds`` runs of the campaign on the 2-worker
cluster.
"""
import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from .report import environment, fmt, publish, table

TITLE = '## Sweeps (Dask campaigns)'


def _rss():
    """A worker's resident memory [bytes] (run on the worker)."""
    import psutil
    return psutil.Process().memory_info().rss


def campaign_text(cases, duration):
    return (f"name: bench_sweep\nscene: conveyor\nduration: {duration!r}\n"
            f"vary:\n  load.torque: {{range: [0.0, 16.0], num: {cases}}}\n"
            f"metrics: [mean_ratio, efficiency, peak_clutch_torque, switches_per_second, "
            f"energy_residual]\ntime_budget: 600.0\n")


def measure(campaign, workers, rounds, folder, log):
    """Run the campaign ``rounds`` times on a fresh cluster of ``workers``; per round: wall
    time, Σ case wall time, failed cases, RSS per worker after it."""
    from ..sweep.cluster import open_cluster, run_campaign
    results = []
    with open_cluster(workers=workers, dashboard=':0') as cluster:
        client = cluster.client
        rss0 = client.run(_rss)
        for r in range(rounds):
            t0, cpu0 = time.perf_counter(), time.process_time()
            run = run_campaign(campaign, Path(folder) / f"w{workers}-{r}-{time.time_ns()}",
                               cluster)
            wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
            busy = sum(row['wall_time'] for row in run.rows)
            results.append({'wall': wall, 'busy': busy, 'failed': run.failed, 'cpu': cpu,
                            'cases': len(run.rows), 'rss': client.run(_rss)})
            log(f"{workers} worker(s), round {r + 1}: {wall:.2f} s, "
                f"{len(run.rows) / wall:.1f} cases/s, {run.failed} failed")
    return rss0, results


def overhead(result, workers):
    """Scheduling overhead per case [s]."""
    return (result['wall'] * workers - result['busy']) / result['cases']


def section(cfg, env, one_a, two, one_b, rss0, command, load_end):
    w1 = 0.5 * (one_a['wall'] + one_b['wall'])
    speedup = w1 / two[0]['wall']
    per_case = one_a['busy'] / one_a['cases']
    L = [TITLE, '']
    L += [f"Made by `{command}` on {env['cpu']}, {env['cores']} cores; load average "
          f"{env['load'][0]:.2f} (1 min) / {env['load'][1]:.2f} (5 min) at the start, "
          f"{load_end:.2f} at the end — other developers' jobs shared the machine. "
          f"Revision {env['revision']}, {env['date']}.", '']
    L += [f"Campaign: {cfg.cases} cases of the conveyor scene, {cfg.duration:g} s simulated "
          f"each (load torque 0 … 16 N·m), the five required metrics (steady-state window, "
          f"energy residual); one case ≈ {per_case * 1e3:.0f} ms on one worker. Method: "
          f"cvt_ros/bench/sweep.py docstring (clusters up and kernels loaded before timing; "
          f"the speed-up against the mean of a 1-worker run before and after the 2-worker "
          f"one).", '']
    rows = []
    for label, res, n in (('1 (before)', one_a, 1), ('2', two[0], 2), ('1 (after)', one_b, 1)):
        rows.append([label, fmt(res['wall']), fmt(res['cases'] / res['wall']),
                     fmt(res['busy']), fmt(overhead(res, n) * 1e3), fmt(res['cpu']),
                     fmt(w1 / res['wall']) if n == 2 else '1', res['failed']])
    L += table(['workers', 'wall [s]', 'cases/s', 'Σ case wall time [s]',
                'scheduling overhead per case [ms]', 'client + scheduler CPU [s]', 'speed-up',
                'failed'], rows)
    worst = max(overhead(two[0], 2), overhead(one_a, 1), overhead(one_b, 1))
    L += ['', f"Targets (issue 15): speed-up ≥ 1.8 on 2 workers: **{speedup:.2f}** "
              f"({'met' if speedup >= 1.8 else 'not met'}); scheduling overhead ≤ 20 ms per "
              f"case: **{worst * 1e3:.1f} ms** at worst ({'met' if worst <= 0.02 else 'not met'})."
          + ('' if speedup >= 1.8 else
             f" Other jobs loaded the machine: each case ran "
             f"{two[0]['busy'] / (0.5 * (one_a['busy'] + one_b['busy'])) - 1:.0%} longer on 2 "
             f"workers than on 1 (Σ case wall time), so two free cores were not there; with "
             f"that slowdown the best possible speed-up was "
             f"{2 * 0.5 * (one_a['busy'] + one_b['busy']) / two[0]['busy']:.2f}."), '']
    names = sorted(rss0)
    header = ['worker', 'after warm-up [MB]'] + [
        f"after {(r + 1) * cfg.cases} cases [MB]" for r in range(len(two))] + ['growth [MB]']
    rows = []
    for k, name in enumerate(names):
        seq = [rss0[name]] + [res['rss'].get(name, float('nan')) for res in two]
        rows.append([k + 1] + [fmt(x / 2 ** 20, 4) for x in seq]
                    + [fmt((seq[-1] - seq[1]) / 2 ** 20, 3)])
    L += [f"Memory per worker (2-worker cluster, RSS; {len(two)} runs of the campaign "
          f"back to back, {len(two) * cfg.cases} cases; growth from the end of the first run "
          f"to the end of the last):", '']
    L += table(header, rows)
    L += ['', 'Reproduce: `./run.sh bench sweep` (options: `--cases`, `--duration`, `--rounds`; '
              '`--write BENCHMARKS.md` puts the section there).', '']
    return '\n'.join(L)


def main(argv=None):
    ap = argparse.ArgumentParser(prog='cvt-sim bench sweep',
                                 description=__doc__.split('\n\n')[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--cases', type=int, default=256, help='cases (default %(default)s)')
    ap.add_argument('--duration', type=float, default=2.0,
                    help='simulated span per case [s] (default %(default)s)')
    ap.add_argument('--rounds', type=int, default=3,
                    help='runs of the campaign on the 2-worker cluster, for the memory '
                         '(default %(default)s)')
    ap.add_argument('--write', '--out', metavar='FILE', dest='out',
                    help="put the section into FILE, e.g. BENCHMARKS.md (default: print it "
                         "only)")
    cfg = ap.parse_args(argv)
    from ..sweep.campaign import load_campaign

    def log(msg):
        print(f"bench sweep: {msg}", file=sys.stderr, flush=True)

    env = environment()
    with tempfile.TemporaryDirectory(prefix='cvt_bench_sweep_') as folder:
        path = Path(folder) / 'bench_sweep.yaml'
        path.write_text(campaign_text(cfg.cases, cfg.duration))
        campaign = load_campaign(path)
        _, (one_a,) = measure(campaign, 1, 1, folder, log)
        rss0, two = measure(campaign, 2, max(1, cfg.rounds), folder, log)
        _, (one_b,) = measure(campaign, 1, 1, folder, log)
    command = './run.sh bench sweep' + (' ' + ' '.join(argv) if argv else '')
    text = section(cfg, env, one_a, two, one_b, rss0, command, os.getloadavg()[0])
    return publish(text, cfg.out, TITLE, log)


if __name__ == '__main__':
    sys.exit(main())
