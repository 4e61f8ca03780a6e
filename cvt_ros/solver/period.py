"""One control period per compiled call: the device's fast path over a Simulator (DEVICE room).

A device in lockstep makes, every period, a crank command, ``Simulator.advance(dt)`` and
``Simulator.sample()``: the last two are Python-level calls that each unbox a dozen arrays, build
Python objects and run Python bookkeeping (~15 µs of the ~20 µs a 1 ms period once cost).
``PeriodStepper`` does their work in one compiled call per period, writing the sample into a
buffer it owns, with no Python object made per period:

    stepper = PeriodStepper(sim, dt)
    sim.command_crank_length(0.05)          # one compiled call too (physics.drives.replan_into)
    row = stepper.advance()                 # = sim.advance(dt); sim.sample()  (row is reused)
    stepper.switches, stepper.crank_rate    # the clutch switches inside, the actuator's rate

It is bit-identical to those Simulator calls (test_device_period.py checks it over commands, clutch
events, angle rebasing and both simulator classes) and leaves the Simulator in the same state, so
the two can be mixed. The rare cases — clutch events (their ClutchSwitch objects), a full event
table, the whole-turn rebase of φ1/φ4, a failed step — are finished in Python by the Simulator's
own code.

numba caches a kernel keyed on its own file only; the kernels here inline the core's, so their
cache is dropped when any solver/physics source is newer (physics/compiled.py).
"""
import math

import numpy as np
from numba import njit

from ..physics import layout as L
from ..physics.compiled import FASTMATH
from ..physics.drives import crank_actuator
from ..physics.dynamics import rhs
from ..physics.paths import P_PATHS, paths_rhs
from . import advance_layout as AL
from . import hybrid
from . import paths_layout as PL
from .averaged import AveragedSimulator, averaged_advance, averaged_sample
from .output import COL, N_COLUMNS, write_sample
from .paths_hybrid import advance_paths
from .paths_simulator import PathsSimulator
from .paths_steps import write_paths_sample
from .simulator import (
    F_ACT,
    F_AUX,
    F_DY,
    F_H,
    F_LEDGER,
    F_P,
    F_ROW,
    F_S,
    F_SCRATCH,
    F_SIZE,
    F_Y,
    I_COUNTERS,
    I_MS,
    REBASE_TURNS,
    SimulationError,
)
from .steppers import RK4

_PHI1, _PHI3, _PHI4 = COL['phi1'], COL['phi3'], COL['phi4']
TWO_PI = 2.0 * math.pi

# return codes of the period kernels
DONE = 0          # sampled; no clutch event
EVENTS = 1        # sampled; clutch events to report (counters[C_EVENTS] rows)
UNFINISHED = 2    # not sampled: events table full, a failure, or angles to rebase (Python)
NO_SWITCHES = ()


@njit(cache=True, error_model='numpy', fastmath=FASTMATH, _nrt=False)
def _finish(t, y, mode, P, ACT, turns1, turns4, dy, aux, row):
    """Simulator.sample() into ``row`` (unless angles are due for rebasing); the actuator rate."""
    if (abs(math.floor(y[L.PHI1] / TWO_PI)) >= REBASE_TURNS
            or abs(math.floor(y[L.PHI4] / TWO_PI)) >= REBASE_TURNS):
        return False, 0.0
    rhs(t, y, mode, P, ACT, dy, aux)
    write_sample(row, t, y, mode, aux)
    row[_PHI1] += turns1
    row[_PHI3] += turns4
    row[_PHI4] += turns4
    _, ad, _ = crank_actuator(t, ACT)
    return True, ad


