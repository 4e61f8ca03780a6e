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
    tight = long['tight']
    T = long['marks'][-1]
    L = [f'## Long run ({T / 3600:g} h simulated)' if T >= 3600 else
         f'## Long run ({T:g} s simulated)', '']
    L += ['The paper scene, default settings, one `advance()` per checkpoint; angles are folded '
          'by whole turns inside the simulator (their sines keep full precision) and restored on '
          f'output. Phase error: |φ − φ_tight| against dopri5 at rtol 1e-9 ({tight}). Energy '
          'residual: relative, of the integrated balance (physics.md §4). Paper formulation: '
          'the constraint drift |f(φ1, φ2)| [m²] as well.', '']
    L += ['The last checkpoint of each run (every checkpoint: long_run.csv beside '
          'work_precision.csv).', '']
    rows = long_csv_rows(long)
    last = {}
    for r in rows:
        last[r[0]] = r
    body = [[label, fmt(t), fmt(wall), f'{rtf:.0f}', fmt(energy),
             '–' if label == tight else fmt(e1), '–' if label == tight else fmt(e4),
             '–' if label == tight else fmt(rel), switches,
             fmt(drift) if 'paper' in label else '–']
            for label, t, wall, rtf, energy, e1, e4, rel, switches, drift in last.values()]
    L += table(['run', 't [s]', 'wall [s]', 'RTF', 'energy residual', 'φ1 phase error [rad]',
                'φ4 phase error [rad]', 'φ4 rel. error', 'switches', 'constraint drift'], body)
    L += ['']
    for label, problem in long.get('problems', {}).items():
        L += [f"**{label}: {problem}** (run in a child process so the benchmark can go on; see "
              "[Known defects](#known-defects)). Its rows stop at the last checkpoint reached.",
              '']
    return L


LONG_COLUMNS = ('run', 't_s', 'wall_s', 'rtf', 'energy_residual', 'phi1_phase_error_rad',
                'phi4_phase_error_rad', 'phi4_rel_error', 'switches', 'constraint_drift_m2')


def long_csv_rows(long):
    """Every checkpoint of every run; phase errors against the tight run's same checkpoint."""
    runs, tight = long['runs'], long['tight']
    tight_rows = {r['t']: r for r in runs[tight]}
    out = []
    for label, rows in runs.items():
        for r in rows:
            t = tight_rows.get(r['t'], {'phi1': math.nan, 'phi4': math.nan})
            e1 = abs(r['phi1'] - t['phi1'])
            e4 = abs(r['phi4'] - t['phi4'])
            out.append([label, r['t'], r['wall'], r['t'] / r['wall'], r['energy'],
                        math.nan if label == tight else e1, math.nan if label == tight else e4,
                        math.nan if label == tight else e4 / abs(t['phi4']), r['switches'],
                        r['constraint'] if 'paper' in label else math.nan])
    return out
