"""One run analysed: its crank cycles and per-run windows, energy balance and step responses
(:func:`analyze_trace`); what the report, the JSON and the plots are made from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .cycles import CycleTable, cycle_metrics
from .energy import energy_balance
from .steps import StepResponse, step_responses
from .trace import Trace

__all__ = ['RunAnalysis', 'analyze_trace']


@dataclass
class RunAnalysis:
    """Everything :func:`analyze_trace` computes for one run."""

    trace: Trace
    cycles: CycleTable
    boundaries: np.ndarray
    summary: dict[str, dict[str, float]]    # 'all' / 'last_quarter' -> metric -> value
    energy: dict[str, Any]
    steps: list[StepResponse]


def analyze_trace(trace: Trace) -> RunAnalysis:
    """Split one run into crank cycles and compute every metric (:mod:`.cycles`,
    :mod:`.energy`, :mod:`.steps`). Raises :class:`~.errors.AnalysisError` for unusable
    samples."""
    cycles, boundaries, summary = cycle_metrics(trace)
    return RunAnalysis(trace, cycles, boundaries, summary, energy_balance(trace),
                       step_responses(trace, cycles))