@njit(cache=True, error_model='numpy', fastmath=FASTMATH, _nrt=False)
def hybrid_period(t, dt, h_fixed, F, I, LIN, events, turns1, turns4):
    """Simulator.advance(dt) then Simulator.sample() into the row, over the Simulator's blocks
    (simulator.F_*, I_*: the same arrays as its attributes): (t, code, crank rate)."""
    y = F[F_Y:F_P]
    P = F[F_P:F_ACT]
    ACT = F[F_ACT:F_S].reshape((L.N_ACT_SEGMENTS, 4))
    S = F[F_S:F_H]
    no_grid = F[:0]
    if S[AL.S_METHOD] == RK4:
        n = max(1, math.ceil(dt / h_fixed - 1e-9))
        S[AL.S_H_FIXED] = dt / n
    ms = I[I_MS:I_COUNTERS]
    counters = I[I_COUNTERS:]
    t = hybrid.advance(t, t + dt, y, ms, P, ACT, LIN, S, F[F_H:F_LEDGER], no_grid,
                       no_grid.reshape((0, N_COLUMNS)), events, counters, F[F_LEDGER:F_DY],
                       F[F_SCRATCH:F_SIZE])
    if counters[AL.C_STATUS] != AL.STATUS_OK:
        return t, UNFINISHED, 0.0
    sampled, rate = _finish(t, y, ms[0], P, ACT, turns1, turns4, F[F_DY:F_AUX],
                            F[F_AUX:F_ROW], F[F_ROW:F_SCRATCH])
    if not sampled:
        return t, UNFINISHED, 0.0
    return t, EVENTS if counters[AL.C_EVENTS] > 0 else DONE, rate


@njit(cache=True, error_model='numpy', fastmath=FASTMATH, _nrt=False)
def paths_period(t, dt, h_fixed, F, I, LIN, events, turns1, turns4):
    """PathsSimulator.advance(dt) then .sample() into its row, over its blocks
    (paths_layout.PF_*): (t, code, crank rate), as hybrid_period."""
    n = int(F[PL.PF_P + P_PATHS])
    columns = N_COLUMNS + PL.N_PATH_COLUMNS * n
    y = F[PL.PF_Y:PL.PF_Y + L.N_STATE + n]
    P = F[PL.PF_P:PL.PF_ACT]
    ACT = F[PL.PF_ACT:PL.PF_S].reshape((L.N_ACT_SEGMENTS, 4))
    S = F[PL.PF_S:PL.PF_H]
    no_grid = F[:0]
    if S[AL.S_METHOD] == RK4:
        S[AL.S_H_FIXED] = dt / max(1, math.ceil(dt / h_fixed - 1e-9))
    ms = I[I_MS:I_COUNTERS]
    counters = I[I_COUNTERS:]
    t = advance_paths(t, t + dt, y, ms, P, ACT, LIN, S, F[PL.PF_H:PL.PF_LEDGER], no_grid,
                      no_grid.reshape((0, columns)), events, counters, F[PL.PF_LEDGER:PL.PF_DY],
                      F[PL.PF_SCRATCH:PL.PF_SIZE])
    if counters[AL.C_STATUS] != AL.STATUS_OK or _rebase_due(y):
        return t, UNFINISHED, 0.0
    row = F[PL.PF_ROW:PL.PF_ROW + columns]
    paths_rhs(t, y, ms[0], P, ACT, F[PL.PF_DY:PL.PF_DY + L.N_STATE + n], F[PL.PF_AUX:PL.PF_ROW])
    write_paths_sample(row, t, y, ms[0], F[PL.PF_AUX:PL.PF_ROW], P)
    row[_PHI1] += turns1
    row[_PHI3] += turns4
    row[_PHI4] += turns4
    _, ad, _ = crank_actuator(t, ACT)
    return t, EVENTS if counters[AL.C_EVENTS] > 0 else DONE, ad


@njit(cache=True, error_model='numpy', fastmath=FASTMATH, _nrt=False)
def _rebase_due(y):
    return (abs(math.floor(y[L.PHI1] / TWO_PI)) >= REBASE_TURNS
            or abs(math.floor(y[L.PHI4] / TWO_PI)) >= REBASE_TURNS)


