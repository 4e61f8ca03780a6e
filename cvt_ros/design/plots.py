"""The design tools' figures (matplotlib Agg): what a controls engineer checks a model against.

* :func:`plot_plant` (``cvt-sim identify --plot``): per input, the device's cycle-mean step
  responses (both directions, scaled by the step) with both fitted models driven by the same
  input, and a Bode diagram — the fitted models' curves over the points the sine sweeps measured
  on the full hybrid model. Motor speed in the step panels too (right axis).
* :func:`plot_schedule` (``cvt-sim identify --grid``): gain, time constant, delay, ratio and
  efficiency over the grid of operating points.
* :func:`plot_tuning` (``cvt-sim tune``): the model's predicted closed-loop step against the
  device's, run by the controller kit.
"""
import math

import numpy as np

from .fit import simulate

DPI = 110
ROUGH_FIT = 0.05             # schedule: a point whose FOPDT fit error exceeds this is ringed
COLOURS = {'fopdt': 'tab:blue', 'second_order': 'tab:orange', 'device': 'black'}
LABELS = {'crank_length': 'crank length', 'load_torque': 'load torque'}


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _step_panel(ax, output_model, motor_model):
    for k, step in enumerate(output_model.steps):
        mid = 0.5 * (step.bounds[:-1] + step.bounds[1:]) - step.t_step
        label = 'device (cycle means)' if k == 0 else None
        ax.plot(mid, step.y / step.size, 'o', ms=2.5, color='black' if k == 0 else 'grey',
                label=label if k == 0 else 'device, step down')
        for kind in ('fopdt', 'second_order'):
            m = output_model.model(kind)
            y = simulate(m.num, m.den, m.delay, step.t, step.u)
            ax.plot(step.t - step.t_step, y / step.size, '-', lw=1, color=COLOURS[kind],
                    label=(f"{kind} (fit error {m.fit_error:.2%})" if k == 0 else None))
    ax.axhline(0.0, color='0.8', lw=0.5)
    motor = ax.twinx()
    step = motor_model.steps[0]
    mid = 0.5 * (step.bounds[:-1] + step.bounds[1:]) - step.t_step
    motor.plot(mid, step.y / step.size, '.', ms=2, color='tab:green', alpha=0.6)
    m = motor_model.model(motor_model.best)
    motor.plot(step.t - step.t_step, simulate(m.num, m.den, m.delay, step.t, step.u) / step.size,
               '-', lw=0.8, color='tab:green', alpha=0.8)
    motor.set_ylabel(f'motor speed Δω̄1 / Δu ({motor_model.best})', color='tab:green',
                     fontsize=8)
    motor.tick_params(axis='y', labelcolor='tab:green', labelsize=7)


def _bode(ax_mag, ax_phase, input_model):
    out = input_model.outputs['output_speed']
    fr = input_model.frequency
    high = fr.frequency[-1] if fr is not None else 1.0 / out.fopdt.time_constant
    low = fr.frequency[0] if fr is not None else high / 1000
    f = np.geomspace(low / 2, high * 2, 300)
    reference = 0.0 if out.fopdt.gain >= 0 else 180.0     # the phase at 0 Hz
    for kind in ('fopdt', 'second_order'):
        g = out.model(kind).response(f)
        ax_mag.loglog(f, np.abs(g), color=COLOURS[kind], lw=1, label=kind)
        phase = np.degrees(np.unwrap(np.angle(g)))
        phase += 360.0 * round((reference - phase[0]) / 360.0)      # one branch for all
        ax_phase.semilogx(f, phase, color=COLOURS[kind], lw=1)
    if fr is not None:
        g = fr.output_speed
        ax_mag.loglog(fr.frequency, np.abs(g), 'o', color='black', ms=4,
                      label='device (sine sweeps)')
        phase = np.degrees(np.unwrap(np.angle(g)))
        model = np.degrees(np.unwrap(np.angle(out.fopdt.response(np.append(f[0],
                                                                           fr.frequency[0])))))
        model += 360.0 * round((reference - model[0]) / 360.0)
        phase += 360.0 * round((model[1] - phase[0]) / 360.0)       # the models' branch
        ax_phase.semilogx(fr.frequency, phase, 'o', color='black', ms=4)
        for ax in (ax_mag, ax_phase):
            ax.axvline(fr.crank_frequency * fr.fraction, color='0.7', lw=0.8, ls=':')
    ax_mag.set_ylabel('|G| output speed')
    ax_phase.set_ylabel('phase [deg]')
    ax_phase.set_xlabel('frequency [Hz]')
    ax_mag.legend(fontsize=7)
    for ax in (ax_mag, ax_phase):
        ax.grid(True, which='both', color='0.9')


