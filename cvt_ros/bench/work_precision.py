"""Work-precision of the hybrid solver against its baselines (SciMLBenchmarks' method).

Every method runs the same scene from the same consistent initial state over the same span; its
error is measured against one reference solution computed at a tolerance of 1e-13 and checked
against an independent solver; its cost is the wall time of the integration, the minimum of
several runs after a warm-up. Each method sweeps its accuracy knob (rtol, or the fixed step),
which traces a curve of error against time.

Methods (all on the same equations, physics/dynamics.rhs):

* ``dopri5``: the project's adaptive Dormand-Prince 5(4) with events on its dense output and the
  disengaged output subsystem in closed form (``solver.method: dopri5``), rtol swept,
  atol = 1e-2·rtol;
* ``dopri5_integrated``: the same with the output subsystem integrated on its own clock
  (``solver.output_subsystem: integrate``): the ablation of the exact output;
* ``rk4``: the project's real-time mode, fixed-step RK4, events located inside the step, the step
  refined below the shaft's stability limit (``solver.refine_step: auto``), fixed_step swept;
* ``paper_rk4``: the paper's method: its index-reduced DAE with Baumgarte stabilization
  (``model.formulation: paper``) and classical fixed-step RK4 without step refinement; its clutch
  switches are located by the project's event location (the paper does not say how it found them);
* ``scipy_*``: ``scipy.integrate.solve_ivp`` with terminal events (RK45, DOP853, Radau, LSODA) on
  the same right-hand side and automaton (solver/reference.py), rtol swept, atol = 1e-2·rtol;
* ``cvode_*``: SUNDIALS CVODE, BDF and Adams (scikit-sundae's wheel: sundials4py has none here),
  driven the same way (solver/cvode.py): the compiled right-hand side per clutch mode, the guard
  as CVODE's root function, terminal roots → reset map → restart; rtol swept as the project's,
  atol = 1e-2·rtol. Skipped with a note when scikit-sundae is not installed.

Errors: relative error of φ4 and of ω4 at the end of the span; switch-time error = max |Δt| over
the clutch switches matched in order (NaN when the number of switches differs from the
reference's; the mismatch is reported).
"""
import math
import time
from dataclasses import dataclass, field

from ..scene import load_scene
from ..solver import cvode
from ..solver.reference import solve_reference
from ..solver.simulator import SimulationError, fixed_step
from .measure import (
    BLOWUP_RESIDUAL,
    Outcome,
    relative,
    run_cvode,
    run_project,
    run_scipy,
    switch_error,
    timed,
)
from .report import fmt, table

SCENES = ('paper', 'conveyor', 'mixer', 'stiff_shaft')


# simulated span per scene [s]: (full, --quick)
DURATIONS = {'paper': (10.0, 2.0), 'conveyor': (5.0, 1.0), 'mixer': (5.0, 1.0),
             'stiff_shaft': (1.0, 0.3)}


DEFAULT_DURATION = (5.0, 1.0)


RTOLS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11)


QUICK_RTOLS = (1e-4, 1e-6, 1e-8)


SCIPY_RTOLS = RTOLS[:-1]   # 1e-11 costs scipy RK45/Radau minutes and adds nothing


QUICK_SCIPY_RTOLS = (1e-4, 1e-6)


STEPS = (1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5, 5e-6, 2e-6, 1e-6, 5e-7, 2e-7)


N_STEPS, QUICK_N_STEPS = 7, 3


REFERENCE = {'solver.method': 'dopri5', 'solver.rtol': 1e-13, 'solver.atol': 1e-15,
             'solver.max_step': 1e-3, 'solver.output_subsystem': 'exact'}


SELF_CHECK = dict(REFERENCE, **{'solver.rtol': 1e-12, 'solver.atol': 1e-14})


CHECK_METHOD, CHECK_RTOL, CHECK_ATOL = 'DOP853', 1e-12, 1e-14


