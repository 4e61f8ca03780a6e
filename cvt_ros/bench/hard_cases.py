"""Every solver mode through the hard cases of physics.md §7: finite, no backward slip, no
pulling clutch, energy balance, switches per crank turn, no chattering."""
import math
import time

import numpy as np

from ..scene import load_scene
from ..solver.output import COL
from ..solver.simulator import SimulationError, Simulator
from .report import fmt, table

HARD_SCENES = ('paper', 'conveyor', 'mixer', 'stiff_shaft', 'massless_clutch', 'rigid_shaft',
               'neutral_crank', 'near_grashof', 'grazing')


def hard_cases(cfg, log):
    modes = (('dopri5', {}), ('dopri5, output integrated', {'solver.output_subsystem':
                                                             'integrate'}),
             ('rk4 (real-time)', {'solver.method': 'rk4'}),
             ('paper formulation, dopri5', {'model.formulation': 'paper'}),
             ('paper formulation, rk4', {'model.formulation': 'paper', 'solver.method': 'rk4'}))
    rows = []
    t0 = time.perf_counter()
    for name in cfg.hard_scenes:
        base = load_scene(name)
        for label, changes in modes:
            rows.append(hard_case_row(name, label, dict(base, **changes), cfg.hard_duration))
    log(f"hard cases: {len(rows)} runs, {time.perf_counter() - t0:.1f} s")
    return rows


def hard_case_row(name, mode, values, duration):
    row = {'scene': name, 'mode': mode, 'status': 'ok'}
    sim = Simulator(values)
    try:
        result = sim.run(duration, duration / 100000.0 if duration > 0 else 1e-5)
    except SimulationError as exc:
        row['status'] = f'failed: {exc}'
        return row
    s = result.samples
    engaged = s[:, COL['engaged']] == 1.0
    slip = s[:, COL['omega3']] - s[:, COL['omega2']]
    speed = max(1.0, float(np.max(np.abs(s[:, [COL['omega2'], COL['omega3']]]))))
    torque = s[:, COL['clutch_torque']]
    tscale = max(1.0, float(np.max(np.abs(torque))))
    real = [x for x in result.switches if x.kind != 'graze']
    turns = (s[-1, COL['phi1']] - s[0, COL['phi1']]) / (2.0 * math.pi)
    late = [x for x in real if x.t > duration / 2.0]
    late_turns = (s[-1, COL['phi1']] - np.interp(duration / 2.0, s[:, 0], s[:, COL['phi1']])) \
        / (2.0 * math.pi)
    gaps = np.diff([x.t for x in real])
    row.update({
        'finite': bool(np.all(np.isfinite(s))),
        'slip_min': float(np.min(slip[~engaged])) / speed if (~engaged).any() else math.nan,
        'torque_min': float(np.min(torque[engaged])) / tscale if engaged.any() else math.nan,
        'energy': result.energy['relative_residual'],
        'per_turn': len(late) / late_turns if late_turns > 0.1 else math.nan,
        'switches': len(real), 'grazes': len(result.switches) - len(real),
        'turns': turns, 'min_gap': float(np.min(gaps)) if len(gaps) else math.nan,
        'wall': result.wall_time, 'rtol': values['solver.rtol'],
    })
    if name == 'neutral_crank':
        c, load = values['shaft.stiffness'], values['load.torque']
        row['note'] = (f"φ4 min {np.min(s[:, COL['phi4']]):.3e} rad "
                       f"(static twist −M4/c = {-load / c:.3e}); "
                       f"|ω4| at end {abs(s[-1, COL['omega4']]):.1e} rad/s")
    elif name == 'near_grashof':
        u_max = np.max(np.abs(s[:, COL['omega2']])) / np.max(np.abs(s[:, COL['omega1']]))
        row['note'] = f"max |ω2| / max |ω1| = {u_max:.2f}"
    elif name == 'grazing':
        row['note'] = f"{row['grazes']} grazing contacts, none a switch"
    if values['model.formulation'] == 'paper':
        drift = float(np.max(np.abs(s[:, COL['constraint']])))
        row['note'] = (row.get('note', '') + '; ' if row.get('note') else '') + \
            f'constraint drift {drift:.1e} m²'
    return row


