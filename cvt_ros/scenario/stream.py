"""A scenario run as it passes, block by block: its metrics, its recording, its plot and the
samples it keeps, in memory that does not grow with its length.

The harness (harness.py) writes each period's sample and command into a block of BLOCK periods;
each full block goes through :class:`RunStream`, which

* rounds the sample times to whole nanoseconds (the stamps every back end's controller saw);
* feeds the step metrics (``analysis.step_stream.StepStream``: cycles, windows, run figures);
* writes the MCAP recording (``recording.ScenarioRecording``), if one was asked for;
* adds the plot's envelopes (:class:`Outline`: min and max per column of the figure);
* keeps the samples: every period's while the run has at most KEEP_PERIODS periods (or
  ``keep_samples=True``), else every ``stride``-th one (the thinned trace of a long run).

Over DDS the node's own recording is the trace (every period, each clutch switch at its own
time): the blocks keep only the commands (to a temporary file, :class:`CommandLog`), and the
recording is streamed through the same steps after the run (:meth:`RunStream.replay`).
"""
import math
import tempfile
import time

import numpy as np

from ..analysis.errors import AnalysisError
from ..analysis.step_stream import StepStream
from ..analysis.stepinfo import METRICS, StepEvent
from ..solver.clutch_sets import path_masks, set_changes
from ..solver.output import COL, N_COLUMNS

BLOCK = 1 << 16               # control periods per block
KEEP_PERIODS = 1_000_000      # a run of at most this many periods keeps every sample
OUTLINE_POINTS = 4000         # the plot's columns: min and max of each signal per column
_TIME, _ENGAGED, _A = COL['t'], COL['engaged'], COL['crank_length']
_PHI = [COL[c] for c in ('phi1', 'phi2', 'phi3', 'phi4')]
_OMEGA = [COL[c] for c in ('omega1', 'omega2', 'omega3', 'omega4')]
_EFFORT = [COL[c] for c in ('motor_torque', 'clutch_torque', 'shaft_torque', 'load_torque')]


def step_events(scenario, start_speed, end=math.inf):
    """The steps a run has to answer: its start (ω4 at t = 0 → the initial set point), then each
    set-point and load change before ``end`` [s], in time order (set point first)."""
    evs = [StepEvent(0.0, 'start', float(start_speed), scenario.setpoint.initial)]
    for kind, sched in (('setpoint', scenario.setpoint), ('load', scenario.load)):
        changes = [c for c in sched.changes if c.at < end]
        # (every change's levels in one call each: per change, it was quadratic)
        before = sched.sample(np.array([c.at - 1e-12 for c in changes]))
        after = sched.sample(np.array([c.end for c in changes]))
        evs += [StepEvent(c.at, kind, float(b), float(a))
                for c, b, a in zip(changes, before, after, strict=True)]
    return sorted(evs, key=lambda e: (e.t, e.kind != 'setpoint'))


class CommandLog:
    """The controller's commands (period, value) on a temporary file: a DDS run's commands wait
    there for the node's recording, read after the run (a command every period of a day would
    be 1.6 GB in memory)."""

    def __init__(self):
        self.file = tempfile.TemporaryFile()
        self.count = 0

    def add(self, ks, values):
        given = np.isfinite(values)
        if np.any(given):
            np.column_stack([ks[given], values[given]]).astype(np.float64).tofile(self.file)
            self.count += int(np.count_nonzero(given))

    def pairs(self, chunk=BLOCK):
        """(periods, values) chunks in the order they were added."""
        self.file.flush()
        self.file.seek(0)
        while True:
            data = np.fromfile(self.file, dtype=np.float64, count=2 * chunk)
            if not len(data):
                break
            data = data.reshape(-1, 2)
            yield data[:, 0].astype(np.int64), data[:, 1]

    def close(self):
        self.file.close()


