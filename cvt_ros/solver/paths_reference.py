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
                          max_switches=100000):
    """Integrate an N-path scene from its consistent initial state (a PathsSimulator's, start-up
    impact included) to t_end [s]; returns a ReferenceResult whose switch_times and switch_modes
    (the engaged set after each reset, a bitmask) list every reset that changed the set, and
    ``switch_paths`` the paths whose clutch switched there."""
    sim = PathsSimulator(values)
    P, ACT, t, y, mode = sim.P, sim.ACT, sim.t, sim.y.copy(), int(sim.ms[0])
    dy = np.empty_like(y)
    aux = np.empty(N_PATH_AUX)
    scratch = (np.empty_like(y), np.empty_like(y))
    result = ReferenceResult(t=t, y=y)
    result.switch_paths = []
    wall0 = time.perf_counter()

    def fun(tt, yy):
        out = np.empty_like(yy)
        paths_rhs(tt, yy, mode, P, ACT, out, aux)
        return out

    def guard_of(k):
        def guard(tt, yy):
            paths_rhs(tt, yy, mode, P, ACT, dy, aux)
            return path_guard(k, mode, aux, P)[0]
        guard.terminal = True
        guard.direction = -1.0
        return guard

    guards = [guard_of(k) for k in range(n_paths(P))]
    while t < t_end and len(result.switch_times) < max_switches:
        sol = solve_ivp(fun, (t, t_end), y, method=method, rtol=rtol, atol=atol, events=guards)
        result.nfev += sol.nfev
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t = {sol.t[-1]}: {sol.message}")
        if sol.status != 1:
            t, y = float(sol.t[-1]), np.array(sol.y[:, -1])
            break
        fired = min((float(te[0]), k) for k, te in enumerate(sol.t_events) if len(te))
        t, path = fired
        y = np.array(sol.y_events[path][0])
        old = mode
        paths_project(t, y, old, P, ACT, aux)
        exclude = bit(path) if old & bit(path) else 0
        mode, _, _ = settle_contacts(t, y, old & ~exclude, exclude, False, P, ACT, dy, aux,
                                     *scratch)
        if mode != old:
            result.switch_times.append(t)
            result.switch_modes.append(mode)
            result.switch_paths.append([k + 1 for k in range(n_paths(P))
                                        if (old ^ mode) & bit(k)])
    result.t = t
    result.y = y
    result.wall_time = time.perf_counter() - wall0
    return result
