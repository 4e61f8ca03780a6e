"""A recording as CSV for spreadsheets and other tools (``cvt-sim export FILE --csv OUT``).

The sample CSV has the columns of ``cvt-sim run --csv`` (``t, phi1..phi4, omega1..omega4,
engaged, twist, clutch_torque, crank_length, load_torque``) followed by ``motor_torque`` and
``shaft_torque``; SI units, one row per joint_states sample, t = simulation time [s]. ``engaged``
is the clutch state after the last switch at or before the sample; ``twist`` = φ3 − φ4;
``crank_length`` is solved from (φ1, φ2) and the linkage (paper eq. 1) when the recording has the
scene parameters, else empty. After a ``~/reset`` t starts again from 0 (a new run).

``--events OUT`` writes the clutch switches and commands with their exact simulation times:
``run, t, topic, value`` (value: 1/0 for engaged/released, the command's value).
"""

from __future__ import annotations

import csv
import math
from typing import Any

import numpy as np

from ..solver.output import CSV_COLUMNS
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
    return cols


def export_csv(traces: list[Trace], out: Any) -> int:
    """Write the sample CSV to the open text file ``out``; returns the rows written."""
    out.write(','.join(EXPORT_COLUMNS) + '\n')
    rows = 0
    for trace in traces:
        cols = _columns(trace)
        data = np.column_stack([cols[name] for name in EXPORT_COLUMNS])
        engaged = EXPORT_COLUMNS.index('engaged')
        for row in data.tolist():
            out.write(','.join(
                '' if not math.isfinite(v) else
                (str(int(v)) if i == engaged else f'{v:.12g}')
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
        events += [(c.t, c.key, c.value) for c in trace.commands]
        events.sort(key=lambda e: e[0])
        for t, topic, value in events:
            writer.writerow([trace.run_index + 1, f'{t:.12g}', topic,
                             f'{value:.12g}' if topic != 'clutch_engaged' else int(value)])
            rows += 1
    return rows
