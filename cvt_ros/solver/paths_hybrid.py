"""The hybrid loop of the N-path machine (issue 33): steps, every path's clutch events, the reset
map over the set of engaged clutches and the samples, in one compiled call (hybrid.py is the
one-path machine's; this is its generalization for N ≥ 2, and the independent check of it at
N = 1).

``advance_paths`` integrates from t to t_end. After every accepted step every path's guard is
watched along the whole step (paths_watch.py); the earliest crossing is reached by a step
re-taken exactly to it (one that lands short of the guard's band goes on from there, armed; one
that lands further past it than rtol × its scale is moved back, ``_settle_back``),
and the reset map (physics/path_contacts.py) decides the new engaged set there: a release, a
catch, a handoff (one path engaging as another releases) or the locked crank, by
complementarity, with an impact only where a rocker is found faster than the node (a start, a
parameter change, a catch found late: FOUND_LATE, counted in C_LATE as for one path). The whole
state is integrated in every set (no split of the open output: with N ≥ 2 some clutch is
engaged most of the time), by Dormand–Prince under hybrid.py's step-size control or by RK4 on
the fixed grid with the events located inside its steps on the Hermite continuous extension.

Arrays as hybrid.advance's (advance_layout.py), except: the state has the rocker speeds after
the one-path slots and P the path count and phase offsets after the one-path parameters
(physics/paths.py); ms = (engaged set, armed set) as bitmasks (bit k−1 = path k); event rows
carry the path (paths_layout.E_PATH), one row per clutch that switched (a handoff: two rows at
the same time).
"""
import math

import numpy as np

from ..physics.clutch import SLIP_TOLERANCE, TORQUE_TOLERANCE
from ..physics.compiled import inline_kernel, kernel
from ..physics.drives import next_actuator_break
from ..physics.dynamics import disengaged_output_rates, finite_state
from ..physics.layout import (
    N_OUTPUT,
    OMEGA3,
    OMEGA4,
    OUTPUT_STATES,
    P_C,
    P_J3,
    P_KD,
    P_LINEAR_OUTPUT,
    P_RIGID,
    TWIST,
)
from ..physics.path_contacts import settle_contacts
from ..physics.paths import (
    A_ACCEL,
    A_SLIP,
    A_SLIP_RATE,
    A_SPEED,
    MAX_PATHS,
    N_PATH_AUX,
    bit,
    n_paths,
    paths_project,
    paths_rhs,
    set_size,
    take_linkage,
)
from . import advance_layout as AL
from .advance_layout import DIP_STACK, N_MODAL
from .dense_step import sample_due
from .guard_watch import SETTLE_BANDS, SETTLE_OVERSHOOT, SETTLE_STEPS
from .hybrid import (
    ERR_OLD_START,
    FILTER_ALPHA,
    FILTER_BETA,
    MAX_EVENTS_AT_ONE_TIME,
    PI_ALPHA,
    PI_BETA,
    PI_SAFETY,
)
from .paths_layout import E_PATH, MAX_STATE
from .paths_open import N_LOOK_ROWS, open_watch
from .paths_steps import emit_paths_samples, paths_euler_step, paths_initial_step, paths_step
from .paths_watch import first_crossing, path_guard, path_guard_polynomial
from .steppers import (
    DOPRI5,
    DP_ERROR_EXPONENT,
    FULL,
    INPUT,
    MAX_FACTOR,
    MIN_FACTOR,
    RK4,
    SAFETY,
)
from .witness import N_GUARD, N_POLY, guard_rate

KIND_RELEASE = 0        # physics/clutch.py's KIND_* (the one-path event kinds)
KIND_ENGAGE = 1
KIND_ENGAGE_IMPACT = 2
KIND_GRAZE = 3
# A creep step onto a catch (``_creep_onto_catch``) is an explicit Euler step where its error
# estimate (Heun's step against it) is below this fraction of the tolerance, Dormand–Prince's
# where not
CREEP_EULER = 1e-6