@dataclass(frozen=True)
class Method:
    key: str
    label: str
    knob: str                  # 'rtol' | 'h'
    changes: tuple = ()        # parameter values on top of the scene
    scipy: str = ''            # solve_ivp method, if a scipy baseline
    cvode: str = ''            # CVODE method (BDF / Adams), if a SUNDIALS baseline
    project: bool = False      # the project's solver (numerator of the speed-ups)
    style: tuple = ('-', 'o')  # plot line style, marker

    @property
    def values(self):
        return dict(self.changes)

    @property
    def counts_rhs(self):
        """Its work is counted in RHS evaluations (a baseline), not in steps."""
        return bool(self.scipy or self.cvode)


METHODS = (
    Method('dopri5', 'project dopri5', 'rtol', (('solver.method', 'dopri5'),), project=True,
           style=('-', 'o')),
    Method('dopri5_integrated', 'project dopri5, output integrated', 'rtol',
           (('solver.method', 'dopri5'), ('solver.output_subsystem', 'integrate')),
           project=True, style=('-', 's')),
    Method('rk4', 'project rk4 (real-time)', 'h',
           (('solver.method', 'rk4'), ('solver.refine_step', 'auto')), project=True,
           style=('-', 'D')),
    Method('paper_rk4', "paper's method (DAE + RK4)", 'h',
           (('solver.method', 'rk4'), ('model.formulation', 'paper'),
            ('solver.refine_step', 'off')), style=('--', 'v')),
    Method('scipy_RK45', 'scipy RK45', 'rtol', scipy='RK45', style=(':', '^')),
    Method('scipy_DOP853', 'scipy DOP853', 'rtol', scipy='DOP853', style=(':', 'P')),
    Method('scipy_Radau', 'scipy Radau', 'rtol', scipy='Radau', style=(':', 'X')),
    Method('scipy_LSODA', 'scipy LSODA', 'rtol', scipy='LSODA', style=(':', '*')),
    Method('cvode_BDF', 'SUNDIALS CVODE BDF', 'rtol', cvode='BDF', style=('-.', 'h')),
    Method('cvode_Adams', 'SUNDIALS CVODE Adams', 'rtol', cvode='Adams', style=('-.', 'p')),
)


METHOD_BY_KEY = {m.key: m for m in METHODS}


@dataclass
class Point:
    setting: float
    status: str = 'ok'         # ok | failed: … | skipped: …
    wall: float = math.nan
    repeats: int = 0
    phi4_err: float = math.nan
    omega4_err: float = math.nan
    switch_err: float = math.nan
    switches: int = 0
    work: int = 0
    energy: float = math.nan
    h: float = math.nan
    rejected: int = 0

    @property
    def ok(self):
        return self.status == 'ok'


@dataclass
class Reference:
    phi4: float
    omega4: float
    switches: list
    wall: float
    checks: list = field(default_factory=list)   # (what, φ4 rel, ω4 rel, switches, max Δt)
    label: str = ''


@dataclass
class SceneResult:
    name: str
    duration: float
    reference: Reference
    curves: dict = field(default_factory=dict)   # method key → [Point]
    notes: list = field(default_factory=list)


def score(point, out, ref):
    point.phi4_err = relative(out.phi4, ref.phi4)
    point.omega4_err = relative(out.omega4, ref.omega4)
    point.switches = len(out.switches)
    point.switch_err = switch_error(out.switches, ref.switches)
    point.work = out.work
    point.energy = out.energy
    point.h = out.h
    point.rejected = out.rejected


