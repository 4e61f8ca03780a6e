"""Offline analysis of recordings: crank-cycle metrics, steady state, energy balance, step
responses, reports, CSV export and plots.

Layers inside the package (imports go one way)::

    trace (Trace, derived signals) ← bag (MCAP) ← inputs (load: MCAP or CSV)
    trace ← cycles (cycle detection, per-cycle and per-window metrics) ← energy, steps
    cycles, energy, steps ← analyze (RunAnalysis) ← report, plots;  trace ← export

Nothing here imports rclpy or matplotlib at import time (plots import matplotlib when drawing).
The library raises :class:`AnalysisError` and never prints; ``cvt-sim analyze/export`` turn
results into output and exit codes.
"""

from .analyze import RunAnalysis, analyze_trace
from .cycles import CYCLE_FIELDS, CycleTable, cycle_boundaries, cycle_metrics
from .energy import energy_balance
from .errors import AnalysisError
from .inputs import load, load_csv, load_mcap
from .steps import StepResponse, step_responses
from .trace import Command, RecordingInfo, Trace, crank_length_from_angles

__all__ = [
    'CYCLE_FIELDS',
    'AnalysisError',
    'Command',
    'CycleTable',
    'RecordingInfo',
    'RunAnalysis',
    'StepResponse',
    'Trace',
    'analyze_trace',
    'crank_length_from_angles',
    'cycle_boundaries',
    'cycle_metrics',
    'energy_balance',
    'load',
    'load_csv',
    'load_mcap',
    'step_responses',
]
