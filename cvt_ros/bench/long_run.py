"""One hour of simulated time: energy residual, phase error against a tight run, constraint
drift (paper formulation), each mode in a watched child process."""
import math

from ..scene import load_scene
from .measure import run_watched
from .report import fmt, table

TIGHT = {'solver.rtol': 1e-9, 'solver.atol': 1e-11}   # the long run's comparison run


def long_run(cfg, log):
    base = load_scene('paper')
    marks = [t for t in cfg.long_marks if t < cfg.long_duration] + [cfg.long_duration]
    runs, problems = {}, {}
    modes = (('dopri5 (default)', {}), ('rk4 (real-time, default step)', {'solver.method':
                                                                             'rk4'}),
             ('paper formulation, dopri5', {'model.formulation': 'paper'}),
             ('dopri5, rtol 1e-9 (comparison)', TIGHT))
    for label, changes in modes:
        rows, problem = run_watched(dict(base, **changes), marks)
        runs[label] = rows
        if problem:
            problems[label] = problem
        wall = rows[-1]['wall'] if rows else math.nan
        log(f"long run {label}: {rows[-1]['t'] if rows else 0:g} s simulated in {wall:.1f} s"
            + (f' ({problem})' if problem else ''))
    return {'marks': marks, 'runs': runs, 'tight': modes[-1][0], 'problems': problems}


def section_long(long, cfg):
    runs, tight = long['runs'], long['tight']
    T = long['marks'][-1]
    L = [f'## Long run ({T / 3600:g} h simulated)' if T >= 3600 else
         f'## Long run ({T:g} s simulated)', '']
    L += ['The paper scene, default settings, one `advance()` per checkpoint; angles are folded '
          'by whole turns inside the simulator (their sines keep full precision) and restored on '
          f'output. Phase error: |φ − φ_tight| against dopri5 at rtol 1e-9 ({tight}). Energy '
          'residual: relative, of the integrated balance (physics.md §4). Paper formulation: '
          'the constraint drift |f(φ1, φ2)| [m²] as well.', '']
    tight_rows = {r['t']: r for r in runs[tight]}
    body = []
    for label, rows in runs.items():
        for r in rows:
            t = tight_rows.get(r['t'], {'phi1': math.nan, 'phi4': math.nan})
            body.append([label, fmt(r['t']), fmt(r['wall']), f"{r['t'] / r['wall']:.0f}",
                         fmt(r['energy']),
                         fmt(abs(r['phi1'] - t['phi1'])) if label != tight else '–',
                         fmt(abs(r['phi4'] - t['phi4'])) if label != tight else '–',
                         fmt(abs(r['phi4'] - t['phi4']) / abs(t['phi4'])) if label != tight
                         else '–', r['switches'],
                         fmt(r['constraint']) if 'paper' in label else '–'])
    L += table(['run', 't [s]', 'wall [s]', 'RTF', 'energy residual', 'φ1 phase error [rad]',
                'φ4 phase error [rad]', 'φ4 rel. error', 'switches', 'constraint drift'], body)
    L += ['']
    for label, problem in long.get('problems', {}).items():
        L += [f"**{label}: {problem}** (run in a child process so the benchmark can go on; see "
              "[Known defects](#known-defects)). Its rows stop at the last checkpoint reached.",
              '']
    return L
