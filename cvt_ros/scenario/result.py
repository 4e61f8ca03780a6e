"""A finished scenario run: its trace, its metrics, and the ways out (JSON, table, MCAP, plot)."""
import json
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..analysis.stepinfo import METRICS, StepEvent, step_metrics, summarize_steps
from ..analysis.trace import Trace
from ..solver.output import COL


@dataclass(eq=False)
class ScenarioRun:
    """``samples``: (n+1, COLUMNS) plant samples at t_k = k·period (the true state, not the
    sensed one); ``setpoint``, ``load``: the schedules at t_k; ``commands``: the crank-length
    command of period k after the limiter (NaN: the controller kept the last one); ``switches``:
    (t, engaged) clutch switches; ``error``: why the run stopped early (None: it ran to the end);
    ``exception``: what the controller raised, with its traceback (None otherwise); dds back end:
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
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

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
        c = self.commands.copy()
        idx = np.where(np.isfinite(c), np.arange(len(c)), 0)
        np.maximum.accumulate(idx, out=idx)
        held = c[idx]
        if not np.isfinite(c[0]):
            first = np.flatnonzero(np.isfinite(c))
            held[:first[0] if len(first) else len(c)] = np.nan
        return held

    def trace(self):
        """The run as an analysis Trace (true state, exact switch times)."""
        s = self.samples
        sw_t = np.array([t for t, _ in self.switches], dtype=float)
        sw_on = np.array([e for _, e in self.switches], dtype=bool)
        pick = [COL[c] for c in ('motor_torque', 'clutch_torque', 'shaft_torque', 'load_torque')]
        return Trace(source=str(self.scenario.path), kind='scenario', t=s[:, COL['t']].copy(),
                     phi=s[:, [COL['phi1'], COL['phi2'], COL['phi3'], COL['phi4']]],
                     omega=s[:, [COL['omega1'], COL['omega2'], COL['omega3'], COL['omega4']]],
                     effort=s[:, pick], twist=s[:, COL['twist']].copy(),
                     crank_length=s[:, COL['crank_length']].copy(), switch_t=sw_t,
                     switch_engaged=sw_on, initial_engaged=bool(s[0, COL['engaged']] > 0.5),
                     switches_exact=True, parameters=dict(self.scenario.values),
                     scene=str(self.scenario.scene))

    def events(self):
        """The steps the loop had to answer: the start, each set-point and load change."""
        sc = self.scenario
        end = float(self.t[-1]) if len(self.t) else 0.0
        evs = [StepEvent(0.0, 'start', float(self.column('omega4')[0]), sc.setpoint.initial)]
        for kind, sched in (('setpoint', sc.setpoint), ('load', sc.load)):
            changes = [c for c in sched.changes if c.at < end]
            # (every change's levels in one call each: per change, it was quadratic)
            before = sched.sample(np.array([c.at - 1e-12 for c in changes]))
            after = sched.sample(np.array([c.end for c in changes]))
            evs += [StepEvent(c.at, kind, float(b), float(a))
                    for c, b, a in zip(changes, before, after, strict=True)]
        return sorted(evs, key=lambda e: (e.t, e.kind != 'setpoint'))

    @cached_property
    def steps(self):
        """Per-step metrics (list of dicts; :mod:`cvt_ros.analysis.stepinfo`)."""
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
        [t, end]): e.g. the set-point steps without the start-up from rest; None: all."""
        if len(self.t) < 3:
            return dict.fromkeys(METRICS, math.nan)
        return summarize_steps(self.steps, self.trace(), self._grid(), self.setpoint, since=t)

    def missing_metrics(self):
        """Why a run gave no run-level metric at all ('' when it gave some): an answer of only
        n/a is no answer, and must not read as one."""
        if any(v is not None and math.isfinite(v) for v in self.metrics.values()):
            return ''
        return (f"no metric could be computed from {len(self.t)} samples "
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
            'commands_clamped': self.clamped, 'clutch_switches': len(self.switches),
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
                f"{len(self.switches)} clutch switches{suspect}, {self.clamped} commands "
                f"clamped; {status}")
