"""Figures of a whole run, start-up included: the peaks a designer sizes parts by.

Peaks are the extremes of the recorded samples over the whole run (no cycle window: the start-up
holds the largest clutch torque and twist of a run that starts from rest); means are time means
over the sampled span [t0, tn] (trapezoidal integrals of the samples, the motion from the angle
differences); switches are counted from the clutch events in (t0, tn].
"""

from __future__ import annotations

import math

import numpy as np

from .cycles import TWO_PI, Integrator, efficiency
from .trace import Trace

__all__ = ['whole_run_metrics']


def _peak(values: np.ndarray, fn=np.max) -> float:
    finite = values[np.isfinite(values)]
    return float(fn(finite)) if len(finite) else math.nan


def whole_run_metrics(trace: Trace) -> dict[str, float]:
    """Whole-run figures of ``trace`` (keys as :meth:`CycleTable.window` where they mean the
    same, plus peaks and minima over the run and the works)."""
    t = trace.t
    span = float(t[-1] - t[0])
    integ = Integrator(t)
    phi, w, eff = trace.phi, trace.omega, trace.effort
    m1, tc, m4 = eff[:, 0], eff[:, 1], eff[:, 3]
    dphi1 = float(phi[-1, 0] - phi[0, 0])
    dphi4 = float(phi[-1, 3] - phi[0, 3])
    with np.errstate(invalid='ignore', over='ignore'):
        motor_work = float(integ.cumulative(m1 * w[:, 0])[-1])
        output_work = float(integ.cumulative(m4 * w[:, 3])[-1])
        tc_mean = float(integ.cumulative(tc)[-1]) / span
        twist_mean = float(integ.cumulative(trace.twist)[-1]) / span
    ratio = dphi4 / dphi1 if dphi1 != 0 else math.nan
    turns = dphi1 / TWO_PI
    switches = float(np.count_nonzero((trace.switch_t > t[0]) & (trace.switch_t <= t[-1]))) \
        if trace.initial_engaged is not None else math.nan
    engaged = float(trace.engaged_time(np.array([t[-1]]))[0]) / span
    out = {
        't_start': float(t[0]),
        't_end': float(t[-1]),
        'crank_turns': turns,
        'ratio': ratio,
        'crank_speed': dphi1 / span,
        'output_speed': dphi4 / span,
        'output_speed_min': _peak(w[:, 3], np.min),
        'output_speed_max': _peak(w[:, 3]),
        'twist_peak': _peak(trace.twist),
        'twist_min': _peak(trace.twist, np.min),
        'twist_mean': twist_mean,
        'clutch_torque_peak': _peak(tc),
        'clutch_torque_mean': tc_mean,
        'motor_torque_peak': _peak(m1),
        'engaged_fraction': engaged,
        'switches': switches,
        'switches_per_cycle': switches / turns if turns > 0 else math.nan,
        'motor_work': motor_work,
        'output_work': output_work,
        'motor_power': motor_work / span,
        'output_power': output_work / span,
        'efficiency': efficiency(output_work, motor_work, ratio),
    }
    out['load_factor'] = out['clutch_torque_peak'] / tc_mean if tc_mean > 0 else math.nan
    return out
