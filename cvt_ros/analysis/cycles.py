"""Crank cycles of a run and the metrics per cycle and per window of whole cycles.

A crank cycle is one turn of the crank between successive crossings of φ1 = 2πk (k integer: the
crank along the frame line O1→O2), located on the cubic Hermite interpolant of (φ1, ω1); only
complete cycles count. :func:`cycle_metrics` gives the per-cycle table; :meth:`CycleTable.window`
aggregates any run of whole cycles (the steady state, :mod:`.steady`). Over a window [ta, tb]:

* ratio i = Δφ4 / Δφ1 (= mean ω4 / mean ω1);
* output speed ripple = (max ω4 − min ω4) / |mean ω4| (n/a while |i| < 1e-3: neutral crank);
* torsion twist θ = φ3 − φ4: peak (max θ) and time mean;
* peak clutch torque Tc,max and the **dynamic load factor** K = Tc,max / mean Tc (mean over the
  whole window, engaged or not: the torque the clutch transmits on average);
* engaged fraction = time engaged / window length (exact from the switch times);
* switches per cycle (engage + release; grazing contacts are not switches);
* motor power P1 = ∫M1·ω1 dt / T, output power P4 = ∫M4·ω4 dt / T (the power taken by the load),
  efficiency η = ∫M4·ω4 / ∫M1·ω1 (n/a while |i| < 1e-3 or the motor does no work). The model
  is lossless except shaft damping (and the rare plastic engagement at start-up), so η < 1 in
  steady state only by damping; over a window that is not in steady state the change of stored
  energy enters, and η can leave [0, 1] (:func:`physical` tells; reports flag it).

Integrals and means use the piecewise-linear interpolant of the samples, integrated exactly
between the (interpolated) cycle boundaries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import AnalysisError
from .trace import Trace

__all__ = ['CYCLE_FIELDS', 'DRIVEN_RATIO', 'TWO_PI', 'UNPHYSICAL_NOTES', 'CycleTable', 'Integrator',
           'cycle_boundaries', 'cycle_metrics', 'physical']

TWO_PI = 2.0 * math.pi
#: Below this |ratio| the output is not driven (neutral crank): ripple and efficiency are n/a.
DRIVEN_RATIO = 1e-3
#: Per-cycle metrics, in table order, with units.
CYCLE_FIELDS = (
    ('cycle', '-'), ('t_start', 's'), ('period', 's'), ('crank_speed', 'rad/s'),
    ('ratio', '-'), ('output_speed', 'rad/s'), ('ripple', '-'), ('twist_peak', 'rad'),
    ('twist_mean', 'rad'), ('clutch_torque_peak', 'N*m'), ('clutch_torque_mean', 'N*m'),
    ('load_factor', '-'), ('engaged_fraction', '-'), ('switches', '-'), ('motor_power', 'W'),
    ('output_power', 'W'), ('efficiency', '-'), ('crank_length', 'm'), ('load_torque', 'N*m'),
)


def _hermite(s: np.ndarray, h: np.ndarray, p0: np.ndarray, p1: np.ndarray, m0: np.ndarray,
             m1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Hermite value and d/ds on [0, 1] (h: interval length, m: slopes per unit time)."""
    s2, s3 = s * s, s * s * s
    value = ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * m0
             + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * m1)
    slope = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * h * m0
             + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * h * m1)
    return value, slope


