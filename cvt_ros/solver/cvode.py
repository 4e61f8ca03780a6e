"""SUNDIALS CVODE (BDF or Adams) as a driver of the same equations, a peer of solver/reference.py.

CVODE comes from scikit-sundae (``sksundae.cvode.CVODE``, SUNDIALS bundled in its wheel): the
sundials4py package has no wheel for this platform. The driver mirrors ``solve_reference``: one
CVODE instance per clutch mode on the compiled right-hand side of that mode (physics/dynamics.rhs),
the clutch guard of that mode as CVODE's root function (direction −1, terminal), and at a root the
automaton's reset map, as the compiled solver applies it: release / engage by complementarity /
graze (no switch), then ``project`` and a restart (CVodeReInit) of the new mode's instance.

What is compiled: the right-hand side and the guard (numba kernels, the same machine code the
reference uses, called on SUNDIALS' own memory: no copies). What is not: scikit-sundae calls
Python callables only (no C function pointer), so every RHS and root evaluation passes through a
Python wrapper (N_Vector → numpy view, then the kernel's dispatch); ``callback_overhead`` measures
that cost against the kernel's own. The Jacobian is SUNDIALS' dense difference quotient
(N_STATE RHS calls per Jacobian, counted in ``nfev``).
"""
import time
from dataclasses import dataclass

import numpy as np

from ..physics import layout as L
from ..physics.clutch import clutch_guard
from ..physics.compiled import kernel
from ..physics.dynamics import project, rhs
from .reference import ReferenceResult, initial_state, next_mode
from .simulator import Simulator

METHODS = ('BDF', 'Adams')
MAX_NUM_STEPS = 10_000_000   # per CVode call (one segment between switches); scikit's default 500


def available():
    """None if CVODE can be used, else a one-line reason."""
    try:
        import sksundae.cvode  # noqa: F401
    except ImportError as exc:
        return f'SUNDIALS CVODE not available (pip install scikit-sundae: {exc})'
    return None


@kernel
def mode_guard(t, y, mode, P, ACT, dy, aux):
    """The clutch guard of ``mode`` at (t, y): the root function CVODE locates."""
    rhs(t, y, mode, P, ACT, dy, aux)
    return clutch_guard(mode, y, dy, aux, P)[0]


@kernel
def _rhs_loop(t, y, mode, P, ACT, dy, aux, n):
    for _ in range(n):
        rhs(t, y, mode, P, ACT, dy, aux)
    return dy[0]


@dataclass
class CvodeResult(ReferenceResult):
    """ReferenceResult (nfev: the difference-quotient Jacobian's RHS calls included) and:"""
    njev: int = 0          # Jacobian evaluations
    steps: int = 0         # CVode calls (segments between roots)


class _ModeSolver:
    """One CVODE instance integrating the dynamics of one clutch mode, its guard as a root."""

    def __init__(self, mode, P, ACT, method, rtol, atol, max_step):
        from sksundae.cvode import CVODE
        aux_rhs = np.empty(L.N_AUX)
        dy = np.empty(L.N_STATE)
        aux = np.empty(L.N_AUX)

        def rhsfn(t, y, yp):
            rhs(t, y, mode, P, ACT, yp, aux_rhs)

        def guardfn(t, y, g):
            g[0] = mode_guard(t, y, mode, P, ACT, dy, aux)

        guardfn.terminal = [True]
        guardfn.direction = [-1]
        self.guard = guardfn
        self.solver = CVODE(rhsfn, method=method, rtol=rtol, atol=atol, max_step=max_step,
                            eventsfn=guardfn, num_events=1, max_num_steps=MAX_NUM_STEPS)

    def start(self, t, y):
        self.solver.init_step(t, y)
        self.nfev = self.njev = 0

    def advance(self, t_end):
        out = self.solver.step(t_end, method='normal', tstop=t_end)
        self.nfev, self.njev = out.nfev, out.njev   # since the last (re)start
        # scikit-sundae keeps every root it has returned on the function object and turns the
        # whole list into arrays at each call: forget them (we read the root from ``out``)
        for name in ('_i', '_t', '_y'):
            getattr(self.guard, name).clear()
        self.guard._i_cnt[:] = 0
        return out


