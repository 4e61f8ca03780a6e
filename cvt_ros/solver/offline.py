"""The offline run as a library: a scene as fast as the core allows, its samples, its summary.

What ``cvt-sim run`` does, without the command line: :func:`run_scene` loads and simulates,
:func:`write_csv` writes the samples, :func:`summarize` gives the numbers a person checks first.
Raises the core's typed errors (SceneError, SimulationError); prints nothing.
"""
import math

import numpy as np

from ..scene import load_scene
from .fidelity import make_simulator
from .output import CSV_COLUMNS

# Columns printed as integers; every other column keeps 12 significant digits (1e-9 rad on φ4
# after hours of running at ~40 rad/s).
_CSV_FORMATS = ['%d' if name == 'engaged' else '%.12g' for name in CSV_COLUMNS]
# A mean crank speed below this fraction of the largest |ω1| is "at rest": no ratio is defined.
RATIO_DEFINED_BELOW = 1e-6
# An energy balance that closes worse than this fraction of the work is not a converged answer.
RESIDUAL_SUSPECT = 1e-3


def run_scene(scene, duration, overrides=None, sample_dt=1e-3, progress=None, origins=None):
    """Load ``scene`` (name or path) with ``overrides``, simulate ``duration`` [s] sampled every
    ``sample_dt`` [s]; returns (simulator, RunResult). ``progress(done, total)`` is called as it
    goes; ``origins`` names where each override came from (for error messages)."""
    values = load_scene(scene, overrides, origins)
    sim = make_simulator(values)
    return sim, sim.run(duration, sample_dt, progress=progress)


def write_csv(path, samples):
    """The CSV columns of ``cvt-sim run`` (output.CSV_COLUMNS, in order) with a header line."""
    np.savetxt(path, samples[:, :len(CSV_COLUMNS)], delimiter=',', fmt=_CSV_FORMATS,
               header=','.join(CSV_COLUMNS), comments='')


def _ratio(w4, w1):
    """Mean ratio ω4/ω1, or nan when the crank is (on average) at rest."""
    m1 = float(np.mean(w1))
    scale = float(np.max(np.abs(w1))) if len(w1) else 0.0
    if not math.isfinite(m1) or abs(m1) <= RATIO_DEFINED_BELOW * max(scale, 1e-300):
        return math.nan
    return float(np.mean(w4)) / m1


def summarize(result, duration):
    """The numbers a person checks first after a run (dict of floats and ints), and the warnings
    that qualify them (``warnings``: list of text; a figure that is not meaningful is nan)."""
    c = result.column
    w1, w4 = c('omega1'), c('omega4')
    tail = slice(len(w1) - max(1, len(w1) // 4), None)   # the last quarter of the run
    switches = [s for s in result.switches if s.kind != 'graze']
    summary = {
        'duration_s': duration,
        'mean_ratio': _ratio(w4, w1),
        'mean_ratio_last_quarter': _ratio(w4[tail], w1[tail]),
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
    warnings = []
    if math.isnan(summary['mean_ratio']):
        warnings.append('the crank is at rest on average: no ratio ω4/ω1 is defined')
    relative = summary['energy_residual_relative']
    if not math.isfinite(relative) or relative > RESIDUAL_SUSPECT:
        warnings.append(f"the energy balance does not close ({relative:.2g} of the work done, "
                        f"more than {RESIDUAL_SUSPECT:g}): the solver did not resolve this scene; "
                        f"tighten solver.rtol / solver.fixed_step or check the parameters")
    summary['warnings'] = warnings
    return summary


__all__ = ['RATIO_DEFINED_BELOW', 'RESIDUAL_SUSPECT', 'run_scene', 'summarize', 'write_csv']
