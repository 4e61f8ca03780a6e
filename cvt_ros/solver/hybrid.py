"""The hybrid integration loop: steps, clutch events, resets and samples, all in one compiled call.

``advance`` integrates from t to t_end in the current clutch mode. After every accepted step the
clutch witness function is watched along the whole step (guard_watch.py; while the clutch is
open, the slip by the open output's watch, slip_watch.py): a crossing found there is reached by a
true step re-taken exactly to it, the automaton's reset map (physics/clutch.py) applies here and
the run goes on in the new mode with a fresh starting step for it. A guard found beyond its band
after a step ('late') is switched at once and counted (C_LATE): a possibly missed event that the
caller reports. Samples on a caller-given grid are written from the dense output, so sampling
never shortens a step.

Step size: Dormand–Prince's error estimate through Söderlind's H211b digital filter (PI control,
Hairer's DOPRI5 constants, for a step without a whole accepted one before it), restarted after
each switch by the Hairer–Nørsett–Wanner estimate in the new mode.

While the clutch is open an elastic output with J3 > 0 (or a massless damped node) runs apart
from the input (slip_watch.py): exactly when it is linear, else on its own clock.
The loop never leaves compiled code between events.
"""
import math

import numpy as np

from ..physics.clutch import (
    KIND_ENGAGE,
    KIND_ENGAGE_IMPACT,
    KIND_GRAZE,
    KIND_RELEASE,
    clutch_engages,
    clutch_guard,
    guard_tolerance,
)
from ..physics.compiled import kernel
from ..physics.drives import next_actuator_break
from ..physics.dynamics import engage_with_impact, finite_state, project, rhs
from ..physics.layout import (
    AUX_SLIP,
    DISENGAGED,
    ENGAGED,
    N_AUX,
    N_OUTPUT,
    N_STATE,
    OUTPUT_STATES,
    P_C,
    P_J3,
    P_KD,
    P_LINEAR_OUTPUT,
    P_RIGID,
    TWIST,
)
from .advance_layout import (
    C_ENGAGED_STEPS,
    C_EVENTS,
    C_LATE,
    C_REJECTED,
    C_RHS,
    C_STATUS,
    C_STEPS,
    C_SWITCHES,
    CROSSING,
    DIP_STACK,
    E_KIND,
    E_LATE,
    E_MODE,
    E_T,
    E_VALUE,
    FOUND_LATE,
    H_MAIN,
    H_RESTART,
    N_MODAL,
    NO_EVENT,
    S_ATOL,
    S_H_FIXED,
    S_MAX_STEP,
    S_METHOD,
    S_RTOL,
    S_STEP_BUDGET,
    STATUS_EVENTS_FULL,
    STATUS_NO_PROGRESS,
    STATUS_NONFINITE,
    STATUS_OK,
    STATUS_STEP_TOO_SMALL,
    STATUS_ZENO,
)
from .dense_step import take_step, twist_relaxes
from .guard_watch import creep_onto_catch, relax_twist, watch_step
from .slip_watch import split_output
from .steppers import (
    DOPRI5,
    DP_ERROR_EXPONENT,
    ERR_FULL,
    ERR_INPUT,
    ERR_MASSLESS,
    FULL,
    INPUT,
    MASSLESS,
    MAX_FACTOR,
    MIN_FACTOR,
    SAFETY,
    initial_step,
)
from .witness import N_GUARD, N_POLY

MAX_EVENTS_AT_ONE_TIME = 8
PI_BETA = 0.04           # Hairer's DOPRI5: h·err^−(0.2 − 0.75β)·err_old^β
PI_ALPHA = 0.2 - 0.75 * PI_BETA
PI_SAFETY = 0.8
# Söderlind's H211b digital filter (b = 4, k = 5): h·(err·err_old)^(−1/(b·k))·(h/h_old)^(−1/b).
# Where the rocker's speed makes the error estimate swing between steps of nearly the same size
# (its leading term changes sign several times a crank turn), the PI controller grew the step
# into the next lobe and had it rejected once or twice a turn, at some tolerances and not at
# others; the filter smooths the step sequence instead (BENCHMARKS.md, Stepping experiments)
FILTER_B = 4.0
FILTER_BETA = 1.0 / (FILTER_B * 5.0)
FILTER_ALPHA = 1.0 / FILTER_B
ERR_OLD_START = 1e-4


