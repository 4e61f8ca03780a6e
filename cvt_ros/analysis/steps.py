"""Step responses: how the cycle-mean ratio and output speed answer each command.

:func:`response_metrics` is the definition on any sampled response (times, values, the value
before and the settled final value): 10 → 90 % rise time, settling time into ±2 % of the change for
good, overshoot. :func:`step_responses` applies it to the cycle-mean ratio after each command of
a run that is a step — one that the next command (or the end of the run) follows no sooner than
MIN_STEP_CYCLES whole crank cycles later: a controller that commands every period or every turn
is a closed loop, whose commands are no open-loop steps — with the final value taken only from a
detected steady state (:mod:`.steady`): a ratio that is still moving at the end of the window has
no final value, so it gets no rise or settling time ("not settled"). Both work on plain arrays,
for any other response (e.g. closed-loop speed steps, :mod:`cvt_ros.analysis.stepinfo`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cycles import CycleTable
from .steady import MIN_CYCLES, TOLERANCE, SteadyState, find_steady_state
from .trace import Command, Trace

__all__ = ['MAX_SHOWN_STEPS', 'MIN_STEP_CYCLES', 'RISE_LIMITS', 'SETTLING_BAND',
           'ResponseMetrics', 'StepResponse', 'commanded_before', 'response_metrics',
           'step_responses']

#: Settling band: ± this fraction of the change around the final value.
SETTLING_BAND = 0.02
#: Rise time from the first to the second fraction of the change.
RISE_LIMITS = (0.1, 0.9)
#: Cycles before a command whose mean is the value before it.
CYCLES_BEFORE = 5
#: Whole crank cycles to the next command that make a command a step: closer commands are a
#: command stream (a closed loop), not steps.
MIN_STEP_CYCLES = 3
#: Step responses the text report lists and the plots draw (the JSON holds them all).
MAX_SHOWN_STEPS = 20
#: The parameter each command topic sets (its value before the first command).
COMMAND_PARAMETERS = {'crank_length_cmd': 'linkage.crank_length', 'load_torque_cmd': 'load.torque'}


@dataclass(frozen=True)
class ResponseMetrics:
    """A response y(t) to a step at ``t_step`` from ``initial`` to ``final`` (times in s after
    the step; fractions of the change). NaN where a figure does not exist."""

    initial: float
    final: float
    rise_time: float        # first time at RISE_LIMITS[1] of the change − first at [0]
    settling_time: float    # from the step until y stays within ±band of the change of final
    overshoot: float        # peak − max(1, lowest after it), ≥ 0, as a fraction of the change
    peak: float             # the value farthest in the direction of the change
    peak_time: float


def response_metrics(t: np.ndarray, y: np.ndarray, t_step: float, initial: float,
                     final: float, *, band: float = SETTLING_BAND,
                     rise: tuple[float, float] = RISE_LIMITS) -> ResponseMetrics:
    """Step metrics of the response ``y`` at times ``t`` (those ≥ ``t_step`` count) to a
    change from ``initial`` to the settled ``final`` value. The settling time is NaN when the
    last value is still outside the band (not settled within the data)."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    keep = (t >= t_step) & np.isfinite(y)
    t, y = t[keep], y[keep]
    change = final - initial
    nan = math.nan
    if not len(t) or not math.isfinite(change) or change == 0.0:
        return ResponseMetrics(initial, final, nan, nan, nan, nan, nan)
    frac = (y - initial) / change
    k = int(np.argmax(frac))
    reached = [np.flatnonzero(frac >= level) for level in rise]
    rise_time = float(t[reached[1][0]] - t[reached[0][0]]) if all(len(r) for r in reached) \
        else nan
    outside = np.flatnonzero(np.abs(frac - 1.0) > band)
    if not len(outside):
        settling = float(t[0] - t_step)
    elif outside[-1] + 1 < len(t):
        settling = float(t[outside[-1] + 1] - t_step)
    else:
        settling = nan
    # overshoot: what the response gave back after its peak, beyond the final value. A ratio
    # still creeping towards its end has its peak last and gives nothing back: the final value
    # (a tail mean) is not exceeded by an overshoot there, only by the creep
    overshoot = max(0.0, float(frac[k]) - max(1.0, float(np.min(frac[k:]))))
    return ResponseMetrics(initial, final, rise_time, settling, overshoot, float(y[k]),
                           float(t[k] - t_step))


