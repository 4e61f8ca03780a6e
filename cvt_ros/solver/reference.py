"""An independent driver of the same equations: scipy's ``solve_ivp`` with terminal events.

Used as the tight-tolerance reference in the tests and as a baseline in the benchmarks. It shares
only the right-hand side (physics/dynamics.rhs) and the automaton's rules with the compiled
solver: stepping, dense output and event location are scipy's own.
"""
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from ..physics import layout as L
from ..physics.clutch import clutch_engages, clutch_guard, guard_tolerance
from ..physics.dynamics import project, rhs
from .simulator import Simulator


@dataclass
class ReferenceResult:
    t: float
    y: np.ndarray
    switch_times: list = field(default_factory=list)
    switch_modes: list = field(default_factory=list)
    nfev: int = 0
    wall_time: float = 0.0
    samples: np.ndarray = None   # state rows at t_eval (if given)


def initial_state(values, start=None):
    """(P, ACT, t, y, mode) to start from: the scene's consistent initial state, or the state of
    the Simulator ``start`` at its time; y is a copy."""
    sim = start if start is not None else Simulator(values)  # consistent state and mode
    return sim.P, sim.ACT, sim.t, sim.y.copy(), int(sim.ms[0])


def next_mode(t, y, mode, P, ACT, dy, aux, scratch):
    """The automaton's reset map at a located root of ``mode``'s guard (physics/clutch.py), as
    the compiled solver applies it: the new mode, or None when the clutch does not switch (a
    grazing contact does not engage). A release guard's root always opens the clutch: the twist
    rule's guard max(θ, Tc/c) has complementarity in it."""
    if mode == L.ENGAGED:
        return L.DISENGAGED
    if clutch_engages(t, y, P, ACT, dy, aux, scratch):
        return L.ENGAGED
    return None


def solve_reference(values, t_end, method='DOP853', rtol=1e-12, atol=1e-14, t_eval=None,
                    max_switches=100000, start=None, max_step=np.inf, half_open=False):
    """Integrate a scene from its initial state (or from the state of the Simulator ``start``,
    at its time) to t_end [s] with scipy; returns the final state, the switch times and modes,
    and the number of RHS evaluations.

    scipy looks for an event's sign change at its steps' ends only: a phase shorter than a step
    is seen only with ``max_step`` [s] below it. ``half_open``: the core's half-open rule, as
    paths_reference.py keeps it for N paths: a guard that a segment starts inside its band (a
    switch's new guard) is watched for leaving the band, upwards (armed from there: its root is
    the switch) or downwards (a switch there), not for its root, which it sits on. Without it
    a guard that a reset leaves at zero and that falls out of the band at once is lost when the
    rounding starts it just below zero (no sign change), or switched at the segment's start."""
    P, ACT, t, y, mode = initial_state(values, start)
    dy = np.empty(L.N_STATE)
    aux = np.empty(L.N_AUX)
    scratch = np.empty(L.N_STATE)
    result = ReferenceResult(t=t, y=y)
    rows = []
    wall0 = time.perf_counter()

    def fun(tt, yy):
        out = np.empty(L.N_STATE)
        rhs(tt, yy, mode, P, ACT, out, aux)
        return out

    def guard(tt, yy):
        rhs(tt, yy, mode, P, ACT, dy, aux)
        return clutch_guard(mode, yy, dy, aux, P)[0]

    def band_edge(side):
        def edge(tt, yy):
            rhs(tt, yy, mode, P, ACT, dy, aux)
            return clutch_guard(mode, yy, dy, aux, P)[0] - side * guard_tolerance(mode, yy,
                                                                                  aux, P)
        edge.terminal = True
        edge.direction = side
        return edge

    def outside_band(tt, yy):
        rhs(tt, yy, mode, P, ACT, dy, aux)
        return abs(clutch_guard(mode, yy, dy, aux, P)[0]) > guard_tolerance(mode, yy, aux, P)

    guard.terminal = True
    guard.direction = -1.0
    # (event, leaves the band upwards: arm, no switch)
    disarmed = ((band_edge(1.0), True), (band_edge(-1.0), False))
    armed = not half_open or (start is not None and start.ms[1] == 1) or outside_band(t, y)
    while t < t_end and len(result.switch_times) < max_switches:
        seg_eval = None
        if t_eval is not None:
            seg_eval = t_eval[(t_eval >= t) & (t_eval <= t_end)]
        watched = ((guard, False),) if armed else disarmed
        sol = solve_ivp(fun, (t, t_end), y, method=method, rtol=rtol, atol=atol,
                        events=[w[0] for w in watched], t_eval=seg_eval, max_step=max_step)
        result.nfev += sol.nfev
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t = {sol.t[-1]}: {sol.message}")
        arming = False
        if sol.status == 1:
            t_new, i = min((float(te[0]), i) for i, te in enumerate(sol.t_events) if len(te))
            y = np.array(sol.y_events[i][0])
            arming = watched[i][1]
        else:
            t_new = float(sol.t[-1])
            y = np.array(sol.y[:, -1])
        if t_eval is not None and len(sol.t):
            keep = sol.t <= t_new
            for tt, yy in zip(sol.t[keep], sol.y[:, keep].T, strict=True):
                if not rows or tt > rows[-1][0]:
                    rows.append(np.concatenate(([tt], yy)))
        if t_new <= t and sol.status != 1:
            break
        t = t_new
        if sol.status != 1:
            break
        if arming:
            armed = True
            continue
        new = next_mode(t, y, mode, P, ACT, dy, aux, scratch)
        if new is None:
            armed = not half_open
            continue
        mode = new
        project(t, y, mode, P, ACT)
        armed = not half_open or outside_band(t, y)
        result.switch_times.append(t)
        result.switch_modes.append(mode)
    result.t = t
    result.y = y
    result.wall_time = time.perf_counter() - wall0
    if rows:
        result.samples = np.array(rows)
    return result
