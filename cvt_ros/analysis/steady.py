"""Steady state, detected from the signal: the cycle means have settled within a tolerance.

A run (or the part of it after a command) is in steady state over its trailing cycles
``first … end`` when every cycle's mean crank speed ω1, output speed ω4, ratio i, motor power P1
and output power P4 lies within ±``tolerance`` of that window's mean (relative; with an absolute
floor where a mean is near zero: the neutral crank, an unloaded output), for at least
``min_cycles`` cycles. The powers matter: the speeds of a lightly damped machine settle long
before the energy its flywheels and shaft exchange does, and an efficiency over a window whose
stored energy still swings is no steady-state figure (it can exceed 100 %). A signal the input
does not carry (motor torque in some CSVs) is left out. The window is the longest such tail: it
starts where the cycle means entered the band for good. A run that ends in a transient has no
steady state, and then none of its figures is called one ("none", with the reason).

:func:`settled_tail` is the detector on plain arrays (any per-cycle or per-sample series), so step
metrics (:mod:`.steps`, :mod:`.stepinfo`) decide "settled" the same way.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .cycles import DRIVEN_RATIO, CycleTable

__all__ = ['MIN_CYCLES', 'SETTLED_SIGNALS', 'TOLERANCE', 'SteadyState', 'find_steady_state',
           'settled_tail']

#: Default band of the cycle means around their window mean (±0.5 %).
TOLERANCE = 5e-3
#: Default minimum length of a steady window [crank cycles].
MIN_CYCLES = 10


def settled_tail(series: Mapping[str, np.ndarray], tolerance: float, min_count: int,
                 floors: Mapping[str, float] | None = None) -> int | None:
    """Index of the first element of the longest tail in which every series stays within
    ±max(tolerance·|tail mean|, floor) of its tail mean, or None if the last ``min_count``
    elements do not (or there are fewer). Non-finite values never settle. O(n)."""
    floors = floors or {}
    arrays = {name: np.asarray(values, dtype=float) for name, values in series.items()}
    n = min((len(v) for v in arrays.values()), default=0)
    if n < max(min_count, 1):
        return None
    ok = np.ones(n, dtype=bool)              # ok[s]: the tail s … n−1 is within its band
    for name, values in arrays.items():
        tail = values[len(values) - n:][::-1]   # reversed: prefix k = the tail of length k
        finite = np.logical_and.accumulate(np.isfinite(tail))
        with np.errstate(invalid='ignore', over='ignore'):
            count = np.arange(1, n + 1)
            mean = np.cumsum(tail) / count
            high = np.maximum.accumulate(tail)
            low = np.minimum.accumulate(tail)
            band = np.maximum(tolerance * np.abs(mean), floors.get(name, 0.0))
            inside = finite & (high - mean <= band) & (mean - low <= band)
        ok &= inside[::-1]
    start = n - min_count
    if not ok[start]:
        return None
    # extend backwards while the tail stays in its band (stop at the first tail that leaves it)
    bad = np.flatnonzero(~ok[:start + 1])
    return int(bad[-1] + 1) if len(bad) else 0


@dataclass(frozen=True)
class SteadyState:
    """The steady window of a run: cycles ``first`` … ``stop − 1`` (found), or why there is
    none (``reason``)."""

    found: bool
    first: int = 0
    stop: int = 0
    t_start: float = float('nan')
    t_end: float = float('nan')
    tolerance: float = TOLERANCE
    min_cycles: int = MIN_CYCLES
    reason: str = ''

    @property
    def cycles(self) -> int:
        return self.stop - self.first if self.found else 0


#: The cycle means that must have settled for steady-state figures (CycleTable names).
SETTLED_SIGNALS = ('crank_speed', 'output_speed', 'ratio', 'motor_power', 'output_power')
_SIGNAL_NAMES = {'crank_speed': 'crank speed', 'output_speed': 'output speed', 'ratio': 'ratio',
                 'motor_power': 'motor power', 'output_power': 'output power'}


def _median_abs(values: np.ndarray) -> float:
    finite = np.abs(values[np.isfinite(values)])
    return float(np.median(finite)) if len(finite) else 0.0


def cycle_mean_floors(cycles: CycleTable, first: int = 0) -> dict[str, float]:
    """Absolute floors of the bands: a ratio, ω4 or power near zero (neutral crank, unloaded
    output) settles at 0."""
    w1 = _median_abs(cycles['crank_speed'][first:])
    p1 = _median_abs(cycles['motor_power'][first:])
    return {'ratio': 0.1 * DRIVEN_RATIO, 'output_speed': 0.1 * DRIVEN_RATIO * w1,
            'crank_speed': 1e-9, 'motor_power': 1e-3 * p1 + 1e-12,
            'output_power': 1e-3 * p1 + 1e-12}


def find_steady_state(cycles: CycleTable, first: int = 0, stop: int | None = None, *,
                      tolerance: float = TOLERANCE, min_cycles: int = MIN_CYCLES,
                      signals: tuple[str, ...] = SETTLED_SIGNALS,
                      floors: Mapping[str, float] | None = None) -> SteadyState:
    """The steady window among cycles ``first`` … ``stop − 1`` (default: all), ending at the
    last of them; ``found=False`` with the reason when the cycle means of ``signals`` have not
    settled. ``floors``: absolute bands that replace the defaults (:func:`cycle_mean_floors`)
    where larger."""
    stop = len(cycles) if stop is None else stop
    count = max(stop - first, 0)
    if count < min_cycles:
        return SteadyState(False, tolerance=tolerance, min_cycles=min_cycles,
                           reason=f'{count} complete crank cycle(s), {min_cycles} needed to '
                                  'tell a steady state')
    series = {name: cycles[name][first:stop] for name in signals
              if not np.all(np.isnan(cycles[name][first:stop]))}
    bands = cycle_mean_floors(cycles, first)
    for name, floor in (floors or {}).items():
        bands[name] = max(bands.get(name, 0.0), floor)
    start = settled_tail(series, tolerance, min_cycles, bands)
    if start is None:
        tail = {name: values[-min_cycles:] for name, values in series.items()}
        spread = {name: float(np.ptp(v) / max(abs(float(np.mean(v))), 1e-300))
                  for name, v in tail.items() if np.all(np.isfinite(v))}
        worst = max(spread, key=spread.get) if spread else 'ratio'
        what = _SIGNAL_NAMES[worst]
        moved = f' by {spread[worst]:.2%}' if worst in spread else ''
        return SteadyState(False, tolerance=tolerance, min_cycles=min_cycles,
                           reason=f'not settled: the cycle-mean {what} still moves{moved} over '
                                  f'the last {min_cycles} cycles (band ±{tolerance:.2%})')
    lo = first + start
    names = ', '.join(_SIGNAL_NAMES[name] for name in series)
    return SteadyState(True, lo, stop, float(cycles['t_start'][lo]),
                       float(cycles.t_end[stop - 1]), tolerance, min_cycles,
                       f'cycle means of {names} within ±{tolerance:.2%} for {stop - lo} cycles')