@dataclass
class StepResponse:
    """The response of the cycle-mean ratio and output speed to one command.

    ``ratio_after`` / ``speed_after``: the steady state after the command (``settled``), else
    the last complete cycle before the window ends (``settled`` False: no rise, settling or
    overshoot figures then)."""

    command: Command
    previous: float             # the value in force before (previous command or parameter)
    ratio_before: float
    ratio_after: float
    speed_before: float
    speed_after: float
    rise_time: float            # [s] (NaN: n/a)
    settling_time: float        # [s] (NaN: not settled, or no change)
    window_end: float
    settled: bool = False
    overshoot: float = math.nan  # fraction of the ratio change
    steady: SteadyState | None = None


def commanded_before(trace: Trace, key: str) -> float:
    """The value of command topic ``key`` before its first command: the scene parameter."""
    try:
        return float((trace.parameters or {})[COMMAND_PARAMETERS[key]])
    except (KeyError, TypeError, ValueError):
        return math.nan


def step_responses(trace: Trace, cy: CycleTable, *, tolerance: float = TOLERANCE,
                   min_cycles: int = MIN_CYCLES) -> list[StepResponse]:
    """The response to each command of ``trace`` that is a step (window: until the next
    command or the end of the run; a command followed by the next, or by the end, within fewer
    than MIN_STEP_CYCLES whole cycles is left out); ``cy``: the run's cycles; ``tolerance``/
    ``min_cycles``: the test that the ratio has settled, which gives the final value
    (:func:`~.steady.find_steady_state`)."""
    if not len(cy):
        return []
    mid = cy['t_start'] + 0.5 * cy['period']
    ratio, speed = cy['ratio'], cy['output_speed']
    out = []
    last = {key: commanded_before(trace, key) for key in COMMAND_PARAMETERS}
    commands = trace.commands
    for j, cmd in enumerate(commands):
        previous = last.get(cmd.key, math.nan)
        last[cmd.key] = cmd.value
        end = commands[j + 1].t if j + 1 < len(commands) else float(trace.t[-1])
        # the cycles wholly inside the window (cycles follow each other: sorted both ways)
        first = int(np.searchsorted(cy['t_start'], cmd.t, 'left'))
        stop = int(np.searchsorted(cy.t_end, end, 'right'))
        if stop - first < MIN_STEP_CYCLES:
            continue   # a command stream's, or too close to the end to answer
        ended = int(np.searchsorted(cy.t_end, cmd.t, 'right'))   # cycles over by the command
        before = np.arange(max(0, ended - CYCLES_BEFORE), ended)
        after = np.arange(first, stop)
        rb = float(np.mean(ratio[before])) if len(before) else math.nan
        sb = float(np.mean(speed[before])) if len(before) else math.nan
        steady = None
        if len(after):
            # settled: the ratio stays within ±tolerance of its tail mean, or within half the
            # settling band of the change if that is wider (a ramp still under way is neither)
            change = abs(float(ratio[after[-1]]) - rb) if math.isfinite(rb) else 0.0
            steady = find_steady_state(cy, int(after[0]), int(after[-1]) + 1,
                                       tolerance=tolerance, min_cycles=min_cycles,
                                       signals=('ratio',),
                                       floors={'ratio': 0.5 * SETTLING_BAND * change})
        response = StepResponse(cmd, previous, rb, math.nan, sb, math.nan, math.nan, math.nan,
                                end, steady=steady)
        if steady is not None and steady.found:
            window = cy.window(steady.first, steady.stop)
            response.ratio_after, response.speed_after = window['ratio'], window['output_speed']
            response.settled = True
        elif len(after):
            response.ratio_after = float(ratio[after[-1]])
            response.speed_after = float(speed[after[-1]])
        change = response.ratio_after - rb
        noise = float(np.std(ratio[before])) if len(before) > 1 else 0.0
        significant = math.isfinite(change) and \
            abs(change) > max(5.0 * noise, 1e-4 * abs(response.ratio_after))
        if response.settled and significant:
            m = response_metrics(mid[after], ratio[after], cmd.t, rb, response.ratio_after)
            response.rise_time, response.settling_time = m.rise_time, m.settling_time
            response.overshoot = m.overshoot
        out.append(response)
    return out