def plot_plant(plant, path):
    """The identify figure of a :class:`~cvt_ros.design.identify.PlantModel`."""
    plt = _plt()
    fig = plt.figure(figsize=(13, 8.5))
    grid = fig.add_gridspec(4, 2, width_ratios=[1.25, 1], hspace=0.75, wspace=0.3)
    for row, (name, model) in enumerate(plant.inputs.items()):
        unit, gain_unit = ('m', 'rad/s per m') if name == 'crank_length' else \
            ('N·m', 'rad/s per N·m')
        ax = fig.add_subplot(grid[2 * row:2 * row + 2, 0])
        out = model.outputs['output_speed']
        _step_panel(ax, out, model.outputs['motor_speed'])
        ax.set_title(f"step of {LABELS[name]} ±{model.step:.3g} {unit}: K = {out.fopdt.gain:.4g} "
                     f"{gain_unit}, τ = {out.fopdt.time_constant:.3g} s, θ = "
                     f"{out.fopdt.delay * 1e3:.3g} ms", fontsize=9)
        ax.set_xlabel('time after the step [s]')
        ax.set_ylabel(f'output speed Δω̄4 / Δu [{gain_unit}]')
        ax.legend(fontsize=7, loc='lower right' if out.fopdt.gain > 0 else 'upper right')
        ax_mag = fig.add_subplot(grid[2 * row, 1])
        ax_phase = fig.add_subplot(grid[2 * row + 1, 1], sharex=ax_mag)
        _bode(ax_mag, ax_phase, model)
        ax_mag.set_title(f"{LABELS[name]} → output speed (dotted: highest sweep frequency)",
                         fontsize=9)
    p = plant.operating_point
    fig.suptitle(f"{plant.scene}: plant at a = {p.crank_length * 1e3:.4g} mm, load "
                 f"{p.load_torque:.4g} N·m — ω̄4 = {p.output_speed:.4g} rad/s, ω̄1 = "
                 f"{p.crank_speed:.4g} rad/s, ratio {p.ratio:.4g}, efficiency "
                 f"{p.efficiency:.2%}, crank {p.crank_frequency:.3g} Hz", fontsize=10)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def plot_schedule(rows, x, y, path):
    """Gain, time constant, delay (crank length → output speed), ratio and efficiency over the
    operating points ``rows`` (dicts), over ``x``, one line per value of ``y``."""
    plt = _plt()
    panels = [('crank_length_gain', 'gain a → ω̄4 [rad/s per m]'),
              ('crank_length_time_constant', 'time constant τ [s]'),
              ('crank_length_delay', 'delay θ [s]'),
              ('load_torque_gain', 'gain load → ω̄4 [rad/s per N·m]'),
              ('ratio', 'ratio ω̄4/ω̄1'), ('efficiency', 'efficiency')]
    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
    ys = sorted({r[y] for r in rows}) if y else [None]
    cmap = plt.get_cmap('viridis')
    for ax, (key, label) in zip(axes.flat, panels, strict=True):
        for k, value in enumerate(ys):
            sel = sorted((r for r in rows if y is None or r[y] == value), key=lambda r: r[x])
            ok = [r for r in sel if r['status'] == 'ok']
            colour = cmap(k / max(len(ys) - 1, 1))
            ax.plot([r[x] for r in ok], [r[key] for r in ok], 'o-', ms=3, color=colour,
                    label=f"{y} = {value:g}" if y else None)
            rough = [r for r in ok if not r['crank_length_fit_error'] <= ROUGH_FIT]
            ax.plot([r[x] for r in rough], [r[key] for r in rough], 'o', ms=8, mfc='none',
                    color='red')
            bad = [r for r in sel if r['status'] != 'ok']
            if bad:
                ax.plot([r[x] for r in bad], [0.0] * len(bad), 'x', color='red', ms=6)
        ax.set_xlabel(x)
        ax.set_ylabel(label)
        ax.grid(True, color='0.9')
    if y:
        axes.flat[0].legend(fontsize=7)
    failed = sum(r['status'] != 'ok' for r in rows)
    fig.suptitle(f"gain schedule: {len(rows)} operating points (red ring: the FOPDT fits the "
                 f"crank-length steps with more than {ROUGH_FIT:.0%} error)"
                 + (f", {failed} without a model (red ×)" if failed else ''), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def plot_tuning(check, path):
    """The predicted closed-loop step (model + PI) against the device's (controller kit)."""
    plt = _plt()
    fig, (ax, ax_u) = plt.subplots(2, 1, figsize=(10, 7), sharex=True,
                                   gridspec_kw={'height_ratios': [2, 1]})
    ax.plot(check.t_device, check.speed_device, color='black', lw=1,
            label='device (controller kit, cycle means)')
    ax.plot(check.t_model, check.speed_model, color='tab:blue', lw=1.2, ls='--',
            label=f'model + PI (predicted, {check.model})')
    ax.step(np.concatenate([[check.t_device[0]], check.t_model]),
            np.concatenate([[check.speed_model[0]], check.setpoint]), where='post',
            color='0.6', lw=0.8, ls=':', label='set point')
    ax.set_ylabel('output speed ω̄4 [rad/s]')
    ax.legend(fontsize=8)
    ax.grid(True, color='0.9')
    ax_u.plot(check.t_device, np.asarray(check.crank_device) * 1e3, color='black', lw=1,
              label='device')
    ax_u.plot(check.t_model, np.asarray(check.crank_model) * 1e3, color='tab:blue', lw=1.2,
              ls='--', label='model')
    ax_u.set_ylabel('crank length [mm]')
    ax_u.set_xlabel('time [s]')
    ax_u.grid(True, color='0.9')
    g = check.gains
    ax.set_title(f"{check.rule}: kp = {g['kp']:.3g} m/(rad/s), ki = {g['ki']:.3g} m/rad\n"
                 f"settling (2 %) model {_s(check.settling_model)}, device "
                 f"{_s(check.settling_device)}; overshoot model {check.overshoot_model:.1%}, "
                 f"device {check.overshoot_device:.1%}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _s(value):
    return f"{value:.3g} s" if math.isfinite(value) else 'n/a'


__all__ = ['plot_plant', 'plot_schedule', 'plot_tuning']
