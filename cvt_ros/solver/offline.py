"""The offline run as a library: a scene as fast as the core allows, its samples, its summary.

What ``cvt-sim run`` does, without the command line: :func:`run_scene` loads and simulates,
:func:`write_csv` writes the samples, :func:`summarize` gives the numbers a person checks first.
Raises the core's typed errors (SceneError, SimulationError); prints nothing.
"""
import math

import numpy as np

from ..scene import load_scene
from .fidelity import make_simulator
from .output import COL, COLUMNS, CSV_COLUMNS, csv_columns

# The engaged columns are printed as integers; every other column keeps 12 significant digits
# (1e-9 rad on φ4 after hours of running at ~40 rad/s).
# A mean crank speed below this fraction of the largest |ω1| is "at rest": no ratio is defined.
RATIO_DEFINED_BELOW = 1e-6
# An energy balance that closes worse than this fraction of the work is not a converged answer.
RESIDUAL_SUSPECT = 1e-3


def simulator_for(scene, overrides=None, origins=None):
    """The simulator of ``scene`` (name or path) with ``overrides``, kernels loaded; ``origins``
    names where each override came from (for error messages)."""
    return make_simulator(load_scene(scene, overrides, origins))


def run_scene(scene, duration, overrides=None, sample_dt=1e-3, progress=None, origins=None,
              on_samples=None, keep_samples=True):
    """Simulate ``scene`` for ``duration`` [s] sampled every ``sample_dt`` [s]; returns
    (simulator, RunResult). ``progress(done, total)`` is called as it goes; ``on_samples(block)``
    gets the sample rows as they are made, ``keep_samples=False`` keeps none in the result,
    nor the switches (constant memory for any duration; RunResult.switch_count counts them)."""
    sim = simulator_for(scene, overrides, origins)
    return sim, sim.run(duration, sample_dt, progress=progress, on_samples=on_samples,
                        keep_samples=keep_samples)


class CsvWriter:
    """The CSV of ``cvt-sim run --csv``, written block by block (``add(block)``), so that a run
    of any length streams to disk in constant memory. A context manager; ``rows`` counts.
    ``columns``: the samples' (an N-path machine's add its per-path ones to the CSV)."""

    def __init__(self, path, columns=COLUMNS):
        names = csv_columns(columns)
        self._index = [columns.index(name) for name in names]
        self._formats = ['%d' if name.startswith('engaged') else '%.12g' for name in names]
        self._file = open(path, 'w')   # noqa: SIM115 — closed by close() / __exit__
        self._file.write(','.join(names) + '\n')
        self.rows = 0

    def add(self, block):
        rows = block[:, :len(CSV_COLUMNS)] if len(self._index) == len(CSV_COLUMNS) else \
            block[:, self._index]
        np.savetxt(self._file, rows, delimiter=',', fmt=self._formats)
        self.rows += len(block)

    def close(self):
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()


def write_csv(path, samples, columns=COLUMNS):
    """The CSV columns of ``cvt-sim run`` (output.csv_columns of the samples' ``columns``, in
    order) with a header line."""
    with CsvWriter(path, columns) as csv:
        csv.add(samples)


class SampleStatistics:
    """The figures of the summary that come from the samples, accumulated block by block (constant
    memory): mean crank and output speed over the run and over its last quarter (from
    ``t_tail``), peak clutch torque and peak |twist| over the whole run, start-up included."""

    def __init__(self, t_tail, columns=COLUMNS):
        self.t_tail = t_tail
        # an N-path machine's clutch torques, path by path (peak per path)
        self._path_torques = [i for i, name in enumerate(columns)
                              if name.startswith('clutch_torque_')]
        self.peak_clutch_torque_per_path = [-math.inf] * len(self._path_torques)
        self.count = self.tail_count = 0
        self.sum_w1 = self.sum_w4 = self.tail_w1 = self.tail_w4 = 0.0
        self.max_abs_w1 = self.tail_max_abs_w1 = 0.0
        self.peak_clutch_torque = self.peak_twist = -math.inf

    def add(self, block):
        w1, w4 = block[:, COL['omega1']], block[:, COL['omega4']]
        tail = block[:, COL['t']] >= self.t_tail
        self.count += len(block)
        self.sum_w1 += float(np.sum(w1))
        self.sum_w4 += float(np.sum(w4))
        self.max_abs_w1 = max(self.max_abs_w1, float(np.max(np.abs(w1), initial=0.0)))
        if tail.any():
            self.tail_count += int(np.count_nonzero(tail))
            self.tail_w1 += float(np.sum(w1[tail]))
            self.tail_w4 += float(np.sum(w4[tail]))
            self.tail_max_abs_w1 = max(self.tail_max_abs_w1, float(np.max(np.abs(w1[tail]))))
        clutch_torque, twist = block[:, COL['clutch_torque']], np.abs(block[:, COL['twist']])
        self.peak_clutch_torque = max(self.peak_clutch_torque,
                                      float(np.max(clutch_torque, initial=-math.inf)))
        self.peak_twist = max(self.peak_twist, float(np.max(twist, initial=-math.inf)))
        for k, i in enumerate(self._path_torques):
            self.peak_clutch_torque_per_path[k] = max(
                self.peak_clutch_torque_per_path[k], float(np.max(block[:, i],
                                                                  initial=-math.inf)))

    @staticmethod
    def _ratio(sum_w4, sum_w1, max_abs_w1):
        """Mean ratio ω4/ω1 (ratio of the means), nan when the crank is (on average) at rest."""
        if not (math.isfinite(sum_w1) and abs(sum_w1) > RATIO_DEFINED_BELOW * max_abs_w1
                and max_abs_w1 > 0.0):
            return math.nan
        return sum_w4 / sum_w1

    @property
    def mean_ratio(self):
        return self._ratio(self.sum_w4, self.sum_w1, self.max_abs_w1)

    @property
    def mean_ratio_tail(self):
        return self._ratio(self.tail_w4, self.tail_w1, self.tail_max_abs_w1)


