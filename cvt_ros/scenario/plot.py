"""The one picture of a scenario run: set point vs speed, crank command vs actual, load, clutch."""
import math

import numpy as np

from ..analysis.cycles import cycle_metrics

MAX_POINTS = 4000     # raw traces are thinned to min/max envelopes of this many points


def _envelope(t, y, points=MAX_POINTS):
    """Min/max per bucket, so a 60 000-sample ripple draws as the band it is."""
    n = len(t)
    if n <= 2 * points:
        return t, y
    k = n // points
    m = (n // k) * k
    tt = t[:m].reshape(-1, k)[:, 0]
    yy = y[:m].reshape(-1, k)
    return np.repeat(tt, 2), np.column_stack([yy.min(axis=1), yy.max(axis=1)]).ravel()


def _settling_bands(ax, steps):
    """Each step's settling band (its final set point ± 2 % of the change, or of the speed for a
    load step) over its window, and where it settled: what settling_time was judged by. Edged,
    so that a narrow band (±0.3 rad/s for a 15 rad/s step) shows as drawn in the legend."""
    label = 'settling band: ±2 % of the step (load steps: of the speed); |: settled'
    for s in steps:
        band = s.get('settling_band', math.nan)
        if not math.isfinite(band):
            continue
        target = s['settling_target']
        ax.fill_between([s['t'], s['window_end']], target - band, target + band,
                        facecolor=(0.17, 0.63, 0.17, 0.3), edgecolor='C2', lw=0.8, label=label)
        if math.isfinite(s['settling_time']):
            ax.plot([s['t'] + s['settling_time']], [target], marker='|', ms=14, mew=1.5,
                    color='C2', label='_nolegend_')
        label = None


def plot_run(run, path):
    """Write the PNG of ``run`` (a ScenarioRun) to ``path``; returns ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t = run.t
    table = cycle_metrics(run.trace())[0] if len(t) > 2 else None
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(11, 10),
                             gridspec_kw={'height_ratios': [3, 2, 1.2, 1.6]})
    ax = axes[0]
    tr, wr = _envelope(t, run.column('omega4'))
    ax.plot(tr, wr, color='0.75', lw=0.5, label='ω4 (raw: pulses at the clutch frequency)')
    if table is not None and len(table):
        tm = table['t_start'] + 0.5 * table['period']
        ax.plot(tm, table['output_speed'], color='C0', lw=1.8, label='ω4, mean per crank turn')
    ax.step(t, run.setpoint, where='post', color='C3', ls='--', lw=1.3, label='set point')
    _settling_bands(ax, run.steps)
    ax.set_ylabel('output speed [rad/s]')
    ax.legend(loc='best', fontsize=8)

    ax = axes[1]
    # the actuator under the command: where it follows, the command stays visible on top
    ax.plot(t, run.column('crank_length') * 1e3, color='C2', lw=2.4, alpha=0.55,
            label='crank length (actuator)')
    ax.step(t, run.held_commands() * 1e3, where='post', color='C1', lw=1.1, ls=(0, (4, 2)),
            label='crank length command')
    lim = run.scenario.crank_limits
    top = np.nanmax(run.column('crank_length'))
    if top > 0.8 * lim.max:     # the limit only when the crank comes near it
        ax.axhline(lim.max * 1e3, color='0.6', ls=':', lw=0.8, label='crank limit')
    ax.set_ylabel('crank length [mm]')
    ax.legend(loc='best', fontsize=8)

    ax = axes[2]
    ax.step(t, run.load, where='post', color='C4', lw=1.2, label='load torque (schedule)')
    ax.set_ylabel('load [N·m]')
    ax.legend(loc='best', fontsize=8)

    ax = axes[3]
    if table is not None and len(table):
        ax.plot(tm, table['clutch_torque_peak'], color='C5', lw=1.0,
                label='peak clutch torque per turn')
        ax.set_ylabel('clutch torque [N·m]')
        ax2 = ax.twinx()
        ax2.plot(tm, table['engaged_fraction'], color='C7', lw=0.9,
                 label='engaged fraction per turn')
        ax2.set_ylim(-0.05, 1.05)
        ax2.set_ylabel('engaged fraction')
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, loc='best', fontsize=8)
    ax.set_xlabel('simulation time [s]')
    for a in axes:
        a.grid(True, lw=0.3)
        for s in run.steps[1:]:
            a.axvline(s['t'], color='0.5', lw=0.6, ls=':')
    m = run.metrics

    def fmt(name, unit, scale=1.0):
        v = m.get(name)
        return f"{name} {v * scale:.3g} {unit}" if v is not None and math.isfinite(v) \
            else f"{name} n/a"
    status = '' if run.ok else f"\nSTOPPED: {run.error}"
    fig.suptitle(f"{run.scenario.name} — {run.backend_text}, {run.controller}\n"
                 f"{fmt('rise_time', 's')}, {fmt('overshoot', '%')}, "
                 f"{fmt('settling_time', 's')}, {fmt('steady_state_error', 'rad/s')}\n"
                 + (f"{fmt('max_deviation', 'rad/s')} (load steps), "
                    if math.isfinite(m.get('max_deviation', math.nan)) else '')
                 + f"{fmt('iae', 'rad')}, {fmt('peak_clutch_torque', 'N·m')} (whole run)"
                 f"{status}",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
