"""Speed-up at equal error, and the default settings measured against every baseline.

Each method's Pareto front of (wall time, φ4 error) is interpolated log-linearly at the error
levels; ratio = baseline time / project time.
"""
import math

import numpy as np

from ..scene import load_scene
from .measure import run_project
from .report import fmt, table
from .work_precision import METHOD_BY_KEY, Point, score

ERROR_LEVELS = (1e-4, 1e-6, 1e-8)


def time_at_error(points, level):
    """(time [s], exact) to reach φ4 error ``level`` on the method's Pareto front, interpolated
    log-linearly; exact False: already the fastest point is more accurate (an upper bound).
    None: not reached in the sweep."""
    pts = sorted((p.wall, p.phi4_err) for p in points
                 if p.ok and math.isfinite(p.phi4_err) and p.phi4_err > 0.0)
    front = []
    for wall, err in pts:
        if not front or err < front[-1][1]:
            front.append((wall, err))
    if not front:
        return None
    if level >= front[0][1]:
        return front[0][0], False
    for (w0, e0), (w1, e1) in zip(front, front[1:], strict=False):
        if e0 >= level >= e1:
            x = (math.log(level) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(w0) + x * (math.log(w1) - math.log(w0))), True
    return None


def ratio_text(base, proj):
    """Speed-up baseline/project at one error level, with bounds spelled out."""
    if base is None:
        return 'n/r (baseline)'
    if proj is None:
        return 'n/r (project)'
    r = base[0] / proj[0]
    if base[1] and proj[1]:
        return f'{r:.3g}'
    if proj[1]:
        return f'≤ {r:.3g}'
    if base[1]:
        return f'≥ {r:.3g}'
    return f'~{r:.3g} (both at their loosest)'


