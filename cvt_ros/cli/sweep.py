"""``cvt-sim sweep CAMPAIGN.yaml --out DIR``: check the campaign, run it on Dask, print.

Exit codes: 0 every case ok, 1 the campaign ran but some cases failed (the table says which and
why), 2 bad input (campaign file, too many cases without --yes, an output folder or table that
cannot be used, no cluster at --scheduler) and nothing ran, 130 interrupted (the cases done are
in the table; run again to resume).
"""
import argparse
import collections
import contextlib
import sys
import warnings
from pathlib import Path

DEFAULT_MAX_CASES = 10_000

EPILOG = """\
examples:
  cvt-sim sweep config/campaigns/conveyor_ratio_map.yaml --out ratio_map/
  cvt-sim sweep config/campaigns/conveyor_pi_gains.yaml --out gains/ --workers 8
  cvt-sim sweep big.yaml --out big/ --scheduler tls://head-node:8786 --yes \\
      --tls-ca ca.pem --tls-cert me.pem --tls-key me-key.pem
  cvt-sim sweep config/campaigns/conveyor_shaft_stiffness.yaml --out x/ --dry-run  # list cases

DIR gets results.parquet (one row per case: parameters, metrics, status, error, wall time),
summary.png and campaign.yaml (the campaign as run); a campaign.yaml or summary.png in DIR that
an earlier sweep did not write is refused (--overwrite replaces it). Rerunning the same command
skips the cases already in the table. A cluster's workers run whatever their scheduler sends:
connect to another machine's scheduler with tls:// (plain tcp:// is refused there without
--insecure). Campaign files and the cluster set-up: docs/sweeps.md.
"""


def _count(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text[:40]!r} is not a whole number") from None
    if not 1 <= value <= 10 ** 7:
        raise argparse.ArgumentTypeError(f"{value} is outside [1, 10000000]")
    return value