def cycle_boundaries(t: np.ndarray, phi1: np.ndarray, omega1: np.ndarray,
                     turns: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Crossings of φ1 = 2πk: (times, sample index i with t[i] ≤ tb < t[i+1], fraction s in
    [0, 1), k). Only forward crossings of a new, higher k count. ``turns``: the highest k
    reached up to the first sample, when the samples are a part of a longer run (a run
    analysed block by block: :mod:`.step_stream`)."""
    k = np.floor(phi1 / TWO_PI)
    if turns is not None and len(k):
        k[0] = max(k[0], turns)
    running = np.maximum.accumulate(k)
    idx = np.flatnonzero(running[1:] > running[:-1])
    if len(idx) and np.any(running[idx + 1] - running[idx] > 1):
        raise AnalysisError('the crank turns more than once between two samples: the sample '
                            'interval is too coarse to split crank cycles')
    kk = running[idx + 1]
    target = kk * TWO_PI
    h = t[idx + 1] - t[idx]
    p0, p1 = phi1[idx], phi1[idx + 1]
    m0, m1 = omega1[idx], omega1[idx + 1]
    with np.errstate(invalid='ignore', divide='ignore'):
        s = np.clip((target - p0) / (p1 - p0), 0.0, 1.0)
    for _ in range(6):
        value, slope = _hermite(s, h, p0, p1, m0, m1)
        with np.errstate(invalid='ignore', divide='ignore'):
            step = np.where(slope > 0, (value - target) / slope, 0.0)
        s = np.clip(s - step, 0.0, 1.0)
    return t[idx] + s * h, idx, s, kk


class Integrator:
    """Exact integrals of the piecewise-linear interpolant of samples f(t)."""

    def __init__(self, t: np.ndarray):
        self.t = t
        self.h = np.diff(t)

    def cumulative(self, f: np.ndarray) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * self.h)])

    def at(self, F: np.ndarray, f: np.ndarray, idx: np.ndarray, s: np.ndarray) -> np.ndarray:
        """∫ from t[0] to t[idx] + s·h[idx]."""
        idx = np.minimum(idx, len(self.h) - 1)
        h = self.h[idx]
        tau = s * h
        return F[idx] + f[idx] * tau + (f[idx + 1] - f[idx]) * tau * tau / (2.0 * h)


def _lerp(f: np.ndarray, idx: np.ndarray, s: np.ndarray) -> np.ndarray:
    idx = np.minimum(idx, len(f) - 2)
    return f[idx] + s * (f[idx + 1] - f[idx])


def _window_extrema(f: np.ndarray, lo: np.ndarray, hi: np.ndarray, fa: np.ndarray,
                    fb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """max/min of samples lo..hi (inclusive; may be empty when hi < lo) and the ends fa, fb."""
    mx = np.maximum(fa, fb)
    mn = np.minimum(fa, fb)
    nonempty = np.flatnonzero(hi >= lo)
    if len(nonempty):
        # reduceat over [start, end) pairs: the even segments are the ranges (the odd ones, the
        # gaps between them, are dropped); one sentinel sample lets an end be len(f)
        edges = np.empty(2 * len(nonempty), dtype=np.intp)
        edges[0::2], edges[1::2] = lo[nonempty], hi[nonempty] + 1
        padded = np.append(f, f[-1])
        seg_max = np.maximum.reduceat(padded, edges)[0::2]
        seg_min = np.minimum.reduceat(padded, edges)[0::2]
        mx[nonempty] = np.maximum(mx[nonempty], seg_max)
        mn[nonempty] = np.minimum(mn[nonempty], seg_min)
    return mx, mn


#: Per-cycle integrals kept for aggregating windows of whole cycles (:meth:`CycleTable.window`).
_TOTALS = ('period', 'dphi4', 'twist', 'clutch_torque', 'engaged', 'motor_work', 'output_work')


@dataclass
class CycleTable:
    """Per-cycle metrics: one array per name of ``CYCLE_FIELDS`` (length = complete cycles),
    the cycles' end times and their integrals (for :meth:`window`)."""

    values: dict[str, np.ndarray]
    t_end: np.ndarray
    totals: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.values['cycle'])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]

    def rows(self) -> list[dict[str, float]]:
        """One dict per cycle; ``cycle`` its number from 1 (an int)."""
        return [{k: int(v[i]) if k == 'cycle' else float(v[i]) for k, v in self.values.items()}
                for i in range(len(self))]

    def window(self, first: int, stop: int) -> dict[str, float]:
        """Metrics of the whole cycles ``first`` … ``stop − 1`` (sums of their integrals, so
        means are time means over the window); {} for an empty window."""
        sel = slice(first, stop)
        n = len(self.values['cycle'][sel])
        T = float(np.sum(self.totals['period'][sel]))
        if not n or not T > 0:
            return {}
        total = {key: float(np.sum(self.totals[key][sel])) for key in _TOTALS}
        ripple = self.values['ripple'][sel]
        out = {
            'cycles': float(n),
            't_start': float(self.values['t_start'][sel][0]),
            't_end': float(self.t_end[sel][-1]),
            'ratio': total['dphi4'] / (TWO_PI * n),
            'crank_speed': TWO_PI * n / T,
            'output_speed': total['dphi4'] / T,
            'ripple': float(np.nanmean(ripple)) if np.any(np.isfinite(ripple)) else math.nan,
            'ripple_max': float(np.nanmax(ripple)) if np.any(np.isfinite(ripple)) else math.nan,
            'twist_peak': float(np.max(self.values['twist_peak'][sel])),
            'twist_mean': total['twist'] / T,
            'clutch_torque_peak': float(np.max(self.values['clutch_torque_peak'][sel])),
            'clutch_torque_mean': total['clutch_torque'] / T,
            'engaged_fraction': total['engaged'] / T,
            'switches_per_cycle': float(np.sum(self.values['switches'][sel]) / n),
            'motor_power': total['motor_work'] / T,
            'output_power': total['output_work'] / T,
        }
        out['load_factor'] = out['clutch_torque_peak'] / out['clutch_torque_mean'] \
            if out['clutch_torque_mean'] > 0 else math.nan
        out['efficiency'] = efficiency(total['output_work'], total['motor_work'], out['ratio'])
        if abs(out['ratio']) < DRIVEN_RATIO:
            out['ripple'] = out['ripple_max'] = math.nan
        return out


def efficiency(output_work: float, motor_work: float, ratio: float) -> float:
    """η = W4 / W1; NaN while the output is not driven (|i| < DRIVEN_RATIO) or the motor does
    no work."""
    if not motor_work > 0 or not abs(ratio) >= DRIVEN_RATIO:
        return math.nan
    return output_work / motor_work