@inline_kernel
def _grid_step(t, t_start, h_fixed):
    """RK4's step to the next point of its grid t_start + k·h_fixed; a remainder below the
    grid's rounding (or below what moves t at all) belongs to the step after it."""
    k = math.floor((t - t_start) / h_fixed + 1e-9) + 1.0
    h = t_start + k * h_fixed - t
    return h + h_fixed if h < max(1e-9 * h_fixed, 8.0 * 2.2e-16 * abs(t)) else h


@inline_kernel
def _growth(err, err_old, h, h_old, rejected_last):
    """The next step's factor after an accepted Dormand–Prince step: hybrid.py's controller
    (Söderlind's H211b filter after a whole accepted step, PI control otherwise, no growth
    right after a rejection)."""
    if err == 0.0:
        grow = MAX_FACTOR
    elif h_old > 0.0:
        grow = PI_SAFETY * (max(err, ERR_OLD_START) * err_old) ** -FILTER_BETA * (
            h / h_old) ** -FILTER_ALPHA
    else:
        grow = PI_SAFETY * err ** -PI_ALPHA * err_old ** PI_BETA
    grow = min(MAX_FACTOR, max(MIN_FACTOR, grow))
    return min(grow, 1.0) if rejected_last else grow


@inline_kernel
def _resized(err):
    """The step factor Dormand–Prince's error asks for (steppers.py's limits)."""
    if err == 0.0:
        return MAX_FACTOR
    return min(MAX_FACTOR, max(MIN_FACTOR, SAFETY * err ** DP_ERROR_EXPONENT))


@kernel
def _creep_onto_catch(method, t, t_end, y, y_new, K, path, mode, P, ACT, aux1, ytmp, rtol, atol,
                      grid, out, counters, dytmp, auxtmp, zs, LIN, W, ztmp):
    """Short true steps from a landing short of path's catch (y at t, K[6] and aux1 its rates)
    to the slip's band, each SETTLE_OVERSHOOT × the Newton step on the exact slip rate (as
    guard_watch.creep_onto_catch for one path); stops at the band or past it, or where a step
    would go further past zero than the first landing fell short. Returns (t, slip).
    Dormand–Prince's steps are explicit Euler steps where those are as good (CREEP_EULER; at the
    defaults ~1e-10 s long, one right-hand side instead of six), else its own."""
    g = aux1[A_SLIP + path]
    first = g
    n = y.shape[0]
    if g > SETTLE_BANDS * path_guard(path, mode, aux1, P)[1]:
        return t, g
    for _ in range(SETTLE_STEPS):
        rate = aux1[A_SLIP_RATE + path]
        dt = SETTLE_OVERSHOOT * g / -rate if rate < 0.0 else -1.0
        if not (dt > 0.0 and t + dt <= t_end):
            break
        for i in range(n):
            K[0, i] = K[6, i]
        stepper = method
        if method != DOPRI5 or paths_euler_step(t, y, dt, mode, P, ACT, K, y_new, aux1, rtol,
                                                atol, counters) > CREEP_EULER:
            paths_step(method, FULL, t, y, dt, mode, P, ACT, K, y_new, ytmp, aux1, rtol, atol,
                       counters)
        else:
            stepper = RK4   # (its samples from the Hermite cubic of y, y_new, K[0], K[6])
        if aux1[A_SLIP + path] < -first:   # too far past: stay (aux1 back at y)
            paths_rhs(t, y, mode, P, ACT, K[6], aux1)
            counters[AL.C_RHS] += 1
            break
        if sample_due(grid, counters, t + dt):
            emit_paths_samples(stepper, t, dt, y, y_new, K, mode, P, ACT, grid, out, counters,
                               t + dt, ytmp, dytmp, auxtmp, False, zs, LIN, W, ztmp)
        t += dt
        for i in range(n):
            y[i] = y_new[i]
        g = aux1[A_SLIP + path]
        if g <= path_guard(path, mode, aux1, P)[1]:
            break
    return t, g


