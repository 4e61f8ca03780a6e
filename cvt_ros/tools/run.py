"""``cvt-sim run``: a scene as fast as the core allows, samples to CSV, a summary on stdout."""
import math
import sys

import numpy as np

from ..scene import load_scene, parse_override
from ..solver.fidelity import choose_fidelity, make_simulator
from ..solver.output import COL, CSV_COLUMNS

# Columns printed as integers; every other column keeps 12 significant digits (1e-9 rad on φ4
# after hours of running at ~40 rad/s).
_CSV_FORMATS = ['%d' if name == 'engaged' else '%.12g' for name in CSV_COLUMNS]


def overrides_from(set_args):
    """``--set KEY=VALUE`` arguments → (overrides, origins: key → the argument as given)."""
    overrides, origins = {}, {}
    for text in set_args or ():
        key, value = parse_override(text)
        overrides[key] = value
        origins[key] = f"--set {text if len(text) <= 80 else text[:80] + '…'}"
    return overrides, origins


def write_csv(path, samples):
    """The CSV columns of ``cvt-sim run`` (output.CSV_COLUMNS, in order) with a header line."""
    np.savetxt(path, samples[:, :len(CSV_COLUMNS)], delimiter=',', fmt=_CSV_FORMATS,
               header=','.join(CSV_COLUMNS), comments='')


def summarize(result, duration):
    """The numbers a person checks first after a run (dict of floats and ints)."""
    c = result.column
    w1, w4 = c('omega1'), c('omega4')
    # steady-state-ish ratio: the last quarter of the run
    tail = slice(len(w1) - max(1, len(w1) // 4), None)
    ratio_all = float(np.mean(w4) / np.mean(w1)) if np.mean(w1) != 0 else math.nan
    ratio_tail = float(np.mean(w4[tail]) / np.mean(w1[tail])) if np.mean(w1[tail]) != 0 \
        else math.nan
    switches = [s for s in result.switches if s.kind != 'graze']
    return {
        'duration_s': duration,
        'mean_ratio': ratio_all,
        'mean_ratio_last_quarter': ratio_tail,
        'mean_crank_speed_rad_s': float(np.mean(w1[tail])),
        'mean_output_speed_rad_s': float(np.mean(w4[tail])),
        'switches': len(switches),
        'grazing_contacts': len(result.switches) - len(switches),
        'peak_clutch_torque_Nm': float(np.max(c('clutch_torque'))),
        'peak_twist_rad': float(np.max(np.abs(c('twist')))),
        'energy_residual_J': float(result.energy['residual']),
        'energy_residual_relative': float(result.energy['relative_residual']),
        'work_motor_J': float(result.energy['work_motor']),
        'steps': result.steps,
        'rejected_steps': result.rejected,
        'wall_time_s': result.wall_time,
        'real_time_factor': duration / result.wall_time if result.wall_time > 0 else math.inf,
    }


def format_summary(summary, scene):
    s = summary
    lines = [
        f"scene            {scene}",
        f"simulated        {s['duration_s']:g} s",
        f"mean ratio i     {s['mean_ratio']:.6f} (ω4/ω1 over the run), "
        f"{s['mean_ratio_last_quarter']:.6f} over the last quarter",
        f"mean speeds      crank {s['mean_crank_speed_rad_s']:.4f} rad/s, output "
        f"{s['mean_output_speed_rad_s']:.4f} rad/s (last quarter)",
        f"clutch switches  {s['switches']} ({s['grazing_contacts']} grazing contacts without "
        f"switch)",
        f"peaks            clutch torque {s['peak_clutch_torque_Nm']:.4f} N·m, twist "
        f"{s['peak_twist_rad']:.6f} rad",
        f"energy balance   residual {s['energy_residual_J']:.3e} J = "
        f"{s['energy_residual_relative']:.2e} of the work done",
        f"solver           {s['steps']} steps, {s['rejected_steps']} rejected",
        f"wall time        {s['wall_time_s']:.4f} s, real-time factor "
        f"{s['real_time_factor']:.0f}x",
    ]
    return '\n'.join(lines)


def progress_bar(duration):
    """A tqdm bar on stderr that appears only if the run takes more than 2 s of wall time."""
    from tqdm import tqdm
    bar = tqdm(total=duration, unit='s sim', delay=2.0, file=sys.stderr, leave=False,
               bar_format='{l_bar}{bar}| {n:.1f}/{total:.1f} s sim [{elapsed}<{remaining}]')

    def update(done, total):
        bar.update(done - bar.n)  # update(), not refresh(): keeps the 2 s delay
    return bar, update


def run_scene(scene, duration, overrides=None, sample_dt=1e-3, progress=True, origins=None):
    """Load, simulate, return (simulator, result)."""
    values = load_scene(scene, overrides, origins)
    sim = make_simulator(values)
    if progress:
        bar, update = progress_bar(duration)
        try:
            result = sim.run(duration, sample_dt, progress=update)
        finally:
            bar.close()
    else:
        result = sim.run(duration, sample_dt)
    return sim, result


def pick_fidelity(args, overrides, origins=None):
    """``--fidelity auto --tolerance X``: probe the fidelities against the full model and keep
    the cheapest within X (relative error of the mean output speed and ratio)."""
    if args.fidelity != 'auto':
        if args.fidelity:
            overrides['model.fidelity'] = args.fidelity
        return
    values = load_scene(args.scene, overrides, origins)
    probe = min(args.duration, 4.0)
    fidelity, table = choose_fidelity(values, args.tolerance, probe=probe)
    print(f"fidelity         auto (tolerance {args.tolerance:g}, probed over {probe:g} s):")
    for name, row in table.items():
        print(f"  {name:12s} output speed error {row['speed_error']:.2e}, ratio error "
              f"{row['ratio_error']:.2e}, wall {row['wall_time']:.3f} s")
    print(f"                 → {fidelity}")
    overrides['model.fidelity'] = fidelity


def command(args):
    """Run a scene; returns the exit code."""
    overrides, origins = overrides_from(args.set)
    load_scene(args.scene, overrides, origins)   # every input error before any work
    pick_fidelity(args, overrides, origins)
    mcap = getattr(args, 'mcap', None)
    if mcap:  # refuse a target that cannot be written before a long run, not after it
        from ..recording.recorder import check_target
        check_target(mcap, args.overwrite)
    sim, result = run_scene(args.scene, args.duration, overrides, args.sample_dt,
                            progress=not args.quiet, origins=origins)
    if args.csv:
        write_csv(args.csv, result.samples)
    summary = summarize(result, args.duration)
    print(format_summary(summary, args.scene))
    if args.csv:
        print(f"samples          {len(result.samples)} rows → {args.csv}")
    if mcap:
        from ..recording.recorder import write_run
        count, error = write_run(mcap, sim, result, scene=args.scene, overwrite=args.overwrite)
        if error is not None:
            print(f"cvt-sim run: error: {error}", file=sys.stderr)
            return 1
        print(f"recording        {count} messages → {mcap}")
    return 0


__all__ = ['command', 'run_scene', 'summarize', 'write_csv', 'COL']