class Outline:
    """The signals of a run as the plot draws them, bounded: raw while the run has at most
    2·OUTLINE_POINTS samples, else the min and the max of each signal in each of OUTLINE_POINTS
    columns of [0, duration] (so a pulse or a spike stays visible, as a band or a tick)."""

    def __init__(self, duration, samples, points=OUTLINE_POINTS):
        self.raw = samples <= 2 * points
        self.points = points
        self.width = max(duration, 1e-12) / points
        self.series = {}

    def add(self, name, t, y):
        if not len(t):
            return
        if self.raw:
            self.series.setdefault(name, []).append((np.array(t, dtype=float),
                                                     np.array(y, dtype=float)))
            return
        lo, hi = self.series.setdefault(name, (np.full(self.points, np.nan),
                                               np.full(self.points, np.nan)))
        col = np.clip((np.asarray(t) / self.width).astype(np.int64), 0, self.points - 1)
        edges = np.flatnonzero(np.diff(col)) + 1
        starts = np.concatenate([[0], edges])
        cols = col[starts]
        lo[cols] = np.fmin(lo[cols], np.fmin.reduceat(y, starts))   # (NaN: no value there)
        hi[cols] = np.fmax(hi[cols], np.fmax.reduceat(y, starts))

    def get(self, name):
        """(t, y) to draw: the raw points, or each column's min and max at its start time."""
        data = self.series.get(name)
        if data is None:
            return np.empty(0), np.empty(0)
        if self.raw:
            return (np.concatenate([d[0] for d in data]), np.concatenate([d[1] for d in data]))
        lo, hi = data
        cols = np.flatnonzero(np.isfinite(lo))
        t = np.repeat(cols * self.width, 2)
        return t, np.column_stack([lo[cols], hi[cols]]).ravel()

    def top(self, name):
        """The largest value of a signal (NaN if none)."""
        y = self.get(name)[1]
        return float(np.nanmax(y)) if len(y) and np.any(np.isfinite(y)) else math.nan


