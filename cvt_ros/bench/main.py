"""``cvt-sim bench`` (``./run.sh bench``): the core benchmarks into a report of their own
(``bench-DATE.md`` and its plots, or ``--out FILE``); ``--write BENCHMARKS.md`` updates the
published report and docs/plots in place, and nothing else does.

``cvt-sim bench [OPTIONS]`` runs the sections (work-precision and the defaults, hard cases, the
RK4 stability limit, the long run, the known-defect checks); ``cvt-sim bench node ARGS`` the ROS
node's benchmark (cvt_ros.bench.node); ``cvt-sim bench fidelity ARGS`` the fidelity table;
``cvt-sim bench sweep ARGS`` the Dask campaign benchmark (cvt_ros.bench.sweep); ``cvt-sim bench
design ARGS`` the design tools (cvt_ros.bench.design); ``cvt-sim bench
profile ARGS`` where the core's time goes at steady state (Linux perf, cvt_ros.bench.profile);
``cvt-sim bench paths`` what N paths cost (cvt_ros.bench.paths);
``cvt-sim bench compile ARGS`` what compiling the kernels costs a first run (cvt_ros.bench.compile).
"""
import argparse
import importlib
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .defects import known_defects, section_defects
from .hard_cases import HARD_COLUMNS, HARD_SCENES, hard_cases, hard_csv_rows, section_hard
from .long_run import LONG_COLUMNS, long_csv_rows, long_run, section_long
from .plots import plot_all
from .report import OWN_TITLE, environment, stamp, write_report
from .scaling import (
    QUICK_SPANS,
    SPANS,
    event_sweep,
    section_events,
    section_scaling,
    stiffness_scaling,
    time_scaling,
)
from .scaling import STIFFNESSES as SCALING_STIFFNESSES
from .speedup import (
    ERROR_LEVELS,
    SPEEDUP_COLUMNS,
    default_settings,
    section_default,
    section_speedup,
    speedup_csv_rows,
)
from .stability import STIFFNESSES, section_limits, stability_limits
from .steady_state import SCENES as STEADY_SCENES
from .steady_state import STEADY_SPAN, section_steady, steady_state
from .work_precision import (
    CHECK_METHOD,
    CSV_COLUMNS,
    DEFAULT_DURATION,
    DURATIONS,
    METHOD_BY_KEY,
    N_STEPS,
    QUICK_N_STEPS,
    QUICK_RTOLS,
    QUICK_SCIPY_RTOLS,
    RTOLS,
    SCENES,
    SCIPY_RTOLS,
    csv_rows,
    cvode_overhead,
    section_cvode,
    section_plots,
    section_references,
    work_precision,
    write_csv,
)

SECTIONS = ('work', 'steady', 'scaling', 'events', 'hard', 'stability', 'long', 'defects')
# modules with their own main(argv)
SUBCOMMANDS = ('node', 'fidelity', 'sweep', 'profile', 'design', 'paths', 'compile')


def stamped(lines, line):
    """A section's lines with its stamp (``report.stamp``) under the heading."""
    return lines[:2] + [line, ''] + lines[2:] if lines else lines


