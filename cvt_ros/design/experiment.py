"""Experiments on the device: hold it, or drive its inputs (crank-length command, load torque)
along a signal, and the cycle means of what it did.

Everything goes through the Simulator's public calls (``command_crank_length``,
``set_load_torque``, ``run``), so any simulator class the scene's fidelity or path count gives
takes part. A driven input is commanded every ``command_dt`` (a multiple of the sample interval:
one ``run`` call per command, ~70 µs of overhead each, so the command interval follows the
signal's period instead of the sample interval).

Cycle means are taken over whole crank turns (:func:`cvt_ros.analysis.cycles.cycle_metrics`):
the output speed's ripple is periodic in the crank angle, so its mean over a turn is free of it.
A cycle mean is a sample at the crank frequency, centred in its turn; the fits compare models
with the device over the same turns (:func:`window_means`), so the averaging is modelled, not
mistaken for delay.
"""
from dataclasses import dataclass

import numpy as np

from ..analysis.cycles import cycle_metrics
from ..solver.output import COL
from ..solver.simulator import RunResult
from ..sweep.metrics import trace_of_run


@dataclass
class Record:
    """Samples of an experiment (rows of ``solver.output.COLUMNS``), its clutch switches and
    its crank cycles (``cycles``: the per-cycle table; ``bounds``: the cycles' boundary
    times, one more than cycles)."""
    samples: np.ndarray
    switches: list
    cycles: object
    bounds: np.ndarray

    @property
    def t(self):
        return self.samples[:, COL['t']]

    def column(self, name):
        return self.samples[:, COL[name]]

    @property
    def t_mid(self):
        """Midpoints of the crank cycles [s]."""
        return 0.5 * (self.bounds[:-1] + self.bounds[1:])

    def mean(self, name):
        """Cycle means of a CycleTable field ('output_speed', 'crank_speed', 'crank_length',
        'load_torque', 'efficiency', …)."""
        return self.cycles[name]


def record_of(values, samples, switches):
    """The :class:`Record` of samples and switches of one experiment."""
    cycles, bounds = cycle_metrics(trace_of_run(values, RunResult(samples, switches)))
    return Record(samples, switches, cycles, bounds)


def command_interval(period, sample_dt, per_period=50, longest=0.05):
    """The command interval [s] for a signal of ``period`` [s]: ≥ ``per_period`` commands per
    period, at most ``longest``, a whole number of sample intervals (≥ 1)."""
    wanted = min(period / per_period, longest)
    return max(1, int(wanted / sample_dt)) * sample_dt


def drive(sim, duration, sample_dt, command_dt=None, crank=None, load=None):
    """Run ``sim`` for ``duration`` [s] sampled every ``sample_dt``; ``crank(t)`` [m] and
    ``load(t)`` [N·m], when given, are commanded every ``command_dt`` [s] (held in between).
    Returns (samples, switches) from the present state on (its sample first)."""
    if crank is None and load is None:
        result = sim.run(duration, sample_dt)
        return result.samples, result.switches
    steps = max(1, int(round(duration / command_dt)))
    t0 = sim.t
    blocks, switches = [], []
    for j in range(steps):
        t = t0 + j * command_dt
        if crank is not None:
            sim.command_crank_length(crank(t))
        if load is not None:
            sim.set_load_torque(load(t))
        result = sim.run(command_dt, sample_dt)
        blocks.append(result.samples if j == 0 else result.samples[1:])
        switches += result.switches
    return np.concatenate(blocks), switches


def staircase(t0, command_dt, signal, t):
    """The command in force at each of the times ``t`` when ``signal`` is commanded every
    ``command_dt`` from ``t0`` and held in between (the value on [t_k, t_k+1) of a grid
    whose points are command times or between them); ``signal`` takes arrays."""
    index = np.floor((np.asarray(t) - t0) / command_dt + 1e-9)
    return np.asarray(signal(t0 + index * command_dt), dtype=float)


def staircase_means(knots, values, bounds):
    """Exact means of a piecewise-constant signal (``values[j]`` on [knots[j], knots[j+1]))
    over the windows between successive ``bounds`` (its integral is piecewise linear)."""
    F = np.concatenate([[0.0], np.cumsum(values[:-1] * np.diff(knots))])
    return np.diff(np.interp(bounds, knots, F)) / np.diff(bounds)


def window_means(t, f, bounds):
    """Means of the piecewise-linear interpolant of samples ``f(t)`` over the windows between
    successive ``bounds`` (exact: the trapezoid integral, interpolated at the bounds)."""
    F = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(t))])
    at = np.interp(bounds, t, F)
    return np.diff(at) / np.diff(bounds)


__all__ = ['Record', 'command_interval', 'drive', 'record_of', 'staircase', 'staircase_means',
           'window_means']
