"""One run analysed (:func:`analyze_trace`): its crank cycles, the whole-run figures (start-up
included), the steady state detected from the cycle means and its figures, the energy balance
and the step responses — what the report, the JSON and the plots are made from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .cycles import CycleTable, cycle_metrics
from .energy import energy_balance
from .path_metrics import path_metrics
from .steady import MIN_CYCLES, TOLERANCE, SteadyState, find_steady_state
from .steps import StepResponse, step_responses
from .trace import Trace
from .whole_run import whole_run_metrics

__all__ = ['RunAnalysis', 'analyze_trace']


@dataclass
class RunAnalysis:
    """Everything :func:`analyze_trace` computes for one run."""

    trace: Trace
    cycles: CycleTable
    boundaries: np.ndarray          # cycle boundary times [s] (len(cycles) + 1, or fewer)
    whole_run: dict[str, float]     # whole_run_metrics: peaks and means over every sample
    steady: SteadyState             # the detected steady window, or why there is none
    steady_metrics: dict[str, float]  # CycleTable.window over the steady window ({} if none)
    energy: dict[str, Any]
    steps: list[StepResponse]
    #: N ≥ 2 paths: per-path figures (path_metrics) over 'whole_run' and 'steady_state' ({} for
    #: one path; the steady list empty without a steady state)
    paths: dict[str, list[dict[str, float]]] | None = None

    @property
    def streamed_commands(self) -> dict[str, int]:
        """Commands per topic that are not steps (steps.MIN_STEP_CYCLES): a closed loop's."""
        counts: dict[str, int] = {}
        for cmd in self.trace.commands:
            counts[cmd.key] = counts.get(cmd.key, 0) + 1
        for step in self.steps:
            counts[step.command.key] -= 1
        return {key: n for key, n in counts.items() if n}

    @property
    def summary(self) -> dict[str, dict[str, float]]:
        """{'whole_run': …, 'steady_state': …} (the latter {} without a steady state)."""
        return {'whole_run': self.whole_run, 'steady_state': self.steady_metrics}


def analyze_trace(trace: Trace, *, tolerance: float = TOLERANCE,
                  min_cycles: int = MIN_CYCLES) -> RunAnalysis:
    """Split one run into crank cycles and compute every figure (:mod:`.cycles`,
    :mod:`.whole_run`, :mod:`.steady`, :mod:`.energy`, :mod:`.steps`). ``tolerance`` and
    ``min_cycles`` define the steady state. Raises :class:`~.errors.AnalysisError` for
    unusable samples."""
    # extreme but finite samples (a damaged recording) may overflow: NaN/inf figures are
    # reported as n/a, not as warnings
    with np.errstate(all='ignore'):
        cycles, boundaries = cycle_metrics(trace)
        steady = find_steady_state(cycles, tolerance=tolerance, min_cycles=min_cycles)
        steady_metrics = cycles.window(steady.first, steady.stop) if steady.found else {}
        paths = {}
        if trace.paths is not None:
            paths = {'whole_run': path_metrics(trace),
                     'steady_state': path_metrics(trace, steady_metrics['t_start'],
                                                  steady_metrics['t_end'])
                     if steady_metrics else []}
        return RunAnalysis(trace, cycles, boundaries, whole_run_metrics(trace), steady,
                           steady_metrics, energy_balance(trace),
                           step_responses(trace, cycles, tolerance=tolerance,
                                          min_cycles=min_cycles), paths)
