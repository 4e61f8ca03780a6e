"""A finished scenario run: its trace, its metrics, and the ways out (JSON, table, MCAP, plot).

A run keeps every period's sample up to KEEP_PERIODS periods (or with ``keep_samples=True``),
else every ``sample_stride``-th one (scenario/stream.py). Its step metrics come from the whole
trace while it keeps every sample (stepinfo on the trace: the numbers a run always gave, to the
bit), else from the stream's (analysis/step_stream.py: the same figures, made as the run went,
the sums in another order — equal to rounding, test_scenario_stream.py)."""
import json
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..analysis.stepinfo import METRICS, step_metrics, summarize_steps
from ..analysis.trace import trace_of_samples
from ..solver.output import COL, N_COLUMNS, path_columns


@dataclass(eq=False)
class ScenarioRun:
    """``samples``: (n+1, COLUMNS) plant samples at t_k = k·period (the true state, not the
    sensed one); ``setpoint``, ``load``: the schedules at t_k; ``commands``: the crank-length
    command of period k after the limiter (NaN: the controller kept the last one); ``switches``:
    (t, engaged) clutch switches (N ≥ 2 paths: (t, engaged, path), each clutch's; the samples
    then carry each path's columns, ``output.path_columns``). A run longer than KEEP_PERIODS
    periods (scenario/stream.py) keeps every ``sample_stride``-th sample only (t_k, k a multiple
    of the stride), the schedules there, the command *in force* there (held: no NaN after the
    first), and no switches (``switch_count`` counts them); its metrics, plot and ``--mcap``
    recording are of every period all the same. ``error``: why the run stopped early (None: it
    ran to the end); ``exception``: what the controller raised, with its traceback (None
    otherwise); dds back end:
    ``domain`` (the node's ROS domain), and against the wall clock ``node_timing`` (the node's
    missed deadlines, resyncs, jitter and step time from its last /diagnostics: TIMING_KEYS of
    scenario/dds.py) and ``diagnostics`` (its /diagnostics messages: (t [s], CDR bytes))."""
    scenario: object
    backend: str
    controller: str
    samples: np.ndarray
    setpoint: np.ndarray
    load: np.ndarray
    commands: np.ndarray
    switches: list = field(default_factory=list)
    clamped: int = 0
    wall_time: float = 0.0
    error: str = None
    exception: BaseException = None
    realtime: float = None      # dds back end against the wall clock: its real-time factor
    domain: int = None          # dds back end: the node's ROS domain
    node_timing: dict = None    # dds, realtime: the node's timing
    diagnostics: list = field(default_factory=list)   # dds, realtime: the node's /diagnostics
    # the solver's self-check (Simulator.self_check(); None: the plant ran in another process)
    self_check: dict = None
    sample_stride: int = 1      # 1: every period's sample; k: every k-th (a long run)
    summary: object = None      # the stream's metrics and counts (stream.RunSummary)
    outline: object = None      # the plot's bounded signals (stream.Outline)
    recording_count: int = 0    # run_scenario(mcap=...): messages recorded
    recording_error: Exception = None   # ... and the error that stopped the recording

    @property
    def possible_missed_events(self):
        """Clutch events the solver may have missed in this run (its self-check), or None."""
        if self.self_check is None:
            return None
        return self.self_check['possible_missed_events'] + self.self_check['stray_samples']

    @property
    def backend_text(self):
        """The back end as a person reads it: 'dds, realtime 1x' for a wall-clock run."""
        return self.backend if not self.realtime else f"{self.backend}, realtime {self.realtime:g}x"

    # ------------------------------------------------------------------ derived
    @property
    def t(self):
        return self.samples[:, COL['t']]

    @property
    def duration(self):
        """Simulated time from the first sample to the last [s]."""
        return float(self.summary.duration)

    @property
    def switch_count(self):
        """Clutch switches in the run (``switches`` holds them unless the run was thinned)."""
        return self.summary.switch_count

    @property
    def real_time_factor(self):
        return self.duration / self.wall_time if self.wall_time > 0 else math.inf

    @property
    def ok(self):
        return self.error is None

    def column(self, name):
        return self.samples[:, COL[name]]

    def held_commands(self):
        """The command in force in each period (the last one given; NaN before the first)."""
        if self.sample_stride != 1:   # (a thinned run keeps the command in force)
            return self.commands.copy()
        c = self.commands.copy()
        idx = np.where(np.isfinite(c), np.arange(len(c)), 0)
        np.maximum.accumulate(idx, out=idx)
        held = c[idx]
        if not np.isfinite(c[0]):
            first = np.flatnonzero(np.isfinite(c))
            held[:first[0] if len(first) else len(c)] = np.nan
        return held

    @property
    def columns(self):
        """The samples' columns (output.path_columns of the machine's paths)."""
        return path_columns((self.samples.shape[1] - N_COLUMNS) // 4)

    def trace(self):
        """The run as an analysis Trace (true state, exact switch times); a run that kept every
        sample only."""
        if self.sample_stride != 1:
            raise ValueError(f"{self.scenario.name}: the run kept every "
                             f"{self.sample_stride}th sample of its {self.scenario.periods} "
                             f"periods; run_scenario(..., keep_samples=True) keeps them all")
        return trace_of_samples(self.samples, self.columns, self.switches,
                                source=str(self.scenario.path), kind='scenario',
                                parameters=dict(self.scenario.values),
                                scene=str(self.scenario.scene))

    def events(self):
        """The steps the loop had to answer: the start, each set-point and load change."""
        from .stream import step_events
        start_speed = self.column('omega4')[0] if len(self.samples) else math.nan
        return step_events(self.scenario, start_speed, self.summary.last_t)

    @property
    def whole_trace(self):
        """True while the run kept every sample: its metrics come from its whole trace."""
        return self.sample_stride == 1

    @cached_property
    def steps(self):
        """Per-step metrics (list of dicts; :mod:`cvt_ros.analysis.stepinfo`)."""
        if not self.whole_trace:
            return self.summary.steps
        if len(self.t) < 3:
            return []
        return step_metrics(self.trace(), self._grid(), self.setpoint, self.events())

    def _grid(self):
        """k·period: the times the schedules were sampled at (the sample stamps accumulate
        rounding, and a change at t = 2 s belongs to period 2000, not to a stamp 1.9999…)."""
        return np.arange(len(self.setpoint)) * self.scenario.control_period

    @cached_property
    def metrics(self):
        """Run-level metrics by name (rise_time, overshoot, settling_time, ...)."""
        return self.metrics_since(None)

    def metrics_since(self, t):
        """Run-level metrics over the steps from ``t`` [s] on (the whole-run figures over
        [t, end]): e.g. the set-point steps without the start-up from rest; None: all. ``t``
        other than None is named before a run that keeps a thinned trace (longer than
        KEEP_PERIODS periods): ``run_scenario(..., metrics_since=t)``."""
        if not self.whole_trace:
            return self.summary.metrics_since(t)
        if len(self.t) < 3:
            return dict.fromkeys(METRICS, math.nan)
        return summarize_steps(self.steps, self.trace(), self._grid(), self.setpoint, since=t)

    def missing_metrics(self):
        """Why a run gave no run-level metric at all ('' when it gave some): an answer of only
        n/a is no answer, and must not read as one."""
        if any(v is not None and math.isfinite(v) for v in self.metrics.values()):
            return ''
        return (f"no metric could be computed from {self.summary.samples} samples "
                f"({self.duration:g} s simulated)")

    # ------------------------------------------------------------------ outputs
    def to_dict(self):
        def clean(v):
            if isinstance(v, float) and not math.isfinite(v):
                return None
            if isinstance(v, (np.floating, np.integer)):
                return clean(v.item())
            if isinstance(v, dict):
                return {k: clean(x) for k, x in v.items()}
            if isinstance(v, list):
                return [clean(x) for x in v]
            return v
        sc = self.scenario
        return clean({
            'scenario': str(sc.path), 'scene': str(sc.scene), 'backend': self.backend,
            'realtime': self.realtime, 'ros_domain': self.domain,
            'node_timing': dict(self.node_timing) if self.node_timing else None,
            'controller': self.controller, 'duration': sc.duration,
            'simulated': self.duration, 'control_period': sc.control_period, 'seed': sc.seed,
            'completed': self.ok, 'error': self.error,
            'wall_time': self.wall_time, 'real_time_factor': self.real_time_factor,
            'commands_clamped': self.clamped, 'clutch_switches': self.switch_count,
            'solver_self_check': self.self_check,
            'units': dict(METRICS),
            'metrics': dict(self.metrics),
            'steps': [dict(s) for s in self.steps],
        })

    def write_json(self, path):
        with open(path, 'w') as f:
            json.dump(self.to_dict(), f, indent=2, allow_nan=False)
            f.write('\n')

    def format_table(self):
        """The metrics as a Markdown table: one row per step, then the run."""
        cols = list(METRICS)
        head = ['step', 't [s]', 'change'] + [f"{c} [{METRICS[c]}]" for c in cols]
        lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]

        def fmt(v):
            return 'n/a' if v is None or not math.isfinite(v) else f"{v:.4g}"
        for i, s in enumerate(self.steps):
            unit = 'N*m' if s['kind'] == 'load' else 'rad/s'
            change = f"{s['kind']} {s['before']:.4g} → {s['after']:.4g} {unit}"
            lines.append(f"| {i} | {s['t']:.3f} | {change} | "
                         + ' | '.join(fmt(s[c]) for c in cols) + ' |')
        lines.append('| run | | | ' + ' | '.join(fmt(self.metrics[c]) for c in cols) + ' |')
        if self.node_timing:
            lines += ['', self.format_node_timing()]
        return '\n'.join(lines)

    def format_node_timing(self):
        """The node's timing against the wall clock (realtime) as a one-row Markdown table."""
        g = self.node_timing.get
        cells = [f"{g('sim_time', math.nan):.3f}", f"{g('missed_deadlines', math.nan):.0f}",
                 f"{g('resyncs', math.nan):.0f}", f"{g('slipped_s', math.nan):.3g}",
                 ' / '.join(f"{g(f'jitter_{q}_us', math.nan):.4g}" for q in ('p50', 'p99', 'max')),
                 ' / '.join(f"{g(f'step_time_{q}_us', math.nan):.4g}"
                            for q in ('p50', 'p99', 'max'))]
        head = ['node timing at t [s]', 'missed deadlines', 'resyncs', 'slipped [s]',
                'jitter p50 / p99 / max [µs]', 'step time p50 / p99 / max [µs]']
        return '\n'.join(['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head),
                          '| ' + ' | '.join(cells) + ' |'])

    def summary_line(self):
        status = 'completed' if self.ok else f"STOPPED: {self.error}"
        missed = self.possible_missed_events
        suspect = (f", {missed} possibly missed clutch events (the solver's self-check: "
                   f"{self.self_check['solver']})" if missed else '')
        where = f" on ROS domain {self.domain}" if self.domain is not None else ''
        return (f"{self.scenario.name}: {self.backend_text}{where}, {self.duration:g} s "
                f"simulated in "
                f"{self.wall_time:.3f} s ({self.real_time_factor:.3g}x real time), "
                f"{self.switch_count} clutch switches{suspect}, {self.clamped} commands "
                f"clamped; {status}")
