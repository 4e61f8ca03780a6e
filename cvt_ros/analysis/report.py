"""The results of :func:`~cvt_ros.analysis.analyze.analyze_trace` as text (the printed
report), JSON and a per-cycle CSV.

Two columns per run: the **whole run** (every sample, start-up included: the peaks a designer
sizes parts by) and the **steady state** (the window :mod:`.steady` detected, or "none" with the
reason). A figure no steady state can have (:func:`~.cycles.physical`: an efficiency outside
0–100 %, …) is never printed as a plain number: it carries a ``!`` and a note says why.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from typing import IO, Any

import numpy as np

from .analyze import RunAnalysis
from .cycles import CYCLE_FIELDS, UNPHYSICAL_NOTES, physical
from .path_metrics import PATH_FIELDS
from .steps import MAX_SHOWN_STEPS, MIN_STEP_CYCLES, SETTLING_BAND, StepResponse
from .trace import RecordingInfo

__all__ = ['format_run', 'to_json', 'write_cycles_csv']

#: (key, label, format) of the per-run table; '' where a column has no such figure.
_SUMMARY_ROWS = (
    ('cycles', 'complete crank cycles', '{:.0f}'),
    ('crank_turns', 'crank turns', '{:.2f}'),
    ('crank_speed', 'mean crank speed ω1 [rad/s]', '{:.4f}'),
    ('output_speed', 'mean output speed ω4 [rad/s]', '{:.4f}'),
    ('output_speed_min', 'lowest output speed ω4 [rad/s]', '{:.4f}'),
    ('output_speed_max', 'highest output speed ω4 [rad/s]', '{:.4f}'),
    ('ratio', 'mean ratio i = ω4/ω1', '{:.6f}'),
    ('ripple', 'output speed ripple (max−min)/mean', '{:.4%}'),
    ('twist_peak', 'peak torsion twist [rad]', '{:.6f}'),
    ('twist_min', 'lowest torsion twist [rad]', '{:.6f}'),
    ('twist_mean', 'mean torsion twist [rad]', '{:.6f}'),
    ('clutch_torque_peak', 'peak clutch torque [N·m]', '{:.4f}'),
    ('clutch_torque_mean', 'mean clutch torque [N·m]', '{:.4f}'),
    ('load_factor', 'dynamic load factor peak/mean', '{:.4f}'),
    ('motor_torque_peak', 'peak motor torque [N·m]', '{:.4f}'),
    ('engaged_fraction', 'engaged fraction of the time', '{:.4%}'),
    ('switches', 'clutch switches', '{:.0f}'),
    ('switches_per_cycle', 'clutch switches per crank turn', '{:.3f}'),
    ('motor_power', 'motor power [W]', '{:.4f}'),
    ('output_power', 'output (load) power [W]', '{:.4f}'),
    ('efficiency', 'efficiency P4/P1', '{:.4%}'),
)


def _fmt(template: str, value: Any) -> str:
    if value is None or (isinstance(value, (float, np.floating)) and not math.isfinite(value)):
        return 'n/a'
    return template.format(value)


def _cell(key: str, template: str, window: dict[str, float], flags: set[str]) -> str:
    if key not in window:
        return '—'
    value = window[key]
    text = _fmt(template, value)
    if not physical(key, value):
        flags.add(key)
        text += ' !'
    return text


def _step_line(step: StepResponse) -> str:
    c = step.command
    crank = c.key == 'crank_length_cmd'
    what, unit = ('crank length', 'm') if crank else ('load torque', 'N·m')
    was = f' (was {_fmt("{:g}", step.previous)} {unit})' if math.isfinite(step.previous) else ''
    head = f'  step at t = {c.t:.4f} s: {what} → {c.value:g} {unit}{was}: '
    ratio = f'ratio {_fmt("{:.5f}", step.ratio_before)} → {_fmt("{:.5f}", step.ratio_after)}'
    speed = f'ω4 {_fmt("{:.3f}", step.speed_before)} → {_fmt("{:.3f}", step.speed_after)} rad/s'
    if step.settled:
        times = (f'rise (10–90 %) {_fmt("{:.3f} s", step.rise_time)}, settling '
                 f'(±{SETTLING_BAND:.0%}) {_fmt("{:.3f} s", step.settling_time)}, overshoot '
                 f'{_fmt("{:.1%}", step.overshoot)}')
        if not math.isfinite(step.settling_time):
            times += ' (no change beyond the scatter)'
        return head + f'{ratio} (settled), {speed}, {times}'
    why = step.steady.reason.removeprefix('not settled: ') if step.steady is not None \
        else 'no complete cycle after it'
    return (head + f'{ratio} at t = {step.window_end:.4f} s, {speed}: not settled ({why}); '
            'no rise or settling time')


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
    steady = analysis.steady
    if steady.found:
        lines.append(f'  steady state: cycles {steady.first + 1}–{steady.stop} of '
                     f'{len(analysis.cycles)}, t = {steady.t_start:.4f}–{steady.t_end:.4f} s '
                     f'({steady.reason})')
    else:
        lines.append(f'  steady state: none ({steady.reason}); whole-run figures only')
    whole, st = analysis.whole_run, analysis.steady_metrics
    whole = dict(whole, cycles=float(len(analysis.cycles)))
    flags: set[str] = set()
    lines.append(f"  {'':38s} {'whole run':>14s} {'steady state':>14s}")
    window = f"{st['t_start']:.3f}–{st['t_end']:.3f}" if st else 'none'
    lines.append(f"  {'window [s]':38s} {whole['t_start']:>6.3f}–{whole['t_end']:<7.3f} "
                 f"{window:>14s}")
    for key, label, template in _SUMMARY_ROWS:
        lines.append(f'  {label:38s} {_cell(key, template, whole, flags):>14s} '
                     f'{_cell(key, template, st, flags) if st else "":>14s}')
    lines.extend(_path_lines(analysis))
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
            eta = _fmt('{:8.3%}', v['efficiency'])
            if not physical('efficiency', v['efficiency']):
                flags.add('efficiency')
                # digits enough to show it is out of range (100.000% would read as 100 %)
                eta = f"{v['efficiency'] * 100.0:.9g}%!"
            lines.append('  ' + ' '.join(cell.rjust(9) for cell in [
                f"{v['cycle']:9.0f}", f"{v['t_start']:9.4f}", f"{v['period'] * 1e3:9.3f}",
                _fmt('{:9.5f}', v['ratio']), _fmt('{:9.3%}', v['ripple']),
                _fmt('{:9.5f}', v['twist_peak']), _fmt('{:9.5f}', v['twist_mean']),
                _fmt('{:9.3f}', v['clutch_torque_peak']), _fmt('{:9.4f}', v['load_factor']),
                _fmt('{:9.3%}', v['engaged_fraction']), _fmt('{:9.0f}', v['switches']),
                _fmt('{:9.3f}', v['motor_power']), eta]))
    for key in sorted(flags):
        lines.append(f'  ! {UNPHYSICAL_NOTES.get(key, f"{key}: not physical")}')
    for step in analysis.steps[:MAX_SHOWN_STEPS]:
        lines.append(_step_line(step))
    if len(analysis.steps) > MAX_SHOWN_STEPS:
        lines.append(f'  … and {len(analysis.steps) - MAX_SHOWN_STEPS} more steps (--json lists '
                     f'them all)')
    for key, count in analysis.streamed_commands.items():
        lines.append(f'  {count} commands on {key} followed by the next (or the end) within '
                     f'fewer than {MIN_STEP_CYCLES} crank cycles (a closed loop): not analysed '
                     f'as steps; the time series shows them')
    return '\n'.join(lines)


def _path_lines(analysis: RunAnalysis) -> list[str]:
    """N ≥ 2 paths: one line per path, its clutch's figures over the whole run and the steady
    state (the machine's own figures — the total clutch torque, "any clutch engaged" — are in
    the table above)."""
    paths = analysis.paths
    if not paths:
        return []
    steady = paths.get('steady_state') or []
    head = ('engaged', 'Tc,max [N·m]', 'Tc,mean', 'K', 'switches')
    width = 13 * len(head) - 1
    lines = ["  per path: each clutch (the clutch torque above is their sum, the engaged fraction "
             "any one's)",
             f"  {'':6s} {'whole run':^{width}s} |{'steady state':^{width}s}".rstrip(),
             '  ' + f"{'path':>6s} " + ' '.join(f'{h:>12s}' for h in head) + ' |'
             + ' '.join(f'{h:>12s}' for h in head)]
    formats = ('{:.3%}', '{:.3f}', '{:.3f}', '{:.4f}', '{:.0f}')

    def cells(row: dict[str, float] | None) -> str:
        if row is None:
            return ' '.join(f'{"":>12s}' for _ in formats)
        return ' '.join(f'{_fmt(fmt, row[key]):>12s}'
                        for (key, _), fmt in zip(PATH_FIELDS, formats, strict=True))
    for i, row in enumerate(paths['whole_run']):
        lines.append(f"  {row['path']:>6d} {cells(row)} |"
                     f"{cells(steady[i] if i < len(steady) else None)}")
    return lines


def write_cycles_csv(out: IO[str], analyses: Sequence[RunAnalysis]) -> int:
    """All per-cycle metrics of all runs (a ``run`` column first) into the open text file
    ``out``; returns the rows written."""
    count = 0
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['run'] + [f'{name} [{unit}]' if unit != '-' else name
                               for name, unit in CYCLE_FIELDS])
    for analysis in analyses:
        for row in analysis.cycles.rows():
            writer.writerow([analysis.trace.run_index + 1]
                            + ['' if not math.isfinite(row[k]) else f'{row[k]:.10g}'
                               for k, _ in CYCLE_FIELDS])
            count += 1
    return count


def _clean(value: Any) -> Any:
    """JSON-safe: NaN/inf → null, numpy scalars → Python."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _flags(windows: dict[str, dict[str, float]]) -> list[dict[str, Any]]:
    return [{'window': name, 'figure': key, 'value': value,
             'reason': UNPHYSICAL_NOTES.get(key, 'not physical')}
            for name, window in windows.items() for key, value in window.items()
            if not physical(key, value)]