def add_parser(sub):
    """The ``sweep`` command on an argparse subparsers object."""
    p = sub.add_parser(
        'sweep', help='run a campaign of cases (parameter/gain sweeps) on Dask',
        description='Run every case of a campaign file — a base scene or scenario, the '
                    'parameters to vary (grid, lists, random, Latin hypercube), the metrics to '
                    'keep — on a Dask cluster: a local one with one single-threaded worker per '
                    'core by default, or an existing one (--scheduler). Writes a Parquet table '
                    'and a summary plot; resumable.',
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('campaign', metavar='CAMPAIGN.yaml',
                   help='campaign file, or a shipped campaign by name (conveyor_ratio_map, '
                        'conveyor_pi_gains, conveyor_shaft_stiffness)')
    p.add_argument('--out', required=True, metavar='DIR',
                   help='output folder (created; holds the table, the plot, recordings)')
    p.add_argument('--scheduler', metavar='tls://HOST:8786',
                   help='run on the Dask cluster of this scheduler instead of a local one '
                        '(tls:// with --tls-* or the Dask config; tcp:// on this machine only, '
                        'unless --insecure)')
    p.add_argument('--tls-ca', metavar='FILE',
                   help='tls:// scheduler: the CA certificate (PEM) that signed the cluster\'s '
                        'certificates')
    p.add_argument('--tls-cert', metavar='FILE',
                   help="tls:// scheduler: this client's certificate (PEM), signed by the CA")
    p.add_argument('--tls-key', metavar='FILE',
                   help="tls:// scheduler: the certificate's private key (PEM; omit if the "
                        "certificate file holds it)")
    p.add_argument('--insecure', action='store_true',
                   help='allow a plain tcp:// scheduler on another machine (anyone who can '
                        'reach it runs code on its workers): only on a network you control')
    p.add_argument('--overwrite', action='store_true',
                   help='replace a campaign.yaml or summary.png in DIR that this sweep did not '
                        'write')
    p.add_argument('--workers', type=_count, metavar='N',
                   help='local cluster: N worker processes (default: one per core); with '
                        '--scheduler: wait until N workers are connected (default 1)')
    p.add_argument('--yes', action='store_true',
                   help='run a campaign of more than --max-cases cases')
    p.add_argument('--max-cases', type=_count, default=DEFAULT_MAX_CASES, metavar='N',
                   help='refuse campaigns of more cases without --yes (default %(default)s)')
    p.add_argument('--retry-failed', action='store_true',
                   help='run again the cases the table holds as failed')
    p.add_argument('--dashboard', default='127.0.0.1:8787', metavar='[HOST]:PORT',
                   help="local cluster: the Dask dashboard's address (default %(default)s: "
                        "this machine only; another free port if taken)")
    p.add_argument('--dry-run', action='store_true',
                   help='check the campaign and list its cases; run nothing')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    p.set_defaults(func=sweep_command)


def _fail(message, code=2):
    print(f"cvt-sim sweep: error: {message}", file=sys.stderr)
    return code


def _dry_run(campaign, tasks):
    print(f"{campaign.path}: {len(tasks)} cases ({campaign.kind} {campaign.base}, "
          f"{campaign.sampling if not campaign.cases else 'explicit cases'}); metrics: "
          f"{', '.join(campaign.metrics)}")
    shown = tasks if len(tasks) <= 12 else tasks[:6] + tasks[-6:]
    for k, task in enumerate(shown):
        if len(tasks) > 12 and k == 6:
            print('  …')
        print(f"  case {task.index}: " + ', '.join(f"{n} = {v!r}"
                                                  for n, v in task.variables.items()))
    return 0


class _Progress:
    """The progress bar (stderr): cases done and failed, rate, ETA."""

    def __init__(self, quiet):
        self.quiet = quiet
        self.bar = None
        self.ok = self.failed = 0

    def __call__(self, kind, info):
        if kind == 'start':
            if info['skipped']:
                print(f"resuming: {info['skipped']} of {info['total']} cases are in the table "
                      f"already; {info['todo']} to run", file=sys.stderr)
            if not self.quiet:
                from tqdm import tqdm
                self.bar = tqdm(total=info['todo'], unit='case', file=sys.stderr,
                                dynamic_ncols=True, smoothing=0.1)
        elif kind == 'case':
            if info['status'] == 'ok':
                self.ok += 1
            else:
                self.failed += 1
            if self.bar is not None:
                self.bar.set_postfix_str(f"ok {self.ok}, failed {self.failed}", refresh=False)
                self.bar.update(1)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _report(run, plot):
    rows = run.rows
    failed = [r for r in rows if r['status'] != 'ok']
    print(f"{len(rows)} cases: {len(rows) - len(failed)} ok, {len(failed)} failed "
          f"({run.ran} run now in {run.wall_time:.1f} s, {run.skipped} from before)")
    kinds = collections.Counter(r['failure'] for r in failed)
    for kind, count in kinds.most_common():
        first = next(r for r in failed if r['failure'] == kind)
        print(f"  {count} {kind}: e.g. case {first['case']}: {first['error'][:300]}")
    warned = [r for r in rows if r['status'] == 'ok' and r['warnings']]
    if warned:   # ok, but not to be read as plain numbers: a reader of the table must know
        print(f"  {len(warned)} of the ok cases with warnings (the table's warnings column), "
              f"e.g. case {warned[0]['case']}: {warned[0]['warnings'][:300]}")
    for problem in run.problems:
        print(f"  note: {problem}")
    print(f"table: {run.path}")
    if plot:
        print(f"plot:  {plot}")
    return 1 if failed else 0


def sweep_command(args):
    from ..sweep.campaign import CampaignError, load_campaign
    from ..sweep.cases import build_tasks
    try:
        campaign = load_campaign(args.campaign)
        count = campaign.case_count()
        if count > args.max_cases and not args.yes and not args.dry_run:
            return _fail(f"{args.campaign}: {count:,} cases, more than --max-cases "
                         f"{args.max_cases:,}: check the campaign, or pass --yes to run them")
        out = Path(args.out)
        tasks = build_tasks(campaign, out)
    except CampaignError as exc:
        return _fail(str(exc))
    if args.dry_run:
        return _dry_run(campaign, tasks)
    from ..sweep.cluster import (
        SweepError,
        check_scheduler,
        open_cluster,
        plan_campaign,
        run_campaign,
        tls_security,
    )
    from ..sweep.folder import SUMMARY, write_own
    from ..sweep.plots import plot_summary
    from ..sweep.table import TableError
    progress = _Progress(args.quiet)
    try:
        security = tls_security(args.tls_ca, args.tls_cert, args.tls_key)
        if args.scheduler:   # (before any case, before the folder is made)
            with warnings.catch_warnings(record=True) as warned:
                warnings.simplefilter('always')
                check_scheduler(args.scheduler, security, args.insecure)
            for warning in warned:
                print(f"cvt-sim sweep: warning: {warning.message}", file=sys.stderr)
        elif security is not None:
            return _fail('--tls-ca/--tls-cert/--tls-key apply to a --scheduler tls://…; the '
                         'local cluster stays on this machine')
        plan = plan_campaign(campaign, out, tasks=tasks, retry_failed=args.retry_failed,
                             overwrite=args.overwrite)
        with contextlib.ExitStack() as stack:
            cluster = None
            if plan.todo:
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore')   # (said once above)
                    cluster = stack.enter_context(open_cluster(
                        args.scheduler, args.workers, args.dashboard, security=security,
                        insecure=args.insecure))
                workers = cluster.workers()
                print(f"{args.scheduler or 'local cluster'}: {len(workers)} workers, "
                      f"{sum(workers.values())} threads; dashboard "
                      f"{cluster.dashboard or '(none: install bokeh)'}", file=sys.stderr)
            stack.callback(progress.close)
            run = run_campaign(campaign, out, cluster, plan=plan, on_event=progress)
    except (SweepError, TableError) as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        print(f"cvt-sim sweep: interrupted; the cases done are in {out / 'results.parquet'} "
              f"(run the same command again to resume)", file=sys.stderr)
        return 130
    try:
        plot = write_own(out, SUMMARY, lambda path: plot_summary(campaign, run.rows, path)) \
            if run.rows else None
    except TableError as exc:
        _report(run, None)
        return _fail(str(exc))
    return _report(run, plot)
