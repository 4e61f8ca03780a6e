"""Inputs of the analysis: an MCAP recording (:mod:`cvt_ros.analysis.bag`) or a CSV of
``cvt-sim run --csv`` / ``cvt-sim export``, read into :class:`~cvt_ros.analysis.trace.Trace` runs.

The library raises :class:`~cvt_ros.analysis.errors.AnalysisError` when nothing is usable and
lists read problems of a damaged file in :attr:`RecordingInfo.problems` (partial results).
"""

from __future__ import annotations

import csv
import math
import os

import numpy as np

from .. import interface as I
from .bag import MAX_RUNS, load_mcap
from .errors import AnalysisError
from .trace import PathTrace, RecordingInfo, Trace, fill_derived_signals

__all__ = ['load', 'load_csv', 'load_mcap']


def load(path: str, *, scene: str | None = None, namespace: str | None = None
         ) -> tuple[list[Trace], RecordingInfo]:
    """Read an MCAP recording or a cvt-sim CSV into runs. ``scene`` (name or path) supplies the
    parameters when the file has none (or overrides them). Raises :class:`AnalysisError` when
    nothing can be read; read problems of a damaged file are in ``RecordingInfo.problems``."""
    if not os.path.exists(path):
        raise AnalysisError(f'{path}: no such file')
    if not os.path.isfile(path):
        raise AnalysisError(f'{path}: is a directory, not a recording' if os.path.isdir(path)
                            else f'{path}: not a regular file')
    try:
        with open(path, 'rb') as f:
            head = f.read(8)
    except OSError as exc:
        raise AnalysisError(f'{path}: cannot read: {exc.strerror or exc}') from None
    if head == b'\x89MCAP0\r\n':
        traces, info = load_mcap(path, namespace=namespace)
    elif head[:1] in (b'\x89', b'\x00') or not head:
        raise AnalysisError(f'{path}: not an MCAP recording or a CSV file'
                            if head else f'{path}: empty file')
    else:
        traces, info = load_csv(path)
    if scene:
        from ..physics.linkage import GrashofError
        from ..scene import load_scene

        try:
            values = load_scene(scene)
        except (ValueError, GrashofError) as exc:  # SceneError, ParameterError
            raise AnalysisError(f'--scene: {exc}') from None
        for trace in traces:
            if trace.parameters:
                trace.notes.append(f'--scene {scene} replaces the parameters the recording '
                                   f'holds ({trace.parameters_origin or "its own"}): figures '
                                   f'that use them (energy balance, efficiency) are then '
                                   f"the scene's, not this run's")
            a0 = float(trace.crank_length[0]) if len(trace.crank_length) else math.nan
            if math.isfinite(a0) and abs(a0 - values['linkage.crank_length']) > 1e-9:
                trace.notes.append(f"--scene {scene}: its crank length "
                                   f"{values['linkage.crank_length']:g} m is not the recorded "
                                   f"one ({a0:g} m at the start): is it this run's scene?")
            trace.parameters = values
            trace.parameters_origin = f'--scene {scene}'
            trace.scene = trace.scene or scene
    for trace in traces:
        fill_derived_signals(trace)
        if (trace.parameters or {}).get('model.fidelity') == 'averaged':
            trace.notes.append('model.fidelity averaged: ripple, twist, clutch torque and '
                               'switches are not modelled (mean motion only)')
    return traces, info


# .................................................................................. CSV
_CSV_REQUIRED = ('t', 'phi1', 'phi2', 'phi3', 'phi4', 'omega1', 'omega2', 'omega3', 'omega4')


