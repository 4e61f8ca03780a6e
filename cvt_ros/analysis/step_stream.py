"""Step metrics computed as a run passes (:class:`StepStream`): the metrics of
:mod:`.stepinfo` from blocks of samples fed in time order, in memory that does not grow with the
run's samples — a day of a 1 kHz run is 8.6·10⁷ samples, too many to keep.

What is kept instead:

* the samples of the crank cycle under way (:class:`CycleStream`: from the interval of its
  first boundary on; a crank that stalls for longer than MAX_CARRY samples keeps its cycle's
  boundary interval and the peak of the rest);
* per step window, the sample figures so far (peak clutch torque, crank travel, whether it
  has samples, its switch count) and, until the window is over, its whole cycles' ends, mean
  speeds and set points (24 bytes a crank turn: the rise, settling and steady-state figures
  need the set point in force at the window's end before they can look at the first cycle);
* for the whole-run figures from ``since``, their running sums and peaks.

Each figure is the number :func:`.stepinfo.step_metrics` and :func:`.stepinfo.summarize_steps`
give on the whole trace, to the bit — the cycles' boundaries, mean speeds and peaks are local to
a cycle's samples, the window metrics are :func:`.stepinfo.cycle_window_metrics` on the same
arrays — except two sums whose order changes: ``crank_travel`` (per step and run) is summed
block by block, and the run's ``iae`` chunk of cycles by chunk of cycles, where numpy sums a
whole window pairwise: they agree to rounding (1e-15 relative; test_scenario_stream.py).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from .cycles import cycle_boundaries, cycle_metrics
from .stepinfo import METRICS, StepEvent, combine_steps, cycle_window_metrics
from .trace import Trace

__all__ = ['MAX_CARRY', 'CycleStream', 'StepStream']

#: samples of one unfinished crank cycle kept; beyond, its interior is reduced to its peak
MAX_CARRY = 1 << 18
_FIELDS = ('t', 'phi', 'omega', 'effort', 'twist', 'crank_length')


def _nanmax(x):
    with warnings.catch_warnings():   # (an all-NaN slice is NaN, as np.nanmax's answer)
        warnings.simplefilter('ignore', RuntimeWarning)
        return float(np.nanmax(x))


class CycleStream:
    """The crank cycles of a run fed in blocks of samples (:meth:`add`, in time order): the
    cycles :func:`.cycles.cycle_metrics` finds in the whole run, with the same boundaries,
    cycle-mean output speeds and clutch torque peaks to the bit (each is made of its own
    cycle's samples and the two intervals of its boundaries). The engaged fraction is taken
    from the switches since the carried samples' first one (the plot's; rounding apart)."""

    def __init__(self):
        self.carry = None          # arrays of _FIELDS: the samples from the pending boundary on
        self.turns = None          # highest floor(φ1/2π) reached at the carry's first sample
        self.engaged = None        # clutch state at the carry's first sample
        self.switches = ([], [])   # switches after the carry's first sample: times, states
        self.pending = False       # the carry starts at a boundary's interval
        self.dropped_peak = None   # clutch torque peak of the interior samples dropped

    def add(self, block: dict, switch_t, switch_on, engaged: bool) -> dict:
        """``block``: arrays of _FIELDS (the new samples), the switches among them, the clutch
        state at the first sample of the run (used once). Returns the cycles completed: arrays
        t_start, t_end, output_speed, clutch_torque_peak, engaged_fraction."""
        if self.carry is None:
            data, self.engaged = block, bool(engaged)
        else:
            data = {k: np.concatenate([self.carry[k], block[k]]) for k in _FIELDS}
        sw_t = np.concatenate([self.switches[0], np.asarray(switch_t, dtype=float)])
        sw_on = np.concatenate([self.switches[1], np.asarray(switch_on, dtype=bool)])
        t = data['t']
        tb, idx, _, kk = cycle_boundaries(t, data['phi'][:, 0], data['omega'][:, 0], self.turns)
        out = {'t_start': np.empty(0), 't_end': np.empty(0), 'output_speed': np.empty(0),
               'clutch_torque_peak': np.empty(0), 'engaged_fraction': np.empty(0)}
        if len(tb) >= 2:
            trace = Trace(source='', kind='stream', t=t, phi=data['phi'], omega=data['omega'],
                          effort=data['effort'], twist=data['twist'],
                          crank_length=data['crank_length'], switch_t=sw_t,
                          switch_engaged=sw_on, initial_engaged=self.engaged,
                          switches_exact=True)
            table, _ = cycle_metrics(trace, self.turns)
            peak = table['clutch_torque_peak'].copy()
            if self.dropped_peak is not None:   # (NaN stays NaN, as numpy's maximum has it)
                peak[0] = np.maximum(peak[0], self.dropped_peak)
                self.dropped_peak = None
            out = {'t_start': table['t_start'], 't_end': table.t_end,
                   'output_speed': table['output_speed'], 'clutch_torque_peak': peak,
                   'engaged_fraction': table['engaged_fraction']}
        if len(tb):
            start, self.pending = int(idx[-1]), True
            self.turns = float(kk[-1] - 1)   # (a crossing raises the count by exactly one)
        elif self.pending:
            start = 0
        else:   # no cycle begun: the last sample and the turns counted up to it
            start = len(t) - 1
            k = np.floor(data['phi'][:, 0] / (2.0 * math.pi))
            self.turns = float(np.max(k) if self.turns is None else max(np.max(k), self.turns))
        self._keep(data, start, sw_t, sw_on)
        return out

    def _keep(self, data, start, sw_t, sw_on):
        t0 = data['t'][start]
        before = sw_t <= t0
        if np.any(before):
            self.engaged = bool(sw_on[before][-1])
        self.switches = (sw_t[~before], sw_on[~before])
        carry = {k: data[k][start:] for k in _FIELDS}
        if len(carry['t']) > MAX_CARRY:   # a stalled crank: keep the boundary's interval, the
            # last sample and the peak of the rest (all its cycle needs from them)
            inner = float(np.max(carry['effort'][2:-1, 1]))
            self.dropped_peak = inner if self.dropped_peak is None else \
                float(np.maximum(self.dropped_peak, inner))
            carry = {k: np.concatenate([v[:2], v[-1:]]) for k, v in carry.items()}
        self.carry = {k: v.copy() for k, v in carry.items()}   # (not a view of a whole block)


@dataclass
class _Span:
    """The sample figures of a span of the run so far: peak clutch torque, crank travel,
    whether it has samples, its switches."""
    peak: float = math.nan
    travel: float = 0.0
    sampled: bool = False
    switches: int = 0


@dataclass
class _Window(_Span):
    """One step's window as the run passes it."""
    event: StepEvent = None
    speed_at_start: float = math.nan   # ω4 at the step (interpolated between samples)
    speed_before: float | None = None  # cycle-mean speed of the last cycle ended by the step
    resolved: bool = False             # speed_before is known
    cycles: list = field(default_factory=list)   # (t_start[0], t_end, y, r_mid) chunks
    figures: dict | None = None        # the cycle figures, once the window is over


