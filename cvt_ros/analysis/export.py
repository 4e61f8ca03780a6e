"""A recording as CSV for spreadsheets and other tools (``cvt-sim export FILE --csv OUT``).

The sample CSV has the columns of ``cvt-sim run --csv`` (``t, phi1..phi4, omega1..omega4,
engaged, twist, clutch_torque, crank_length, load_torque``) followed by ``motor_torque`` and
``shaft_torque``; SI units, one row per joint_states sample, t = simulation time [s]. ``engaged``
is the clutch state after the last switch at or before the sample; ``twist`` = φ3 − φ4;
``crank_length`` is solved from (φ1, φ2) and the linkage (paper eq. 1) when the recording has the
scene parameters, else empty. After a ``~/reset`` t starts again from 0 (a new run).

``--events OUT`` writes the clutch switches and commands with their exact simulation times:
``run, t, topic, value`` (value: 1/0 for engaged/released, the command's value).

A machine of N ≥ 2 paths (a recording with ``rocker_1 … rocker_N``) adds each path's columns,
as ``cvt-sim run --csv`` writes them (``phi2_1 … phi2_N, omega2_1 …, engaged_1 …,
clutch_torque_1 …``; ``clutch_torque`` is their sum, ``engaged`` any clutch's), and its events
each clutch's switches (topic ``clutch_k``) besides those of ``clutch_engaged``.
"""

from __future__ import annotations

import csv
import math
from typing import Any

import numpy as np

from ..solver.output import CSV_COLUMNS, N_COLUMNS, path_columns
from .trace import Trace

__all__ = ['EXPORT_COLUMNS', 'export_csv', 'export_events']

EXPORT_COLUMNS = (*CSV_COLUMNS, 'motor_torque', 'shaft_torque')


def _columns(trace: Trace) -> dict[str, np.ndarray]:
    cols = {'t': trace.t}
    for j in range(4):
        cols[f'phi{j + 1}'] = trace.phi[:, j]
        cols[f'omega{j + 1}'] = trace.omega[:, j]
    cols['engaged'] = trace.engaged_at(trace.t)
    cols['twist'] = trace.twist
    cols['clutch_torque'] = trace.effort[:, 1]
    cols['crank_length'] = trace.crank_length
    cols['load_torque'] = trace.effort[:, 3]
    cols['motor_torque'] = trace.effort[:, 0]
    cols['shaft_torque'] = trace.effort[:, 2]
    paths = trace.paths
    if paths is not None:
        for k in range(1, paths.n_paths + 1):
            cols[f'phi2_{k}'] = paths.phi[:, k - 1]
            cols[f'omega2_{k}'] = paths.omega[:, k - 1]
            cols[f'engaged_{k}'] = _states(paths, k, trace.t)
            cols[f'clutch_torque_{k}'] = paths.torque[:, k - 1]
    return cols


def _states(paths: Any, k: int, t: np.ndarray) -> np.ndarray:
    """Clutch k's state (1/0, NaN unknown) after its last switch at or before each of t."""
    if paths.initial is None:
        return np.full(len(t), np.nan)
    states = np.concatenate([[float(paths.initial[k - 1])],
                             paths.switch_engaged[k - 1].astype(float)])
    return states[np.searchsorted(paths.switch_t[k - 1], t, side='right')]


def _export_columns(traces: list[Trace]) -> tuple[str, ...]:
    """EXPORT_COLUMNS, and each path's when every run has the same N ≥ 2 paths."""
    counts = {t.paths.n_paths if t.paths is not None else 1 for t in traces}
    n = counts.pop() if len(counts) == 1 else 1
    return EXPORT_COLUMNS + (path_columns(n)[N_COLUMNS:] if n > 1 else ())


def export_csv(traces: list[Trace], out: Any) -> int:
    """Write the sample CSV to the open text file ``out``; returns the rows written."""
    columns = _export_columns(traces)
    out.write(','.join(columns) + '\n')
    rows = 0
    states = {i for i, name in enumerate(columns) if name.startswith('engaged')}
    for trace in traces:
        cols = _columns(trace)
        data = np.column_stack([cols[name] for name in columns])
        for row in data.tolist():
            out.write(','.join(
                '' if not math.isfinite(v) else
                (str(int(v)) if i in states else f'{v:.12g}')
                for i, v in enumerate(row)) + '\n')
        rows += len(data)
    return rows


def export_events(traces: list[Trace], out: Any) -> int:
    """Write clutch switches and commands (``run, t, topic, value``); returns the rows."""
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(['run', 't', 'topic', 'value'])
    rows = 0
    for trace in traces:
        events = [(float(t), 'clutch_engaged', float(on))
                  for t, on in zip(trace.switch_t, trace.switch_engaged, strict=True)]
        if trace.paths is not None:
            for k in range(1, trace.paths.n_paths + 1):
                events += [(float(t), f'clutch_{k}', float(on)) for t, on in zip(
                    trace.paths.switch_t[k - 1], trace.paths.switch_engaged[k - 1],
                    strict=True)]
        events += [(c.t, c.key, c.value) for c in trace.commands]
        events.sort(key=lambda e: e[0])
        for t, topic, value in events:
            writer.writerow([trace.run_index + 1, f'{t:.12g}', topic,
                             int(value) if topic.startswith('clutch_') else f'{value:.12g}'])
            rows += 1
    return rows