def page(cfg, env, parts, plots, data, command, wall_total):
    """The report: a title block (kept from the file by ``--write``), then one section per
    thing measured, each with its stamp; the tables behind the plots go to CSV files
    (``data``: name → path relative to the report)."""
    L = [OWN_TITLE, '']
    L += [f'Made by `{command}` in {wall_total / 60:.1f} min. Machine: {env["cpu"]}, '
          f'{env["cores"]} cores ({env["platform"]}), Python {env["python"]}, '
          + ', '.join(f'{k} {v}' for k, v in env['versions'].items())
          + f". Revision {env['revision']}, {env['date']}.", '']
    loads = parts['loads']

    def mark(lines, *keys):
        first = loads[keys[0]]
        return stamped(lines, stamp(command, env, (first[0], loads[keys[-1]][1])))
    results, default = parts['work'], parts['default']
    if parts['steady']:
        L += mark(section_steady(parts['steady'], parts['steady_load']), 'steady')
    if parts['scaling']:
        L += mark(section_scaling(*parts['scaling'], cfg), 'scaling')
    if parts['events']:
        L += mark(section_events(parts['events'], cfg), 'events')
    if default:
        L += mark(section_default(default, results, cfg, command), 'work')
    if results:
        W = ['## Work-precision', '']
        W += ['Every method integrates the same scene from the same consistent initial state '
              'over the same span; **time** is the wall time of the integration alone (set-up '
              'and compilation excluded), the minimum of several runs after a warm-up (5 below '
              '0.3 s, 3 below 1 s, 2 below 3 s, 1 above), one core each. **Errors** against the '
              'reference: relative error of φ4 and ω4 at the end of the span, and the '
              'switch-time error max |Δt| over the switches matched in order (nan where the '
              'count differs). Methods: **project dopri5** (adaptive DP5(4), events on its '
              'dense output, the open clutch\'s output in closed form), **dopri5, output '
              'integrated** (the ablation), **project rk4** (the realtime mode: fixed step, '
              'events located inside the step, the step refined below the stability limit of '
              'what it integrates), **paper\'s method** (its index-reduced DAE, eqs. 9/11/12, '
              'Baumgarte at 200 1/s, classical RK4, no refinement, the project\'s event '
              'location), scipy `solve_ivp` RK45, DOP853, Radau, LSODA with terminal events on '
              'the same right-hand side (solver/reference.py) and SUNDIALS CVODE BDF and Adams '
              '(solver/cvode.py); atol = 1e-2·rtol. A baseline setting predicted to take more '
              f'than {cfg.budget:g} s is skipped, with the tighter ones.', '']
        W += section_cvode(parts['cvode'], cfg)
        W += ["Reference per scene: the project's dopri5 at rtol 1e-13, atol 1e-15, max_step "
              "1e-3, checked against its other output variant, against itself at rtol 1e-12 "
              f"and against scipy {CHECK_METHOD} at rtol 1e-12, atol 1e-14:", '']
        W += section_references(results)
        if 'work' in data:
            W += [f"Every point of every curve (wall time, real-time factor, errors, steps or "
                  f"right-hand sides, energy residual): [{data['work']}]({data['work']}).", '']
        W += section_plots(results, plots)
        L += mark(W, 'work')
        L += mark(section_speedup(results, cfg), 'work')
    if parts['hard']:
        L += mark(section_hard(parts['hard'], cfg), 'hard')
    if parts['stability']:
        L += mark(section_limits(parts['stability'], cfg, plots), 'stability')
    if parts['long']:
        L += mark(section_long(parts['long'], cfg), 'long')
    if parts['defects']:
        L += mark(section_defects(parts['defects']), 'defects')
    return '\n'.join(L).rstrip() + '\n'


def write_tables(parts, cfg, folder):
    """The CSV files behind the page's summaries; name → path."""
    out = {}
    if parts['work']:
        out['work'] = write_csv(folder / 'work_precision.csv', CSV_COLUMNS,
                                csv_rows(parts['work']))
        out['speed_up'] = write_csv(folder / 'speed_up.csv', SPEEDUP_COLUMNS,
                                    speedup_csv_rows(parts['work'], cfg))
    if parts['hard']:
        out['hard'] = write_csv(folder / 'hard_cases.csv', HARD_COLUMNS,
                                hard_csv_rows(parts['hard']))
    if parts['long']:
        out['long'] = write_csv(folder / 'long_run.csv', LONG_COLUMNS, long_csv_rows(parts['long']))
    return out


@dataclass
class Config:
    quick: bool
    scenes: list
    methods: list
    rtols: list
    scipy_rtols: list
    steps: list | None
    n_steps: int
    budget: float
    durations: dict
    levels: tuple
    hard_scenes: list
    hard_duration: float
    stiffnesses: list
    stability_duration: float
    stability_formulations: tuple
    long_duration: float
    long_marks: tuple
    default_repeats: int
    steady_scenes: list
    steady_span: float
    scaling_spans: list
    scaling_stiffnesses: list
    stiffness_span: float
    sweep_span: float
    warm: bool = True
    skipped: list = field(default_factory=list)   # one line per method family left out

    def duration_for(self, name):
        return self.durations[name]