def compute_reference(name, values, duration, log):
    """The project's dopri5 at rtol 1e-13 with the open clutch's output in closed form, and the
    same with that output integrated; the closed form is used unless the two disagree (a known
    defect of the closed form can miss a short re-engagement: then the integrated one is the
    reference). Checked against the chosen variant at rtol 1e-12 and scipy DOP853."""
    variants = {'exact': run_project(dict(values, **REFERENCE), duration)}
    if values['load.quadratic'] == 0.0:   # (a quadratic load is integrated either way)
        variants['integrate'] = run_project(dict(values, **dict(REFERENCE, **{
            'solver.output_subsystem': 'integrate'})), duration)
    chosen = 'exact'
    if 'integrate' in variants:
        a, b = variants['exact'], variants['integrate']
        dt = switch_error(a.switches, b.switches)
        if not (dt <= 1e-9) or relative(a.phi4, b.phi4) > 1e-10:
            chosen = 'integrate'
    out = variants[chosen]
    label = {'exact': 'output in closed form', 'integrate': 'output integrated'}
    if values['load.quadratic'] != 0.0:
        label['exact'] = 'output integrated (a quadratic load has no closed form)'
    ref = Reference(out.phi4, out.omega4, out.switches, out.wall)
    ref.label = f"project dopri5, rtol 1e-13, atol 1e-15, max_step 1e-3, {label[chosen]}"
    log(f"[{name}] reference: {ref.label}, {len(out.switches)} switches, {out.wall:.2f} s")
    checks = [(f"project dopri5, rtol 1e-13, {label[k]}", o) for k, o in variants.items()
              if k != chosen]
    extra = {} if chosen == 'exact' else {'solver.output_subsystem': 'integrate'}
    checks.append((f'project dopri5, rtol 1e-12, atol 1e-14, {label[chosen]}',
                   run_project(dict(values, **dict(SELF_CHECK, **extra)), duration)))
    r = solve_reference(values, duration, method=CHECK_METHOD, rtol=CHECK_RTOL, atol=CHECK_ATOL)
    checks.append((f'scipy {CHECK_METHOD}, rtol 1e-12, atol 1e-14',
                   Outcome(float(r.y[6]), float(r.y[7]), list(r.switch_times), r.wall_time)))
    for what, o in checks:
        ref.checks.append((what, relative(o.phi4, ref.phi4), relative(o.omega4, ref.omega4),
                           len(o.switches), switch_error(o.switches, ref.switches), o.wall))
    log(f"[{name}] reference checked against {CHECK_METHOD} ({r.wall_time:.1f} s)")
    return ref


def step_sweep(values, n):
    """The rk4 steps for a scene: the largest the real-time mode takes (its refined step), then
    the round steps below it, n in all."""
    h_stable = fixed_step(values)[0]
    steps = [min(STEPS[0], h_stable)]
    steps += [h for h in STEPS if h < steps[0] * (1.0 - 1e-9)]
    return steps[:n]


def sweep(method, name, values, duration, settings, ref, cfg, log):
    """One method's curve: loose to tight; a run predicted (from the last two) to take longer
    than the budget is skipped with all tighter ones."""
    points = [Point(s) for s in settings]
    walls = []
    t_start = time.perf_counter()
    for k, point in enumerate(points):
        setting = point.setting
        if walls:
            growth = max(1.0, walls[-1] / walls[-2]) if len(walls) >= 2 else 1.0
            predicted = walls[-1] * growth
            if predicted > cfg.budget:
                for p in points[k:]:
                    p.status = f'skipped: predicted {predicted:.0f} s > {cfg.budget:g} s'
                break
        if method.scipy:
            def fn(setting=setting):
                return run_scipy(values, duration, method.scipy, setting)
        elif method.cvode:
            def fn(setting=setting):
                return run_cvode(values, duration, method.cvode, setting)
        else:
            extra = dict(method.values)
            if method.knob == 'rtol':
                extra.update({'solver.rtol': setting, 'solver.atol': setting * 1e-2})
            else:
                extra['solver.fixed_step'] = setting

            def fn(extra=extra):
                return run_project(dict(values, **extra), duration)
        try:
            out, wall, n = timed(fn, cfg.quick)
        except (SimulationError, RuntimeError, FloatingPointError, ValueError) as exc:
            point.status = f'failed: {str(exc).splitlines()[0][:90]}'
            continue
        if not (math.isfinite(out.phi4) and math.isfinite(out.omega4)):
            point.status = 'failed: non-finite state'
            continue
        if method.key == 'paper_rk4' and out.energy > BLOWUP_RESIDUAL:
            point.status = f'failed: unstable (energy residual {out.energy:.1e})'
            continue
        point.wall, point.repeats = wall, n
        score(point, out, ref)
        walls.append(wall)
    done = [p for p in points if p.ok]
    log(f"[{name}] {method.label}: {len(done)}/{len(points)} points, "
        f"{time.perf_counter() - t_start:.1f} s")
    return points


