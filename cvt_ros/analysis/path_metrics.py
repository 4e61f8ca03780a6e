"""Figures of each path of an N-path machine (issue 33) over a window [ta, tb]: what each
one-way clutch does — the part a designer sizes per path.

* engaged fraction = time the clutch is engaged / window (exact from its switch times);
* peak clutch torque Tc,k,max (the sampled extremes and the window's interpolated ends) and mean
  clutch torque (time mean, engaged or not: the torque the clutch passes on average);
* dynamic load factor K_k = Tc,k,max / mean Tc,k;
* switches (engage + release) in (ta, tb].

Integrals use the piecewise-linear interpolant of the samples, as :mod:`.cycles` does. The
machine's own figures (output ripple, the total clutch torque's K) are the run's, in
:mod:`.whole_run` and :mod:`.cycles`.
"""

from __future__ import annotations

import math

import numpy as np

from .cycles import Integrator
from .trace import Trace

__all__ = ['PATH_FIELDS', 'path_metrics']

#: Per-path figures, in table order, with units.
PATH_FIELDS = (('engaged_fraction', '-'), ('clutch_torque_peak', 'N*m'),
               ('clutch_torque_mean', 'N*m'), ('load_factor', '-'), ('switches', '-'))


def _at(t: np.ndarray, f: np.ndarray, x: float) -> float:
    """The piecewise-linear interpolant of samples f at x (clamped to the samples' span)."""
    return float(np.interp(x, t, f))


def _integral(integ: Integrator, t: np.ndarray, f: np.ndarray, a: float, b: float) -> float:
    F = integ.cumulative(f)
    ends = np.array([a, b])
    idx = np.clip(np.searchsorted(t, ends, side='right') - 1, 0, len(t) - 2)
    s = np.clip((ends - t[idx]) / integ.h[idx], 0.0, 1.0)
    lo, hi = integ.at(F, f, idx, s)
    return float(hi - lo)


def path_metrics(trace: Trace, t_start: float | None = None, t_end: float | None = None
                 ) -> list[dict[str, float]]:
    """One dict of ``PATH_FIELDS`` per path (``path``: 1 … N) over [t_start, t_end] (default:
    the whole run); [] for a one-path trace or an empty window."""
    paths = trace.paths
    t = trace.t
    if paths is None or len(t) < 2:
        return []
    a = float(t[0]) if t_start is None else max(float(t_start), float(t[0]))
    b = float(t[-1]) if t_end is None else min(float(t_end), float(t[-1]))
    span = b - a
    if not span > 0:
        return []
    integ = Integrator(t)
    inside = (t > a) & (t < b)
    out = []
    for k in range(1, paths.n_paths + 1):
        tc = paths.torque[:, k - 1]
        with np.errstate(invalid='ignore', over='ignore'):
            samples = np.concatenate([tc[inside], [_at(t, tc, a), _at(t, tc, b)]])
            finite = samples[np.isfinite(samples)]
            peak = float(np.max(finite)) if len(finite) else math.nan
            mean = _integral(integ, t, tc, a, b) / span
            engaged = paths.engaged_time(k, float(t[0]), np.array([a, b]))
        sw = paths.switch_t[k - 1]
        out.append({
            'path': k,
            'engaged_fraction': float(engaged[1] - engaged[0]) / span,
            'clutch_torque_peak': peak,
            'clutch_torque_mean': mean,
            'load_factor': peak / mean if mean > 0 else math.nan,
            'switches': float(np.count_nonzero((sw > a) & (sw <= b)))
            if paths.initial is not None else math.nan,
        })
    return out