@kernel
def _settle_back(method, t, h_whole, theta, y, y_new, K, path, mode, P, ACT, G, aux1, ytmp, rtol,
                 atol, counters):
    """θ of the re-taken step's landing on path's switch, moved back where it fell further past
    the guard than rtol × the guard's scale (guard_watch.watch_step's settling for one path): the
    true step re-taken to θ follows the state, not the long step's dense output, and at a loose
    rtol crosses before it (rtol 1e-4, a 6.7 ms engaged step: a release placed at −4.8e-3 N·m,
    10 µs past, on a 10 N·m machine). Newton steps on the guard polynomial's rate G (of the whole
    step), aimed just past zero (SETTLE_OVERSHOOT, at most half the bound), each a true step
    re-taken (y_new, K[6], aux1 there); never forwards."""
    for _ in range(SETTLE_STEPS):
        g, band = path_guard(path, mode, aux1, P)
        bound = rtol * band / (TORQUE_TOLERANCE if mode & bit(path) else SLIP_TOLERANCE)
        rate = guard_rate(G, theta)
        if not (g < -bound and rate < 0.0):
            break
        back = theta - (g + min((SETTLE_OVERSHOOT - 1.0) * abs(g), 0.5 * bound)) / rate
        if not 0.0 < back < theta:
            break
        theta = back
        paths_step(method, FULL, t, y, theta * h_whole, mode, P, ACT, K, y_new, ytmp, aux1, rtol,
                   atol, counters)
    return theta


@inline_kernel
def _guards(mode, aux, P, g):
    """Every path's guard into g; returns the set of paths whose guard is outside its band."""
    outside = 0
    for k in range(n_paths(P)):
        g[k], band = path_guard(k, mode, aux, P)
        if abs(g[k]) > band:
            outside |= bit(k)
    return outside


@kernel
def _record(events, counters, t, old, new, struck, path, value, late, npaths):
    """The event rows of a reset: one per clutch that switched (``value``, the guard where the
    switch was placed, on the row of ``path``), or a graze of ``path`` when none did."""
    changed = old ^ new
    e = counters[AL.C_EVENTS]
    for k in range(npaths):
        if not (changed & bit(k) or changed == 0 and k == path):
            continue
        if changed == 0:
            kind = KIND_GRAZE
        elif new & bit(k):
            kind = KIND_ENGAGE_IMPACT if struck & bit(k) else KIND_ENGAGE
        else:
            kind = KIND_RELEASE
        events[e, AL.E_T] = t
        events[e, AL.E_MODE] = new
        events[e, AL.E_KIND] = kind
        events[e, AL.E_VALUE] = value if k == path else 0.0
        events[e, AL.E_LATE] = 1.0 if late else 0.0
        events[e, E_PATH] = k
        e += 1
    counters[AL.C_EVENTS] = e


@inline_kernel
def _freeze_output(K0):
    """K0 as the rates of an INPUT step: the open output's held at zero (it runs apart)."""
    for i in OUTPUT_STATES:
        K0[i] = 0.0


@inline_kernel
def _open_slips(y, P, aux):
    """Every path's slip and slip rate in aux at a split step's end (paths_open.py): the
    right-hand side there saw the output frozen at the step's start; y holds the exact one."""
    _, dw3, _, _, _ = disengaged_output_rates(y[TWIST], y[OMEGA3], y[OMEGA4], P)
    for k in range(n_paths(P)):
        aux[A_SLIP + k] = y[OMEGA3] - aux[A_SPEED + k]
        aux[A_SLIP_RATE + k] = dw3 - aux[A_ACCEL + k]