def parse_args(argv):
    ap = argparse.ArgumentParser(
        prog='cvt-sim bench', description=__doc__.split('\n\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='sections: work (work-precision, default settings), steady (speed at steady '
               'state vs scipy and the RHS floor), scaling (time, stiffness), events (switch '
               'counts at every rtol), hard (hard cases), stability (RK4 step limit), long '
               '(1 h run), defects (known-defect checks).\n'
               'other benchmarks: cvt-sim bench node --help (the ROS node), '
               'cvt-sim bench fidelity --help (each fidelity against the full model), '
               'cvt-sim bench sweep --help (Dask campaigns), '
               'cvt-sim bench profile --help (a perf profile of the steady-state runs), '
               'cvt-sim bench compile --help (the first run\'s kernel compilation)')
    ap.add_argument('--quick', action='store_true', help='CI-sized: short spans, fewer points')
    where = ap.add_mutually_exclusive_group()
    where.add_argument('--out', metavar='FILE',
                       help='write the report to this new file (an existing one only with '
                            '--overwrite; default: a new bench-DATE.md in this folder)')
    where.add_argument('--write', metavar='FILE',
                       help='update the sections this benchmark owns in FILE, in place, '
                            'keeping the others (the published report: --write BENCHMARKS.md; '
                            'its plots go to docs/plots beside it)')
    ap.add_argument('--overwrite', action='store_true', help='replace an existing --out file')
    ap.add_argument('--plots', metavar='DIR',
                    help='PNG directory (default: docs/plots beside a --write file, else '
                         'REPORT-plots/ beside the report)')
    ap.add_argument('--scenes', nargs='+', default=None, metavar='SCENE',
                    help=f"work-precision scenes (default {' '.join(SCENES)})")
    ap.add_argument('--methods', nargs='+', default=None, choices=list(METHOD_BY_KEY),
                    metavar='METHOD', help=f"methods (default all: {' '.join(METHOD_BY_KEY)})")
    ap.add_argument('--duration', type=float, default=None,
                    help='simulated span of every work-precision scene [s]')
    ap.add_argument('--rtols', nargs='+', type=float, default=None,
                    help='rtol sweep of the project and CVODE')
    ap.add_argument('--scipy-rtols', nargs='+', type=float, default=None,
                    help='scipy rtol sweep')
    ap.add_argument('--steps', nargs='+', type=float, default=None,
                    help='fixed-step sweep [s] (default: from the largest the real-time mode '
                         'takes, down)')
    ap.add_argument('--budget', type=float, default=None,
                    help='skip runs predicted to take longer [s] (default 20, 5 with --quick)')
    ap.add_argument('--sections', nargs='+', default=list(SECTIONS), choices=list(SECTIONS))
    ap.add_argument('--hard-scenes', nargs='+', default=None, metavar='SCENE')
    ap.add_argument('--hard-duration', type=float, default=None)
    ap.add_argument('--stiffness', nargs='+', type=float, default=None,
                    help=f"shaft stiffnesses of the stability limit (default "
                         f"{' '.join(f'{c:g}' for c in STIFFNESSES)})")
    ap.add_argument('--stability-duration', type=float, default=1.0)
    ap.add_argument('--long-duration', type=float, default=None,
                    help='simulated span of the long run [s] (default 3600, 60 with --quick)')
    ap.add_argument('--steady-scenes', nargs='+', default=None, metavar='SCENE',
                    help=f"steady-state speed scenes (default {' '.join(STEADY_SCENES)})")
    ap.add_argument('--steady-span', type=float, default=None,
                    help=f'timed steady-state span [s] (default {STEADY_SPAN:g}, 20 with --quick)')
    ap.add_argument('--scaling-spans', nargs='+', type=float, default=None,
                    help='simulated spans of the time scaling [s] (default 1 … 3600)')
    ap.add_argument('--scaling-stiffnesses', nargs='+', type=float, default=None,
                    help='shaft stiffnesses of the stiffness scaling [N·m/rad] (1e3 … 1e7)')
    ap.add_argument('--stiffness-span', type=float, default=None,
                    help='simulated span per stiffness [s] (default 1, 0.2 with --quick)')
    ap.add_argument('--sweep-span', type=float, default=None,
                    help='simulated span of the switch-count sweep [s] (default 5, 1 with --quick)')
    return ap.parse_args(argv)


def make_config(a):
    q = a.quick
    scenes = a.scenes or list(SCENES)
    durations = {}
    for s in scenes:
        full, quick = DURATIONS.get(s, DEFAULT_DURATION)
        durations[s] = a.duration if a.duration else (quick if q else full)
    long_duration = a.long_duration or (60.0 if q else 3600.0)
    return Config(
        quick=q, scenes=scenes,
        methods=[METHOD_BY_KEY[k] for k in (a.methods or list(METHOD_BY_KEY))],
        rtols=a.rtols or list(QUICK_RTOLS if q else RTOLS),
        scipy_rtols=a.scipy_rtols or list(QUICK_SCIPY_RTOLS if q else SCIPY_RTOLS),
        steps=a.steps, n_steps=QUICK_N_STEPS if q else N_STEPS,
        budget=a.budget or (5.0 if q else 20.0), durations=durations, levels=ERROR_LEVELS,
        hard_scenes=a.hard_scenes or list(HARD_SCENES),
        hard_duration=a.hard_duration or (0.5 if q else 3.0),
        stiffnesses=a.stiffness or list(STIFFNESSES),
        stability_duration=a.stability_duration,
        stability_formulations=('reduced', 'paper'),
        long_duration=long_duration,
        long_marks=(10.0, 30.0) if q else (60.0, 600.0, 2040.0),
        default_repeats=5 if q else 20,
        steady_scenes=a.steady_scenes or list(STEADY_SCENES),
        steady_span=a.steady_span or (20.0 if q else STEADY_SPAN),
        scaling_spans=a.scaling_spans or list(QUICK_SPANS if q else SPANS),
        scaling_stiffnesses=a.scaling_stiffnesses or list(SCALING_STIFFNESSES),
        stiffness_span=a.stiffness_span or (0.2 if q else 1.0),
        sweep_span=a.sweep_span or (1.0 if q else 5.0))


def output_targets(a, now=None):
    """(report file, plots folder, update in place?) of a run: ``--write FILE`` updates FILE
    (the published BENCHMARKS.md changes only when asked so); ``--out FILE`` writes a new
    report (an existing FILE only with --overwrite); neither: a new ``bench-DATE.md`` in the
    current folder. Raises OutputError before any work for a target that cannot be written."""
    from ..recording import OutputError, OutputFiles
    if a.write:
        out = Path(a.write)
        plots = Path(a.plots) if a.plots else out.parent / 'docs' / 'plots'
    else:
        if a.out:
            out = Path(a.out)
        else:
            stamp = (now or time.strftime('%Y%m%d-%H%M%S'))
            out = Path(f'bench-{stamp}.md')
            for k in range(2, 1000):    # a new file: never one that is there
                if not os.path.lexists(out) and not os.path.lexists(f'{out.stem}-plots'):
                    break
                out = Path(f'bench-{stamp}-{k}.md')
        plots = Path(a.plots) if a.plots else out.with_name(f'{out.stem}-plots')
    targets = OutputFiles()
    targets.check(out, overwrite=bool(a.write or a.overwrite), suffixes=('.md',))
    if plots.exists():
        targets.check(plots, directory=True)
    if not a.write and plots.exists() and any(plots.iterdir()) and not (a.plots or a.overwrite):
        raise OutputError(f'{plots}: exists and is not empty (--plots DIR, or --overwrite)')
    return out, plots, bool(a.write)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in SUBCOMMANDS:  # a benchmark with its own parser takes the rest
        return importlib.import_module(f'.{argv[0]}', __package__).main(argv[1:])
    a = parse_args(argv)
    from ..recording import OutputError
    try:   # every target before an hour of benchmarks, not after
        out, plot_dir, update = output_targets(a)
    except OutputError as exc:
        print(f'cvt-sim bench: error: {exc}', file=sys.stderr)
        return 2
    cfg = make_config(a)

    def log(msg):
        print(f'bench: {msg}', file=sys.stderr, flush=True)

    env = environment()
    t0 = time.perf_counter()
    parts = dict.fromkeys(SECTIONS + ('default', 'steady_load', 'cvode'))
    parts['work'] = []
    parts['loads'] = loads = {}

    def measured(key, fn):
        load0 = os.getloadavg()[0]
        value = fn()
        loads[key] = (load0, os.getloadavg()[0])
        return value
    if 'work' in a.sections:
        def work():
            parts['cvode'] = cvode_overhead(cfg, log)
            results = work_precision(cfg, log)
            parts['default'] = default_settings(cfg, results, log)
            return results
        parts['work'] = measured('work', work)
    if 'steady' in a.sections:
        parts['steady'] = measured('steady', lambda: steady_state(cfg, log))
        parts['steady_load'] = (f"{loads['steady'][0]:.2f} at its start, "
                                f"{loads['steady'][1]:.2f} at its end")
    if 'scaling' in a.sections:
        parts['scaling'] = measured('scaling', lambda: (time_scaling(cfg, log),
                                                        stiffness_scaling(cfg, log)))
    for key, fn in (('events', event_sweep), ('hard', hard_cases),
                    ('stability', stability_limits), ('long', long_run)):
        if key in a.sections:
            parts[key] = measured(key, lambda fn=fn: fn(cfg, log))
    if 'defects' in a.sections:
        parts['defects'] = measured('defects', lambda: known_defects(log))
    plots = plot_all(parts['work'], parts['stability'], parts['default'], plot_dir, cfg)
    data_dir = plot_dir.parent / 'bench' if update and not a.plots else plot_dir
    tables = write_tables(parts, cfg, data_dir)
    here = out.resolve().parent
    rel = {k: os.path.relpath(v, here) for k, v in plots.items()}
    data = {k: os.path.relpath(v, here) for k, v in tables.items()}
    command = 'cvt-sim bench' + (' ' + ' '.join(argv) if argv else '')
    text = page(cfg, env, parts, rel, data, command, time.perf_counter() - t0)
    write_report(out, text, keep_others=update)
    log(f"wrote {out}, {len(plots)} plots in {plot_dir} and {len(tables)} tables in {data_dir} "
        f"({(time.perf_counter() - t0) / 60:.1f} min)")
    return 0
