"""One measured run: the project's simulator or a scipy / CVODE baseline, timed, with its end
state.

Shared by every benchmark: ``run_project`` / ``run_scipy`` / ``run_cvode`` return an Outcome
(final φ4, ω4, the switch times, wall time, cost); ``timed`` repeats a run and keeps the minimum
wall time; ``run_watched`` runs the simulator in a child process so that a run which hangs in
compiled code (it cannot be interrupted in-process) is reported instead of stopping the
benchmark.
"""
import math
import multiprocessing
import time
from dataclasses import dataclass

import numpy as np

from ..solver import advance_layout as AL
from ..solver.cvode import solve_cvode
from ..solver.output import COL
from ..solver.reference import solve_reference
from ..solver.simulator import Simulator

BLOWUP_RESIDUAL = 1e-2     # relative energy residual that counts as a blow-up


@dataclass
class Outcome:
    """One integration: final φ4, ω4 [rad, rad/s], switch times [s], wall time [s], cost."""
    phi4: float
    omega4: float
    switches: list
    wall: float
    work: int = 0              # steps (project) or RHS evaluations (scipy, CVODE)
    energy: float = math.nan   # relative energy residual (project)
    h: float = math.nan        # effective fixed step (rk4)
    rejected: int = 0          # rejected steps (project dopri5)


def run_project(values, duration):
    sim = Simulator(values)
    steps0, rejected0 = int(sim.counters[AL.C_STEPS]), int(sim.counters[AL.C_REJECTED])
    t0 = time.perf_counter()
    switches = sim.advance(duration)
    wall = time.perf_counter() - t0
    row = sim.sample()
    return Outcome(float(row[COL['phi4']]), float(row[COL['omega4']]),
                   [s.t for s in switches if s.kind != 'graze'], wall,
                   int(sim.counters[AL.C_STEPS]) - steps0,
                   sim.energy_balance()['relative_residual'], sim.h_fixed,
                   int(sim.counters[AL.C_REJECTED]) - rejected0)


def run_scipy(values, duration, method, rtol):
    r = solve_reference(values, duration, method=method, rtol=rtol, atol=rtol * 1e-2)
    if r.t < duration * (1.0 - 1e-12):
        raise RuntimeError(f"stopped at t = {r.t:.6g} s")
    return Outcome(float(r.y[6]), float(r.y[7]), list(r.switch_times), r.wall_time, r.nfev)


def run_cvode(values, duration, method, rtol):
    r = solve_cvode(values, duration, method=method, rtol=rtol, atol=rtol * 1e-2)
    if r.t < duration * (1.0 - 1e-12):
        raise RuntimeError(f"stopped at t = {r.t:.6g} s")
    return Outcome(float(r.y[6]), float(r.y[7]), list(r.switch_times), r.wall_time, r.nfev)


def repeats_for(wall, quick):
    """How often a run is timed (after the warm-up), given its first time [s]."""
    if quick:
        return 2 if wall < 0.5 else 1
    if wall < 0.3:
        return 5
    if wall < 1.0:
        return 3
    if wall < 3.0:
        return 2
    return 1


def timed(fn, quick):
    """(outcome, min wall, repeats): ``fn`` is run once, then repeated; the minimum counts."""
    first = fn()
    walls = [first.wall]
    for _ in range(repeats_for(first.wall, quick) - 1):
        walls.append(fn().wall)
    return first, min(walls), len(walls)


def relative(x, ref):
    return abs(x - ref) / abs(ref) if ref != 0.0 else abs(x - ref)


def switch_error(switches, ref_switches):
    if len(switches) != len(ref_switches):
        return math.nan
    if not switches:
        return 0.0
    return float(np.max(np.abs(np.subtract(switches, ref_switches))))


def _long_child(values, marks, conn, t0):
    """Child process of the long run: one row per checkpoint through the pipe. The clock
    starts at t0 (only for time-invariant scenes: no crank-length command)."""
    sim = Simulator(values)
    sim.t = t0
    wall = 0.0
    for t_mark in marks:
        t0 = time.perf_counter()
        sim.advance(t_mark - sim.t)
        wall += time.perf_counter() - t0
        s = sim.sample()
        e = sim.energy_balance()
        conn.send({'t': t_mark, 'phi1': float(s[COL['phi1']]), 'phi4': float(s[COL['phi4']]),
                   'energy': e['relative_residual'], 'constraint': abs(float(s[COL['constraint']])),
                   'wall': wall, 'switches': sim.switch_count})
    conn.close()


def run_watched(values, marks, first_timeout=120.0, slack=4.0, min_timeout=20.0, t0=0.0):
    """Run ``values`` to each checkpoint in a child process; a checkpoint that does not arrive
    within ``slack`` times the expected wall time (from the previous ones) means the run hangs
    (compiled code cannot be interrupted in-process). Returns (rows, None) or (rows, hang text)."""
    ctx = multiprocessing.get_context('fork')
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_long_child, args=(values, marks, child, t0), daemon=True)
    proc.start()
    child.close()
    rows, problem, t_prev = [], None, t0
    for t_mark in marks:
        if rows:
            rate = max(rows[-1]['wall'], 1e-3) / (rows[-1]['t'] - t0)
            timeout = max(min_timeout, slack * rate * (t_mark - t_prev))
        else:
            timeout = first_timeout
        if parent.poll(timeout):
            try:
                rows.append(parent.recv())
            except EOFError:
                problem = f'the run stopped between t = {t_prev:g} s and {t_mark:g} s'
                break
            t_prev = t_mark
        else:
            problem = (f'no progress from t = {t_prev:g} s to {t_mark:g} s within {timeout:.0f} s '
                       f'of wall time (expected ~{timeout / slack:.0f} s): hangs')
            proc.terminate()
            break
    proc.join(5.0)
    if proc.is_alive():
        proc.kill()
        proc.join()
    return rows, problem
