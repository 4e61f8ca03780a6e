"""``cvt-sim bench paths``: what N paths cost (issue 33) — the steady-state run time per simulated
second of the conveyor with N = 1, 2, 4, 6 paths (defaults, one run, best of --repeats windows,
the path counts in turn), and in-process lockstep at 1 kHz on the 4-path conveyor
(Device.advance_row: the compiled period, a Python PI controller, as the controller kit's
in-process back end)."""
import argparse
import copy
import os
import time

from ..scene import load_scene
from ..solver.fidelity import make_simulator
from .node import inprocess

COUNTS = (1, 2, 4, 6)
SETTLE = 3.0   # [s] past the start-up (its stall and lock at N ≥ 2) before measuring


def steady_costs(counts, span, repeats=3):
    """Per path count n of ``counts``: (wall time per simulated second [s], steps, right-hand
    sides and switches per simulated second, energy residual) of the conveyor with n paths at
    steady state, the best of ``repeats`` runs of the same window SETTLE … SETTLE + span, each
    from a copy of the state there (the conveyor's cost per second drifts over minutes: 4 paths
    887 steps a second at 3 … 18 s, 1190 at 500 s). The path counts take turns window by window,
    so that a busy spell of the machine slows all of them, not one."""
    settled = {}
    for n in counts:
        settled[n] = make_simulator(load_scene('conveyor', {'paths.count': n}))
        settled[n].run(SETTLE, 0.01, keep_samples=False)
    best = {}
    for _ in range(repeats):
        for n in counts:
            result = copy.deepcopy(settled[n]).run(span, 0.01, keep_samples=False)
            if n not in best or result.wall_time < best[n].wall_time:
                best[n] = result
    return [{'paths': n, 'wall_per_s': r.wall_time / span, 'steps': r.steps / span,
             'rhs': r.diagnostics['rhs_evaluations'] / span, 'switches': r.switch_count / span,
             'residual': r.energy['relative_residual']} for n, r in best.items()]


def main(argv=None):
    parser = argparse.ArgumentParser(prog='cvt-sim bench paths', description=__doc__)
    parser.add_argument('--span', type=float, default=5.0, help='simulated seconds per repeat')
    parser.add_argument('--repeats', type=int, default=3,
                        help='windows of --span per path count, the best one reported (a 5 s '
                             'window of 4 paths is ~14 ms of wall time: on a busy machine take '
                             'more)')
    parser.add_argument('--lockstep', type=float, default=10.0,
                        help='simulated seconds of in-process lockstep')
    args = parser.parse_args(argv)
    print(f"load average {os.getloadavg()}, {time.strftime('%Y-%m-%d %H:%M')}")
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1, got {args.repeats}")
    rows = steady_costs(COUNTS, args.span, args.repeats)
    base = rows[0]['wall_per_s']
    print('| N | wall per simulated s | × one path | limit (N ×) | steps/s | rhs/s | switches/s '
          '| energy residual |')
    print('|---|---|---|---|---|---|---|---|')
    for r in rows:
        print(f"| {r['paths']} | {r['wall_per_s'] * 1e3:.2f} ms | {r['wall_per_s'] / base:.2f} "
              f"| {r['paths']} | {r['steps']:.0f} | {r['rhs']:.0f} | {r['switches']:.0f} "
              f"| {r['residual']:.1e} |")
    print('\n| lockstep 1 kHz | paths | real-time factor | per period |')
    print('|---|---|---|---|')
    for method in ('dopri5', 'rk4'):
        for n in (1, 4):
            out = inprocess(args.lockstep, method=method, paths=n)
            print(f"| {method} | {n} | {out['rtf']:.0f}× | {out['per_period'] * 1e6:.1f} µs |")
    print(f"load average {os.getloadavg()}")
    return 0