#: why a figure fails :func:`physical`, as reports say it
UNPHYSICAL_NOTES = {
    'efficiency': 'efficiency outside 0–100 %: not a transmission efficiency — over this window '
                  'the inertias and the shaft released (or took) stored energy, or the load '
                  'drives the output',
    'engaged_fraction': 'engaged fraction outside 0–100 %: inconsistent clutch events',
    'ripple': 'negative ripple: inconsistent samples',
    'ripple_max': 'negative ripple: inconsistent samples',
    'clutch_torque_mean': 'negative mean clutch torque: a one-way clutch cannot transmit it '
                          '(inconsistent samples)',
    'load_factor': 'negative load factor: inconsistent samples',
}


def physical(name: str, value: float) -> bool:
    """False for a figure no steady state of this machine can have: an efficiency outside
    [0, 1] (energy stored in the inertias and the shaft was released, or taken, in the window;
    or an overhauling load), a negative ripple or engaged fraction outside [0, 1]. Reports flag
    such figures instead of printing them as plain numbers."""
    if not math.isfinite(value):
        return True  # printed as n/a
    if name in ('efficiency', 'engaged_fraction'):
        return 0.0 <= value <= 1.0
    if name in ('ripple', 'ripple_max', 'clutch_torque_mean', 'load_factor', 'period'):
        return value >= 0.0
    return True


def cycle_metrics(trace: Trace, turns: float | None = None) -> tuple[CycleTable, np.ndarray]:
    """Split one run into crank cycles: (per-cycle table, cycle boundary times). ``turns``: see
    :func:`cycle_boundaries`."""
    t = trace.t
    if np.any(np.diff(t) <= 0):
        raise AnalysisError('sample times are not increasing')
    phi1, w1 = trace.phi[:, 0], trace.omega[:, 0]
    tb, idx, s, _ = cycle_boundaries(t, phi1, w1, turns)
    n_cyc = max(len(tb) - 1, 0)
    integ = Integrator(t)
    h = np.diff(t)

    def at(f: np.ndarray) -> np.ndarray:
        return integ.at(integ.cumulative(f), f, idx, s)

    phi4_b = _hermite(s, h[np.minimum(idx, len(h) - 1)], trace.phi[idx, 3],
                      trace.phi[np.minimum(idx + 1, len(t) - 1), 3], trace.omega[idx, 3],
                      trace.omega[np.minimum(idx + 1, len(t) - 1), 3])[0]
    T = np.diff(tb)
    a, b = slice(0, n_cyc), slice(1, n_cyc + 1)
    dphi4 = np.diff(phi4_b)
    m1, tc, m4 = trace.effort[:, 0], trace.effort[:, 1], trace.effort[:, 3]
    w4 = trace.omega[:, 3]
    twist_int = np.diff(at(trace.twist))
    tc_int = np.diff(at(tc))
    w1_int = np.diff(at(m1 * w1))
    w4_int = np.diff(at(m4 * w4))
    m4_int = np.diff(at(m4))
    a_int = np.diff(at(trace.crank_length))
    engaged_int = np.diff(trace.engaged_time(tb))
    # samples strictly inside each cycle: idx[k] + 1 .. idx[k + 1]
    lo, hi = idx[a] + 1, idx[b]
    w4_b = _lerp(w4, idx, s)
    th_b = _lerp(trace.twist, idx, s)
    tc_b = _lerp(tc, idx, s)
    w4_max, w4_min = _window_extrema(w4, lo, hi, w4_b[a], w4_b[b])
    th_max, _ = _window_extrema(trace.twist, lo, hi, th_b[a], th_b[b])
    tc_max, _ = _window_extrema(tc, lo, hi, tc_b[a], tc_b[b])
    sw = np.searchsorted(trace.switch_t, tb, side='left')
    switches = np.diff(sw).astype(float) if trace.initial_engaged is not None \
        else np.full(n_cyc, np.nan)
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        out_speed = dphi4 / T
        ratio = dphi4 / TWO_PI
        values = {
            'cycle': np.arange(1, n_cyc + 1, dtype=float),   # numbered from 1, as reports say
            't_start': tb[a],
            'period': T,
            'crank_speed': TWO_PI / T,
            'ratio': ratio,
            'output_speed': out_speed,
            'ripple': np.where(np.abs(ratio) < DRIVEN_RATIO, np.nan,
                               (w4_max - w4_min) / np.abs(out_speed)),
            'twist_peak': th_max,
            'twist_mean': twist_int / T,
            'clutch_torque_peak': tc_max,
            'clutch_torque_mean': tc_int / T,
            'load_factor': np.where(tc_int > 0, tc_max / (tc_int / T), np.nan),
            'engaged_fraction': engaged_int / T,
            'switches': switches,
            'motor_power': w1_int / T,
            'output_power': w4_int / T,
            'efficiency': np.where((np.abs(ratio) < DRIVEN_RATIO) | ~(w1_int > 0), np.nan,
                                   w4_int / w1_int),
            'crank_length': a_int / T,
            'load_torque': m4_int / T,
        }
    totals = {'period': T, 'dphi4': dphi4, 'twist': twist_int, 'clutch_torque': tc_int,
              'engaged': engaged_int, 'motor_work': w1_int, 'output_work': w4_int}
    return CycleTable(values, tb[b], totals), tb
