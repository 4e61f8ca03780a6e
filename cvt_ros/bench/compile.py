"""What the first run pays: ``cvt-sim warmup`` on a fresh kernel cache, per compiled kernel.

    cvt-sim bench compile [--baseline DIR [--baseline-label REV]] [--repeats N] [--write FILE]

Each run is a child process with an empty NUMBA_CACHE_DIR of its own (a first run, as `./run.sh`
set-up makes it) that records numba's compile events (numba.core.event 'numba:compile': one per
compiled version of a kernel, nested where a kernel compiles its callees) while it runs
``cvt-sim warmup``. A kernel's **own** time is its compile minus the compiles it caused of the
kernels it calls; **with callees** includes them. With ``--baseline DIR`` (another checkout of
cvt_ros, e.g. an older revision) the runs alternate between it and this checkout in the same
session, so that both see the same machine and load; the ratio is per pair.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from .report import ROOT, environment, publish, table

TITLE = '## Compile time (first run)'
TOP = 10   # kernels listed

# the child: compile events → JSON on stdout's last line (self-contained: it also runs against
# an older checkout's cvt_ros)
CHILD = r"""
import json, sys, time
from numba.core import event
stack, own, total, versions = [], {}, {}, {}
class Listener(event.Listener):
    def on_start(self, ev):
        stack.append([ev.data['dispatcher'], time.perf_counter(), 0.0])
    def on_end(self, ev):
        disp, t0, inner = stack.pop()
        dt = time.perf_counter() - t0
        f = disp.py_func
        name = f'{f.__module__}.{f.__qualname__}'
        own[name] = own.get(name, 0.0) + dt - inner
        total[name] = total.get(name, 0.0) + dt
        versions[name] = versions.get(name, 0) + 1
        if stack:
            stack[-1][2] += dt
event.register('numba:compile', Listener())
t0 = time.perf_counter()
from cvt_ros.cli import main
code = main(['warmup'])
wall = time.perf_counter() - t0
print(json.dumps({'code': code, 'wall': wall, 'own': own, 'total': total,
                  'versions': versions}))
