"""Model only what a scene needs: pick the simulator for ``model.fidelity``.

* ``full`` — the 4-inertia hybrid model (the shaft's J3 mode, clutch events).
* ``rigid_shaft`` — c → ∞: J3 and J4 lumped, no twist, no stiff mode (physics/dynamics.py).
* ``averaged`` — the mean motion through a calibrated steady-state ratio map (averaged.py).
Degenerate elements reduce automatically in every fidelity (J3 = 0, c = ∞).

``choose_fidelity`` (``cvt-sim run --fidelity auto --tolerance X``) runs each candidate, cheapest
first, against the full model over a probe window and keeps the first whose mean output speed
and mean ratio are within the tolerance.
"""
import time

import numpy as np

from .averaged import AveragedSimulator
from .paths_simulator import PathsSimulator
from .simulator import Simulator

FIDELITIES = ('full', 'rigid_shaft', 'averaged')
CHEAPEST_FIRST = ('averaged', 'rigid_shaft', 'full')


def make_simulator(values, progress=None):
    """The simulator for the scene's ``model.fidelity`` and ``paths.count`` (N ≥ 2: the
    N-path core, paths_simulator.py)."""
    if values.get('model.fidelity', 'full') == 'averaged':
        return AveragedSimulator(values, progress)
    if values.get('paths.count', 1) > 1:
        return PathsSimulator(values)
    return Simulator(values)


def fidelity_errors(values, duration, sample_dt=1e-3):
    """Relative errors of each fidelity against ``full`` over ``duration`` [s] of the scene:
    mean output speed and mean ratio over the last half (whole crank turns do not matter at
    the 1e-3 level over a half of ≥ 1 s), output speed ripple (peak-to-peak / mean), wall time."""
    rows = {}
    for fidelity in FIDELITIES:
        sim = make_simulator(dict(values, **{'model.fidelity': fidelity}))
        t0 = time.perf_counter()
        result = sim.run(duration, sample_dt)
        wall = time.perf_counter() - t0
        half = result.samples[result.samples[:, 0] >= duration / 2]
        w1, w4 = half[:, 5], half[:, 8]
        rows[fidelity] = {'mean_output_speed': float(np.mean(w4)),
                          'mean_ratio': float(np.mean(w4) / np.mean(w1)),
                          'ripple': float(np.ptp(w4) / abs(np.mean(w4))) if np.mean(w4) else 0.0,
                          'wall_time': wall}
    full = rows['full']
    for row in rows.values():
        row['speed_error'] = abs(row['mean_output_speed'] - full['mean_output_speed']) / max(
            abs(full['mean_output_speed']), 1e-9)
        row['ratio_error'] = abs(row['mean_ratio'] - full['mean_ratio']) / max(
            abs(full['mean_ratio']), 1e-9)
    return rows


def choose_fidelity(values, tolerance, probe=2.0):
    """The cheapest fidelity whose mean output speed and ratio errors (vs full, over a probe
    run) are within ``tolerance`` (relative). Returns (fidelity, the error table)."""
    table = fidelity_errors(values, probe)
    for fidelity in CHEAPEST_FIRST:
        row = table[fidelity]
        if max(row['speed_error'], row['ratio_error']) <= tolerance:
            return fidelity, table
    return 'full', table
