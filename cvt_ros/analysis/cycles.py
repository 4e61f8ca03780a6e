"""Crank cycles of a run and the metrics per cycle and per window of whole cycles.

Metrics (:func:`cycle_metrics`), per crank cycle and per run. A crank cycle is one turn of the
crank between successive crossings of φ1 = 2πk (k integer: the crank along the frame line
O1→O2), located on the cubic Hermite interpolant of (φ1, ω1); only complete cycles count.
Over a window [ta, tb] (one cycle, all cycles of a run, or the last quarter of them):

* ratio i = Δφ4 / Δφ1 (= mean ω4 / mean ω1);
* output speed ripple = (max ω4 − min ω4) / mean ω4 (n/a while |i| < 1e-3: neutral crank);
* torsion twist θ = φ3 − φ4: peak (max θ) and time mean;
* peak clutch torque Tc,max and the **dynamic load factor** K = Tc,max / mean Tc (mean over the
  whole window, engaged or not: the torque the clutch transmits on average);
* engaged fraction = time engaged / window length (exact from the switch times);
* switches per cycle (engage + release; grazing contacts are not switches);
* motor power P1 = ∫M1·ω1 dt / T, output power P4 = ∫M4·ω4 dt / T (the power taken by the load),
  efficiency η = ∫M4·ω4 / ∫M1·ω1 (n/a while |i| < 1e-3 or the motor does no work). The model
  is lossless except shaft damping (and the rare plastic engagement at start-up), so η < 1 in
  steady state only by damping and by the change of stored energy over the window;
* energy residual (per run, over the whole sampled span): ΔE − (W1 − W4 − Wd) with stored energy
  E = ½ΣJk·ωk² + ½c·θ² (inertias, stiffness, damping from the scene parameters), W1 = ∫M1ω1,
  W4 = ∫M4ω4, Wd = ∫kd·(ω3 − ω4)². Integrals are trapezoidal over the samples, so the residual
  measures the sampling (O(Δt²), at the clutch switches O(Δt)) more than the solver; the
  crank-length actuator's work is not recorded (flagged when the crank length moved).

Integrals and means use the piecewise-linear interpolant of the samples, integrated exactly
between the (interpolated) cycle boundaries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import AnalysisError
from .trace import Trace

__all__ = ['CYCLE_FIELDS', 'DRIVEN_RATIO', 'TWO_PI', 'CycleTable', 'cycle_boundaries',
           'cycle_metrics']

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


def cycle_boundaries(t: np.ndarray, phi1: np.ndarray, omega1: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Crossings of φ1 = 2πk: (times, sample index i with t[i] ≤ tb < t[i+1], fraction s in
    [0, 1), k). Only forward crossings of a new, higher k count."""
    k = np.floor(phi1 / TWO_PI)
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
    nonempty = hi >= lo
    if np.any(nonempty):
        starts = lo[nonempty]
        ends = hi[nonempty] + 1
        # reduceat over [start, next start) — build explicit index ranges for safety
        seg_max = np.array([np.max(f[a:b]) for a, b in zip(starts, ends, strict=True)])
        seg_min = np.array([np.min(f[a:b]) for a, b in zip(starts, ends, strict=True)])
        mx[nonempty] = np.maximum(mx[nonempty], seg_max)
        mn[nonempty] = np.minimum(mn[nonempty], seg_min)
    return mx, mn


@dataclass
class CycleTable:
    """Per-cycle metrics: one array per name of ``CYCLE_FIELDS`` (length = complete cycles)."""

    values: dict[str, np.ndarray]
    t_end: np.ndarray

    def __len__(self) -> int:
        return len(self.values['cycle'])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]

    def rows(self) -> list[dict[str, float]]:
        return [{k: float(v[i]) for k, v in self.values.items()} for i in range(len(self))]