def warm_up(methods, log):
    """Compile / load every kernel and the scipy path once, on a short span of the paper scene
    (stable for every method at its default settings)."""
    values = load_scene('paper')
    t0 = time.perf_counter()
    for m in methods:
        v = dict(values, **m.values)
        if m.scipy:
            solve_reference(values, 0.02, method=m.scipy, rtol=1e-4, atol=1e-6)
        elif m.cvode:
            cvode.solve_cvode(values, 0.02, method=m.cvode, rtol=1e-4)
        else:
            run_project(v, 0.02)
    log(f"warm-up: {time.perf_counter() - t0:.1f} s")


def usable_methods(cfg, log):
    """cfg.methods without the CVODE ones when scikit-sundae is missing (one line says so)."""
    missing = cvode.available() if any(m.cvode for m in cfg.methods) else None
    if missing is None:
        return list(cfg.methods)
    log(f'{missing}: the CVODE methods are left out')
    cfg.skipped.append(missing)
    return [m for m in cfg.methods if not m.cvode]


def cvode_overhead(cfg, log):
    """Per-call cost of CVODE's callbacks on the paper scene (solver/cvode.callback_overhead),
    or None without CVODE methods."""
    if not any(m.cvode for m in cfg.methods) or cvode.available() is not None:
        return None
    out = cvode.callback_overhead(load_scene('paper'))
    log(f"CVODE callbacks: kernel {out['kernel_s'] * 1e9:.0f} ns, from Python "
        f"{out['python_call_s'] * 1e9:.0f} ns, CVODE wall per RHS "
        f"{out['cvode_per_rhs_s'] * 1e9:.0f} ns")
    return out


def work_precision(cfg, log):
    results = []
    methods = usable_methods(cfg, log)
    for name in cfg.scenes:
        values = load_scene(name)
        duration = cfg.duration_for(name)
        if cfg.warm:
            warm_up(methods, log)
            cfg.warm = False
        ref = compute_reference(name, values, duration, log)
        res = SceneResult(name, duration, ref)
        steps = cfg.steps or step_sweep(values, cfg.n_steps)
        for m in methods:
            if m.knob == 'h':
                settings = steps
            elif m.scipy:
                settings = cfg.scipy_rtols
            else:
                settings = cfg.rtols
            res.curves[m.key] = sweep(m, name, values, duration, list(settings), ref, cfg, log)
        if values['load.quadratic'] != 0.0:
            res.notes.append('The quadratic load makes the open clutch\'s output nonlinear: it is '
                             'integrated on its own clock in both dopri5 variants (no closed '
                             'form), so the two curves measure the same method.')
        results.append(res)
    return results


def setting_text(method, p):
    if method.knob == 'rtol':
        return f'rtol {p.setting:.0e}'
    if math.isfinite(p.h) and abs(p.h - p.setting) > 1e-12 * p.setting:
        return f'h {fmt(p.setting)} → {fmt(p.h)}'
    return f'h {fmt(p.setting)}'


CSV_COLUMNS = ('scene', 'span_s', 'method', 'setting', 'status', 'wall_s', 'repeats', 'rtf',
               'phi4_rel_error', 'omega4_rel_error', 'switch_time_error_s', 'switches',
               'reference_switches', 'work', 'work_counted', 'rejected', 'energy_residual',
               'step_taken_s')