@kernel
def advance(t, t_end, y, ms, P, ACT, LIN, S, h_io, grid, out, events, counters, ledger, scratch):
    """Integrate the hybrid system from t to t_end [s]; returns the time reached.

    y: state (in/out); ms: int64[2] (clutch mode, guard armed); LIN: modal form of the linear
    output subsystem (physics/output_exact.py); S: settings (S_*);
    h_io: float[N_PROPOSALS] step-size proposals (H_*) carried between calls (≤ 0: choose);
    grid/out: sample times and rows (counters[C_NEXT_SAMPLE] is the next one to fill);
    events: rows (t, new mode, kind, value, late); ledger: float[1] kinetic energy lost in late
    (impact) engagements [J].
    scratch: float[N_SCRATCH], the working arrays of the call (nothing is allocated per call).
    Stops early with counters[C_STATUS] ≠ 0 when the event table is full, a step fails or the
    step budget S_STEP_BUDGET is spent.
    """
    method = int(S[S_METHOD])
    rtol = S[S_RTOL]
    atol = S[S_ATOL]
    n = N_STATE
    K = scratch[0:7 * n].reshape((7, n))
    o = 7 * n
    y_new = scratch[o:o + n]
    ytmp = scratch[o + n:o + 2 * n]
    dytmp = scratch[o + 2 * n:o + 3 * n]
    ycomb = scratch[o + 3 * n:o + 4 * n]
    o += 4 * n
    aux0 = scratch[o:o + N_AUX]
    aux1 = scratch[o + N_AUX:o + 2 * N_AUX]
    auxtmp = scratch[o + 2 * N_AUX:o + 3 * N_AUX]
    o += 3 * N_AUX
    Ko = scratch[o:o + 7 * N_OUTPUT].reshape((7, N_OUTPUT))
    o += 7 * N_OUTPUT
    z = scratch[o:o + N_OUTPUT]
    z_new = scratch[o + N_OUTPUT:o + 2 * N_OUTPUT]
    ztmp = scratch[o + 2 * N_OUTPUT:o + 3 * N_OUTPUT]
    zs = scratch[o + 3 * N_OUTPUT:o + 4 * N_OUTPUT]
    o += 4 * N_OUTPUT
    C = scratch[o:o + 3 * N_POLY].reshape((3, N_POLY))
    G = scratch[o + 3 * N_POLY:o + 3 * N_POLY + N_GUARD]
    o += 3 * N_POLY + N_GUARD
    W = scratch[o:o + N_MODAL].view(np.complex128).reshape((2, 3))   # modal coordinates
    o += N_MODAL
    stack = scratch[o:o + 6 * DIP_STACK].reshape((6, DIP_STACK))
    exact = P[P_LINEAR_OUTPUT] > 0.0
    # a disengaged elastic output with J3 > 0 runs apart from the input (see split_output):
    # exactly when it is linear, else on its own clock. rk4 too: stepped with the input at a
    # fixed h·λ ≤ 0.5, the undamped ringing drifts in phase (1e-4 rad a step) until, over a long
    # open phase, a catch the ring's bottom grazes is missed (stiff shaft: 1373 switches in 5 s
    # against 1447)
    can_split = P[P_RIGID] == 0.0 and P[P_J3] > 0.0
    clock = (Ko, zs, LIN, W, stack)
    mode = ms[0]
    armed = ms[1] == 1
    counters[C_STATUS] = STATUS_OK

    rhs(t, y, mode, P, ACT, K[0], aux0)
    counters[C_RHS] += 1
    g0, _ = clutch_guard(mode, y, K[0], aux0, P)
    armed = armed or abs(g0) > guard_tolerance(mode, y, aux0, P)
    h_prop = h_io[H_MAIN]
    if method == DOPRI5 and h_prop <= 0.0:
        h_prop = initial_step(FULL, t, y, mode, P, ACT, K[0], rtol, atol, ytmp, dytmp, auxtmp,
                              ERR_FULL)
        counters[C_RHS] += 1
    err_old = ERR_OLD_START
    t_start = t
    h_fixed = S[S_H_FIXED]
    t_last_event = -math.inf
    stalled = 0
    steps0 = counters[C_STEPS]
    budget = S[S_STEP_BUDGET]
    rejected_last = False
    restarted = False   # no step accepted yet since the last switch
    h_old = -1.0        # the last accepted whole step (≤ 0: none since a switch, clip or rejection)

    while t < t_end:
        if counters[C_STEPS] - steps0 > budget:
            counters[C_STATUS] = STATUS_NO_PROGRESS
            break
        # ---- step size: error control or the fixed grid, clipped at t_end and actuator breaks
        clipped = False
        if method == DOPRI5:
            h = min(h_prop, S[S_MAX_STEP])
        else:
            k = math.floor((t - t_start) / h_fixed + 1e-9) + 1.0
            h = t_start + k * h_fixed - t
            # a remainder below the grid's rounding, or one that would not move t at all (t of
            # thousands of seconds: its ulp exceeds 1e-9·h), belongs to the next grid step
            if h < max(1e-9 * h_fixed, 8.0 * 2.2e-16 * abs(t)):
                h += h_fixed
        if t + h >= t_end:
            h = t_end - t
            clipped = True
        t_break = next_actuator_break(t, ACT)
        if t + h > t_break:
            h = t_break - t
            clipped = True
        if h <= 0.0:
            break

        split = can_split and mode == DISENGAGED
        kind = FULL
        err_idx = ERR_FULL
        if split:
            kind = INPUT
            err_idx = ERR_INPUT
        elif twist_relaxes(mode, P):
            kind = MASSLESS
            err_idx = ERR_MASSLESS
        err = take_step(method, kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux1, rtol, atol,
                        err_idx, counters)
        counters[C_STEPS] += 1
        counters[C_ENGAGED_STEPS] += mode
        factor = 1.0
        if method == DOPRI5:
            if not (err <= 1.0) or not finite_state(y_new):
                counters[C_REJECTED] += 1
                factor = max(MIN_FACTOR, SAFETY * err ** DP_ERROR_EXPONENT) if (
                    err < math.inf and finite_state(y_new)) else MIN_FACTOR
                h_prop = h * min(factor, 1.0)
                rejected_last = True
                h_old = -1.0
                if h_prop < 1e-14 * max(1.0, abs(t)):
                    counters[C_STATUS] = STATUS_STEP_TOO_SMALL
                    break
                continue
            # the next step: filtered after a whole accepted step, else PI control (no growth
            # right after a rejection)
            if err == 0.0:
                factor = MAX_FACTOR
            elif h_old > 0.0:
                factor = min(MAX_FACTOR, max(MIN_FACTOR, PI_SAFETY * (
                    max(err, ERR_OLD_START) * err_old) ** -FILTER_BETA
                    * (h / h_old) ** -FILTER_ALPHA))
            else:
                factor = min(MAX_FACTOR, max(MIN_FACTOR, PI_SAFETY * err ** -PI_ALPHA
                                             * err_old ** PI_BETA))
            h_old = -1.0 if clipped else h
            if rejected_last:
                factor = min(factor, 1.0)
            if restarted and not clipped:
                # the cap of the first step after the next switch into this mode
                h_io[H_RESTART + mode] = h * (MAX_FACTOR if err == 0.0 else min(
                    MAX_FACTOR, max(MIN_FACTOR, SAFETY * err ** DP_ERROR_EXPONENT)))
            restarted = False
            err_old = max(err, ERR_OLD_START)
            rejected_last = False
        elif not finite_state(y_new):
            counters[C_STATUS] = STATUS_NONFINITE
            break

        if split:
            t_new, fire, g1, armed = split_output(
                method, exact, t, h, y, y_new, K, mode, P, ACT, clock, rtol, atol, armed, g0, h_io,
                grid, out, counters, z, z_new, ztmp, ycomb, ytmp, dytmp, auxtmp, C[0], C[1])
            if counters[C_STATUS] != STATUS_OK:
                break
            if fire == NO_EVENT:
                h_prop = max(h_prop, h * factor) if clipped else h * factor
                t = t_end if (clipped and t + h >= t_end) else t_new
                for i in range(n):
                    y[i] = y_new[i]
                    K[0, i] = K[6, i]  # FSAL: the input part is exact (output not used split)
                project(t, y, mode, P, ACT)
                g0 = g1
                continue
            t = t_new
            for i in range(n):
                y[i] = y_new[i]
            rhs(t, y, mode, P, ACT, dytmp, aux1)
            counters[C_RHS] += 1
            g1 = aux1[AUX_SLIP]
            if fire == CROSSING and g1 > guard_tolerance(mode, y, aux1, P):
                t, g1 = creep_onto_catch(t, t_end, y, mode, P, ACT, clock, K, y_new, ytmp, aux1,
                                         dytmp, auxtmp, rtol, atol, grid, out, counters)
            if fire == CROSSING and g1 > guard_tolerance(mode, y, aux1, P):
                # the true state at the located time has not reached the guard (the dense
                # output's error at loose tolerances): not yet, go on from here, armed (the
                # slip is above its band: the crossing that follows is searched, not found late)
                armed = True
                project(t, y, mode, P, ACT)
                for i in range(n):
                    K[0, i] = dytmp[i]
                for i in OUTPUT_STATES:
                    K[0, i] = 0.0
                g0 = g1
                continue
        else:
            if kind == MASSLESS:
                relax_twist(t + h, h, y, y_new, mode, P, ACT, aux1, dytmp, counters)
            t_new, fire, g1 = watch_step(
                method, kind, err_idx, t, h, clipped, t_end, y, y_new, K, mode, P, ACT, clock,
                armed, g0, aux1, rtol, atol, grid, out, counters, ytmp, dytmp, auxtmp, C, G)
            t = t_new
            for i in range(n):
                y[i] = y_new[i]
            if fire == CROSSING and g1 > guard_tolerance(mode, y, aux1, P):
                fire = NO_EVENT   # the true state has not reached the guard yet: go on
            if fire == NO_EVENT:
                h_prop = max(h_prop, h * factor) if clipped else h * factor
                project(t, y, mode, P, ACT)
                for i in range(n):
                    K[0, i] = K[6, i]
                g0, _ = clutch_guard(mode, y, K[0], aux1, P)
                gtol = guard_tolerance(mode, y, aux1, P)
                if not armed and abs(g0) > gtol:
                    armed = True
                continue

        # ---- reset map of the clutch automaton
        ev_kind = KIND_GRAZE
        value = aux1[AUX_SLIP]
        if mode == ENGAGED:
            value = g1  # the release guard where the switch was placed (≈ 0 unless late)
            # (the twist rule's guard max(θ, Tc/c) already asks whether the clutch can open)
            # The step to the event integrated ω3 on its own; the state there is still an
            # engaged one, so ω3 = v first: else the open clutch starts with the step's
            # truncation error as slip (RK4 at 1 ms: −6e-6 rad/s, below its band) and 'engages'
            # by impact at once, pulling until the next step's end
            project(t, y, ENGAGED, P, ACT)
            ev_kind = KIND_RELEASE
            mode = DISENGAGED
            if P[P_J3] == 0.0 and P[P_KD] == 0.0 and P[P_RIGID] == 0.0:
                # an undamped massless node carries no torque when open, so no twist: what
                # is left of it (the release's location error) snaps back, its energy lost
                ledger[0] += 0.5 * P[P_C] * y[TWIST] ** 2
                y[TWIST] = 0.0
        else:
            if fire == FOUND_LATE:
                ledger[0] += engage_with_impact(t, y, P, ACT)
                ev_kind = KIND_ENGAGE_IMPACT
                mode = ENGAGED
            elif clutch_engages(t, y, P, ACT, dytmp, auxtmp, ytmp):
                ev_kind = KIND_ENGAGE
                mode = ENGAGED
            counters[C_RHS] += 1
        if fire == FOUND_LATE and ev_kind != KIND_GRAZE:
            counters[C_LATE] += 1
        project(t, y, mode, P, ACT)
        e = counters[C_EVENTS]
        events[e, E_T] = t
        events[e, E_MODE] = mode
        events[e, E_KIND] = ev_kind
        events[e, E_VALUE] = value
        events[e, E_LATE] = 1.0 if fire == FOUND_LATE else 0.0
        counters[C_EVENTS] = e + 1
        if ev_kind != KIND_GRAZE:
            counters[C_SWITCHES] += 1
        rhs(t, y, mode, P, ACT, K[0], aux0)
        counters[C_RHS] += 1
        g0, _ = clutch_guard(mode, y, K[0], aux0, P)
        # half-open rule: disarmed only while the new guard is still inside its band; a graze
        # leaves the guard where it was, at its root, so it must leave the band first
        armed = ev_kind != KIND_GRAZE and abs(g0) > guard_tolerance(mode, y, aux0, P)
        if method == DOPRI5 and ev_kind != KIND_GRAZE:
            # a fresh start in the new mode: its dynamics differ (the shaft's twist mode
            # joins or leaves), so the old proposal would be rejected or wasted. The
            # Hairer–Nørsett–Wanner estimate cannot see a stiff mode that the switch has not
            # excited yet: it is capped by the first step accepted after the last switch into
            # this mode, resized by its error (a periodic run's switches repeat their conditions)
            h_new = initial_step(FULL, t, y, mode, P, ACT, K[0], rtol, atol, ytmp, dytmp, auxtmp,
                                 ERR_FULL)
            counters[C_RHS] += 1
            h_prop = min(h_new, 4.0 * h) if h_new > 0.0 else h_prop
            if h_io[H_RESTART + mode] > 0.0:
                h_prop = min(h_prop, h_io[H_RESTART + mode])
            restarted = True
            err_old = ERR_OLD_START
            h_old = -1.0
        if t > t_last_event:
            t_last_event = t
            stalled = 0
        else:
            stalled += 1
            if stalled > MAX_EVENTS_AT_ONE_TIME:
                counters[C_STATUS] = STATUS_ZENO
                break
        if counters[C_EVENTS] >= events.shape[0]:
            counters[C_STATUS] = STATUS_EVENTS_FULL
            break
    ms[0] = mode
    ms[1] = 1 if armed else 0
    h_io[H_MAIN] = h_prop
    return t
