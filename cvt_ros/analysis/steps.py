"""Step responses: how the cycle-mean ratio and output speed answer each command.

Works on any run's per-cycle table, so controller tests (:mod:`cvt_ros.analysis.stepinfo`) and
``cvt-sim analyze`` share one definition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cycles import CycleTable
from .trace import Command, Trace

__all__ = ['StepResponse', 'step_responses']


@dataclass
class StepResponse:
    """The response of the cycle-mean ratio and output speed to one command."""

    command: Command
    previous: float
    ratio_before: float
    ratio_after: float
    speed_before: float
    speed_after: float
    rise_time: float        # 10 → 90 % of the ratio change [s] after the command (NaN: n/a)
    settling_time: float    # into a ±2 % band of the change, for good [s] (NaN: not settled)
    window_end: float


def _initial_value(trace: Trace, key: str) -> float:
    p = trace.parameters or {}
    name = {'crank_length_cmd': 'linkage.crank_length', 'load_torque_cmd': 'load.torque'}[key]
    try:
        return float(p[name])
    except (KeyError, TypeError, ValueError):
        return math.nan


def step_responses(trace: Trace, cy: CycleTable) -> list[StepResponse]:
    """Rise and settling time of the cycle-mean ratio after each command of ``trace`` (window:
    until the next command or the end of the run); ``cy``: the run's cycles."""
    if not len(cy):
        return []
    mid = cy['t_start'] + 0.5 * cy['period']
    ratio, speed = cy['ratio'], cy['output_speed']
    out = []
    last = {key: _initial_value(trace, key) for key in ('crank_length_cmd', 'load_torque_cmd')}
    commands = trace.commands
    for j, cmd in enumerate(commands):
        previous = last[cmd.key]
        last[cmd.key] = cmd.value
        end = commands[j + 1].t if j + 1 < len(commands) else float(trace.t[-1])
        before = np.flatnonzero(cy.t_end <= cmd.t)[-5:]
        after = np.flatnonzero((cy['t_start'] >= cmd.t) & (cy.t_end <= end))
        rb = float(np.mean(ratio[before])) if len(before) else math.nan
        sb = float(np.mean(speed[before])) if len(before) else math.nan
        if len(after) >= 6:
            ra = float(np.mean(ratio[after[-3:]]))
            sa = float(np.mean(speed[after[-3:]]))
        else:
            ra = sa = math.nan
        rise = settle = math.nan
        change = ra - rb
        noise = float(np.std(ratio[before])) if len(before) > 1 else 0.0
        significant = math.isfinite(change) and abs(change) > max(5.0 * noise, 1e-4 * abs(ra))
        if len(after) >= 6 and significant:
            frac = (ratio[after] - rb) / change
            t_mid = mid[after]
            outside = np.flatnonzero(np.abs(frac - 1.0) > 0.02)
            if not len(outside):
                settle = float(cy['t_start'][after[0]] - cmd.t)
            elif outside[-1] < len(after) - 3:  # in the band for the last 3 cycles at least
                settle = float(cy.t_end[after[outside[-1]]] - cmd.t)
            i10 = np.flatnonzero(frac >= 0.1)
            i90 = np.flatnonzero(frac >= 0.9)
            if math.isfinite(settle) and len(i10) and len(i90):  # final value known
                rise = float(t_mid[i90[0]] - t_mid[i10[0]])
        out.append(StepResponse(cmd, previous, rb, ra, sb, sa, rise, settle, end))
    return out