@dataclass
class _Whole(_Span):
    """The whole-run figures from ``since`` (IAE, peak, crank travel, switches)."""
    since: float = -math.inf
    iae: float = 0.0
    cycles: int = 0


class StepStream:
    """The step metrics of one run, fed block by block.

    ``events``: every step the run may have (:class:`StepEvent`, time order, the start first;
    those at or after the run's end are dropped by :meth:`finish`); ``setpoint_at(k)``: the set
    point at the control periods ``k`` (an int array) [rad/s]; ``period`` [s]; ``since``: the
    start times for which :meth:`finish`'s run-level metrics are wanted besides the whole run
    (None)."""

    def __init__(self, events, setpoint_at, period, since=()):
        self.events = list(events)
        self.e_t = np.array([e.t for e in self.events], dtype=float)
        self.windows = [_Window(event=e) for e in self.events]
        self.setpoint_at = setpoint_at
        self.dt = float(period)
        self.whole = {s: _Whole(since=-math.inf if s is None else float(s))
                      for s in (None, *since)}
        self.cycles = CycleStream()
        self.prev = None             # the last sample: t, crank length, clutch torque, ω4
        self.first_t = None
        self.k_last = -1
        self.samples = 0
        self.switch_count = 0
        self.last_speed = None       # cycle-mean speed of the last complete cycle
        self.last_cycle_end = -math.inf
        self.unresolved = 0          # first window whose speed_before is not known yet
        self.open = 0                # first window whose cycle figures are not made yet

    # ------------------------------------------------------------------ feeding
    def add(self, ks, block: dict, switch_t, switch_on, engaged0=False):
        """The samples of control periods ``ks`` (increasing): arrays of ``t``, ``phi``,
        ``omega``, ``effort``, ``twist``, ``crank_length`` as a :class:`Trace` has them; the
        clutch switches after the previous block's last sample up to this one's last (times,
        states after); ``engaged0``: the clutch state at the run's first sample. Returns the
        cycles completed (:meth:`CycleStream.add`), with ``middle`` and ``setpoint`` added."""
        t = block['t']
        if not len(t):
            return None
        if self.first_t is None:
            self.first_t = float(t[0])
        self.samples += len(t)
        prev = self.prev
        t_ext = t if prev is None else np.concatenate([[prev[0]], t])
        a_ext = block['crank_length'] if prev is None else \
            np.concatenate([[prev[1]], block['crank_length']])
        tc_ext = block['effort'][:, 1] if prev is None else \
            np.concatenate([[prev[2]], block['effort'][:, 1]])
        w4_ext = block['omega'][:, 3] if prev is None else \
            np.concatenate([[prev[3]], block['omega'][:, 3]])
        self._speeds_at_steps(t_ext, w4_ext, prev is None)
        self._sample_figures(t_ext, a_ext, tc_ext)
        self._switch_counts(np.asarray(switch_t, dtype=float))
        self.k_last = int(ks[-1])
        cycles = self.cycles.add(block, switch_t, switch_on, engaged0)
        if len(cycles['t_end']):
            self._take_cycles(cycles)
        self._close_windows()
        self.prev = (float(t[-1]), float(a_ext[-1]), float(tc_ext[-1]), float(w4_ext[-1]))
        return cycles

    def _speeds_at_steps(self, t_ext, w4_ext, first):
        """ω4 at each step that falls in this block (np.interp as the whole trace has it)."""
        lo = 0 if first else int(np.searchsorted(self.e_t, t_ext[0], side='right'))
        hi = int(np.searchsorted(self.e_t, t_ext[-1], side='right'))
        if hi > lo:
            speeds = np.interp(self.e_t[lo:hi], t_ext, w4_ext)
            for j in range(lo, hi):
                self.windows[j].speed_at_start = float(speeds[j - lo])

    def _bounds(self, j):
        return self.e_t[j + 1] if j + 1 < len(self.e_t) else math.inf

    def _sample_figures(self, t_ext, a_ext, tc_ext):
        """Peak clutch torque and crank travel over the samples of each window (its ends
        included, as searchsorted has them), and over [since, end]."""
        j0 = max(int(np.searchsorted(self.e_t, t_ext[0], side='left')) - 1, 0)
        j1 = int(np.searchsorted(self.e_t, t_ext[-1], side='right'))
        spans = [(w, self.e_t[j], self._bounds(j)) for j, w in
                 zip(range(j0, j1), self.windows[j0:j1], strict=True)]
        spans += [(w, w.since, math.inf) for w in self.whole.values()]
        for w, start, end in spans:
            s0 = int(np.searchsorted(t_ext, start, side='left'))
            s1 = int(np.searchsorted(t_ext, end, side='right'))
            if s1 <= s0:
                continue
            w.sampled = True
            w.peak = float(np.fmax(w.peak, _nanmax(tc_ext[s0:s1])))
            if s1 - s0 > 1:
                w.travel += float(np.nansum(np.abs(np.diff(a_ext[s0:s1]))))

    def _switch_counts(self, sw_t):
        """Switches in (step, next step], as searchsorted(…, 'right') counts them."""
        if not len(sw_t):
            return
        self.switch_count += len(sw_t)
        j = np.searchsorted(self.e_t, sw_t, side='left') - 1
        for jj, count in zip(*np.unique(j[j >= 0], return_counts=True), strict=True):
            self.windows[int(jj)].switches += int(count)
        for w in self.whole.values():
            w.switches += int(np.count_nonzero(sw_t > w.since))

    def _setpoint_at_times(self, tm):
        """np.interp(tm, k·period, set point) on the grid up to the last sample: the two grid
        points around each time, found as its binary search finds them."""
        dt = self.dt
        k = np.floor(tm / dt).astype(np.int64)
        k -= (k * dt > tm)                         # (k·dt ≤ tm < (k + 1)·dt, as computed)
        k += ((k + 1) * dt <= tm)
        k = np.clip(k, 0, self.k_last)
        # the grid points around the times, and no other: np.interp finds the same two
        grid = np.unique(np.concatenate([k, np.minimum(k + 1, self.k_last)]))
        return np.interp(tm, grid * dt, self.setpoint_at(grid))

    def _take_cycles(self, cycles):
        t_start, t_end, y = cycles['t_start'], cycles['t_end'], cycles['output_speed']
        tm = t_start + 0.5 * (t_end - t_start)
        r_mid = self._setpoint_at_times(tm)
        cycles['middle'], cycles['setpoint'] = tm, r_mid
        cost = np.abs(r_mid - y) * (t_end - t_start)
        for w in self.whole.values():
            c0 = int(np.searchsorted(t_start, w.since, side='left'))
            if c0 < len(t_start):
                w.iae += float(np.sum(cost[c0:]))
                w.cycles += len(t_start) - c0
        # the speed before each step: the last cycle ended by it (cycles come in order)
        while self.unresolved < len(self.windows) and \
                self.e_t[self.unresolved] < t_end[-1]:
            w = self.windows[self.unresolved]
            pos = int(np.searchsorted(t_end, w.event.t, side='right'))
            w.speed_before = float(y[pos - 1]) if pos else self.last_speed
            w.resolved = True
            self.unresolved += 1
        self.last_speed, self.last_cycle_end = float(y[-1]), float(t_end[-1])
        # each cycle to the window it lies in wholly: [step, next step]
        j = np.searchsorted(self.e_t, t_start, side='right') - 1
        inside = (j >= 0) & (t_end <= np.array([self._bounds(jj) for jj in j]))
        for jj in np.unique(j[inside]):
            sel = inside & (j == jj)
            self.windows[int(jj)].cycles.append((t_start[sel][0], t_end[sel], y[sel],
                                                 r_mid[sel]))

    def _close_windows(self, end=None):
        """Make the cycle figures of each window that is over: no cycle to come ends in it
        (a later one has ended) and the set point at its end is on the grid so far; at the
        run's end (``end``), the last one."""
        while self.open < len(self.windows):
            j = self.open
            t_e = self._bounds(j) if end is None else min(self._bounds(j), end)
            if end is None and not (t_e < self.last_cycle_end and
                                    t_e < self.k_last * self.dt):
                return
            w = self.windows[j]
            if not w.resolved:
                w.speed_before, w.resolved = self.last_speed, True
            w.figures = self._cycle_figures(w, t_e)
            w.cycles = []
            self.open += 1

    def _cycle_figures(self, w, t_e):
        if not w.cycles:
            return {}
        t_end = np.concatenate([c[1] for c in w.cycles])
        t_start = np.concatenate([[w.cycles[0][0]], t_end[:-1]])   # (consecutive cycles)
        y = np.concatenate([c[2] for c in w.cycles])
        r_mid = np.concatenate([c[3] for c in w.cycles])
        tm = t_start + 0.5 * (t_end - t_start)
        # the set point in force at the window's end, as stepinfo._window finds it on k·period
        dt = self.dt
        if t_e < self.k_last * dt:
            x = t_e - 0.5 * dt
            last = int(math.floor(x / dt))
            last -= last * dt > x
            last += (last + 1) * dt <= x
            last = min(max(last, 0), self.k_last)
        else:
            last = self.k_last
        rf = float(self.setpoint_at(np.array([last]))[0])
        ev = w.event
        y0 = w.speed_before if (w.speed_before is not None and ev.kind != 'start') \
            else w.speed_at_start
        return cycle_window_metrics(ev, tm, t_start, t_end, y, r_mid, rf, y0)

    # ------------------------------------------------------------------ the end
    def finish(self, end):
        """Steps and run-level figures once the run ended at ``end`` (its last sample's time)
        [s]: (steps, {since: whole-run figures}) as stepinfo has them."""
        if self.samples < 3:
            return [], {}
        keep = 1 + int(np.count_nonzero(self.e_t[1:] < end))   # (the start, then changes)
        self.windows, self.e_t = self.windows[:keep], self.e_t[:keep]
        self._close_windows(end)
        steps = []
        for j, w in enumerate(self.windows):
            t_e = self._bounds(j) if j + 1 < keep else end
            ev = w.event
            row = {'t': ev.t, 'kind': ev.kind, 'before': ev.before, 'after': ev.after,
                   'window_end': t_e}
            m = dict.fromkeys(METRICS, math.nan)
            if w.sampled:
                m['peak_clutch_torque'], m['crank_travel'] = w.peak, w.travel
            if t_e - ev.t > 0:
                m['switches_per_second'] = max(w.switches, 0) / (t_e - ev.t)
            m.update(w.figures or {})
            row.update(m)
            steps.append(row)
        whole = {}
        for since, w in self.whole.items():
            start = self.first_t if since is None or since <= self.first_t else since
            m = dict.fromkeys(METRICS, math.nan)
            if w.sampled:
                m['peak_clutch_torque'], m['crank_travel'] = w.peak, w.travel
            if end - start > 0:
                m['switches_per_second'] = w.switches / (end - start)
            if w.cycles:
                m['iae'] = w.iae
            whole[since] = combine_steps(steps, m, since, self.first_t)
        return steps, whole
