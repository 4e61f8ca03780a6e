"""Figures of ``cvt-sim analyze --plots DIR`` (matplotlib, Agg backend, PNG).

* ``fig2_twist_cycle.png``: torsion twist θ = φ3 − φ4 over one crank cycle (the paper's Fig. 2),
  the last complete cycle over the four before it, engaged phases shaded;
* ``fig3_speeds_cycle.png``: angular speeds ω1..ω4 of the members over the same cycle (Fig. 3);
* ``timeseries.png``: speeds, ratio (instantaneous and per cycle), the clutch state (engaged /
  overrunning), clutch and load torque, commanded and actual crank length over the whole run,
  the steady state shaded, commands marked;
* ``step_NN_<topic>.png``: the response to each command, titled with the command as given:
  commanded and actual value, the ratio per cycle with its 10–90 % rise, ±2 % settling and
  overshoot (only once it settled), and the output speed.

With several runs (resets) every file name gets a ``runN_`` prefix.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from functools import partial
from typing import IO

import numpy as np

from ..recording.outputs import OutputFiles
from .analyze import RunAnalysis
from .cycles import TWO_PI
from .steps import MAX_SHOWN_STEPS, SETTLING_BAND, StepResponse, commanded_before
from .trace import Trace

__all__ = ['plot_all', 'plot_files', 'step_title']

DPI = 120
MAX_POINTS = 6000   # longer series are drawn as a min/max envelope per pixel column
COLORS = {'omega1': '#1f77b4', 'omega2': '#2ca02c', 'omega3': '#ff7f0e', 'omega4': '#d62728',
          'engaged': '#9ecae1', 'twist': '#6a3d9a', 'clutch': '#8c564b', 'load': '#7f7f7f'}
LABELS = ('ω1 crank (motor)', 'ω2 rocker', 'ω3 clutch output', 'ω4 output shaft')


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _envelope(t: np.ndarray, y: np.ndarray, points: int = MAX_POINTS
              ) -> tuple[np.ndarray, np.ndarray]:
    """At most ~``points`` points that keep every extreme (min and max per bucket)."""
    n = len(t)
    if n <= points:
        return t, y
    buckets = points // 2
    edges = np.linspace(0, n, buckets + 1).astype(int)
    tt, yy = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b <= a:
            continue
        seg = y[a:b]
        i, j = int(np.nanargmin(seg)) if np.any(np.isfinite(seg)) else 0, \
            int(np.nanargmax(seg)) if np.any(np.isfinite(seg)) else 0
        for k in sorted((i, j)):
            tt.append(t[a + k])
            yy.append(seg[k])
    return np.asarray(tt), np.asarray(yy)


def _engaged_spans(trace: Trace, ta: float, tb: float) -> list[tuple[float, float]]:
    if trace.initial_engaged is None:
        return []
    inside = (trace.switch_t > ta) & (trace.switch_t < tb)
    knots = [ta, *trace.switch_t[inside].tolist(), tb]
    states = trace.engaged_at(np.asarray(knots[:-1]))
    return [(a, b) for a, b, on in zip(knots[:-1], knots[1:], states, strict=True) if on > 0.5]


def _cycle_samples(analysis: RunAnalysis, k: int) -> dict[str, np.ndarray]:
    """Samples of cycle k with the interpolated boundary points, on a crank-angle axis [deg]."""
    tr = analysis.trace
    ta, tb = analysis.boundaries[k], analysis.boundaries[k + 1]
    inside = np.flatnonzero((tr.t > ta) & (tr.t < tb))
    t = np.concatenate([[ta], tr.t[inside], [tb]])

    def series(y: np.ndarray) -> np.ndarray:
        return np.interp(t, tr.t, y)

    base = TWO_PI * math.floor(np.interp(ta, tr.t, tr.phi[:, 0]) / TWO_PI + 0.5)
    angle = np.degrees(series(tr.phi[:, 0]) - base)
    angle[0], angle[-1] = 0.0, 360.0
    out = {'t': t, 'angle': angle, 'twist': series(tr.twist)}
    for j in range(4):
        out[f'omega{j + 1}'] = series(tr.omega[:, j])
    return out


def _to_angle(analysis: RunAnalysis, k: int, times: np.ndarray) -> np.ndarray:
    tr = analysis.trace
    ta = analysis.boundaries[k]
    base = TWO_PI * math.floor(np.interp(ta, tr.t, tr.phi[:, 0]) / TWO_PI + 0.5)
    return np.degrees(np.interp(times, tr.t, tr.phi[:, 0]) - base)


def _shade_engaged(ax, analysis: RunAnalysis, k: int, label: bool = True) -> None:
    tr = analysis.trace
    spans = _engaged_spans(tr, analysis.boundaries[k], analysis.boundaries[k + 1])
    for i, (a, b) in enumerate(spans):
        xa, xb = _to_angle(analysis, k, np.array([a, b]))
        ax.axvspan(xa, xb, color=COLORS['engaged'], alpha=0.35, lw=0,
                   label='clutch engaged' if label and i == 0 else None)


def _cycle_title(analysis: RunAnalysis, k: int) -> str:
    cy = analysis.cycles
    return (f"cycle {k + 1} of {len(cy)}, t = {cy['t_start'][k]:.4f}–{cy.t_end[k]:.4f} s, "
            f"i = {cy['ratio'][k]:.4f}")


def _cycle_axes(ax, analysis: RunAnalysis, k: int, ylabel: str, title: str) -> None:
    """Crank-angle axis 0–360° and labels of a one-cycle figure (Fig. 2/3)."""
    ax.axhline(0.0, color='k', lw=0.6)
    ax.set_xlim(0, 360)
    ax.set_xticks(range(0, 361, 45))
    ax.set_xlabel('crank angle φ1 within the cycle [deg]')
    ax.set_ylabel(ylabel)
    ax.set_title(f'{title}\n{_cycle_title(analysis, k)}', fontsize=11)
    ax.grid(alpha=0.3)


def fig_twist_cycle(analysis: RunAnalysis, path: IO[bytes] | str) -> None:
    plt = _plt()
    k = len(analysis.cycles) - 1
    fig, ax = plt.subplots(figsize=(8, 4.8))
    for j in range(max(0, k - 4), k):
        c = _cycle_samples(analysis, j)
        ax.plot(c['angle'], c['twist'], color='0.75', lw=0.9,
                label='the four cycles before' if j == max(0, k - 4) else None)
    c = _cycle_samples(analysis, k)
    _shade_engaged(ax, analysis, k)
    ax.plot(c['angle'], c['twist'], color=COLORS['twist'], lw=1.8, label='θ = φ3 − φ4')
    peak = int(np.nanargmax(c['twist'])) if np.any(np.isfinite(c['twist'])) else 0
    ax.plot(c['angle'][peak], c['twist'][peak], 'o', color=COLORS['twist'])
    ax.annotate(f"peak {c['twist'][peak]:.4f} rad", (c['angle'][peak], c['twist'][peak]),
                textcoords='offset points', xytext=(8, 4), fontsize=9)
    _cycle_axes(ax, analysis, k, 'torsion twist θ [rad]',
                'Torsion shaft twist over one crank cycle (paper Fig. 2)')
    ax.legend(loc='best', fontsize=9)
    _save(plt, fig, path)


def fig_speeds_cycle(analysis: RunAnalysis, path: IO[bytes] | str) -> None:
    plt = _plt()
    k = len(analysis.cycles) - 1
    c = _cycle_samples(analysis, k)
    fig, ax = plt.subplots(figsize=(8, 4.8))
    _shade_engaged(ax, analysis, k)
    for j in range(4):
        name = f'omega{j + 1}'
        ax.plot(c['angle'], c[name], color=COLORS[name], lw=1.6, label=LABELS[j])
    _cycle_axes(ax, analysis, k, 'angular speed [rad/s]',
                'Angular speeds of the members over one crank cycle (paper Fig. 3)')
    ax.legend(loc='center left', bbox_to_anchor=(1.01, 0.5), fontsize=9)
    _save(plt, fig, path)


def _mark_commands(axes, commands: list) -> None:
    """A dotted line and the value at each of ``commands`` (the steps: a closed loop's stream
    of commands shows in the commanded crank length, not as thousands of lines)."""
    for c in commands:
        for ax in axes:
            ax.axvline(c.t, color='k', ls=':', lw=0.9)
    if commands:
        top = axes[0]
        for c in commands:
            what = 'a' if c.key == 'crank_length_cmd' else 'M4'
            top.annotate(f'{what} → {c.value:g}', (c.t, 1.0), xycoords=('data', 'axes fraction'),
                         xytext=(2, -10), textcoords='offset points', fontsize=8)


def _commanded(trace: Trace, key: str, t0: float, t1: float
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """The commanded value of ``key`` as a step signal over [t0, t1] (None if unknown)."""
    value = commanded_before(trace, key)
    knots, values = [t0], [value]
    for c in trace.commands:
        if c.key != key:
            continue
        if c.t <= t0:
            values[0] = c.value
        elif c.t < t1:
            knots.append(c.t)
            values.append(c.value)
    knots.append(t1)
    values.append(values[-1])
    values = np.asarray(values, dtype=float)
    return (np.asarray(knots), values) if np.any(np.isfinite(values)) else None


def _clutch_state(ax, trace: Trace, t0: float, t1: float) -> None:
    """The clutch state (engaged 1 / overrunning 0) as a filled step signal; a long run is drawn
    as one band per pixel column (every switch is still there, the band shows both states)."""
    if trace.initial_engaged is None:
        ax.text(0.5, 0.5, 'clutch state not recorded', transform=ax.transAxes, ha='center')
        return
    inside = trace.switch_t[(trace.switch_t > t0) & (trace.switch_t < t1)]
    knots = np.concatenate([[t0], inside, [t1]])
    states = trace.engaged_at(knots)
    ax.fill_between(knots, states, step='post', color=COLORS['engaged'], lw=0,
                    label='clutch engaged')
    if len(inside) <= 400:  # an outline only where the switches can be told apart
        ax.step(knots, states, where='post', color=COLORS['omega3'], lw=0.6)
    ax.set_ylim(-0.05, 1.25)
    ax.set_yticks([0, 1])
    ax.set_yticklabels(['overrun', 'engaged'])
    ax.legend(loc='upper right', fontsize=8, ncol=2)


def _crank_length(ax, trace: Trace, t: np.ndarray, sel: slice | np.ndarray, scale: float = 1e3
                  ) -> None:
    """Commanded (step) and actual crank length [mm]."""
    commanded = _commanded(trace, 'crank_length_cmd', float(t[0]), float(t[-1]))
    if commanded is not None:
        ax.step(commanded[0], commanded[1] * scale, where='post', color='k', ls='--', lw=1.1,
                label='commanded (crank_length_cmd)')
    actual = trace.crank_length[sel]
    if np.any(np.isfinite(actual)):
        source = {'recorded': 'recorded', 'csv': 'from the CSV',
                  'reconstructed': 'solved from φ1, φ2'}.get(trace.crank_length_source, '?')
        ax.plot(*_envelope(t, actual * scale), color=COLORS['omega1'], lw=1.2,
                label=f'actual ({source})')
    # a constant crank length: no axis that magnifies round-off into wiggles
    shown = [v for v in (actual * scale, None if commanded is None else commanded[1] * scale)
             if v is not None]
    values = np.concatenate(shown)
    values = values[np.isfinite(values)]
    if len(values):
        lo, hi = float(np.min(values)), float(np.max(values))
        pad = max(0.1 * (hi - lo), 0.5 * (max(1.0, 0.02 * abs(hi)) - (hi - lo)), 0.0)
        ax.set_ylim(lo - pad, hi + pad)
    ax.ticklabel_format(axis='y', useOffset=False)
    ax.set_ylabel('crank length a [mm]')
    ax.legend(loc='best', fontsize=8)


def fig_timeseries(analysis: RunAnalysis, path: IO[bytes] | str) -> None:
    plt = _plt()
    tr, cy = analysis.trace, analysis.cycles
    t = tr.t
    fig, axes = plt.subplots(5, 1, figsize=(10, 11), sharex=True,
                             gridspec_kw={'height_ratios': [3, 2, 1.2, 2, 1.6]})
    ax = axes[0]
    for j in (0, 3):
        name = f'omega{j + 1}'
        ax.plot(*_envelope(t, tr.omega[:, j]), color=COLORS[name], lw=0.9, label=LABELS[j])
    if len(cy):
        ax.step(np.append(cy['t_start'], cy.t_end[-1]),
                np.append(cy['output_speed'], cy['output_speed'][-1]), where='post',
                color='k', lw=1.0, label='ω4 mean per cycle')
    if tr.setpoint:   # a controller-kit recording: what the controller was asked for
        ts = [max(p[0], float(t[0])) for p in tr.setpoint] + [float(t[-1])]
        ax.step(ts, [p[1] for p in tr.setpoint] + [tr.setpoint[-1][1]], where='post',
                color='C3', ls='--', lw=1.3, label='set point (/setpoint)')
    steady = analysis.steady
    if steady.found:
        for a in axes:
            a.axvspan(steady.t_start, steady.t_end, color='g', alpha=0.06, lw=0,
                      label='steady state' if a is axes[0] else None)
    ax.set_ylabel('speed [rad/s]')
    ax.legend(loc='best', fontsize=8, ncol=3)
    ax.set_title(f'{os.path.basename(tr.source)}: run {tr.run_index + 1}, '
                 f'{t[0]:.3f}–{t[-1]:.3f} s'
                 + ('' if steady.found else ' (no steady state)'), fontsize=11)

    ax = axes[1]
    with np.errstate(invalid='ignore', divide='ignore'):
        inst = tr.omega[:, 3] / tr.omega[:, 0]
    ax.plot(*_envelope(t, inst), color='0.7', lw=0.7, label='ω4/ω1 (instantaneous)')
    if len(cy):
        ratio = cy['ratio']
        ax.step(np.append(cy['t_start'], cy.t_end[-1]), np.append(ratio, ratio[-1]),
                where='post', color=COLORS['omega4'], lw=1.4, label='i per crank cycle')
        _limits(ax, ratio, pad_fraction=0.25)
    ax.set_ylabel('ratio i [-]')
    ax.legend(loc='best', fontsize=8)

    _clutch_state(axes[2], tr, float(t[0]), float(t[-1]))
    axes[2].set_ylabel('clutch')

    ax = axes[3]
    ax.plot(*_envelope(t, tr.effort[:, 1]), color=COLORS['clutch'], lw=0.7,
            label='clutch torque Tc')
    if len(cy):
        ax.step(np.append(cy['t_start'], cy.t_end[-1]),
                np.append(cy['clutch_torque_mean'], cy['clutch_torque_mean'][-1]),
                where='post', color=COLORS['omega1'], lw=1.2, label='Tc mean per cycle')
    ax.plot(*_envelope(t, tr.effort[:, 3]), color='k', ls='--', lw=1.0,
            label='load torque M4')
    ax.set_ylabel('torque [N·m]')
    ax.legend(loc='best', fontsize=8)

    _crank_length(axes[4], tr, t, slice(None))
    axes[4].set_xlabel('simulation time t [s]')
    for a in axes:
        a.grid(alpha=0.3)
    _mark_commands(axes, [s.command for s in analysis.steps[:MAX_SHOWN_STEPS]])
    _save(plt, fig, path)


def _limits(ax, values: np.ndarray, pad_fraction: float) -> None:
    """y limits around the finite values' 1–99 % range (outliers of a start-up stay off)."""
    finite = values[np.isfinite(values)]
    if not len(finite):
        return
    lo, hi = np.percentile(finite, [1, 99])
    pad = max(pad_fraction * (hi - lo), 0.05 * abs(hi), 1e-3)
    ax.set_ylim(lo - pad, hi + pad)


