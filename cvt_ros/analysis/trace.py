"""One run of a recording on the simulation-time axis (:class:`Trace`), and the signals a
recording does not carry but the scene parameters give: the crank length solved from (φ1, φ2)
(paper eq. 1) and the motor torque from the torque law (physics.md §5).

A *run* ends where simulation time goes back (a ``~/reset`` of the node). Sample arrays come
from ``joint_states`` (or the CSV rows); clutch switches from ``clutch_engaged`` at their exact
times (a CSV has only the sampled ``engaged`` column: a switch is placed half-way between the two
samples); commands from ``crank_length_cmd`` / ``load_torque_cmd``; scene parameters from the
file's ``cvt_ros`` metadata record (or ``--scene``). Readers: :mod:`cvt_ros.analysis.inputs`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ['Command', 'RecordingInfo', 'Trace', 'crank_length_from_angles',
           'fill_derived_signals']


@dataclass(frozen=True)
class Command:
    """A command the node received: simulation time [s], interface key, value."""

    t: float
    key: str
    value: float


@dataclass
class Trace:
    """One run of a recording: samples on the simulation-time axis and the events in it.

    Arrays have n rows; (n, 4) arrays are in joint order J1..J4. NaN marks what the source does
    not carry (e.g. motor torque in a ``cvt-sim run`` CSV).
    """

    source: str
    kind: str                       # 'mcap' | 'csv'
    t: np.ndarray                   # [s]
    phi: np.ndarray                 # (n, 4) [rad]
    omega: np.ndarray               # (n, 4) [rad/s]
    effort: np.ndarray              # (n, 4) [N*m]: M1, Tc, Ts, M4
    twist: np.ndarray               # [rad]
    crank_length: np.ndarray        # [m] (NaN if unknown)
    switch_t: np.ndarray            # [s] clutch switch times
    switch_engaged: np.ndarray      # state after each switch
    initial_engaged: bool | None    # state at t[0]; None if unknown
    switches_exact: bool            # True: event times; False: located between samples
    commands: list[Command] = field(default_factory=list)
    parameters: dict[str, Any] | None = None
    parameters_origin: str = ''
    parameter_changes: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    scene: str = ''
    run_index: int = 0
    notes: list[str] = field(default_factory=list)
    #: where ``crank_length`` comes from: 'recorded' (a topic of the recording), 'csv',
    #: 'reconstructed' (solved from φ1, φ2 and the geometry) or '' (unknown: all NaN)
    crank_length_source: str = ''
    #: the set point a controller followed, (t [s], value [rad/s]) at t0 and each change: a
    #: controller-kit recording's /setpoint (``cvt-sim scenario run --mcap``), else empty
    setpoint: list[tuple[float, float]] = field(default_factory=list)

    @property
    def n(self) -> int:
        return len(self.t)

    def engaged_at(self, t: np.ndarray) -> np.ndarray:
        """Clutch state (0/1, NaN if unknown) at times ``t``: the state after the last switch
        at or before t."""
        t = np.asarray(t, dtype=float)
        if self.initial_engaged is None:
            return np.full(t.shape, np.nan)
        states = np.concatenate([[float(self.initial_engaged)],
                                 self.switch_engaged.astype(float)])
        return states[np.searchsorted(self.switch_t, t, side='right')]

    def engaged_time(self, t: np.ndarray) -> np.ndarray:
        """∫ engaged dτ from t[0] to each of ``t`` [s] (exact for the step function)."""
        t = np.asarray(t, dtype=float)
        if self.initial_engaged is None:
            return np.full(t.shape, np.nan)
        t0 = self.t[0]
        sw = self.switch_t
        keep = sw > t0
        sw, st = sw[keep], self.switch_engaged[keep].astype(float)
        knots = np.concatenate([[t0], sw])
        states = np.concatenate([[float(self.initial_engaged)], st])
        cum = np.concatenate([[0.0], np.cumsum(states[:-1] * np.diff(knots))])
        i = np.clip(np.searchsorted(knots, t, side='right') - 1, 0, len(knots) - 1)
        return cum[i] + states[i] * (t - knots[i])


@dataclass
class RecordingInfo:
    """What :func:`load` found besides the runs."""

    path: str
    kind: str
    problems: list[str] = field(default_factory=list)
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    source: str = ''
    scene: str = ''



def fill_derived_signals(trace: Trace) -> None:
    """Crank length and motor torque where the source has none but the parameters give them."""
    _fill_crank_length(trace)
    _fill_motor_torque(trace)


def _fill_crank_length(trace: Trace) -> None:
    """Only old recordings need this: newer ones carry the actual crank length."""
    if np.all(np.isnan(trace.crank_length)) and trace.parameters:
        p = trace.parameters
        try:
            trace.crank_length = crank_length_from_angles(
                trace.phi[:, 0], trace.phi[:, 1], p['linkage.rocker_length'],
                p['linkage.coupler_length'], p['linkage.pivot_distance'],
                p['linkage.assembly_mode'])
            trace.crank_length_source = 'reconstructed'
        except (KeyError, TypeError, ValueError):
            pass


def _fill_motor_torque(trace: Trace) -> None:
    """A CSV has no motor torque; with scene parameters the torque law gives it."""
    if not np.all(np.isnan(trace.effort[:, 0])) or not trace.parameters:
        return
    p = trace.parameters
    model = p.get('motor.model')
    w1 = trace.omega[:, 0]
    if model == 'induction':
        w0, mk, sk = p['motor.synchronous_speed'], p['motor.breakdown_torque'], \
            p['motor.breakdown_slip']
        s = (w0 - w1) / w0
        trace.effort[:, 0] = 2.0 * mk * sk * s / (s * s + sk * sk)  # Kloss (physics.md §5)
        trace.notes.append('motor torque computed from ω1 by the scene\'s torque law')
    elif model == 'constant_torque':
        trace.effort[:, 0] = p['motor.torque']
        trace.notes.append('motor torque from the scene (constant)')


def crank_length_from_angles(phi1: np.ndarray, phi2: np.ndarray, b: float, d: float, h: float,
                             sigma: float = 1.0) -> np.ndarray:
    """The crank length a [m] that puts the rocker at φ2 for crank angle φ1 (paper eq. 1
    solved for a): a² − 2a·(h·cos φ1 + b·cos(φ1 − φ2)) + b² + h² − d² + 2bh·cos φ2 = 0.

    A root counts if it lies in [0, Grashof bound] and its closed-form rocker angle (assembly
    mode σ) is φ2. Where both roots count, the one nearer the median of the unambiguous samples
    is taken. NaN where no root fits (a recording of another geometry)."""
    from ..physics.linkage import grashof_bound

    phi1 = np.asarray(phi1, dtype=float)
    phi2 = np.asarray(phi2, dtype=float)
    bound = grashof_bound(b, d, h)
    B = h * np.cos(phi1) + b * np.cos(phi1 - phi2)
    C = b * b + h * h - d * d + 2.0 * b * h * np.cos(phi2)
    root = np.sqrt(np.maximum(B * B - C, 0.0))
    roots, ok = [], []
    for a in (B - root, B + root):
        c1 = np.cos(phi1)
        p = 2.0 * b * h - 2.0 * a * b * c1
        q = -2.0 * a * b * np.sin(phi1)
        r = -(a * a + b * b + h * h - d * d) + 2.0 * a * h * c1
        with np.errstate(invalid='ignore', divide='ignore'):
            phi2_a = np.arctan2(q, p) + sigma * np.arccos(np.clip(r / np.hypot(p, q), -1, 1))
        err = np.abs(np.angle(np.exp(1j * (phi2_a - phi2))))
        roots.append(np.clip(a, 0.0, None))
        ok.append((a >= -1e-9) & (a <= bound + 1e-9) & (err < 1e-6))
    lo, hi = roots
    only_lo, only_hi, both = ok[0] & ~ok[1], ok[1] & ~ok[0], ok[0] & ok[1]
    out = np.where(only_lo, lo, np.where(only_hi, hi, np.nan))
    if np.any(both):
        # the crank length moves slowly: take the root nearer the nearest unambiguous sample
        known = np.flatnonzero(np.isfinite(out))
        amb = np.flatnonzero(both)
        if len(known):
            j = np.clip(np.searchsorted(known, amb), 1, len(known)) - 1
            j_next = np.minimum(j + 1, len(known) - 1)
            nearer = np.where(np.abs(known[j_next] - amb) < np.abs(known[j] - amb), j_next, j)
            ref = out[known[nearer]]
        else:
            ref = np.full(len(amb), 0.5 * bound)
        out[amb] = np.where(np.abs(lo[amb] - ref) <= np.abs(hi[amb] - ref), lo[amb], hi[amb])
    return out