def _window_metrics(cy: CycleTable, sel: slice, totals: dict[str, np.ndarray]) -> dict:
    """Aggregate the cycles ``sel`` (whole cycles: sums of the per-cycle integrals)."""
    T = float(np.sum(totals['T'][sel]))
    if not len(cy['cycle'][sel]) or T <= 0:
        return {}
    n = len(cy['cycle'][sel])
    out = {
        'cycles': float(n),
        't_start': float(cy['t_start'][sel][0]),
        't_end': float(cy.t_end[sel][-1]),
        'ratio': float(np.sum(totals['dphi4'][sel]) / (TWO_PI * n)),
        'crank_speed': TWO_PI * n / T,
        'output_speed': float(np.sum(totals['dphi4'][sel]) / T),
        'ripple': float(np.nanmean(cy['ripple'][sel])) if np.any(np.isfinite(
            cy['ripple'][sel])) else math.nan,
        'ripple_max': float(np.nanmax(cy['ripple'][sel])) if np.any(np.isfinite(
            cy['ripple'][sel])) else math.nan,
        'twist_peak': float(np.max(cy['twist_peak'][sel])),
        'twist_mean': float(np.sum(totals['twist'][sel]) / T),
        'clutch_torque_peak': float(np.max(cy['clutch_torque_peak'][sel])),
        'clutch_torque_mean': float(np.sum(totals['tc'][sel]) / T),
        'engaged_fraction': float(np.sum(totals['engaged'][sel]) / T),
        'switches_per_cycle': float(np.sum(cy['switches'][sel]) / n),
        'motor_power': float(np.sum(totals['w1'][sel]) / T),
        'output_power': float(np.sum(totals['w4'][sel]) / T),
    }
    with np.errstate(invalid='ignore', divide='ignore'):
        out['load_factor'] = out['clutch_torque_peak'] / out['clutch_torque_mean'] \
            if out['clutch_torque_mean'] > 0 else math.nan
        w1 = float(np.sum(totals['w1'][sel]))
        out['efficiency'] = float(np.sum(totals['w4'][sel])) / w1 \
            if w1 > 0 and abs(out['ratio']) >= DRIVEN_RATIO else math.nan
    if abs(out['ratio']) < DRIVEN_RATIO:
        out['ripple'] = out['ripple_max'] = math.nan
    return out


def cycle_metrics(trace: Trace) -> tuple[CycleTable, np.ndarray, dict[str, dict[str, float]]]:
    """Split one run into crank cycles: (per-cycle table, cycle boundary times, per-run windows
    'all' / 'last_quarter' → metric → value); see the module docstring."""
    t = trace.t
    if np.any(np.diff(t) <= 0):
        raise AnalysisError('sample times are not increasing')
    phi1, w1 = trace.phi[:, 0], trace.omega[:, 0]
    tb, idx, s, _ = cycle_boundaries(t, phi1, w1)
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
    with np.errstate(invalid='ignore', divide='ignore'):
        out_speed = dphi4 / T
        values = {
            'cycle': np.arange(n_cyc, dtype=float),
            't_start': tb[a],
            'period': T,
            'crank_speed': TWO_PI / T,
            'ratio': dphi4 / TWO_PI,
            'output_speed': out_speed,
            'ripple': (w4_max - w4_min) / out_speed,
            'twist_peak': th_max,
            'twist_mean': twist_int / T,
            'clutch_torque_peak': tc_max,
            'clutch_torque_mean': tc_int / T,
            'load_factor': np.where(tc_int > 0, tc_max / (tc_int / T), np.nan),
            'engaged_fraction': engaged_int / T,
            'switches': switches,
            'motor_power': w1_int / T,
            'output_power': w4_int / T,
            'efficiency': w4_int / w1_int,
            'crank_length': a_int / T,
            'load_torque': m4_int / T,
        }
    idle = (np.abs(values['ratio']) < DRIVEN_RATIO) | ~(w1_int > 0)
    values['efficiency'] = np.where(idle, np.nan, values['efficiency'])
    values['ripple'] = np.where(np.abs(values['ratio']) < DRIVEN_RATIO, np.nan, values['ripple'])
    cycles = CycleTable(values, tb[b])
    totals = {'T': T, 'dphi4': dphi4, 'twist': twist_int, 'tc': tc_int, 'engaged': engaged_int,
              'w1': w1_int, 'w4': w4_int}
    summary = {}
    if n_cyc:
        summary['all'] = _window_metrics(cycles, slice(0, n_cyc), totals)
        q = max(1, n_cyc // 4)
        summary['last_quarter'] = _window_metrics(cycles, slice(n_cyc - q, n_cyc), totals)
    return cycles, tb, summary