def _save(plt, fig, path: IO[bytes] | str) -> None:
    try:
        fig.tight_layout()
        fig.savefig(path, dpi=DPI, format='png')
    finally:
        plt.close(fig)


def step_title(step: StepResponse) -> str:
    """The title of a step figure: the command as given, then what was in force before."""
    c = step.command
    crank = c.key == 'crank_length_cmd'
    what, unit = ('crank length', 'm') if crank else ('load torque', 'N·m')
    was = f' (was {step.previous:g} {unit})' if math.isfinite(step.previous) else ''
    return f'Response to {c.key} = {c.value:g} {unit} at t = {c.t:.4f} s{was}: {what}'


def fig_step(analysis: RunAnalysis, index: int, path: IO[bytes] | str) -> None:
    plt = _plt()
    tr, cy = analysis.trace, analysis.cycles
    step = analysis.steps[index]
    c = step.command
    span = max(step.window_end - c.t, 1e-3)
    t0 = max(tr.t[0], c.t - max(0.15 * span, 0.1))
    t1 = step.window_end
    sel = (tr.t >= t0) & (tr.t <= t1)
    t = tr.t[sel]
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax = axes[0]
    if c.key == 'crank_length_cmd':
        _crank_length(ax, tr, t, sel)
    else:
        commanded = _commanded(tr, c.key, float(t[0]), float(t[-1]))
        if commanded is not None:
            ax.step(commanded[0], commanded[1], where='post', color='k', ls='--', lw=1.2,
                    label=f'commanded ({c.key})')
        ax.plot(*_envelope(t, tr.effort[sel, 3]), color=COLORS['omega1'], lw=1.2,
                label='load torque M4 (actual)')
        ax.set_ylabel('load torque M4 [N·m]')
        ax.legend(loc='best', fontsize=8)
    ax.set_title(step_title(step), fontsize=11)

    ax = axes[1]
    with np.errstate(invalid='ignore', divide='ignore'):
        inst = tr.omega[sel, 3] / tr.omega[sel, 0]
    ax.plot(*_envelope(t, inst), color='0.75', lw=0.7, label='ω4/ω1 (instantaneous)')
    ksel = (cy['t_start'] >= t0) & (cy.t_end <= t1)
    mid = cy['t_start'][ksel] + 0.5 * cy['period'][ksel]
    ax.plot(mid, cy['ratio'][ksel], 'o-', color=COLORS['omega4'], ms=3, lw=1.2,
            label='i per crank cycle')
    text = []
    if step.settled and math.isfinite(step.ratio_before):
        change = step.ratio_after - step.ratio_before
        for level in (step.ratio_before, step.ratio_after):
            ax.axhline(level, color='k', ls=':', lw=0.8)
        ax.axhspan(step.ratio_after - SETTLING_BAND * abs(change),
                   step.ratio_after + SETTLING_BAND * abs(change), color='g', alpha=0.12,
                   label=f'±{SETTLING_BAND:.0%} band')
        if math.isfinite(step.rise_time):
            text.append(f'rise 10–90 %: {step.rise_time * 1e3:.0f} ms')
        if math.isfinite(step.settling_time):
            text.append(f'settling ±{SETTLING_BAND:.0%}: {step.settling_time * 1e3:.0f} ms')
            ax.axvline(c.t + step.settling_time, color='g', lw=0.9)
        if math.isfinite(step.overshoot):
            text.append(f'overshoot: {step.overshoot:.1%}')
    else:
        text.append('not settled in the window: no rise or settling time')
    ax.text(0.99, 0.05, '\n'.join(text), transform=ax.transAxes, ha='right', va='bottom',
            fontsize=9, bbox={'facecolor': 'white', 'alpha': 0.8, 'lw': 0})
    if np.any(ksel):
        _limits(ax, cy['ratio'][ksel], pad_fraction=0.2)
    ax.set_ylabel('ratio i [-]')
    ax.legend(loc='best', fontsize=8)

    ax = axes[2]
    ax.plot(*_envelope(t, tr.omega[sel, 3]), color=COLORS['omega4'], lw=0.8,
            label='ω4 output shaft')
    ax.plot(mid, cy['output_speed'][ksel], 'o-', color='k', ms=3, lw=1.0,
            label='ω4 mean per cycle')
    ax.set_ylabel('output speed [rad/s]')
    ax.set_xlabel('simulation time t [s]')
    ax.legend(loc='best', fontsize=8)
    for a in axes:
        a.axvline(c.t, color='k', ls=':', lw=0.9)
        a.grid(alpha=0.3)
    _save(plt, fig, path)