def section_hard(rows, cfg):
    L = ['## Numerical stability on hard cases', '']
    L += [f"Every solver mode (default settings otherwise) through every hard case of physics.md "
          f"§7, {cfg.hard_duration:g} s from rest, sampled every {cfg.hard_duration / 1e5:.0e} s. "
          "Columns: all samples finite; the most negative slip ω3 − ω2 while disengaged and the "
          "most negative clutch torque while engaged, relative to the largest member speed / "
          "clutch torque of the run (the clutch forbids both: they must be ≥ −tolerance); the "
          "energy balance's relative residual (physics.md §4) and the mode's rtol; real "
          "switches (engage/release) per crank turn over the second half (2 in steady state, "
          "more only for physical elastic bounces); the smallest time between two switches (a "
          "chattering burst would show ~1e-13 s); grazing contacts (not switches). The same "
          "properties are asserted over random valid parameters in test/test_stability.py.", '']
    L += ["One row per scene: the worst over its modes (each mode's row: hard_cases.csv beside "
          "work_precision.csv).", '']
    body = []
    for name in dict.fromkeys(r['scene'] for r in rows):
        mine = [r for r in rows if r['scene'] == name]
        ok = [r for r in mine if r['status'] == 'ok']
        failed = [f"{r['mode']}: {r['status'][:60]}" for r in mine if r['status'] != 'ok']
        if not ok:
            body.append([name, len(mine), '; '.join(failed)] + [''] * 7)
            continue

        def low(key, ok=ok):
            values = [r[key] for r in ok if math.isfinite(r[key])]
            return fmt(min(values)) if values else 'nan'
        worst = max(ok, key=lambda r: r['energy'] / r['rtol'])
        turns = sorted({fmt(r['per_turn']) for r in ok})
        notes = dict.fromkeys(part for r in ok for part in r.get('note', '').split('; ')
                              if part and not part.startswith('constraint drift'))
        drift = [r['note'].split('constraint drift ')[1] for r in ok
                 if 'constraint drift' in r.get('note', '')]
        if drift:
            notes[f"constraint drift ≤ {max(drift, key=lambda d: float(d.split()[0]))}"] = None
        body.append([name, len(mine), 'yes' if all(r['finite'] for r in ok) else 'NO',
                     low('slip_min'), low('torque_min'),
                     f"{fmt(worst['energy'])} ({worst['mode']})",
                     ' / '.join(turns), ' / '.join(sorted({str(r['switches']) for r in ok})),
                     low('min_gap'), '; '.join(list(notes) + failed)])
    L += table(['scene', 'modes', 'finite', 'min slip (rel.)', 'min torque (rel.)',
                'largest energy residual (mode)', 'switches/turn', 'switches',
                'min gap [s]', 'notes'], body)
    L += ['']
    worst = max((r['energy'] / r['rtol'] for r in rows if r['status'] == 'ok'
                 and 'rk4' not in r['mode']), default=math.nan)
    worst_rk4 = max((r['energy'] for r in rows if r['status'] == 'ok'
                     and 'rk4' in r['mode']), default=math.nan)
    failed = [f"{r['scene']}/{r['mode']}" for r in rows if r['status'] != 'ok']
    L += [f"Largest energy residual: {fmt(worst)}·rtol for the dopri5 modes, {fmt(worst_rk4)} "
          f"for the fixed-step modes (rk4 at its default step). "
          + (f"Failed runs: {', '.join(failed)}." if failed else 'No run failed.'), '']
    return L


HARD_COLUMNS = ('scene', 'mode', 'status', 'finite', 'min_slip_rel', 'min_torque_rel',
                'energy_residual', 'rtol', 'switches_per_turn', 'switches', 'min_gap_s',
                'grazes', 'note')


def hard_csv_rows(rows):
    return [[r['scene'], r['mode'], r['status'], r.get('finite', ''),
             r.get('slip_min', math.nan), r.get('torque_min', math.nan),
             r.get('energy', math.nan), r.get('rtol', math.nan), r.get('per_turn', math.nan),
             r.get('switches', ''), r.get('min_gap', math.nan), r.get('grazes', ''),
             r.get('note', '')] for r in rows]
