"""The results of :func:`~cvt_ros.analysis.analyze.analyze_trace` as text (the printed
report), JSON and a per-cycle CSV."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .analyze import RunAnalysis
from .cycles import CYCLE_FIELDS
from .trace import RecordingInfo

__all__ = ['format_run', 'to_json', 'write_cycles_csv']


_SUMMARY_ROWS = (
    ('cycles', 'complete crank cycles', '{:.0f}'),
    ('crank_speed', 'mean crank speed ω1 [rad/s]', '{:.4f}'),
    ('output_speed', 'mean output speed ω4 [rad/s]', '{:.4f}'),
    ('ratio', 'mean ratio i = ω4/ω1', '{:.6f}'),
    ('ripple', 'output speed ripple (max−min)/mean', '{:.4%}'),
    ('twist_peak', 'peak torsion twist [rad]', '{:.6f}'),
    ('twist_mean', 'mean torsion twist [rad]', '{:.6f}'),
    ('clutch_torque_peak', 'peak clutch torque [N·m]', '{:.4f}'),
    ('clutch_torque_mean', 'mean clutch torque [N·m]', '{:.4f}'),
    ('load_factor', 'dynamic load factor peak/mean', '{:.4f}'),
    ('engaged_fraction', 'engaged fraction of the cycle', '{:.4%}'),
    ('switches_per_cycle', 'clutch switches per cycle', '{:.3f}'),
    ('motor_power', 'motor power [W]', '{:.4f}'),
    ('output_power', 'output (load) power [W]', '{:.4f}'),
    ('efficiency', 'efficiency P4/P1', '{:.4%}'),
)


def _fmt(template: str, value: float) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return 'n/a'
    return template.format(value)


def format_run(analysis: RunAnalysis, cycles_shown: int | None = 10) -> str:
    """The printed report of one run."""
    tr = analysis.trace
    lines = []
    span = f'{tr.t[0]:.6g}–{tr.t[-1]:.6g} s'
    lines.append(f'run {tr.run_index + 1}: {tr.n} samples, {span}, '
                 f'{len(tr.switch_t)} clutch switches, {len(tr.commands)} commands'
                 + (f' (parameters: {tr.parameters_origin})' if tr.parameters_origin else
                    ' (no scene parameters)'))
    for note in tr.notes:
        lines.append(f'  note: {note}')
    s = analysis.summary
    if not s:
        lines.append('  no complete crank cycle: cycle metrics need at least two crossings of '
                     'φ1 = 2πk')
    else:
        allw, last = s['all'], s['last_quarter']
        lines.append(f"  {'per run':38s} {'all cycles':>14s} {'last quarter':>14s}")
        lines.append(f"  {'window [s]':38s} {allw['t_start']:>6.3f}–{allw['t_end']:<7.3f} "
                     f"{last['t_start']:>6.3f}–{last['t_end']:<7.3f}")
        for key, label, template in _SUMMARY_ROWS:
            lines.append(f'  {label:38s} {_fmt(template, allw.get(key)):>14s} '
                         f'{_fmt(template, last.get(key)):>14s}')
    e = analysis.energy
    if e.get('available'):
        lines.append(f"  energy residual                        {e['residual']:.4e} J = "
                     f"{e['relative_residual']:.2e} of the work (motor {e['work_motor']:.4f} J,"
                     f" load {e['work_load']:.4f} J, damping {e['dissipated_damping']:.4f} J, "
                     f"stored {e['stored']:+.4f} J; trapezoidal over the samples)")
        for note in e['notes']:
            lines.append(f'    ({note})')
    else:
        lines.append(f"  energy residual                        unavailable: {e['reason']}")
    cy = analysis.cycles
    if len(cy) and cycles_shown != 0:
        shown = range(len(cy)) if cycles_shown is None else \
            range(max(0, len(cy) - cycles_shown), len(cy))
        if cycles_shown is not None and len(cy) > cycles_shown:
            lines.append(f'  per cycle (last {cycles_shown} of {len(cy)}; --cycles all for '
                         'every one):')
        else:
            lines.append('  per cycle:')
        lines.append('  ' + ' '.join(f'{h:>9s}' for h in (
            'cycle', 't0 [s]', 'T [ms]', 'i', 'ripple', 'θmax', 'θmean', 'Tc,max',
            'K', 'engaged', 'switches', 'P1 [W]', 'η')))
        for i in shown:
            v = {k: float(cy[k][i]) for k, _ in CYCLE_FIELDS}
            lines.append('  ' + ' '.join(cell.rjust(9) for cell in [
                f"{v['cycle'] + 1:9.0f}", f"{v['t_start']:9.4f}", f"{v['period'] * 1e3:9.3f}",
                f"{v['ratio']:9.5f}", _fmt('{:9.3%}', v['ripple']),
                f"{v['twist_peak']:9.5f}", f"{v['twist_mean']:9.5f}",
                f"{v['clutch_torque_peak']:9.3f}", _fmt('{:9.4f}', v['load_factor']),
                _fmt('{:9.3%}', v['engaged_fraction']), _fmt('{:9.0f}', v['switches']),
                _fmt('{:9.3f}', v['motor_power']), _fmt('{:9.3%}', v['efficiency'])]))
    for step in analysis.steps:
        c = step.command
        what = 'crank length' if c.key == 'crank_length_cmd' else 'load torque'
        unit = 'm' if c.key == 'crank_length_cmd' else 'N·m'
        lines.append(
            f'  step at t = {c.t:.4f} s: {what} {_fmt("{:g}", step.previous)} → {c.value:g} '
            f'{unit}: ratio {_fmt("{:.5f}", step.ratio_before)} → '
            f'{_fmt("{:.5f}", step.ratio_after)}, ω4 {_fmt("{:.3f}", step.speed_before)} → '
            f'{_fmt("{:.3f}", step.speed_after)} rad/s, rise (10–90 %) '
            f'{_fmt("{:.3f} s", step.rise_time)}, settling (±2 %) '
            f'{_fmt("{:.3f} s", step.settling_time)}')
    return '\n'.join(lines)


def write_cycles_csv(path: str, analyses: Sequence[RunAnalysis]) -> int:
    """All per-cycle metrics of all runs (a ``run`` column first)."""
    count = 0
    with open(path, 'w', newline='', encoding='utf-8') as f:
        writer = csv.writer(f)
        writer.writerow(['run'] + [f'{name} [{unit}]' if unit != '-' else name
                                   for name, unit in CYCLE_FIELDS])
        for analysis in analyses:
            for row in analysis.cycles.rows():
                writer.writerow([analysis.trace.run_index + 1]
                                + ['' if not math.isfinite(row[k]) else f'{row[k]:.10g}'
                                   for k, _ in CYCLE_FIELDS])
                count += 1
    return count


def to_json(analyses: Sequence[RunAnalysis], info: RecordingInfo) -> dict[str, Any]:
    """Machine-readable results (NaN → null)."""
    def clean(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if isinstance(value, (float, np.floating)):
            return float(value) if math.isfinite(value) else None
        if isinstance(value, np.integer):
            return int(value)
        return value

    runs = []
    for a in analyses:
        runs.append({
            'run': a.trace.run_index + 1, 'samples': a.trace.n,
            't_first': a.trace.t[0], 't_last': a.trace.t[-1],
            'switches': len(a.trace.switch_t), 'summary': a.summary,
            'energy': {k: v for k, v in a.energy.items()},
            'cycles': a.cycles.rows(),
            'steps': [{'t': s.command.t, 'topic': s.command.key, 'value': s.command.value,
                       'previous': s.previous, 'ratio_before': s.ratio_before,
                       'ratio_after': s.ratio_after, 'output_speed_before': s.speed_before,
                       'output_speed_after': s.speed_after, 'rise_time': s.rise_time,
                       'settling_time': s.settling_time} for s in a.steps],
        })
    return clean({'path': info.path, 'kind': info.kind, 'source': info.source,
                  'scene': info.scene, 'problems': info.problems, 'runs': runs})