def csv_rows(results):
    """Every point of every curve, one row each (the page shows the plots and the summary)."""
    rows = []
    for res in results:
        for key, points in res.curves.items():
            m = METHOD_BY_KEY[key]
            for p in points:
                work = ('rhs' if m.counts_rhs else 'steps')
                rows.append([res.name, res.duration, m.label, setting_text(m, p), p.status,
                             p.wall, p.repeats, res.duration / p.wall if p.ok else math.nan,
                             p.phi4_err, p.omega4_err, p.switch_err, p.switches,
                             len(res.reference.switches), p.work, work,
                             p.rejected if m.knob == 'rtol' and not m.counts_rhs else '',
                             p.energy, p.h])
    return rows


def write_csv(path, header, rows):
    """A table for spreadsheets and pandas: floats with 6 significant digits, nan as empty."""
    import csv

    def cell(x):
        if isinstance(x, float):
            return '' if math.isnan(x) else f'{x:.6g}'
        return x
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[cell(x) for x in row] for row in rows])
    return path


def _scipy_disagrees(res):
    return any(what.startswith('scipy') and (n != len(res.reference.switches) or e_phi > 1e-9)
               for what, e_phi, _, n, _, _ in res.reference.checks)


def section_references(results):
    """One row per scene: the reference and how far its three checks are from it."""
    rows = []
    for res in results:
        ref = res.reference
        n = len(ref.switches)
        checks = '; '.join(
            f"{what.split(', atol')[0].replace('project dopri5, ', '')}: "
            f"{fmt(e_phi)}{'' if k == n else f' ({k}/{n} switches)'}"
            for what, e_phi, _, k, _, _ in ref.checks)
        dt = max((c[4] for c in ref.checks if math.isfinite(c[4])), default=math.nan)
        rows.append([f'`{res.name}`', f'{res.duration:g} s',
                     ref.label.split('max_step 1e-3, ')[-1], f'{ref.phi4:.12g}', n, checks,
                     fmt(dt)])
    L = table(['scene', 'span', 'reference output', 'φ4 [rad]', 'switches',
               'φ4 rel. difference of each check', 'max switch Δt [s]'], rows) + ['']
    for res in results:
        if _scipy_disagrees(res):
            L += [f"`{res.name}`: scipy's check misses switches — solve_ivp sees an event only "
                  "by a sign change of the guard between two step ends, so a short elastic "
                  "bounce inside one step goes unseen; the reference rests on the project's own "
                  "convergence there, and the scipy curves carry that model error.", '']
        L += [f'`{res.name}`: {note}' for note in res.notes] + (res.notes and [''] or [])
    return L


def section_plots(results, plots):
    """The work-precision plots two to a row."""
    shown = [res for res in results if res.name in plots]
    L = []
    for k in range(0, len(shown), 2):
        pair = shown[k:k + 2]
        L += ['| ' + ' | '.join(f'![work-precision {r.name}]({plots[r.name]})' for r in pair)
              + ' |']
        if k == 0:
            L += ['|' + '---|' * len(pair)]
    return L + [''] if L else []


def section_cvode(overhead, cfg):
    """What the CVODE baseline is, what of it is compiled and what its callbacks cost."""
    if cfg.skipped:
        return [f'CVODE left out of this run: {line}.' for line in cfg.skipped] + ['']
    if overhead is None:
        return []
    return [f"CVODE: SUNDIALS' CVODE from the scikit-sundae wheel (dense direct linear solver, "
            "difference-quotient Jacobian counted in the RHS evaluations, one instance per "
            "clutch mode, re-initialised at each switch); the right-hand side and the guard are "
            "the project's compiled kernels, called through Python wrappers (scikit-sundae "
            f"takes no C function pointer): the kernel {overhead['kernel_s'] * 1e9:.0f} ns a "
            f"call, from Python {overhead['python_call_s'] * 1e9:.0f} ns, CVODE BDF at rtol "
            f"1e-8 {overhead['cvode_per_rhs_s'] * 1e6:.1f} µs of wall time per RHS evaluation "
            f"({overhead['cvode_per_rhs_s'] / overhead['kernel_s']:.0f}× the kernel). Like "
            "scipy, CVODE sees a root only where the guard changes sign between step ends.", '']
