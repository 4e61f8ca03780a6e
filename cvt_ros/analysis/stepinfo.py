"""Closed-loop step metrics of a speed controller (in the spirit of MATLAB's ``stepinfo``),
computed from the **cycle-mean** output speed: the mean of ω4 over each crank turn
(:func:`cvt_ros.analysis.cycles.cycle_metrics`), because the raw ω4 pulses at the clutch
frequency and would make every threshold crossing a matter of ripple.

A *step* is a change of the set point or of the load (and the start of the run); its window runs
until the next change or the end. With y the cycle-mean speed at each cycle's middle, r the set
point, y0 the speed before the step (last complete cycle before it; ω4 at t = 0 for the start),
rf the set point at the end of the window and Δ = rf − y0:

* ``rise_time`` [s]: from y crossing y0 + 10 % Δ to y crossing y0 + 90 % Δ (linear between cycle
  middles; set-point steps only, NaN if 90 % is never reached);
* ``overshoot`` [%]: max over the window of (y − rf)·sign Δ, in % of |Δ| (≥ 0; set-point steps);
* ``settling_time`` [s]: from the step to the end of the last cycle outside the band rf ± 2 % of
  |Δ| (set-point steps) or of |rf| (load steps); NaN if the window ends outside the band;
* ``steady_state_error`` [rad/s]: rf − mean y over the last 10 % of the window (≥ 3 cycles);
* ``max_deviation`` [rad/s]: max |r − y| after the step (load steps: the disturbance's dip);
* ``iae`` [rad]: ∫|r − y| dt over the window (per cycle: |r(middle) − y|·cycle length);
* ``peak_clutch_torque`` [N·m], ``crank_travel`` [m] (Σ|Δa| of the actual crank length),
  ``switches_per_second`` [1/s]: what the step cost the mechanism.

The run-level summary (:func:`summarize_steps`) takes the worst of each over the steps (NaN if
one of them has none: a step that never settles leaves the run without a settling time; the max
deviation over the load steps only, NaN without one), and IAE, peak clutch torque, crank travel
and switches per second over the whole run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cycles import cycle_metrics
from .trace import Trace

__all__ = ['METRICS', 'StepEvent', 'combine_steps', 'cycle_window_metrics', 'step_metrics',
           'summarize_steps']

SETTLING_BAND = 0.02     # ±2 %
STEADY_FRACTION = 0.1    # steady-state error over the last 10 % of the window
MIN_STEADY_CYCLES = 3

#: metric name → unit, in report order
METRICS = {
    'rise_time': 's', 'overshoot': '%', 'settling_time': 's', 'steady_state_error': 'rad/s',
    'max_deviation': 'rad/s', 'iae': 'rad', 'peak_clutch_torque': 'N*m', 'crank_travel': 'm',
    'switches_per_second': '1/s',
}


@dataclass(frozen=True)
class StepEvent:
    """A change the loop has to answer: time [s], 'start' | 'setpoint' | 'load', values."""
    t: float
    kind: str
    before: float
    after: float


def _crossing(tm: np.ndarray, f: np.ndarray, level: float) -> float:
    """First time the sequence f (at times tm) reaches ``level`` from below, linear in between."""
    hit = np.flatnonzero(f >= level)
    if not len(hit):
        return math.nan
    i = int(hit[0])
    if i == 0:
        return float(tm[0])
    f0, f1 = f[i - 1], f[i]
    s = (level - f0) / (f1 - f0) if f1 != f0 else 0.0
    return float(tm[i - 1] + s * (tm[i] - tm[i - 1]))


def step_metrics(trace: Trace, reference_t: np.ndarray, reference: np.ndarray,
                 events: list[StepEvent]) -> list[dict]:
    """The metrics of each step in ``events`` (time order) for one run.

    ``reference_t``, ``reference``: the set point on a time grid (the control periods).
    Returns one dict per event: its time, kind, before/after values, window end, METRICS and,
    where a settling time applies, the band it is judged by: ``settling_target`` ± ``settling_band``
    [rad/s].
    """
    table = cycle_metrics(trace)[0]
    t_start = table['t_start']
    t_end = table.t_end
    tm = t_start + 0.5 * table['period']
    y = table['output_speed']
    r_mid = np.interp(tm, reference_t, reference)
    a = trace.crank_length
    tc = trace.effort[:, 1]
    out = []
    end_of_run = float(trace.t[-1])
    for j, ev in enumerate(events):
        t_e = events[j + 1].t if j + 1 < len(events) else end_of_run
        row = {'t': ev.t, 'kind': ev.kind, 'before': ev.before, 'after': ev.after,
               'window_end': t_e}
        row.update(_window(trace, tm, t_start, t_end, y, r_mid, reference_t, reference, a, tc,
                           ev, t_e))
        out.append(row)
    return out


def _window(trace, tm, t_start, t_end, y, r_mid, ref_t, ref, a, tc, ev, t_e):
    # the samples, switches and cycles of the window found by bisection (times increase, as a
    # run's do): one step costs its own window, not the whole run (5000 steps over a long run)
    m = dict.fromkeys(METRICS, math.nan)
    s0 = np.searchsorted(trace.t, ev.t, side='left')
    s1 = np.searchsorted(trace.t, t_e, side='right')
    span = t_e - ev.t
    if s1 > s0:
        m['peak_clutch_torque'] = float(np.nanmax(tc[s0:s1]))
        aw = a[s0:s1]
        m['crank_travel'] = float(np.nansum(np.abs(np.diff(aw)))) if len(aw) > 1 else 0.0
    if span > 0:
        n_sw = (np.searchsorted(trace.switch_t, t_e, side='right')
                - np.searchsorted(trace.switch_t, ev.t, side='right'))
        m['switches_per_second'] = max(int(n_sw), 0) / span
    c0 = int(np.searchsorted(t_start, ev.t, side='left'))
    idx = np.arange(c0, max(c0, int(np.searchsorted(t_end, t_e, side='right'))))
    if not len(idx):
        return m
    # the set point in force at the end of the window (a step at t_e belongs to the next one)
    half = 0.5 * (ref_t[1] - ref_t[0]) if len(ref_t) > 1 else 0.0
    last = max(int(np.searchsorted(ref_t, t_e - half, side='right')) - 1, 0)
    rf = float(ref[last]) if t_e < ref_t[-1] else float(ref[-1])
    before = int(np.searchsorted(t_end, ev.t, side='right'))   # cycles ended by the step
    y0 = float(y[before - 1]) if before and ev.kind != 'start' else \
        float(np.interp(ev.t, trace.t, trace.omega[:, 3]))
    m.update(cycle_window_metrics(ev, tm[idx], t_start[idx], t_end[idx], y[idx], r_mid[idx],
                                  rf, y0))
    return m


def cycle_window_metrics(ev: StepEvent, tw: np.ndarray, t_start: np.ndarray,
                         t_end: np.ndarray, yw: np.ndarray, r_mid: np.ndarray, rf: float,
                         y0: float) -> dict:
    """The metrics of a step's window from its whole crank cycles (at least one: their middles
    ``tw``, starts, ends, cycle-mean speeds ``yw`` and set points at the middles ``r_mid``),
    the set point ``rf`` in force at the window's end and the speed ``y0`` before the step:
    IAE, max deviation, steady-state error, rise time, overshoot, settling time (and the band
    it is judged by)."""
    m = {}
    period = t_end - t_start
    err = r_mid - yw
    m['iae'] = float(np.sum(np.abs(err) * period))
    m['max_deviation'] = float(np.max(np.abs(err)))
    n = len(yw)
    n_ss = max(MIN_STEADY_CYCLES, int(math.ceil(STEADY_FRACTION * n)))
    if n >= n_ss:
        m['steady_state_error'] = float(rf - np.mean(yw[-n_ss:]))
    delta = rf - y0
    tracking = ev.kind in ('start', 'setpoint')
    scale = abs(delta) if tracking else abs(rf)
    if tracking and abs(delta) > 0:
        sign = math.copysign(1.0, delta)
        f = (yw - y0) * sign
        t10 = _crossing(tw, f, 0.1 * abs(delta))
        t90 = _crossing(tw, f, 0.9 * abs(delta))
        m['rise_time'] = t90 - t10
        m['overshoot'] = float(max(0.0, np.max((yw - rf) * sign)) / abs(delta) * 100.0)
    if scale > 0:
        m['settling_target'], m['settling_band'] = rf, SETTLING_BAND * scale   # for plots
        outside = np.flatnonzero(np.abs(yw - rf) > SETTLING_BAND * scale)
        if not len(outside):
            m['settling_time'] = 0.0
        elif outside[-1] < n - MIN_STEADY_CYCLES:
            m['settling_time'] = float(t_end[outside[-1]] - ev.t)
    return m


def summarize_steps(steps: list[dict], trace: Trace, reference_t: np.ndarray,
                    reference: np.ndarray, since: float | None = None) -> dict:
    """Run-level metrics: the worst step for the step metrics (rise time, overshoot, settling
    time, |steady-state error| of the last step, max deviation), the whole run for IAE, peak
    clutch torque, crank travel and switches per second. A step that never reaches 90 % or
    never settles makes the run's rise or settling time NaN: the worst of the steps is not
    known, and a test asserting a bound on it must fail. ``since`` [s]: only the steps from
    then on, and the whole-run figures over [since, end] (e.g. without the start-up)."""
    start = float(trace.t[0])
    if since is not None and since > start:
        start = since
    whole = step_metrics(trace, reference_t, reference,
                         [StepEvent(start, 'start', math.nan, math.nan)])[0]
    return combine_steps(steps, whole, since, float(trace.t[0]))


def combine_steps(steps: list[dict], whole: dict, since: float | None, first: float) -> dict:
    """The run-level metrics of :func:`summarize_steps` from the steps and ``whole``, the
    figures of one window [max(since, first), end] (IAE, peak clutch torque, crank travel,
    switches per second); ``first``: the time of the run's first sample [s]."""
    if since is not None and since > first:
        steps = [s for s in steps if s['t'] >= since - 1e-9]

    def applies(step, name):
        """A step with nothing to follow (the set point as the speed already is) has no rise,
        overshoot or settling to be the worst of."""
        moved = step['after'] != step['before']
        if name in ('rise_time', 'overshoot'):
            return step['kind'] in ('start', 'setpoint') and moved
        return name != 'settling_time' or step['kind'] == 'load' or moved

    def worst(name, kinds=None):
        vals = [s[name] for s in steps if (kinds is None or s['kind'] in kinds)
                and applies(s, name)]
        if not vals or any(math.isnan(v) for v in vals):
            return math.nan
        return max(vals, key=abs)
    return {
        'rise_time': worst('rise_time', ('start', 'setpoint')),
        'overshoot': worst('overshoot', ('start', 'setpoint')),
        'settling_time': worst('settling_time'),
        'steady_state_error': steps[-1]['steady_state_error'] if steps else math.nan,
        'max_deviation': worst('max_deviation', ('load',)),
        'iae': whole['iae'],
        'peak_clutch_torque': whole['peak_clutch_torque'],
        'crank_travel': whole['crank_travel'],
        'switches_per_second': whole['switches_per_second'],
    }