def default_settings(cfg, results, log):
    """The default settings on the paper scene: accuracy, real-time factor, speed-up at their
    own error level."""
    res = next((r for r in results if r.name == 'paper'), None)
    if res is None:
        return None
    values = load_scene('paper')
    out = run_project(values, res.duration)
    walls = [run_project(values, res.duration).wall for _ in range(cfg.default_repeats)]
    wall = min(walls)
    p = Point(values['solver.rtol'], wall=wall, repeats=len(walls))
    score(p, out, res.reference)
    rk4 = dict(values, **{'solver.method': 'rk4'})
    out4 = run_project(rk4, res.duration)
    walls4 = [run_project(rk4, res.duration).wall for _ in range(max(3, cfg.default_repeats // 4))]
    p4 = Point(values['solver.fixed_step'], wall=min(walls4), repeats=len(walls4))
    score(p4, out4, res.reference)
    log(f"[paper] default settings: φ4 error {p.phi4_err:.2e}, {res.duration / wall:.0f}x "
        f"real time")
    return {'values': values, 'point': p, 'rk4': p4, 'duration': res.duration,
            'walls': walls, 'result': res}


def section_default(d, results, cfg, command):
    p, p4 = d['point'], d['rk4']
    T = d['duration']
    res = d['result']
    L = [f'## Default settings (paper scene, {T:g} s)', '']
    L += [f"The defaults (`solver.method: dopri5`, rtol {d['values']['solver.rtol']:g}, atol "
          f"{d['values']['solver.atol']:g}, max_step {d['values']['solver.max_step']:g} s) on "
          f"the paper scene, {T:g} s from rest, timed {p.repeats} times (minimum; "
          f"median {np.median(d['walls']) * 1e3:.2f} ms):", '']
    rows = [['project dopri5 (default)', fmt(p.phi4_err), fmt(p.omega4_err),
             fmt(p.switch_err) if math.isfinite(p.switch_err) else
             f'nan ({p.switches}/{len(res.reference.switches)})', p.switches,
             f'{p.wall * 1e3:.2f}', f'{T / p.wall:.0f}'],
            ['project rk4 (real-time, default step '
             f"{d['values']['solver.fixed_step']:g} s)", fmt(p4.phi4_err), fmt(p4.omega4_err),
             fmt(p4.switch_err), p4.switches, f'{p4.wall * 1e3:.2f}', f'{T / p4.wall:.0f}']]
    L += table(['settings', 'φ4 rel. error', 'ω4 rel. error', 'switch-time error [s]',
                'switches', 'wall [ms]', 'real-time factor'], rows)
    L += ['']
    need = 'meets' if p.phi4_err <= 1e-6 else 'MISSES'
    fast = 'meets' if T / p.wall >= 1000.0 else 'MISSES'
    L += [f"Requirement ≤ 1e-6 relative error of φ4 after 10 s: {need} it ({fmt(p.phi4_err)})"
          f"{'' if T == 10.0 else f' (here measured after {T:g} s)'}. Requirement ≥ 1000× real "
          f"time on one core: {fast} it ({T / p.wall:.0f}×, minimum of {p.repeats} runs on a "
          "shared machine).", '']
    level = p.phi4_err
    L += [f"Speed-up of the defaults over each baseline at equal φ4 error ({fmt(level)}, the "
          f"defaults' own error; baselines interpolated on their work-precision curves):", '']
    rows = []
    proj = (p.wall, True)
    for key, points in res.curves.items():
        m = METHOD_BY_KEY[key]
        if key == 'dopri5':
            continue
        base = time_at_error(points, level)
        rows.append([m.label, fmt(base[0]) if base else 'n/r', ratio_text(base, proj)])
    L += table(['baseline', 'time to this error [s]', 'speed-up (baseline / default)'], rows)
    return L + ['']


def _fastest_project(res, level):
    """(method key, (time, exact)) of the project's fastest mode at a φ4 error level, or None."""
    best = None
    for k in res.curves:
        if METHOD_BY_KEY[k].project:
            t = time_at_error(res.curves[k], level)
            if t and (best is None or t[0] < best[1][0]):
                best = (k, t)
    return best


SHORT = {'dopri5': 'dopri5', 'dopri5_integrated': 'dopri5 (output integrated)', 'rk4': 'rk4'}


def section_speedup(results, cfg):
    """One table: per scene and φ4 error level, the project's fastest mode (its real-time
    factor) and every baseline's time over it."""
    L = ['## Speed-up at equal error', '']
    L += ['(baseline time) / (project time) to reach the same relative φ4 error, both '
          'interpolated on their Pareto fronts (work-precision curves); the project side is its '
          'fastest mode at that error, with its real-time factor. "≥": the project is already '
          'more accurate at its loosest setting (a bound); "~": both are; n/r: the sweep did '
          'not reach the level. Every method\'s real-time factor at each level: '
          'speed_up.csv beside work_precision.csv.', '']
    baselines = []
    for res in results:
        baselines += [k for k in res.curves if not METHOD_BY_KEY[k].project
                      and k not in baselines]
    header = ['scene', 'φ4 error', 'project (RTF)'] + [
        METHOD_BY_KEY[k].label.replace('SUNDIALS ', '').replace(" (DAE + RK4)", '')
        for k in baselines]
    rows = []
    for res in results:
        for level in cfg.levels:
            best = _fastest_project(res, level)
            cells = [f'{res.name} ({res.duration:g} s)', f'{level:.0e}']
            if best is None:
                rows.append(cells + ['n/r'] + ['–'] * len(baselines))
                continue
            proj = best[1]
            cells.append(f"{SHORT.get(best[0], best[0])} "
                         f"({'≥ ' if not proj[1] else ''}{res.duration / proj[0]:.0f})")
            for k in baselines:
                cells.append(ratio_text(time_at_error(res.curves[k], level), proj)
                             .replace(' (both at their loosest)', '')
                             if k in res.curves else '–')
            rows.append(cells)
    L += table(header, rows)
    return L + ['']


SPEEDUP_COLUMNS = ('scene', 'method', 'phi4_error_level', 'time_to_level_s', 'bound', 'rtf',
                   'speed_up_of_the_project')


def speedup_csv_rows(results, cfg):
    """Per scene, method and error level: its time and real-time factor there, and the
    project's (fastest mode's) speed-up over it."""
    rows = []
    for res in results:
        for level in cfg.levels:
            best = _fastest_project(res, level)
            for k, points in res.curves.items():
                t = time_at_error(points, level)
                ratio = ('' if t is None or best is None or METHOD_BY_KEY[k].project
                         else ratio_text(t, best[1]))
                rows.append([res.name, METHOD_BY_KEY[k].label, f'{level:.0e}',
                             t[0] if t else math.nan,
                             '' if t is None or t[1] else 'upper (loosest setting)',
                             res.duration / t[0] if t else math.nan, ratio])
    return rows