def plot_files(analyses: list[RunAnalysis]) -> list[tuple[str, Callable[[IO[bytes]], None]]]:
    """(file name, draw(file)) of every figure of every run."""
    files = []
    for analysis in analyses:
        prefix = f'run{analysis.trace.run_index + 1}_' if len(analyses) > 1 else ''
        if len(analysis.cycles):
            files.append((prefix + 'fig2_twist_cycle.png',
                          partial(fig_twist_cycle, analysis)))
            files.append((prefix + 'fig3_speeds_cycle.png',
                          partial(fig_speeds_cycle, analysis)))
        files.append((prefix + 'timeseries.png', partial(fig_timeseries, analysis)))
        if len(analysis.cycles):
            for i, step in enumerate(analysis.steps[:MAX_SHOWN_STEPS]):
                files.append((prefix + f'step_{i + 1:02d}_{step.command.key}.png',
                              partial(fig_step, analysis, i)))
    return files


def plot_all(analyses: list[RunAnalysis], outdir: str, outputs: OutputFiles | None = None
             ) -> list[str]:
    """Write every figure of every run into ``outdir`` (created if missing; its parent must
    exist) through ``outputs`` (a new :class:`OutputFiles` committed here if None): all files
    or none. Returns the paths. Raises :class:`~cvt_ros.recording.OutputError`."""
    own = outputs is None
    outputs = outputs if outputs is not None else OutputFiles()
    try:
        folder = outputs.directory(outdir)
        paths = []
        for name, draw in plot_files(analyses):
            path = os.path.join(folder, name)
            outputs.write(path, draw, 'wb')
            paths.append(path)
    except BaseException:
        if own:
            outputs.discard()
        raise
    if own:
        outputs.commit()
    return paths