def statistics_of(samples, t_tail, columns=COLUMNS):
    stats = SampleStatistics(t_tail, columns)
    stats.add(samples)
    return stats


def tail_start(result_t0, duration):
    """Where the summary's "last quarter" starts [s]."""
    return result_t0 + 0.75 * duration


def summarize(result, duration, statistics=None):
    """The numbers a person checks first after a run (dict of floats and ints) and the warnings
    that qualify them (``warnings``: one line each; a figure that is not meaningful is nan).
    ``statistics``: the SampleStatistics of a streamed run (default: from ``result.samples``)."""
    stats = statistics or statistics_of(result.samples, tail_start(result.samples[0, 0],
                                                                   duration), result.columns)
    diagnostics = getattr(result, 'diagnostics', {})
    summary = {
        'duration_s': duration,
        'mean_ratio': stats.mean_ratio,
        'mean_ratio_last_quarter': stats.mean_ratio_tail,
        'mean_crank_speed_rad_s': stats.tail_w1 / max(stats.tail_count, 1),
        'mean_output_speed_rad_s': stats.tail_w4 / max(stats.tail_count, 1),
        'switches': result.switch_count,
        'grazing_contacts': result.graze_count,
        'peak_clutch_torque_Nm': stats.peak_clutch_torque,
        'peak_twist_rad': stats.peak_twist,
        'energy_residual_J': float(result.energy['residual']),
        'energy_residual_relative': float(result.energy['relative_residual']),
        'work_motor_J': float(result.energy['work_motor']),
        'steps': result.steps,
        'rejected_steps': result.rejected,
        # the run's self-check (docs/solver.md): switches made late at a step's end and samples
        # standing outside their clutch mode; either is a possibly missed event (and a warning)
        'possible_missed_events': int(diagnostics.get('possible_missed_events', 0)),
        'stray_samples': int(diagnostics.get('stray_samples', 0)),
        'solver': diagnostics.get('solver', ''),
        'wall_time_s': result.wall_time,
        'real_time_factor': duration / result.wall_time if result.wall_time > 0 else math.inf,
    }
    if len(result.switches_per_path) > 1:   # an N-path machine: each path's clutch
        summary['switches_per_path'] = list(result.switches_per_path)
        summary['peak_clutch_torque_per_path_Nm'] = list(stats.peak_clutch_torque_per_path)
    warnings = list(diagnostics.get('warnings', ()))
    if math.isnan(summary['mean_ratio']):
        warnings.append('the crank is at rest on average: no ratio ω4/ω1 is defined')
    relative = summary['energy_residual_relative']
    if not math.isfinite(relative) or relative > RESIDUAL_SUSPECT:
        warnings.append(f"the energy balance does not close ({relative:.2g} of the work done, "
                        f"more than {RESIDUAL_SUSPECT:g}): the solver did not resolve this scene; "
                        f"tighten solver.rtol / solver.fixed_step or check the parameters")
    summary['warnings'] = warnings
    return summary


__all__ = ['RATIO_DEFINED_BELOW', 'RESIDUAL_SUSPECT', 'CsvWriter', 'SampleStatistics',
           'run_scene', 'simulator_for', 'statistics_of', 'summarize', 'tail_start', 'write_csv']