"""


def revision(checkout, label=None):
    if label:
        return label
    try:
        rev = subprocess.run(['git', 'describe', '--always', '--dirty'], cwd=checkout,
                             capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        rev = ''
    return rev or str(checkout)


def warmup_run(checkout):
    """One fresh-cache `cvt-sim warmup` of ``checkout``'s code: the child's record, with the
    load average at its start."""
    with tempfile.TemporaryDirectory(prefix='cvt_compile_') as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache,
                   PYTHONPATH=os.pathsep.join(
                       [str(checkout)] + [p for p in os.environ.get('PYTHONPATH', '').split(
                           os.pathsep) if p and Path(p).resolve() != ROOT]))
        load = os.getloadavg()[0]
        proc = subprocess.run([sys.executable, '-c', CHILD], env=env, cwd=checkout,
                              capture_output=True, text=True, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(f'warmup of {checkout} failed: {proc.stderr[-2000:]}')
    record = json.loads(proc.stdout.strip().splitlines()[-1])
    record['load'] = load
    return record


def _short(name):
    return name.removeprefix('cvt_ros.')


def section(runs, labels, command, env):
    """The markdown section: totals per run, then each kernel's time (the first run of each
    revision) beside the baseline's."""
    L = [TITLE, '']
    L += [f"`{command}` (revision {env['revision']}, {env['date']}; {env['cpu']}, "
          f"{env['cores']} cores; load average {env['load'][0]:.2f} at the start, "
          f"{os.getloadavg()[0]:.2f} at the end: the machine was shared). Each run: "
          "`cvt-sim warmup` (the offline core with dopri5 and rk4, a crank command) in a child "
          "process on an empty kernel cache, what `./run.sh` set-up pays once. "
          "Own = a kernel's compile without the kernels it calls; "
          "with callees = the whole compile it started.", '']
    body = []
    for i, run in enumerate(runs):
        body.append([i + 1, labels[run['which']], f"{run['wall']:.1f}", f"{run['load']:.2f}"])
    L += table(['run', 'revision', '`cvt-sim warmup` [s]', 'load average at its start'], body)
    pairs = [(runs[i], runs[i + 1]) for i in range(0, len(runs) - 1, 2)
             if runs[i]['which'] == 'baseline']
    if pairs:
        ratios = [this['wall'] / base['wall'] for base, this in pairs]
        L += ['', 'This revision over the baseline, per pair of consecutive runs: '
              + ', '.join(f'{r:.2f}' for r in ratios) + '.']
    first = {}
    for run in runs:
        first.setdefault(run['which'], run)
    order = sorted(first['this']['own'], key=first['this']['own'].get, reverse=True)
    header = ['kernel (this revision)', 'versions', 'own [s]', 'with callees [s]']
    base = first.get('baseline')
    if base:
        header += [f"{labels['baseline']}: versions", 'own [s]', 'with callees [s]']
    rows = []
    for name in order[:TOP]:
        row = [f'`{_short(name)}`', first['this']['versions'][name],
               f"{first['this']['own'][name]:.2f}", f"{first['this']['total'][name]:.2f}"]
        if base:
            row += ([base['versions'][name], f"{base['own'][name]:.2f}",
                     f"{base['total'][name]:.2f}"] if name in base['own'] else
                    ['–', 'inlined', '–'])
        rows.append(row)
    rest = order[TOP:]
    row = [f'({len(rest)} more)', sum(first['this']['versions'][n] for n in rest),
           f"{sum(first['this']['own'][n] for n in rest):.2f}", '']
    if base:
        listed = {n for n in order[:TOP]}
        others = [n for n in base['own'] if n not in listed]
        row += [sum(base['versions'][n] for n in others),
                f"{sum(base['own'][n] for n in others):.2f}", '']
    rows.append(row)
    r = first['this']
    row = ['**all**', sum(r['versions'].values()), f"{sum(r['own'].values()):.1f}", '']
    if base:
        row += [sum(base['versions'].values()), f"{sum(base['own'].values()):.1f}", '']
    rows.append(row)
    L += ['', f"Per kernel, the first run of each revision (the {TOP} costliest here; "
          "'inlined': the baseline compiled no version of its own, its callers copied it):", '']
    L += table(header, rows)
    return L + ['']


def main(argv=None):
    ap = argparse.ArgumentParser(prog='cvt-sim bench compile', description=__doc__.split('\n\n')[0])
    ap.add_argument('--baseline', metavar='DIR', type=Path,
                    help='another checkout of cvt_ros to measure in the same session')
    ap.add_argument('--baseline-label', metavar='REV',
                    help='its revision as the report names it (default: git describe in DIR)')
    ap.add_argument('--repeats', type=int, default=1,
                    help='runs per revision, alternating (default %(default)s)')
    ap.add_argument('--write', metavar='FILE', help='put the section into this markdown file')
    a = ap.parse_args(argv)
    if a.baseline and not (a.baseline / 'cvt_ros' / '__init__.py').is_file():
        ap.error(f'--baseline {a.baseline}: not a checkout of cvt_ros (no cvt_ros/__init__.py)')
    env = environment()
    labels = {'this': env['revision']}
    if a.baseline:
        labels['baseline'] = revision(a.baseline, a.baseline_label)
    runs = []
    for i in range(a.repeats):
        for which in (('baseline', 'this') if a.baseline else ('this',)):
            checkout = a.baseline if which == 'baseline' else ROOT
            print(f'compile: run {i + 1}/{a.repeats}, {labels[which]} …', file=sys.stderr,
                  flush=True)
            run = warmup_run(checkout)
            run['which'] = which
            print(f"compile: {labels[which]}: {run['wall']:.1f} s (load {run['load']:.2f})",
                  file=sys.stderr, flush=True)
            runs.append(run)
    command = ' '.join(['cvt-sim bench compile'] + list(sys.argv[1:] if argv is None else argv))
    text = '\n'.join(section(runs, labels, command, env)) + '\n'
    return publish(text, a.write, TITLE, lambda msg: print(f'compile: {msg}', file=sys.stderr))


if __name__ == '__main__':
    sys.exit(main())