def to_json(analyses: Sequence[RunAnalysis], info: RecordingInfo) -> dict[str, Any]:
    """Machine-readable results (NaN → null). Per run: ``whole_run``, ``steady_state`` (its
    window and figures, or ``found: false`` and the reason), ``flags`` (figures outside their
    physical range), ``energy``, ``cycles``, ``steps``."""
    runs = []
    for a in analyses:
        s = a.steady
        runs.append({
            'run': a.trace.run_index + 1, 'samples': a.trace.n,
            't_first': a.trace.t[0], 't_last': a.trace.t[-1],
            'switches': len(a.trace.switch_t),
            'whole_run': a.whole_run,
            'steady_state': {'found': s.found, 'reason': s.reason, 'tolerance': s.tolerance,
                             'min_cycles': s.min_cycles,
                             'first_cycle': s.first + 1 if s.found else None,
                             'last_cycle': s.stop if s.found else None,
                             **a.steady_metrics},
            'flags': _flags({'whole_run': a.whole_run, 'steady_state': a.steady_metrics}),
            'energy': dict(a.energy),
            'cycles': a.cycles.rows(),
            'steps': [{'t': s.command.t, 'topic': s.command.key, 'value': s.command.value,
                       'previous': s.previous, 'ratio_before': s.ratio_before,
                       'ratio_after': s.ratio_after, 'output_speed_before': s.speed_before,
                       'output_speed_after': s.speed_after, 'settled': s.settled,
                       'rise_time': s.rise_time, 'settling_time': s.settling_time,
                       'overshoot': s.overshoot, 'window_end': s.window_end}
                      for s in a.steps],
            'streamed_commands': a.streamed_commands,
            **({'paths': a.paths} if a.paths else {}),
        })
    return _clean({'path': info.path, 'kind': info.kind, 'source': info.source,
                   'scene': info.scene, 'problems': info.problems, 'runs': runs})
