"""An independent driver of the N-path machine: scipy's ``solve_ivp`` with one terminal event
per path (reference.py does this for one path).

It shares with the compiled core (paths_hybrid.py) only the right-hand side and the reset map
(physics/paths.py, physics/path_contacts.py) and the guards' definition: stepping, dense output,
event location and the choice of the earliest event are scipy's own.
"""
import time

import numpy as np
from scipy.integrate import solve_ivp

from ..physics.path_contacts import settle_contacts
from ..physics.paths import N_PATH_AUX, bit, n_paths, paths_project, paths_rhs
from .paths_simulator import PathsSimulator
from .paths_watch import path_guard
from .reference import ReferenceResult


def solve_paths_reference(values, t_end, method='DOP853', rtol=1e-12, atol=1e-14,
                          max_switches=100000, max_step=np.inf, start=None):
    """Integrate an N-path scene from its consistent initial state (a PathsSimulator's, start-up
    impact included; or ``start``'s present state, a PathsSimulator of the scene, which is left
    as it is) to t_end [s]; returns a ReferenceResult whose switch_times and switch_modes
    (the engaged set after each reset, a bitmask) list every reset that changed the set, and
    ``switch_paths`` the paths whose clutch switched there.

    scipy looks for an event's sign change at its steps' ends only: a contact shorter than a
    step (the stiff shaft's last ones, 0.2 µs) is seen only with ``max_step`` [s] below it.

    The half-open rule, as the core's: a guard that a segment starts inside its band (every
    guard of a switch, and on a locked crank every open slip, ∝ ω1 ≡ 0, for as long as the lock
    lasts) is watched for leaving the band (upwards: armed from there, the segment goes on; or
    downwards: a switch there), not for its root, which it sits on. Without it scipy finds the
    rounding of those slips crossing zero at every segment's start and never leaves the lock."""
    sim = PathsSimulator(values) if start is None else start
    P, ACT, t, y, mode = sim.P, sim.ACT, sim.t, sim.y.copy(), int(sim.ms[0])
    dy = np.empty_like(y)
    aux = np.empty(N_PATH_AUX)
    scratch = (np.empty_like(y), np.empty_like(y))
    result = ReferenceResult(t=t, y=y)
    result.switch_paths = []
    result.segments = 0
    wall0 = time.perf_counter()
    n = n_paths(P)

    def fun(tt, yy):
        out = np.empty_like(yy)
        paths_rhs(tt, yy, mode, P, ACT, out, aux)
        return out

    def event(k, offset, direction):
        def guard(tt, yy):
            paths_rhs(tt, yy, mode, P, ACT, dy, aux)
            value, band = path_guard(k, mode, aux, P)
            return value + offset * band
        guard.terminal = True
        guard.direction = direction
        return guard

    def bands(tt, yy):
        paths_rhs(tt, yy, mode, P, ACT, dy, aux)
        return [path_guard(k, mode, aux, P) for k in range(n)]

    armed = {k for k, (g, band) in enumerate(bands(t, y)) if abs(g) > band}
    while t < t_end and len(result.switch_times) < max_switches:
        # per path: (its event, what it means): the root of an armed guard; a disarmed one
        # leaving its band upwards (arm it) or downwards (a switch, as the core's found late)
        watched = []
        for k in range(n):
            if k in armed:
                watched.append((event(k, 0.0, -1.0), k, 'switch'))
            else:
                watched.append((event(k, -1.0, 1.0), k, 'arm'))
                watched.append((event(k, 1.0, -1.0), k, 'switch'))
        sol = solve_ivp(fun, (t, t_end), y, method=method, rtol=rtol, atol=atol,
                        events=[w[0] for w in watched], max_step=max_step)
        result.nfev += sol.nfev
        result.segments += 1
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t = {sol.t[-1]}: {sol.message}")
        if sol.status != 1:
            t, y = float(sol.t[-1]), np.array(sol.y[:, -1])
            break
        t, i = min((float(te[0]), i) for i, te in enumerate(sol.t_events) if len(te))
        y = np.array(sol.y_events[i][0])
        _, path, what = watched[i]
        if what == 'arm':
            armed.add(path)
            continue
        old = mode
        paths_project(t, y, old, P, ACT, aux)
        exclude = bit(path) if old & bit(path) else 0
        mode, _, _ = settle_contacts(t, y, old & ~exclude, exclude, False, P, ACT, dy, aux,
                                     *scratch)
        armed = {k for k, (g, band) in enumerate(bands(t, y)) if abs(g) > band}
        if mode != old:
            result.switch_times.append(t)
            result.switch_modes.append(mode)
            result.switch_paths.append([k + 1 for k in range(n) if (old ^ mode) & bit(k)])
    result.t = t
    result.y = y
    result.wall_time = time.perf_counter() - wall0
    return result