@njit(cache=True, error_model='numpy', fastmath=FASTMATH)   # (the averaged kernels allocate)
def averaged_period(t, dt, h_fixed, y, P, ACT, A, W1, M, R, j1e, S, grid, out, counters,
                    turns1, turns4, aux, ysample, row):
    """AveragedSimulator.advance(dt) then .sample() into ``row``: (t, code, crank rate)."""
    if S[AL.S_METHOD] == RK4:
        n = max(1, math.ceil(dt / h_fixed - 1e-9))
        S[AL.S_H_FIXED] = dt / n
    t = averaged_advance(t, t + dt, y, P, ACT, A, W1, M, R, j1e, grid, out, counters)
    if (abs(math.floor(y[L.PHI1] / TWO_PI)) >= REBASE_TURNS
            or abs(math.floor(y[L.PHI4] / TWO_PI)) >= REBASE_TURNS):
        return t, UNFINISHED, 0.0
    md = averaged_sample(t, y, P, ACT, A, W1, M, R, j1e, aux, ysample)
    write_sample(row, t, ysample, L.ENGAGED if md > 0.0 else L.DISENGAGED, aux)
    row[_PHI1] += turns1
    row[_PHI3] += turns4
    row[_PHI4] += turns4
    _, ad, _ = crank_actuator(t, ACT)
    return t, DONE, ad


class PeriodStepper:
    """A Simulator advanced ``dt`` [s] per call, in one compiled call (see the module text).

    ``row``: the sample at the end of the last period (``output.COLUMNS``; one buffer, rewritten
    by each ``advance``); ``switches``: the clutch switches inside it (ClutchSwitch, grazing
    contacts included, as Simulator.advance returns them); ``crank_rate``: the actuator's rate
    at its end [m/s]. It reads the Simulator's arrays and values at each call, so a reset,
    a parameter change or a Simulator call in between needs nothing.
    """

    def __init__(self, sim, dt):
        self.sim = sim
        self.dt = float(dt)
        self.averaged = isinstance(sim, AveragedSimulator)
        self.paths = isinstance(sim, PathsSimulator)
        # the hybrid period writes its sample into the Simulator's block (one per Simulator)
        self.row = (np.empty(N_COLUMNS) if self.averaged else sim._row if self.paths
                    else sim._floats[F_ROW:F_SCRATCH])
        self.switches = NO_SWITCHES
        self.crank_rate = 0.0
        self._aux = np.empty(L.N_AUX)
        self._ysample = np.empty(L.N_STATE)
        self._floats, self._ints, self._events = sim._floats, sim._ints, sim._events_buf

    # ------------------------------------------------------------------ time
    def advance(self):
        """One period: the sample row (the stepper's buffer). Raises SimulationError as
        Simulator.advance does (the Simulator then holds the state it failed in)."""
        sim = self.sim
        t0 = sim.t
        if self.averaged:
            m = sim.ratio_map
            sim.t, code, rate = averaged_period(
                t0, self.dt, sim.h_fixed, sim.y, sim.P, sim.ACT, m.a, m.w1, m.m, m.ratio,
                sim.j1e, sim.S, sim._empty_grid, sim._empty_out, sim.counters, sim.turns_phi1,
                sim.turns_phi4, self._aux, self._ysample, self.row)
        elif self.paths:
            sim.t, code, rate = paths_period(t0, self.dt, sim.h_fixed, self._floats, self._ints,
                                             sim.LIN, self._events, sim.turns_phi1,
                                             sim.turns_phi4)
        else:   # (the blocks and the events table are never rebound: kept at __init__)
            sim.t, code, rate = hybrid_period(t0, self.dt, sim.h_fixed, self._floats,
                                              self._ints, sim.LIN, self._events,
                                              sim.turns_phi1, sim.turns_phi4)
        if code == DONE:
            self.switches = NO_SWITCHES
            self.crank_rate = rate
            return self.row
        self.switches = sim._take_events()
        if code == EVENTS:
            self.crank_rate = rate
            return self.row
        # the rare rest, by the Simulator's own code: a full event table, a failure, a rebase
        status = AL.STATUS_OK if self.averaged else int(sim.counters[AL.C_STATUS])
        if status == AL.STATUS_EVENTS_FULL and sim.t < t0 + self.dt:
            self.switches += sim._advance_to(t0 + self.dt, sim._empty_grid, sim._empty_out)
        elif status not in (AL.STATUS_OK, AL.STATUS_EVENTS_FULL):
            raise SimulationError(sim._failure_text(status, self.switches))
        sim._rebase_angles()
        self.row[:] = sim.sample()
        self.crank_rate = float(crank_actuator(sim.t, sim.ACT)[1])
        return self.row


__all__ = ['PeriodStepper']