def load_csv(path: str) -> tuple[list[Trace], RecordingInfo]:
    """Read a CSV of ``cvt-sim run --csv`` or ``cvt-sim export`` (tolerates a cut-off end)."""
    info = RecordingInfo(path, 'csv')
    try:
        with open(path, newline='', encoding='utf-8') as f:
            text = f.read()
    except OSError as exc:
        raise AnalysisError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except UnicodeDecodeError as exc:
        raise AnalysisError(f'{path}: not a recording (MCAP) or a UTF-8 CSV file (byte '
                            f'{exc.start})') from None
    lines = text.splitlines()
    if not lines:
        raise AnalysisError(f'{path}: empty file')
    header = [h.strip() for h in next(csv.reader([lines[0]]))]
    missing = [c for c in _CSV_REQUIRED if c not in header]
    if missing:
        raise AnalysisError(f'{path}: not a cvt-sim CSV (missing columns {", ".join(missing)})')
    width = len(header)
    rows = []
    for number, line in enumerate(lines[1:], start=2):
        cells = line.split(',')
        if len(cells) != width:
            info.problems.append(f'line {number}: {len(cells)} fields instead of {width} '
                                 '(file cut off?); reading stopped there')
            break
        try:
            rows.append([float(c) if c.strip() else math.nan for c in cells])
        except ValueError:
            info.problems.append(f'line {number}: not a number; reading stopped there')
            break
    if not text.endswith('\n') and rows and not info.problems:
        info.problems.append('the last line has no line end (file cut off?)')
    if len(rows) < 2:
        raise AnalysisError(f'{path}: fewer than 2 sample rows'
                            + (f' ({info.problems[0]})' if info.problems else ''))
    data = _plausible_rows(np.asarray(rows), header, info)
    col = {name: data[:, i] for i, name in enumerate(header)}
    n = len(data)

    def get(name: str) -> np.ndarray:
        return col[name] if name in col else np.full(n, np.nan)

    t = col['t']
    cuts = np.flatnonzero(np.diff(t) < 0) + 1
    bounds = [0, *cuts.tolist(), n]
    if len(bounds) - 1 > MAX_RUNS:
        info.problems.append(f'the time goes back {len(cuts)} times: only the first '
                             f'{MAX_RUNS} runs are analysed')
        bounds = bounds[:MAX_RUNS + 1]
    traces = []
    for r in range(len(bounds) - 1):
        s = slice(bounds[r], bounds[r + 1])
        if bounds[r + 1] - bounds[r] < 2:
            continue
        tt = t[s]
        initial, sw_t, sw_on = _sampled_switches(tt, get('engaged')[s])
        phi = np.column_stack([get(c)[s] for c in I.POSITION_COLUMNS])
        twist = get('twist')[s]
        if np.all(np.isnan(twist)):
            twist = phi[:, 2] - phi[:, 3]
        trace = Trace(path, 'csv', tt, phi,
                      np.column_stack([get(c)[s] for c in I.VELOCITY_COLUMNS]),
                      np.column_stack([get(c)[s] for c in I.EFFORT_COLUMNS]),
                      twist, get('crank_length')[s].copy(), sw_t, sw_on, initial, False,
                      run_index=len(traces))
        if np.any(np.isfinite(trace.crank_length)):
            trace.crank_length_source = 'csv'
        trace.paths = _csv_paths(header, get, s, tt)
        if initial is None:
            trace.notes.append('no engaged column: clutch metrics unavailable')
        traces.append(trace)
    if not traces:
        raise AnalysisError(f'{path}: fewer than 2 samples in every run')
    return traces, info


def _sampled_switches(t: np.ndarray, engaged: np.ndarray
                      ) -> tuple[bool | None, np.ndarray, np.ndarray]:
    """(state at t[0] or None, switch times, states after): a sampled engaged column's
    changes, each placed half-way between its two samples."""
    initial = None if np.isnan(engaged[0]) else bool(engaged[0] > 0.5)
    on = engaged > 0.5
    change = np.flatnonzero(on[1:] != on[:-1])
    return initial, 0.5 * (t[change] + t[change + 1]), on[change + 1]


def _csv_paths(header: list[str], get, rows: slice, t: np.ndarray) -> PathTrace | None:
    """N ≥ 2 paths: the CSV's per-path columns (phi2_k, omega2_k, engaged_k, clutch_torque_k,
    ``cvt-sim run --csv`` of such a machine); None for one path."""
    n = 0
    while f'phi2_{n + 1}' in header:
        n += 1
    if n < 2:
        return None

    def block(q: str) -> np.ndarray:
        return np.column_stack([get(f'{q}_{k}')[rows] for k in range(1, n + 1)])
    switches = [_sampled_switches(t, get(f'engaged_{k}')[rows]) for k in range(1, n + 1)]
    initial = None if any(sw[0] is None for sw in switches) else tuple(sw[0] for sw in switches)
    return PathTrace(block('phi2'), block('omega2'), block('clutch_torque'),
                     [sw[1] for sw in switches], [sw[2] for sw in switches], initial, False)


def _plausible_rows(data: np.ndarray, header: list[str], info: RecordingInfo) -> np.ndarray:
    """Rows a run can have written: finite time and motion, finite torques in the columns the
    file fills, a time different from the row before (a repeated row is dropped)."""
    index = {name: i for i, name in enumerate(header)}
    need = [index[c] for c in _CSV_REQUIRED]
    torques = [index[c] for c in I.EFFORT_COLUMNS if c in index]
    with np.errstate(invalid='ignore'):
        ok = np.all(np.isfinite(data[:, need]), axis=1)
        if torques:
            carried = np.any(np.isfinite(data[:, torques]), axis=0)
            ok &= ~np.any(~np.isfinite(data[:, torques]) & carried, axis=1)
    bad = int(np.count_nonzero(~ok))
    data = data[ok]
    repeated = np.flatnonzero(np.diff(data[:, index['t']]) == 0) + 1
    if len(repeated):
        data = np.delete(data, repeated, axis=0)
    if bad:
        info.problems.append(f'{bad} row(s) with non-finite values skipped')
    if len(data) < 2:
        raise AnalysisError(f'{info.path}: fewer than 2 usable sample rows')
    return data

