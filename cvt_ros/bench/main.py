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
from .hard_cases import HARD_SCENES, hard_cases, section_hard
from .long_run import long_run, section_long
from .plots import plot_all
from .report import OWN_TITLE, environment, write_report
from .scaling import (
    QUICK_SPANS,
    SPANS,
    event_sweep,
    section_scaling,
    stiffness_scaling,
    time_scaling,
)
from .scaling import STIFFNESSES as SCALING_STIFFNESSES
from .speedup import ERROR_LEVELS, default_settings, section_default, section_speedup
from .stability import STIFFNESSES, section_limits, stability_limits
from .steady_state import SCENES as STEADY_SCENES
from .steady_state import STEADY_SPAN, section_steady, steady_state
from .work_precision import (
    CHECK_METHOD,
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
    cvode_overhead,
    section_cvode,
    section_scene,
    work_precision,
)

SECTIONS = ('work', 'steady', 'scaling', 'events', 'hard', 'stability', 'long', 'defects')
# modules with their own main(argv)
SUBCOMMANDS = ('node', 'fidelity', 'sweep', 'profile', 'design', 'paths', 'compile')


def page(cfg, env, parts, plots, command, wall_total):
    L = [OWN_TITLE, '']
    L += [f'Made by `{command}` in {wall_total / 60:.1f} min (the numbers and plots below; '
          f'`cvt-sim bench` runs the same module).', '']
    L += [f"Machine: {env['cpu']}, {env['cores']} cores ({env['platform']}); load average "
          f"{env['load'][0]:.2f} at the start, {os.getloadavg()[0]:.2f} at the end (other jobs "
          f"shared the machine). Python {env['python']}, "
          + ', '.join(f'{k} {v}' for k, v in env['versions'].items())
          + f". Revision {env['revision']}, {env['date']}.", '']
    L += ['Method (SciMLBenchmarks work-precision): every method integrates the same scene from '
          'the same consistent initial state over the same span; **time** is the wall time of '
          'the integration alone (simulator set-up and kernel compilation excluded), the '
          '**minimum** of several runs after a warm-up of every kernel (5 runs below 0.3 s, 3 '
          'below 1 s, 2 below 3 s, 1 above; 2/1 with `--quick`); every solver is '
          'single-threaded (one core). **Errors** against a reference solution: relative error '
          'of φ4 and ω4 at the end of the span, and the switch-time error max |Δt| over the '
          'clutch switches matched in order (nan when the switch count differs from the '
          'reference\'s; the count is then shown as n/N). Real-time factor (RTF) = simulated '
          'span / wall time. Speed-up at equal error = (baseline time) / (project time), both '
          'read off the log-log Pareto front of (time, φ4 error) at the same error level '
          '("≤"/"≥": one side is already more accurate at its loosest setting, so the ratio is '
          'a bound; n/r: the sweep did not reach the level).', '']
    L += ["Reference per scene: the project's dopri5 at rtol 1e-13, atol 1e-15, max_step 1e-3 "
          "(open-clutch output in closed form, or integrated where the two disagree), checked "
          "against the other variant, against itself at rtol 1e-12, and against scipy "
          f"{CHECK_METHOD} (solve_ivp with events, an independent stepper and event locator) at "
          "rtol 1e-12, atol 1e-14; the agreement is tabulated per scene.", '']
    results, default = parts['work'], parts['default']
    hard, limits, long, defects = (parts['hard'], parts['stability'], parts['long'],
                                   parts['defects'])
    if parts['steady']:
        L += section_steady(parts['steady'], parts['steady_load'])
    if parts['scaling'] or parts['events']:
        times, stiffness = parts['scaling'] or ([], [])
        L += section_scaling(times, stiffness, parts['events'], cfg)
    if default:
        L += section_default(default, results, cfg, command)
    L += ['## Work-precision', '']
    L += ['Methods: **project dopri5** (adaptive DP5(4), events on its dense output, the open '
          'clutch\'s linear output subsystem in closed form), **project dopri5, output '
          'integrated** (the ablation: that subsystem integrated on its own clock), **project '
          'rk4 (real-time)** (fixed-step RK4, events located inside the step, the step refined '
          'below the shaft\'s stability limit: "h a → b" is asked → taken), **paper\'s method** '
          '(the paper\'s index-reduced DAE, eqs. 9/11/12 with Baumgarte stabilization at 200 1/s, '
          'classical RK4 at the fixed step, no refinement; its clutch switches are located with '
          'the project\'s event location, which the paper does not describe), and scipy '
          '`solve_ivp` RK45, DOP853, Radau, LSODA with terminal events on the same right-hand '
          'side (cvt_ros/solver/reference.py), and **SUNDIALS CVODE** BDF and Adams (its '
          'variable-order multistep methods with their own root finding) driven the same way '
          '(cvt_ros/solver/cvode.py); atol = 1e-2·rtol everywhere. A baseline setting '
          f'whose run is predicted (from the two looser ones) to take more than {cfg.budget:g} s '
          'is skipped, with all tighter ones.', '']
    L += section_cvode(parts['cvode'], cfg)
    L += [f"Spans: {', '.join(f'{r.name} {r.duration:g} s' for r in results)}"
          + (' (the stiff shaft shorter: scipy needs ~10 s per simulated second there at '
             'tight tolerances).' if any(r.name == 'stiff_shaft' for r in results) else '.'), '']
    for res in results:
        L += section_scene(res, cfg, plots)
    L += section_speedup(results, cfg)
    if hard:
        L += section_hard(hard, cfg)
    if limits:
        L += section_limits(limits, cfg, plots)
    if long:
        L += section_long(long, cfg)
    if defects:
        L += section_defects(defects)
    return '\n'.join(L).rstrip() + '\n'


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
    if 'work' in a.sections:
        parts['work'] = work_precision(cfg, log)
        parts['cvode'] = cvode_overhead(cfg, log)
        parts['default'] = default_settings(cfg, parts['work'], log)
    if 'steady' in a.sections:
        load0 = os.getloadavg()[0]
        parts['steady'] = steady_state(cfg, log)
        parts['steady_load'] = f"{load0:.2f} at its start, {os.getloadavg()[0]:.2f} at its end"
    if 'scaling' in a.sections:
        parts['scaling'] = (time_scaling(cfg, log), stiffness_scaling(cfg, log))
    if 'events' in a.sections:
        parts['events'] = event_sweep(cfg, log)
    if 'hard' in a.sections:
        parts['hard'] = hard_cases(cfg, log)
    if 'stability' in a.sections:
        parts['stability'] = stability_limits(cfg, log)
    if 'long' in a.sections:
        parts['long'] = long_run(cfg, log)
    if 'defects' in a.sections:
        parts['defects'] = known_defects(log)
    plots = plot_all(parts['work'], parts['stability'], parts['default'], plot_dir, cfg)
    rel = {k: os.path.relpath(v, out.resolve().parent) for k, v in plots.items()}
    command = 'cvt-sim bench' + (' ' + ' '.join(argv) if argv else '')
    text = page(cfg, env, parts, rel, command, time.perf_counter() - t0)
    write_report(out, text, keep_others=update)
    log(f"wrote {out} and {len(plots)} plots in {plot_dir} "
        f"({(time.perf_counter() - t0) / 60:.1f} min)")
    return 0
