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
    body = []
    for r in rows:
        if r['status'] != 'ok':
            body.append([r['scene'], r['mode'], r['status'][:80]] + [''] * 8)
            continue
        body.append([r['scene'], r['mode'], 'yes' if r['finite'] else 'NO', fmt(r['slip_min']),
                     fmt(r['torque_min']), f"{fmt(r['energy'])} ({r['rtol']:g})",
                     fmt(r['per_turn']), r['switches'], fmt(r['min_gap']), r['grazes'],
                     r.get('note', '')])
    L += table(['scene', 'mode', 'finite', 'min slip (rel.)', 'min torque (rel.)',
                'energy residual (rtol)', 'switches/turn', 'switches', 'min gap [s]',
                'grazes', 'notes'], body)
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