def solve_cvode(values, t_end, method='BDF', rtol=1e-8, atol=None, max_step=0.0,
                max_switches=100000, start=None):
    """Integrate a scene from its initial state (or from the Simulator ``start``'s state, at its
    time) to t_end [s] with CVODE; returns the final state, the switch times and modes, and the
    RHS count. atol defaults to 1e-2·rtol (as every method of the benchmark). Raises ImportError
    without scikit-sundae and RuntimeError when CVODE fails."""
    if method not in METHODS:
        raise ValueError(f"CVODE method {method!r}: one of {', '.join(METHODS)}")
    atol = rtol * 1e-2 if atol is None else atol
    P, ACT, t, y, mode = initial_state(values, start)
    dy = np.empty(L.N_STATE)
    aux = np.empty(L.N_AUX)
    scratch = np.empty(L.N_STATE)
    result = CvodeResult(t=t, y=y)
    wall0 = time.perf_counter()
    solvers = {m: _ModeSolver(m, P, ACT, method, rtol, atol, max_step)
               for m in (L.ENGAGED, L.DISENGAGED)}
    active = solvers[mode]
    active.start(t, y)
    while t < t_end and len(result.switch_times) < max_switches:
        out = active.advance(t_end)
        result.steps += 1
        if not out.success:
            raise RuntimeError(f"CVODE failed at t = {out.t:.9g}: {out.message}")
        t, y = float(out.t), np.array(out.y)
        if out.status != 2:       # CV_TSTOP_RETURN / CV_SUCCESS: at t_end
            break
        new = next_mode(t, y, mode, P, ACT, dy, aux, scratch)
        if new is None:
            continue              # no switch: CVODE goes on past the root, no restart
        mode = new
        _count(result, active)
        project(t, y, mode, P, ACT)
        result.switch_times.append(t)
        result.switch_modes.append(mode)
        active = solvers[mode]
        active.start(t, y)        # CVodeReInit: order 1, a fresh step-size estimate
    _count(result, active)
    result.t = t
    result.y = y
    result.wall_time = time.perf_counter() - wall0
    return result


def _count(result, mode_solver):
    """Add the RHS and Jacobian counts of a segment (CVodeReInit resets SUNDIALS' counters)."""
    result.nfev += mode_solver.nfev + L.N_STATE * mode_solver.njev
    result.njev += mode_solver.njev


def callback_overhead(values, t_end=0.2, method='BDF', rtol=1e-8, calls=20000):
    """Where CVODE's time goes, per RHS evaluation [s]: the kernel alone (in a compiled loop), the
    kernel called from Python (numba's dispatch), and CVODE's wall time per RHS evaluation on the
    scene (wrapper, views, SUNDIALS' own work and the root function included)."""
    sim = Simulator(values)
    P, ACT, mode = sim.P, sim.ACT, int(sim.ms[0])
    y = sim.y.copy()
    y.flags.writeable = False          # as SUNDIALS hands it over (numba: its own specialization)
    dy, aux = np.empty(L.N_STATE), np.empty(L.N_AUX)
    _rhs_loop(0.0, sim.y, mode, P, ACT, dy, aux, 1)
    rhs(0.0, y, mode, P, ACT, dy, aux)
    t0 = time.perf_counter()
    _rhs_loop(0.0, sim.y, mode, P, ACT, dy, aux, calls)
    kernel_s = (time.perf_counter() - t0) / calls
    t0 = time.perf_counter()
    for _ in range(calls):
        rhs(0.0, y, mode, P, ACT, dy, aux)
    python_s = (time.perf_counter() - t0) / calls
    solve_cvode(values, 0.01, method=method, rtol=rtol)      # warm: the readonly specializations
    r = solve_cvode(values, t_end, method=method, rtol=rtol)
    return {'kernel_s': kernel_s, 'python_call_s': python_s,
            'cvode_per_rhs_s': r.wall_time / r.nfev, 'nfev': r.nfev, 'wall_s': r.wall_time}
