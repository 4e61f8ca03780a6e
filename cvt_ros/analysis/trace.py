"""One run of a recording on the simulation-time axis (:class:`Trace`), and the signals a
recording does not carry but the scene parameters give: the crank length solved from (φ1, φ2)
(paper eq. 1) and the motor torque from the torque law (physics.md §5).

A *run* ends where simulation time goes back (a ``~/reset`` of the node). Sample arrays come
from ``joint_states`` (or the CSV rows); clutch switches from ``clutch_engaged`` at their exact
times (a CSV has only the sampled ``engaged`` column: a switch is placed half-way between the two
samples); commands from ``crank_length_cmd`` / ``load_torque_cmd``; scene parameters from the
file's ``cvt_ros`` metadata record (or ``--scene``). Readers: :mod:`cvt_ros.analysis.inputs`.

A machine of N ≥ 2 paths (issue 33) has its rockers and clutches in :class:`PathTrace`
(``Trace.paths``): each rocker's angle and speed and each clutch's torque (``rocker_1 …
rocker_N`` of joint_states, or the CSV's per-path columns), each clutch's switches
(``clutch_states``). The Trace's own arrays keep the one-path meaning: φ2, ω2 path 1's rocker,
the clutch torque (effort J2) what all the clutches pass to J3, the switches those of "any
clutch engaged" (``clutch_engaged``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ['Command', 'PathTrace', 'RecordingInfo', 'Trace', 'crank_length_from_angles',
           'fill_derived_signals', 'trace_of_samples']


@dataclass(frozen=True)
class Command:
    """A command the node received: simulation time [s], interface key, value."""

    t: float
    key: str
    value: float


def _states_at(t: np.ndarray, initial: bool | None, switch_t: np.ndarray,
               switch_on: np.ndarray) -> np.ndarray:
    t = np.asarray(t, dtype=float)
    if initial is None:
        return np.full(t.shape, np.nan)
    states = np.concatenate([[float(initial)], switch_on.astype(float)])
    return states[np.searchsorted(switch_t, t, side='right')]


def _engaged_time(t0: float, initial: bool | None, switch_t: np.ndarray, switch_on: np.ndarray,
                  t: np.ndarray) -> np.ndarray:
    """∫ engaged dτ from t0 to each of ``t`` of the step function the switches make."""
    t = np.asarray(t, dtype=float)
    if initial is None:
        return np.full(t.shape, np.nan)
    keep = switch_t > t0
    sw, st = switch_t[keep], switch_on[keep].astype(float)
    knots = np.concatenate([[t0], sw])
    states = np.concatenate([[float(initial)], st])
    cum = np.concatenate([[0.0], np.cumsum(states[:-1] * np.diff(knots))])
    i = np.clip(np.searchsorted(knots, t, side='right') - 1, 0, len(knots) - 1)
    return cum[i] + states[i] * (t - knots[i])


@dataclass
class PathTrace:
    """Each path of an N-path machine over one run: (n, N) arrays, path k in column k − 1, and
    each clutch's switches (``switch_t[k − 1]``, ``switch_engaged[k − 1]``; ``initial`` the
    states at t[0], None if unknown; ``exact``: switch times of events, else located between
    samples)."""

    phi: np.ndarray                 # (n, N) rocker angles φ2,k [rad]
    omega: np.ndarray               # (n, N) rocker speeds ω2,k [rad/s]
    torque: np.ndarray              # (n, N) clutch torques [N*m]
    switch_t: list[np.ndarray]
    switch_engaged: list[np.ndarray]
    initial: tuple[bool, ...] | None
    exact: bool = True

    @property
    def n_paths(self) -> int:
        return self.phi.shape[1]

    def engaged_time(self, k: int, t0: float, t: np.ndarray) -> np.ndarray:
        """∫ engaged_k dτ from t0 to each of ``t`` [s] (path ``k`` from 1)."""
        return _engaged_time(t0, None if self.initial is None else self.initial[k - 1],
                             self.switch_t[k - 1], self.switch_engaged[k - 1], t)


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
    #: N ≥ 2 paths: each rocker and clutch (None for the one-path machine)
    paths: PathTrace | None = None

    @property
    def n(self) -> int:
        return len(self.t)

    def engaged_at(self, t: np.ndarray) -> np.ndarray:
        """Clutch state (0/1, NaN if unknown) at times ``t``: the state after the last switch
        at or before t."""
        return _states_at(t, self.initial_engaged, self.switch_t, self.switch_engaged)

    def engaged_time(self, t: np.ndarray) -> np.ndarray:
        """∫ engaged dτ from t[0] to each of ``t`` [s] (exact for the step function)."""
        return _engaged_time(self.t[0], self.initial_engaged, self.switch_t,
                             self.switch_engaged, t)


@dataclass
class RecordingInfo:
    """What :func:`load` found besides the runs."""

    path: str
    kind: str
    problems: list[str] = field(default_factory=list)
    topics: dict[str, tuple[str, int]] = field(default_factory=dict)
    source: str = ''
    scene: str = ''



def trace_of_samples(samples: np.ndarray, columns: tuple[str, ...], switches: list, *,
                     source: str, kind: str, parameters: dict[str, Any] | None = None,
                     scene: str = '') -> Trace:
    """A Trace of the core's sample rows (``columns``: output.path_columns(N)) and its switches
    — ClutchSwitch objects (with ``path``), or (t, engaged[, path]) tuples — the true state with
    exact switch times: offline runs, sweep cases, scenario runs. N ≥ 2: ``Trace.paths`` from the
    per-path columns; the Trace's own switches are those of "any clutch engaged"."""
    from ..solver.clutch_sets import path_masks, set_changes, switch_tuples
    from ..solver.output import COL

    s = samples
    events = switch_tuples(switches)
    initial = bool(s[0, COL['engaged']] > 0.5) if len(s) else None
    n = len(columns) - len(COL) and (len(columns) - len(COL)) // 4
    paths = None
    if n:
        index = {c: i for i, c in enumerate(columns)}

        def block(q: str) -> np.ndarray:
            return s[:, [index[f'{q}_{k}'] for k in range(1, n + 1)]]
        engaged0 = block('engaged')[0] if len(s) else np.zeros(n)
        per_t = [[t for t, _, path in events if path == k] for k in range(1, n + 1)]
        per_on = [[on for _, on, path in events if path == k] for k in range(1, n + 1)]
        paths = PathTrace(block('phi2'), block('omega2'), block('clutch_torque'),
                          [np.asarray(v, dtype=float) for v in per_t],
                          [np.asarray(v, dtype=bool) for v in per_on],
                          tuple(bool(e > 0.5) for e in engaged0))
        changes, _ = set_changes(events, path_masks(engaged0))
        any_t = [c.t for c in changes if c.any_changed]
        any_on = [c.engaged for c in changes if c.any_changed]
    else:
        any_t, any_on = [t for t, _, _ in events], [on for _, on, _ in events]
    pick = [COL[c] for c in ('motor_torque', 'clutch_torque', 'shaft_torque', 'load_torque')]
    return Trace(source=source, kind=kind, t=s[:, COL['t']].copy(),
                 phi=s[:, [COL['phi1'], COL['phi2'], COL['phi3'], COL['phi4']]],
                 omega=s[:, [COL['omega1'], COL['omega2'], COL['omega3'], COL['omega4']]],
                 effort=s[:, pick], twist=s[:, COL['twist']].copy(),
                 crank_length=s[:, COL['crank_length']].copy(),
                 switch_t=np.asarray(any_t, dtype=float),
                 switch_engaged=np.asarray(any_on, dtype=bool), initial_engaged=initial,
                 switches_exact=True, parameters=parameters, scene=scene, paths=paths)


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