class RunStream:
    """One run's samples through metrics, recording, plot and kept trace (module docstring).

    ``recording``: a ``recording.ScenarioRecording`` (or None); ``keep_samples``: True every
    period's sample, False none, None every one up to KEEP_PERIODS periods, else thinned;
    ``metrics_since``: start times whose run-level metrics are wanted too
    (``ScenarioRun.metrics_since``); ``replay``: the trace comes from the plant's recording."""

    def __init__(self, scenario, recording=None, keep_samples=None, metrics_since=(),
                 replay=False):
        self.scenario = scenario
        self.n = n = scenario.periods
        self.dt = scenario.control_period
        self.recording = recording
        self.replay_mode = replay
        self.log = CommandLog() if replay else None
        if keep_samples is None:
            keep_samples = n + 1 <= KEEP_PERIODS
        self.stride = 1 if keep_samples else max(1, -(-(n + 1) // KEEP_PERIODS))
        self.since = tuple(s for s in metrics_since if s is not None)
        self.outline = Outline(scenario.duration, n + 1)
        self.block = BLOCK
        self.kept = None            # kept rows (allocated at the first sample)
        self.kept_k = np.empty(0, dtype=np.int64)
        self.kept_count = 0
        self.kept_commands = None
        self.switches = [] if self.stride == 1 else None
        self.diagnostics = [] if self.stride == 1 else None
        self.held = math.nan        # the command in force (thinned trace, plot)
        self.steps = None           # StepStream, from the first sample
        self.analysis_error = None  # an AnalysisError of the cycles (raised on .steps)
        self.last_t = None
        self.sample_count = 0
        self.switch_count = 0
        self.rows = None
        self.commands = None
        self.busy = 0.0             # wall time spent here [s] (not the loop's: its RTF)

    # ------------------------------------------------------------------ the harness's side
    def start(self, row):
        """The block buffers (rows, commands) with the t = 0 sample in place."""
        width = max(len(row), N_COLUMNS)
        self.rows = np.empty((self.block, width))
        self.commands = np.full(self.block, np.nan)
        self.rows[0] = row
        return self.rows, self.commands

    def flush(self, base, count, switches):
        """The block's first ``count`` samples (periods base …) and the switches among them;
        the buffers are reused for the next block."""
        busy = time.perf_counter()
        ks = np.arange(base, base + count)
        if self.replay_mode:
            self.log.add(ks, self.commands[:count])
        elif count:
            self._take(ks, self.rows[:count], self.commands[:count], switches, ())
        self.commands[:] = np.nan
        self.busy += time.perf_counter() - busy

    def replay(self, messages):
        """The trace of a DDS run from the node's recording (``DdsPlant.replay``: 'sample',
        'switch', 'diagnostics' and 'command' items in time order), with the commands the
        harness gave (the log) or the external controller's ('command' items)."""
        rows = np.empty((self.block, self.rows.shape[1]))
        ks = np.empty(self.block, dtype=np.int64)
        commands = np.full(self.block, np.nan)
        logged = self._logged_commands()
        pending = next(logged, None)
        switches, diagnostics, count = [], [], 0
        external = []
        for kind, item in messages:
            if kind == 'sample':
                k = min(max(int(round(item[_TIME] / self.dt)), 0), self.n)
                if count == self.block:
                    pending = self._replayed(ks, rows, commands, switches, diagnostics, count,
                                             external, logged, pending)
                    switches, diagnostics, external, count = [], [], [], 0
                    commands[:] = np.nan
                rows[count], ks[count] = item, k
                count += 1
            elif kind == 'switch':
                switches.append(item)
            elif kind == 'diagnostics':
                diagnostics.append(item)
            else:   # an external controller's command, at the sample it answered
                external.append(item)
        if count:
            self._replayed(ks, rows, commands, switches, diagnostics, count, external, logged,
                           pending)
        self.log.close()

    def _logged_commands(self):
        for ks, values in self.log.pairs():
            yield from zip(ks.tolist(), values.tolist(), strict=True)

    def _replayed(self, ks, rows, commands, switches, diagnostics, count, external, logged,
                  pending):
        """One block of the recording with its commands; returns the next logged command."""
        ks = ks[:count]
        first, last = int(ks[0]), int(ks[-1])
        where = {k: i for i, k in enumerate(ks.tolist())} if external or pending else {}
        while pending is not None and pending[0] <= last:
            if pending[0] >= first and pending[0] in where:
                commands[where[pending[0]]] = pending[1]
            pending = next(logged, None)
        for t, value in external:
            i = where.get(min(int(round(t / self.dt)), self.n))
            if i is not None:
                commands[i] = value
        self._take(ks, rows[:count], commands[:count], switches, diagnostics)
        return pending

    # ------------------------------------------------------------------ one block
    def _take(self, ks, rows, commands, switches, diagnostics):
        rows[:, _TIME] = np.round(rows[:, _TIME] * 1e9) * 1e-9   # the stamps' whole ns
        grid = ks * self.dt
        setpoint = self.scenario.setpoint.sample(grid)
        load = self.scenario.load.sample(grid)
        if self.steps is None:
            self._begin(rows[0])
        if self.recording is not None:
            self.recording.block(rows, setpoint, load, commands, switches, diagnostics)
        held = self._held(commands)
        self._keep(ks, rows, setpoint, load, held if self.stride > 1 else commands, switches,
                   diagnostics)
        t = rows[:, _TIME]
        self._outline(t, rows, setpoint, load, held)
        self.sample_count += len(ks)
        self.switch_count += len(switches)
        if self.analysis_error is None:
            if self.n_paths > 1:   # the metrics' switches: those of "any clutch engaged"
                changes, self.mask = set_changes(switches, self.mask)
                switches = [(c.t, c.engaged) for c in changes if c.any_changed]
            sw_t = np.array([s[0] for s in switches], dtype=float)
            sw_on = np.array([s[1] for s in switches], dtype=bool)
            block = {'t': t, 'phi': rows[:, _PHI], 'omega': rows[:, _OMEGA],
                     'effort': rows[:, _EFFORT], 'twist': rows[:, COL['twist']],
                     'crank_length': rows[:, _A]}
            try:
                cycles = self.steps.add(ks, block, sw_t, sw_on, self.engaged0)
            except AnalysisError as exc:   # (the sampling cannot split crank cycles)
                self.analysis_error = exc
            else:
                if cycles is not None and len(cycles['t_end']):
                    tm = cycles['middle']
                    self.outline.add('cycle_speed', tm, cycles['output_speed'])
                    self.outline.add('cycle_clutch_peak', tm, cycles['clutch_torque_peak'])
                    self.outline.add('cycle_engaged', tm, cycles['engaged_fraction'])
        self.last_t = float(t[-1])

    def _begin(self, row):
        sc = self.scenario
        self.engaged0 = bool(row[_ENGAGED] > 0.5)
        # N ≥ 2 paths: each clutch's switches, and the engaged set they start from
        self.n_paths = n = (len(row) - N_COLUMNS) // 4
        self.mask = path_masks(row[N_COLUMNS + 2 * n:N_COLUMNS + 3 * n]) if n > 1 else None
        self.start_speed = float(row[_OMEGA[3]])
        self.steps = StepStream(step_events(sc, self.start_speed), self._setpoint_at, self.dt,
                                self.since)
        size = (self.n // self.stride + 1)
        self.kept = np.empty((size, len(row)))
        self.kept_setpoint = np.empty(size)
        self.kept_load = np.empty(size)
        self.kept_commands = np.empty(size)

    def _setpoint_at(self, k):
        return self.scenario.setpoint.sample(np.asarray(k) * self.dt)

    def _held(self, commands):
        """The command in force at each sample (the last one given; NaN before the first)."""
        idx = np.where(np.isfinite(commands), np.arange(len(commands)), -1)
        np.maximum.accumulate(idx, out=idx)
        held = np.where(idx >= 0, commands[np.maximum(idx, 0)], self.held)
        self.held = float(held[-1])
        return held

    def _keep(self, ks, rows, setpoint, load, commands, switches, diagnostics):
        """Every sample, or every stride-th (with the command in force then, not the one
        given in that period)."""
        pick = np.flatnonzero(ks % self.stride == 0) if self.stride > 1 else slice(None)
        n_new = len(ks[pick])
        i0, i1 = self.kept_count, self.kept_count + n_new
        if i1 > len(self.kept):   # (a realtime recording with more samples than periods)
            return
        self.kept[i0:i1] = rows[pick]
        self.kept_setpoint[i0:i1] = setpoint[pick]
        self.kept_load[i0:i1] = load[pick]
        self.kept_commands[i0:i1] = commands[pick]
        self.kept_count = i1
        if self.switches is not None:
            self.switches.extend(switches)
            self.diagnostics.extend(diagnostics)

    def _outline(self, t, rows, setpoint, load, held):
        add = self.outline.add
        add('omega4', t, rows[:, _OMEGA[3]])
        add('setpoint', t, setpoint)
        add('crank_length', t, rows[:, _A])
        add('command', t, held)
        add('load', t, load)

    # ------------------------------------------------------------------ the end
    def finish(self, self_check=None):
        """The ScenarioRun fields the stream made (samples, schedules at them, commands, switches,
        the summary with the step metrics, the outline, the recording's count and error)."""
        count = self.kept_count
        summary = RunSummary(self)
        out = {'samples': self.kept[:count] if self.kept is not None else np.empty((0, 0)),
               'setpoint': self.kept_setpoint[:count] if count else np.empty(0),
               'load': self.kept_load[:count] if count else np.empty(0),
               'commands': self.kept_commands[:count] if count else np.empty(0),
               'switches': self.switches if self.switches is not None else [],
               'sample_stride': self.stride, 'summary': summary, 'outline': self.outline}
        if self.diagnostics is not None:
            out['diagnostics'] = self.diagnostics
        if self.recording is not None:
            out['recording_count'], out['recording_error'] = self.recording.finish(self_check)
        return out


class RunSummary:
    """What a streamed run leaves besides its kept samples: the step metrics, its first and last
    sample times, sample and switch counts."""

    def __init__(self, stream):
        steps = stream.steps
        self.samples = stream.sample_count
        self.switch_count = stream.switch_count
        self.first_t = steps.first_t if steps is not None else 0.0
        self.last_t = stream.last_t if stream.last_t is not None else 0.0
        self.error = stream.analysis_error
        self.since = stream.since
        self._steps, self._whole = ([], {}) if steps is None or self.error is not None \
            else steps.finish(self.last_t)

    @property
    def duration(self):
        return self.last_t - self.first_t

    @property
    def steps(self):
        if self.error is not None:
            raise self.error
        return self._steps

    def metrics_since(self, t):
        """Run-level metrics over the steps from ``t`` on (None: all); ``t`` must have been
        named before the run (``run_scenario(..., metrics_since=t)``)."""
        if self.error is not None:
            raise self.error
        if self.samples < 3:
            return dict.fromkeys(METRICS, math.nan)
        if t not in self._whole:
            raise ValueError(f"metrics since {t!r} s: not computed during the run; name the "
                             f"time before it: run_scenario(..., metrics_since={t!r})")
        return self._whole[t]
