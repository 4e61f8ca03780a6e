"""A run's own samples checked against its clutch modes: the self-check that tells a possibly
missed event where the watches did not (docs/solver.md, "What a run says").

The compiled loop checks every step's end (a guard found beyond its band there is switched at
once and counted late: ``C_LATE``). The samples are points inside the steps, read from the same
dense output the watches bracketed on; one that stands outside its own mode by more than a
location error can leave beside a located switch (STRAY_BAND of the guard's scale, or 10·rtol
at looser tolerances) is a sign that an event inside a step was not found: an open clutch whose
slip stands below zero, an engaged one whose release guard does (the clutch torque; with the
twist rule max(θ, Tc/c), so a negative twist with a clutch that still pulls).
"""
import numpy as np

from ..physics import layout as L
from .output import COL

# how far outside its mode a sample may stand beside a located switch, relative to the guard's
# scale (the test suite's STRAY: 7e-4 of the largest clutch torque seen at rtol 1e-4)
STRAY_BAND = 1e-3
RTOL_BANDS = 10.0   # at loose tolerances: this many rtol of the guard's scale


def stray_band(values):
    """The relative band of the sample check for these solver settings."""
    if values['solver.method'] == 'dopri5':
        return max(STRAY_BAND, RTOL_BANDS * values['solver.rtol'])
    return STRAY_BAND


def stray_samples(rows, P, band, columns=None):
    """(count, time of the first) of the sample rows that stand outside their own clutch mode
    by more than ``band`` of the guard's scale: open with slip ω3 − ω2 below −band·(1 + |ω2| +
    |ω3|), engaged with the release guard below −band × the scene's torque scale (over c with
    the twist rule). ``columns``: the rows' column names (output.COLUMNS by default); an N-path
    machine's rows are checked path by path (``engaged_k``, ``omega2_k``, ``clutch_torque_k``)."""
    if len(rows) == 0:
        return 0, None
    col = COL if columns is None else {name: i for i, name in enumerate(columns)}
    paths = [''] if 'engaged_1' not in col else [f'_{k}' for k in range(1, 9)
                                                 if f'engaged_{k}' in col]
    w3 = rows[:, col['omega3']]
    scale = P[L.P_TORQUE_SCALE]
    twist = P[L.P_RELEASE] == L.RELEASE_TWIST and P[L.P_RIGID] == 0.0
    out = np.zeros(len(rows), dtype=bool)
    for path in paths:
        engaged = rows[:, col['engaged' + path]] == 1.0
        w2 = rows[:, col['omega2' + path]]
        slip_out = (w3 - w2) < -band * (1.0 + np.abs(w2) + np.abs(w3))
        torque = rows[:, col['clutch_torque' + path]]
        if twist:
            guard = np.maximum(rows[:, col['twist']], torque / P[L.P_C])
            torque_out = guard < -band * scale / P[L.P_C]
        else:
            torque_out = torque < -band * scale
        out |= np.where(engaged, torque_out, slip_out)
    count = int(np.count_nonzero(out))
    return count, (float(rows[np.argmax(out), col['t']]) if count else None)