@kernel
def advance_paths(t, t_end, y, ms, P, ACT, LIN, S, h_io, grid, out, events, counters, ledger,
                  scratch):
    """Integrate the N-path machine from t to t_end [s]; returns the time reached (module
    text; the arguments as hybrid.advance's)."""
    method = int(S[AL.S_METHOD])
    rtol = S[AL.S_RTOL]
    atol = S[AL.S_ATOL]
    # the working arrays, carved out of scratch as paths_layout.N_PATH_SCRATCH counts them
    n = y.shape[0]
    m = MAX_STATE
    K = scratch[0:7 * n].reshape((7, n))
    states = scratch[7 * m:11 * m].reshape((4, m))
    y_new, ytmp, dytmp, ycomb = states[0, :n], states[1, :n], states[2, :n], states[3, :n]
    auxes = scratch[11 * m:11 * m + 3 * N_PATH_AUX].reshape((3, N_PATH_AUX))
    aux0, aux1, auxtmp = auxes[0], auxes[1], auxes[2]
    rest = scratch[11 * m + 3 * N_PATH_AUX:]
    C = rest[:3 * N_POLY].reshape((3, N_POLY))
    G = rest[3 * N_POLY:3 * N_POLY + N_GUARD]
    npaths = n_paths(P)
    o = 3 * N_POLY + N_GUARD
    guards = rest[o:o + 2 * MAX_PATHS]
    g0, g1 = guards[:npaths], guards[MAX_PATHS:MAX_PATHS + npaths]
    o += 2 * MAX_PATHS
    # the open output's: its state at the step's start, look and end, its modal coordinates,
    # the dip stack, every rocker speed's polynomial, the looks' per-path rows (paths_open.py)
    outputs = rest[o:o + 4 * N_OUTPUT].reshape((4, N_OUTPUT))
    zs, z, z_new, ztmp = outputs[0], outputs[1], outputs[2], outputs[3]
    o += 4 * N_OUTPUT
    W = rest[o:o + N_MODAL].view(np.complex128).reshape((2, 3))
    o += N_MODAL
    stack = rest[o:o + 6 * DIP_STACK].reshape((6, DIP_STACK))
    o += 6 * DIP_STACK
    Cv = rest[o:o + MAX_PATHS * N_POLY].reshape((MAX_PATHS, N_POLY))
    o += MAX_PATHS * N_POLY
    looks = rest[o:o + N_LOOK_ROWS * MAX_PATHS].reshape((N_LOOK_ROWS, MAX_PATHS))
    massless_undamped = P[P_J3] == 0.0 and P[P_KD] == 0.0 and P[P_RIGID] == 0.0
    # with every clutch open a linear elastic output runs apart, solved exactly
    can_split = P[P_LINEAR_OUTPUT] > 0.0 and P[P_RIGID] == 0.0 and P[P_J3] > 0.0
    mode = ms[0]
    armed = ms[1]
    counters[AL.C_STATUS] = AL.STATUS_OK

    paths_rhs(t, y, mode, P, ACT, K[0], aux0)
    counters[AL.C_RHS] += 1
    split = can_split and mode == 0
    if split:
        _freeze_output(K[0])
    armed |= _guards(mode, aux0, P, g0)
    h_prop = h_io[AL.H_MAIN]
    if method == DOPRI5 and h_prop <= 0.0:
        h_prop = paths_initial_step(INPUT if split else FULL, t, y, mode, P, ACT, K[0], rtol,
                                    atol, ytmp, dytmp, auxtmp)
        counters[AL.C_RHS] += 1
    err_old = ERR_OLD_START
    t_start = t
    h_fixed = S[AL.S_H_FIXED]
    t_last_event = -math.inf
    stalled = 0
    steps0 = counters[AL.C_STEPS]
    rejected_last = False
    restarted = False
    h_old = -1.0

    while t < t_end:
        if counters[AL.C_STEPS] - steps0 > S[AL.S_STEP_BUDGET]:
            counters[AL.C_STATUS] = AL.STATUS_NO_PROGRESS
            break
        h = min(h_prop, S[AL.S_MAX_STEP]) if method == DOPRI5 else _grid_step(t, t_start, h_fixed)
        # cut at t_end and at the actuator's next break (where a'' jumps)
        end = min(t_end, next_actuator_break(t, ACT))
        clipped = t + h >= end
        if clipped:
            h = end - t
        if h <= 0.0:
            break
        split = can_split and mode == 0
        err = paths_step(method, INPUT if split else FULL, t, y, h, mode, P, ACT, K, y_new, ytmp,
                         aux1, rtol, atol, counters)
        counters[AL.C_STEPS] += 1
        counters[AL.C_ENGAGED_STEPS] += 1 if mode != 0 else 0
        factor = 1.0
        if method == DOPRI5:
            finite = finite_state(y_new)
            if not (err <= 1.0 and finite):   # rejected: smaller, never larger, or give up
                counters[AL.C_REJECTED] += 1
                h_prop = h * min(_resized(err) if finite else MIN_FACTOR, 1.0)
                rejected_last = True
                h_old = -1.0
                if h_prop < 1e-14 * max(1.0, abs(t)):
                    counters[AL.C_STATUS] = AL.STATUS_STEP_TOO_SMALL
                    break
                continue
            factor = _growth(err, err_old, h, h_old, rejected_last)
            h_old = -1.0 if clipped else h
            if restarted and not clipped:   # the cap of the first step after such a switch
                h_io[AL.H_RESTART + (1 if mode else 0)] = h * _resized(err)
            restarted = False
            err_old = max(err, ERR_OLD_START)
            rejected_last = False
        elif not finite_state(y_new):
            counters[AL.C_STATUS] = AL.STATUS_NONFINITE
            break

        h_found = h   # the step the event was found in (the restart's scale)
        t_whole = t_end if (clipped and t + h >= t_end) else t + h
        if split:
            # every clutch open: the output apart, exactly; the slips watched on it
            t_new, path, fire, armed = open_watch(
                method, t, h, y, y_new, K, P, ACT, LIN, W, zs, z, z_new, ztmp, stack, Cv, looks,
                armed, g0, rtol, atol, aux1, ytmp, ycomb, dytmp, auxtmp, counters)
            _open_slips(y_new, P, aux1)
            if fire == AL.NO_EVENT:
                t_new = t_whole
            else:
                h = t_new - t
        else:
            theta, path, fire = first_crossing(armed, g0, g1, method, t, h, y, y_new, K, mode,
                                               P, ACT, aux1, C, G, ytmp, dytmp, auxtmp, zs, LIN,
                                               W, ztmp, counters)
            if fire == AL.NO_EVENT or fire == AL.FOUND_LATE:
                t_new = t_whole
            else:
                # a true step re-taken to the located switch (the guard's polynomial over the
                # whole step first: a landing too far past is moved back on its rate)
                poly = path_guard_polynomial(path, method, h, y, y_new, K, mode, P, C, G)
                h_whole = h
                h = theta * h
                paths_step(method, FULL, t, y, h, mode, P, ACT, K, y_new, ytmp, aux1, rtol,
                           atol, counters)
                if poly:
                    h = _settle_back(method, t, h_whole, theta, y, y_new, K, path, mode, P, ACT,
                                     G, aux1, ytmp, rtol, atol, counters) * h_whole
                t_new = t + h
        if sample_due(grid, counters, t_new):
            emit_paths_samples(method, t, h, y, y_new, K, mode, P, ACT, grid, out, counters,
                               t_new, ytmp, dytmp, auxtmp, split, zs, LIN, W, ztmp)
        t = t_new
        for i in range(n):
            y[i] = y_new[i]
        value, band = path_guard(path, mode, aux1, P) if path >= 0 else (0.0, 0.0)
        if fire == AL.CROSSING and value > band and not mode & bit(path):
            # a catch whose re-taken step landed short of the slip's band by the dense
            # output's error: true steps on by Newton on the slip's exact rate (a new step
            # would find the catch again at its very start: a sliver and a restart more)
            if split:   # (short whole-state steps: the rates of the whole state first)
                paths_rhs(t, y, mode, P, ACT, K[6], aux1)
                counters[AL.C_RHS] += 1
            t, value = _creep_onto_catch(method, t, t_end, y, y_new, K, path, mode, P, ACT,
                                         aux1, ytmp, rtol, atol, grid, out, counters, dytmp,
                                         auxtmp, zs, LIN, W, ztmp)
        if fire == AL.NO_EVENT or (fire == AL.CROSSING and value > band):
            # no switch, or the true state has not reached the guard yet: go on from here
            if fire == AL.NO_EVENT:
                h_prop = max(h_prop, h * factor) if clipped else h * factor
            take_linkage(aux1, auxtmp, P)   # (aux1: the right-hand side at y)
            paths_project(t, y, mode, P, ACT, auxtmp)
            for i in range(n):
                K[0, i] = K[6, i]
            if split:
                _freeze_output(K[0])
            armed |= _guards(mode, aux1, P, g0)
            continue

        # ---- reset map: the new engaged set (physics/path_contacts.py)
        old = mode
        exclude = 0
        take_linkage(aux1, auxtmp, P)
        paths_project(t, y, old, P, ACT, auxtmp)
        take_linkage(auxtmp, aux0, P)
        if old & bit(path):   # a release: the path leaves the set and is not re-decided
            exclude = bit(path)
            mode = old & ~exclude
            if mode == 0 and massless_undamped:
                # an undamped massless node carries no torque when open, so no twist: what is
                # left of it (the release's location error) snaps back, its energy lost
                ledger[0] += 0.5 * P[P_C] * y[TWIST] ** 2
                y[TWIST] = 0.0
        mode, struck, loss = settle_contacts(t, y, mode, exclude, fire == AL.FOUND_LATE, P, ACT,
                                             K[0], aux0, ytmp, dytmp)
        ledger[0] += loss
        counters[AL.C_RHS] += 4
        _record(events, counters, t, old, mode, struck, path, value, fire == AL.FOUND_LATE, npaths)
        switched = set_size(old ^ mode)
        counters[AL.C_SWITCHES] += switched
        if fire == AL.FOUND_LATE and switched:
            counters[AL.C_LATE] += 1
        # half-open rule: a guard at zero after the reset is disarmed until it leaves its band
        armed = _guards(mode, aux0, P, g0)
        split = can_split and mode == 0
        if split:
            _freeze_output(K[0])
        if method == DOPRI5 and switched:
            # a fresh start in the new set (hybrid.py: its dynamics differ), capped by the first
            # step accepted after the last switch into an engaged (or open) machine, and by 4×
            # the step the event was found in (not the step re-taken to it: found just after a
            # landing short of it, that one is a sliver)
            h_new = paths_initial_step(INPUT if split else FULL, t, y, mode, P, ACT, K[0], rtol,
                                       atol, ytmp, dytmp, auxtmp)
            counters[AL.C_RHS] += 1
            h_prop = min(h_new, 4.0 * h_found) if h_new > 0.0 else h_prop
            cap = h_io[AL.H_RESTART + (1 if mode else 0)]
            if cap > 0.0:
                h_prop = min(h_prop, cap)
            restarted = True
            err_old = ERR_OLD_START
            h_old = -1.0
        # resets without the time moving on (the automaton would loop), or a full event table
        stalled = stalled + 1 if t <= t_last_event else 0
        t_last_event = max(t, t_last_event)
        if stalled > MAX_EVENTS_AT_ONE_TIME or counters[AL.C_EVENTS] >= events.shape[0] - npaths:
            counters[AL.C_STATUS] = (AL.STATUS_ZENO if stalled > MAX_EVENTS_AT_ONE_TIME
                                     else AL.STATUS_EVENTS_FULL)
            break
    ms[0] = mode
    ms[1] = armed
    h_io[AL.H_MAIN] = h_prop
    return t
