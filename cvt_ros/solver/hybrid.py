"""The hybrid integration loop: steps, clutch events, resets and samples, all in one compiled call.

``advance`` integrates from t to t_end in the current clutch mode and watches the clutch witness
function over every accepted step: not only at its ends but along the whole step, as a polynomial
of the step's dense output (witness.py), so a guard that dips through zero and back inside one
step is seen. A crossing is located on that polynomial (Illinois' regula falsi to ~1e-13 s), a
true step is re-taken exactly to the event, the automaton's reset map (physics/clutch.py) applies
and the run goes on in the new mode with a fresh starting step for it. A guard found beyond its
band after a step ('late') is switched at once and counted (C_LATE): a possibly missed event
that the caller reports. Samples on a caller-given grid are written from the dense output, so
sampling never shortens a step.

Step size: Dormand–Prince's error estimate with a PI controller (Gustafsson; Hairer's DOPRI5
constants), restarted after each switch by the Hairer–Nørsett–Wanner estimate in the new mode.

While the clutch is open an elastic output with J3 > 0 (or a massless damped node) runs apart
from the input (``_split_output``): exactly when it is linear, else on its own clock.
The loop never leaves compiled code between events.
"""
import math

import numpy as np

from ..physics.clutch import (
    KIND_ENGAGE,
    KIND_ENGAGE_IMPACT,
    KIND_GRAZE,
    KIND_RELEASE,
    SLIP_TOLERANCE,
    TWIST_TOLERANCE,
    clutch_engages,
    clutch_guard,
    guard_tolerance,
)
from ..physics.compiled import inline_kernel, kernel
from ..physics.drives import next_actuator_break
from ..physics.dynamics import (
    disengaged_output_rates,
    engage_with_impact,
    finite_state,
    output_rhs,
    project,
    rhs,
    rocker_speed,
)
from ..physics.layout import (
    AUX_SLIP,
    DISENGAGED,
    ENGAGED,
    N_AUX,
    N_OUTPUT,
    N_STATE,
    OMEGA2,
    OMEGA3,
    OUTPUT_STATES,
    P_C,
    P_J3,
    P_KD,
    P_LINEAR_OUTPUT,
    P_OUTPUT_RING,
    P_RIGID,
    TWIST,
    W_DAMPING,
    Z_OMEGA3,
    Z_OMEGA4,
    Z_TWIST,
)
from ..physics.output_exact import (
    modal_coordinates,
    modes_over,
    modulus2,
    output_at,
    output_from_modes,
)
from .output import write_sample
from .steppers import (
    DOPRI5,
    DP_ERROR_EXPONENT,
    ERR_FULL,
    ERR_INPUT,
    ERR_MASSLESS,
    ERR_OUTPUT,
    FULL,
    INPUT,
    MASSLESS,
    MAX_FACTOR,
    MIN_FACTOR,
    OUTPUT,
    SAFETY,
    dense_coefficients,
    dense_state,
    dopri5_step,
    initial_step,
    rk4_step,
)
from .witness import (
    N_GUARD,
    N_POLY,
    guard_polynomial,
    guard_value,
    hermite_minimum,
    illinois_point,
    illinois_update,
    lowest_point,
    poly_root,
    poly_value,
)

# settings vector S
S_METHOD = 0
S_RTOL = 1
S_ATOL = 2
S_H_FIXED = 3
S_MAX_STEP = 4
S_STEP_BUDGET = 5   # steps one call may take before it gives up (no-progress watchdog)
N_SETTINGS = 6

# counters (int64)
C_STEPS = 0
C_REJECTED = 1
C_NEXT_SAMPLE = 2
C_EVENTS = 3
C_STATUS = 4
C_SWITCHES = 5
C_SUBSTEPS = 6
C_ENGAGED_STEPS = 7
C_RHS = 8          # right-hand-side evaluations (every one, in any mode)
C_LATE = 9         # guards found beyond their band after a step: possibly missed events
N_COUNTERS = 10

DIP_STACK = 24   # pieces _split_dip may hold at once
N_MODAL = 2 * 3 * 2   # the modal coordinates W, complex (2, 3), as float64s
# the working arrays of one advance call, carved out of one float64 array (``scratch``) in
# this order: K, y_new, ytmp, dytmp, ycomb; aux0, aux1, auxtmp; Ko, z, z_new, ztmp, zs; C, G;
# W; the dip stack
N_SCRATCH = (11 * N_STATE + 3 * N_AUX + 11 * N_OUTPUT + 3 * N_POLY + N_GUARD + N_MODAL
             + 6 * DIP_STACK)

STATUS_OK = 0
STATUS_EVENTS_FULL = 1
STATUS_STEP_TOO_SMALL = 2
STATUS_NONFINITE = 3
STATUS_ZENO = 4  # events without the time moving on: the automaton would loop
STATUS_NO_PROGRESS = 5  # the step budget of one call is spent

# events table columns
E_T = 0
E_MODE = 1
E_KIND = 2
E_VALUE = 3
E_LATE = 4   # 1.0: switched because the guard was found beyond its band (possibly missed)
N_EVENT_COLUMNS = 5

# step-size proposals h_io carried between calls
H_MAIN = 0
H_OUTPUT = 1       # the open output's own clock
H_RESTART = 2      # + mode: cap of the first step after a switch into that mode (≤ 0: none yet)
N_PROPOSALS = 4

MAX_EVENTS_AT_ONE_TIME = 8
# The open output's slip is watched on sub-intervals, in rad of its fastest mode. A look is the
# Hermite cubic of the slip under its error bound (|a|·|λ|⁴·hs⁴/384 for a mode of amplitude a),
# refined where the bound could hide a dip (_split_dip), so the length trades looks against
# refinements: on the stiff shaft 3 rad (bound 0.21·|a|) took 62 % fewer looks than 0.75 rad
# everywhere and 16–24 % less time, the same switches. Near its band (just after a release, or
# after a crossing of the rocker speed's interpolant alone) a slip is not watched for a crossing,
# and one that leaves the band downwards within a look is found late, not located: short looks
# there.
EXACT_PHASE_STEP = 0.75  # [rad] near the band, and while a fast real mode is alive
ARMED_PHASE_STEP = 3.0   # [rad] while the slip is clearly positive (armed, > 2 bands)
PI_BETA = 0.04           # Hairer's DOPRI5: h·err^−(0.2 − 0.75β)·err_old^β
PI_ALPHA = 0.2 - 0.75 * PI_BETA
PI_SAFETY = 0.8
ERR_OLD_START = 1e-4
OUTPUT_RTOL = 1e-7   # loosest tolerance of the open output integrated on its own clock

_NO_EVENT = 0
_CROSSING = 1
_LATE = 2


@kernel
def _step(method, kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol, err_idx,
          counters):
    if method == DOPRI5:
        counters[C_RHS] += 6
        return dopri5_step(kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol, err_idx)
    counters[C_RHS] += 4
    return rk4_step(t, y, h, mode, P, ACT, K, y_new, ytmp, aux)


@inline_kernel
def _guard_at(method, theta, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp, counters):
    """The guard at t + θ·h from the dense output and one right-hand side (the twist rule)."""
    dense_state(method, theta, h, y0, y1, K, ytmp)
    rhs(t + theta * h, ytmp, mode, P, ACT, dytmp, auxtmp)
    counters[C_RHS] += 1
    g, _ = clutch_guard(mode, ytmp, dytmp, auxtmp, P)
    return g


@inline_kernel
def _output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, with_work):
    """Output subsystem at tau + σ·hs: the exact solution from the step start t (exact), or the
    dense output of the sub-step [tau, tau+hs] that started at z0."""
    Ko, zs, LIN, W, _ = clock
    if exact:
        output_at(tau + sigma * hs - t, zs, P, LIN, W, ztmp, with_work)
    else:
        dense_state(DOPRI5, sigma, hs, z0, z0, Ko, ztmp)


@inline_kernel
def _combine(exact, sigma, t, h, y0, K, tau, hs, z0, clock, P, ycomb, ztmp, with_work):
    """The full state at tau + σ·hs inside a split step: the input subsystem from the main
    step's dense output, the output subsystem from _output_state."""
    tt = tau + sigma * hs
    dense_state(DOPRI5, (tt - t) / h, h, y0, y0, K, ycomb)
    _output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, with_work)
    for i in range(N_OUTPUT):
        ycomb[OUTPUT_STATES[i]] = ztmp[i]
    return tt


@inline_kernel
def _true_split_slip(exact, sigma, t, h, y0, K, tau, hs, z0, clock, P, ACT, ycomb, ztmp):
    """The slip at tau + σ·hs with the rocker speed from the closed-form linkage at the dense
    crank state (what the reset map sees), not from the rocker speed's own dense polynomial."""
    tt = _combine(exact, sigma, t, h, y0, K, tau, hs, z0, clock, P, ycomb, ztmp, False)
    return ycomb[OMEGA3] - rocker_speed(tt, ycomb, P, ACT)


@inline_kernel
def _split_slip(exact, sigma, t, h, tau, hs, z0, clock, P, Cv, ztmp):
    """Slip s = ω3 − v at tau + σ·hs inside a split step [rad/s]: ω3 from the output, v from the
    rocker speed's dense polynomial Cv over the input step."""
    _output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, False)
    return ztmp[Z_OMEGA3] - poly_value(Cv, (tau + sigma * hs - t) / h)


@kernel
def _split_dip(exact, t, h, tau, hs, z0, clock, P, Cv, ztmp, g0, d0, g1, d1, m4, gtol):
    """The slip's lowest point inside the sub-interval [tau, tau+hs] if it falls below -gtol:
    (σ, slip there) or (-1, inf). g, d: the slip and its σ-rate at both ends; m4 a bound on
    |d⁴s/dσ⁴|. The Hermite cubic of each piece is trusted only where its error bound
    m4·w⁴/384 cannot hide a dip; elsewhere the piece is halved (exact values and rates)."""
    tm, pm = hermite_minimum(g0, d0, g1, d1)
    if min(pm, g0, g1) - m4 / 384.0 > -gtol:
        return -1.0, math.inf   # the usual case, settled without the refinement's stack
    stack = clock[4]   # (6, DIP_STACK): the pieces still to look at
    sa = stack[0]
    sb = stack[1]
    ga = stack[2]
    gb = stack[3]
    da = stack[4]
    db = stack[5]
    top = 0
    sa[0], sb[0], ga[0], gb[0], da[0], db[0] = 0.0, 1.0, g0, g1, d0, d1
    while top >= 0:
        a, b, g_a, g_b, d_a, d_b = sa[top], sb[top], ga[top], gb[top], da[top], db[top]
        top -= 1
        w = b - a
        tm, pm = hermite_minimum(g_a, w * d_a, g_b, w * d_b)
        low = min(pm, g_a, g_b)
        err = m4 * w ** 4 / 384.0
        if low - err > -gtol:
            continue        # no dip can hide here
        if tm >= 0.0:
            sm = a + tm * w
            gm = _split_slip(exact, sm, t, h, tau, hs, z0, clock, P, Cv, ztmp)
            if gm < -gtol:
                return sm, gm
        if top + 2 >= sa.shape[0] or w < 1e-6:
            continue
        mid = 0.5 * (a + b)
        gmid = _split_slip(exact, mid, t, h, tau, hs, z0, clock, P, Cv, ztmp)
        if gmid < -gtol:
            return mid, gmid
        dmid = hs * (_omega3_rate(ztmp, P) - _poly_rate(Cv, (tau + mid * hs - t) / h, h))
        top += 1
        sa[top], sb[top], ga[top], gb[top], da[top], db[top] = mid, b, gmid, g_b, dmid, d_b
        top += 1
        sa[top], sb[top], ga[top], gb[top], da[top], db[top] = a, mid, g_a, gmid, d_a, dmid
    return -1.0, math.inf


@inline_kernel
def _modal_jerk_bound(LIN, W):
    """Σ_k |ω3 amplitude of mode k|·|λ_k|⁴: a bound on |d⁴ω3/dt⁴| of the exact output [rad/s⁵]
    over a step (modes that do not grow)."""
    m = 0.0
    for k in range(3):
        lam = LIN[0, k]
        if lam != 0.0:
            m2 = modulus2(lam)
            m += math.sqrt(modulus2(LIN[2, k] * (W[0, k] + W[1, k] / lam))) * m2 * m2
    return m


@inline_kernel
def _slip_floor(h, g0, g1, LIN, W, Cv, modes):
    """A lower bound of the slip ω3 − v over a whole split step [t, t+h] [rad/s], from the exact
    output's modes (output_exact.py) and the rocker speed's polynomial Cv: the modes faster than
    the step (|λ|·h > 1: the shaft's ringing) by their amplitude |a_k|·max(1, e^{Re λ_k·h}), the
    rest (smooth over the step) by the chord between the ends less h²/8·max|f''|. When it stays
    clear of zero no crossing or dip can hide in the step, and its dense watch is skipped.
    modes: the modes over [0, h] (output_exact.modes_over; their e^{λh} is used)."""
    f0 = g0
    f1 = g1
    amp = 0.0
    curv = 0.0
    for k in range(3):
        lam = LIN[0, k]
        if lam == 0.0:
            continue   # the rigid-body mode: ω3 linear in τ, no curvature
        a = LIN[2, k] * (W[0, k] + W[1, k] / lam)
        grow = max(1.0, math.exp(lam.real * h))
        m2 = modulus2(lam)
        if m2 * h * h > 1.0:   # |λ|·h > 1
            f0 -= a.real
            f1 -= (a * modes[k][5]).real   # e^{λh}
            amp += math.sqrt(modulus2(a)) * grow
        else:
            curv += math.sqrt(modulus2(a)) * m2 * grow * h * h
    for k in range(2, N_POLY):
        curv += k * (k - 1) * abs(Cv[k])   # |d²v/dθ²| ≤ Σ k(k−1)|c_k|
    return min(f0, f1) - amp - curv / 8.0


@inline_kernel
def _poly_rate(C, x, h):
    """d/dt of the polynomial C(θ) over a step h, at θ = x."""
    v = 0.0
    for k in range(N_POLY - 1, 0, -1):
        v = v * x + k * C[k]
    return v / h


@inline_kernel
def _omega3_rate(z, P):
    """ω3' of the open output subsystem (J3 > 0) [rad/s²]."""
    _, dw3, _, _, _ = disengaged_output_rates(z[Z_TWIST], z[Z_OMEGA3], z[Z_OMEGA4], P)
    return dw3


@kernel
def _locate(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, Cv, lo,
            hi, glo, ghi, tol_theta, ytmp, dytmp, auxtmp, ztmp, counters):
    """Illinois' regula falsi on the true guard g(θ), g(lo) > 0 > g(hi); θ just past the root.

    θ runs over the step [t, t+h] (split = False: the guard through the right-hand side) or
    over the output sub-step [tau, tau+hs] (the slip, with the linkage's rocker speed).
    """
    side = 0
    for it in range(200):
        if hi - lo <= tol_theta:
            break
        m = illinois_point(it, lo, hi, glo, ghi)
        if split:
            gm = _true_split_slip(exact, m, t, h, y0, K, tau, hs, z0, clock, P, ACT, ytmp, ztmp)
        else:
            gm = _guard_at(method, m, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                           counters)
        lo, hi, glo, ghi, side = illinois_update(m, gm, lo, hi, glo, ghi, side)
    return hi


@inline_kernel
def _twist_relaxes(method, mode, P):
    """An open massless damped node: its twist is solved exactly, not stepped (stiff c/k)."""
    return (method == DOPRI5 and mode == DISENGAGED and P[P_J3] == 0.0 and P[P_KD] > 0.0
            and P[P_RIGID] == 0.0)


@kernel
def _emit(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, grid, out,
          counters, t_limit, ytmp, ztmp, dytmp, auxtmp):
    """Write every grid sample in (…, t_limit] from the dense output of the step [t, t+h], or,
    inside a split step (split), of its input part and of the output sub-step [tau, tau+hs]."""
    i = counters[C_NEXT_SAMPLE]
    while i < grid.shape[0] and grid[i] <= t_limit:
        if split:
            _combine(exact, (grid[i] - tau) / hs if hs > 0.0 else 1.0, t, h, y0, K, tau, hs, z0,
                     clock, P, ytmp, ztmp, True)
        else:
            dense_state(method, (grid[i] - t) / h if h > 0.0 else 1.0, h, y0, y1, K, ytmp)
            if _twist_relaxes(method, mode, P):
                theta = y0[TWIST] * math.exp(-P[P_C] / P[P_KD] * (grid[i] - t))
                ytmp[W_DAMPING] += 0.5 * P[P_C] * (y0[TWIST] ** 2 - theta * theta)
                ytmp[TWIST] = theta
        project(grid[i], ytmp, mode, P, ACT)
        rhs(grid[i], ytmp, mode, P, ACT, dytmp, auxtmp)
        write_sample(out[i], grid[i], ytmp, mode, auxtmp)
        i += 1
    counters[C_NEXT_SAMPLE] = i


@inline_kernel
def _due(grid, counters, t_limit):
    """Is a grid sample due in (…, t_limit]? (Checked before the call: most steps have none.)"""
    i = counters[C_NEXT_SAMPLE]
    return i < grid.shape[0] and grid[i] <= t_limit


@inline_kernel
def _fast_real_modes(t, h, LIN, W, gtol):
    """(rate, until): the open output's fastest real (non-oscillating) mode that is faster than
    the step and still alive above the slip tolerance, and the time until it has died out.
    A strongly damped shaft or a massless damped node relaxes at c/k: watched densely only
    while it matters, not over the whole step."""
    rate = 0.0
    until = t
    for k in range(3):
        lam = LIN[0, k]
        if lam.imag == 0.0 and lam.real < 0.0 and -lam.real * h > EXACT_PHASE_STEP:
            amp = math.sqrt(modulus2(LIN[2, k] * (W[0, k] + W[1, k] / lam)))
            if amp > gtol:
                rate = max(rate, -lam.real)
                until = max(until, t + math.log(amp / gtol) / -lam.real)
    return rate, until


@kernel
def _split_output(exact, t, h, y, y_new, K, mode, P, ACT, clock, rtol, atol, armed, g0, h_io,
                  grid, out, counters, z, z_new, ztmp, ycomb, ytmp, dytmp, auxtmp, Cv, Cz):
    """The disengaged output subsystem over the accepted input step [t, t+h], apart from it:
    solved exactly (linear output, physics/output_exact.py) or integrated on its own adaptive
    clock; the slip is watched on sub-intervals (sub-steps, or ≤ ARMED_PHASE_STEP rad of the
    output's ringing mode, denser near the slip's band and while a fast real mode is alive),
    each checked for a crossing and, by Hermite cubics of the slip and its exact rate under an
    error bound, for a dip.

    The output states of y_new are replaced. On a slip crossing (or a slip found beyond the band,
    'late'), the input step is re-taken exactly to that time and the state there is left in
    y_new. Returns (t reached, fire, last slip, armed).
    """
    Ko, zs, LIN, W, _ = clock
    # the integrated output's own tolerance: its ringing decides where the slip crosses zero,
    # and it costs little (four states), so it is held to OUTPUT_RTOL at loose settings
    rtol = min(rtol, OUTPUT_RTOL)
    atol = min(atol, OUTPUT_RTOL * 1e-2)
    for i in range(N_OUTPUT):
        z[i] = y[OUTPUT_STATES[i]]
        zs[i] = z[i]
    t1 = t + h
    dense_coefficients(DOPRI5, h, y, y, K, OMEGA2, Cv)
    fast_rate = 0.0
    fast_until = t
    h_near = math.inf   # [s] a look's length near the slip's band
    if exact:
        modal_coordinates(z, P, LIN, W)
        if armed and g0 > 0.0:
            modes = modes_over(h, LIN, W)
            output_from_modes(h, zs, P, LIN, modes, z_new, True)
            g1 = z_new[Z_OMEGA3] - poly_value(Cv, 1.0)
            gtol = SLIP_TOLERANCE * (1.0 + abs(Cv[0]) + abs(z[Z_OMEGA3]) + abs(g1) + abs(g0))
            if _slip_floor(h, g0, g1, LIN, W, Cv, modes) > 4.0 * gtol:
                # the usual free-running step: no catch possible anywhere in it
                counters[C_SUBSTEPS] += 1
                if _due(grid, counters, t1):
                    _emit(True, exact, DOPRI5, t, h, y, y, K, t, h, z, clock, mode, P, ACT, grid,
                          out, counters, t1, ycomb, ztmp, dytmp, auxtmp)
                for i in range(N_OUTPUT):
                    y_new[OUTPUT_STATES[i]] = z_new[i]
                return t1, _NO_EVENT, g1, armed
        ring = P[P_OUTPUT_RING]
        n_exact = max(1, int(math.ceil(ring * h / ARMED_PHASE_STEP))) if ring > 0.0 else 1
        h_out = h / n_exact
        if ring > 0.0:
            h_near = EXACT_PHASE_STEP / ring
        fast_rate, fast_until = _fast_real_modes(
            t, h, LIN, W, SLIP_TOLERANCE * (1.0 + abs(z[Z_OMEGA3])))
        dw3_0 = _omega3_rate(z, P)
    else:
        output_rhs(z, P, Ko[0])
        dw3_0 = Ko[0, Z_OMEGA3]
        h_out = h_io[H_OUTPUT]
        if h_out <= 0.0:
            h_out = initial_step(OUTPUT, t, z, mode, P, ACT, Ko[0], rtol, atol, ztmp, dytmp, auxtmp,
                                 ERR_OUTPUT)
    jerk4 = _modal_jerk_bound(LIN, W) if exact else 0.0
    v4 = 24.0 * abs(Cv[4]) / h ** 4   # bound of the rocker speed's 4th derivative [rad/s⁵]
    tau = t
    fire = _NO_EVENT
    dv0 = _poly_rate(Cv, 0.0, h)
    gtol = SLIP_TOLERANCE * (1.0 + abs(Cv[0]) + abs(z[Z_OMEGA3]))   # the slip's band at tau
    factor = 1.0
    while tau < t1:
        if exact:
            hs = h_out
            if tau < fast_until:
                hs = min(hs, EXACT_PHASE_STEP / fast_rate)
            if not (armed and g0 > 2.0 * gtol):
                hs = min(hs, h_near)
            last = tau + hs >= t1 * (1.0 - 1e-15) or t1 - (tau + hs) < 1e-9 * hs
            if last:
                hs = t1 - tau
            output_at(tau + hs - t, zs, P, LIN, W, z_new, False)
            dw3_1 = _omega3_rate(z_new, P)
        else:
            hs = min(h_out, t1 - tau)
            last = tau + hs >= t1
            err = dopri5_step(OUTPUT, tau, z, hs, mode, P, ACT, Ko, z_new, ztmp, auxtmp, rtol,
                              atol, ERR_OUTPUT)
            if not (err <= 1.0):
                h_out = hs * max(MIN_FACTOR, SAFETY * err ** DP_ERROR_EXPONENT) \
                    if err < math.inf else hs * MIN_FACTOR
                if h_out < 1e-14 * max(1.0, abs(tau)):
                    counters[C_STATUS] = STATUS_STEP_TOO_SMALL
                    return tau, fire, g0, armed
                continue
            factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR,
                                                       SAFETY * err ** DP_ERROR_EXPONENT)
            dw3_1 = Ko[6, Z_OMEGA3]
        counters[C_SUBSTEPS] += 1
        x1 = 1.0 if last else (tau + hs - t) / h
        v1 = poly_value(Cv, x1)
        dv1 = _poly_rate(Cv, x1, h)
        g1 = z_new[Z_OMEGA3] - v1
        gtol = SLIP_TOLERANCE * (1.0 + abs(v1) + abs(z_new[Z_OMEGA3]))
        sigma = 1.0
        hi = 1.0
        if armed and g0 > 0.0:
            if g1 < 0.0:
                fire = _CROSSING
            else:
                # both ends positive: a dip inside (a short catch)? Hermite cubics of the slip
                # with its exact rates (ω3' of the output, v' of the input's dense output),
                # refined where their error bound could hide one
                if exact:
                    m4 = hs ** 4 * (jerk4 + v4)
                else:
                    dense_coefficients(DOPRI5, hs, z, z, Ko, Z_OMEGA3, Cz)
                    m4 = 24.0 * abs(Cz[4]) + hs ** 4 * v4
                tm, gm = _split_dip(exact, t, h, tau, hs, z, clock, P, Cv, ztmp, g0,
                                    hs * (dw3_0 - dv0), g1, hs * (dw3_1 - dv1), m4, gtol)
                if tm >= 0.0:
                    fire = _CROSSING
                    hi = tm
            if fire == _CROSSING:
                # located on the true slip (the linkage's rocker speed, as the reset map sees
                # it): the end values must bracket it there too
                tol_s = max(1e-13, 8.0 * 2.2e-16 * abs(tau)) / hs
                gt_hi = _true_split_slip(exact, hi, t, h, y, K, tau, hs, z, clock, P, ACT, ycomb,
                                         ztmp)
                gt_lo = _true_split_slip(exact, 0.0, t, h, y, K, tau, hs, z, clock, P, ACT, ycomb,
                                         ztmp)
                if gt_hi < 0.0 < gt_lo:
                    sigma = _locate(True, exact, DOPRI5, t, h, y, y_new, K, tau, hs, z, clock,
                                    mode, P, ACT, Cv, 0.0, hi, gt_lo, gt_hi, tol_s, ycomb, dytmp,
                                    auxtmp, ztmp, counters)
                elif gt_hi >= -gtol:
                    fire = _NO_EVENT   # a dip of the rocker speed's interpolant alone
                    if hi == 1.0:
                        g1 = gt_hi
                else:
                    sigma = 0.0 if gt_lo <= 0.0 else hi
        if fire == _NO_EVENT and g1 < -gtol:
            fire = _LATE
        if fire != _NO_EVENT:
            t_ev = tau + sigma * hs
            # true states at the event: the output exactly or by a re-taken sub-step, the input
            # by a re-taken step from t
            if exact:
                output_at(t_ev - t, zs, P, LIN, W, z_new, True)
            else:
                dopri5_step(OUTPUT, tau, z, t_ev - tau, mode, P, ACT, Ko, z_new, ztmp, auxtmp,
                            rtol, atol, ERR_OUTPUT)
            if _due(grid, counters, t_ev):
                _emit(True, exact, DOPRI5, t, h, y, y, K, tau, t_ev - tau, z, clock, mode, P, ACT,
                      grid, out, counters, t_ev, ycomb, ztmp, dytmp, auxtmp)
            if t_ev < t1:
                _step(DOPRI5, INPUT, t, y, t_ev - t, mode, P, ACT, K, y_new, ytmp, auxtmp, rtol,
                      atol, ERR_INPUT, counters)
            for i in range(N_OUTPUT):
                y_new[OUTPUT_STATES[i]] = z_new[i]
            if not exact:
                h_io[H_OUTPUT] = h_out
            return t_ev, fire, g1, armed
        if _due(grid, counters, t1 if last else tau + hs):
            _emit(True, exact, DOPRI5, t, h, y, y, K, tau, hs, z, clock, mode, P, ACT, grid, out,
                  counters, t1 if last else tau + hs, ycomb, ztmp, dytmp, auxtmp)
        tau = t1 if last else tau + hs
        for i in range(N_OUTPUT):
            z[i] = z_new[i]
            Ko[0, i] = Ko[6, i]
        g0 = g1
        dv0 = dv1
        dw3_0 = dw3_1
        if not armed and abs(g1) > gtol:
            armed = True
        if not exact:
            h_out = max(h_out, hs * factor) if last else hs * factor
    if exact:
        output_at(h, zs, P, LIN, W, z, True)  # with the work terms
    else:
        h_io[H_OUTPUT] = h_out
    for i in range(N_OUTPUT):
        y_new[OUTPUT_STATES[i]] = z[i]
    return t1, fire, g0, armed


@kernel
def _confirm_root(method, t, h, y, y_new, K, mode, P, ACT, clock, theta, hi, g0, ghi, gtol,
                  tol_theta, ytmp, dytmp, auxtmp, counters):
    """The polynomial's root θ checked on the true guard (one right-hand side): kept when the
    guard there is inside its band, else re-located on the true guard in the bracket the check
    leaves. The reset map's complementarity sees the true guard: a release placed where the
    clutch still pushes would engage again at once (chatter at loose tolerances)."""
    if theta >= hi:
        return hi
    gt = _guard_at(method, theta, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp, counters)
    if abs(gt) <= gtol:
        return theta
    if gt > 0.0:
        return _locate(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT, y,
                       theta, hi, gt, ghi, tol_theta, ytmp, dytmp, auxtmp, ytmp, counters)
    return _locate(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT, y,
                   0.0, theta, g0, gt, tol_theta, ytmp, dytmp, auxtmp, ytmp, counters)


@kernel
def _twist_crossing(method, t, h, y, y_new, K, mode, P, ACT, clock, g0, g1, G, tol_theta,
                    ytmp, dytmp, auxtmp, counters):
    """The twist rule's release inside the step (θ where the guard max(θ, −k·s'_free) falls
    through zero; G holds the twist's polynomial), or −1."""
    theta_z = -1.0
    if G[0] > 0.0:
        tw1 = poly_value(G, 1.0)
        if tw1 < 0.0:
            theta_z = poly_root(G, 0.0, 1.0, G[0], tw1, tol_theta)
        else:
            tm, gm = lowest_point(G, -TWIST_TOLERANCE)
            if gm < -TWIST_TOLERANCE:
                theta_z = poly_root(G, 0.0, tm, G[0], gm, tol_theta)
        if theta_z < 0.0:
            return -1.0
        gz = _guard_at(method, theta_z, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                       counters)
        if gz <= 0.0:
            return theta_z       # the twist reached zero where the clutch can open
        lo, glo = theta_z, gz    # it opens later, once s'_free ≥ 0: by the step's end?
    else:
        lo, glo = 0.0, g0
    if g1 < 0.0:
        return _locate(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT, y,
                       lo, 1.0, glo, g1, tol_theta, ytmp, dytmp, auxtmp, ytmp, counters)
    return -1.0


@inline_kernel
def _relax_twist(t1, h, y, y_new, mode, P, ACT, aux1, dytmp, counters):
    """The open massless damped node over a step: θ = θ0·e^(−(c/k)·h) exactly, the spring's
    energy into the damper; the auxiliaries (the slip) at the step's end refreshed."""
    theta0 = y[TWIST]
    theta1 = theta0 * math.exp(-P[P_C] / P[P_KD] * h)
    y_new[TWIST] = theta1
    y_new[W_DAMPING] = y[W_DAMPING] + 0.5 * P[P_C] * (theta0 * theta0 - theta1 * theta1)
    project(t1, y_new, mode, P, ACT)
    rhs(t1, y_new, mode, P, ACT, dytmp, aux1)
    counters[C_RHS] += 1


@kernel
def _single_rate(method, kind, err_idx, t, h, clipped, t_end, y, y_new, K, mode, P, ACT, clock,
                 armed, g0, aux1, rtol, atol, grid, out, counters, ytmp, dytmp, auxtmp, C, G):
    """Witness function over an accepted step of the whole system: a crossing or a dip through
    zero anywhere inside the step (on the guard's polynomial, witness.py) is located and a true
    step re-taken to it; a guard found beyond its band at the step's end is 'late'. Emits the
    samples up to the time reached and leaves the state there in y_new. Returns (t reached,
    fire, g at that time)."""
    g1, _ = clutch_guard(mode, y_new, K[6], aux1, P)
    gtol = guard_tolerance(mode, y_new, aux1, P)
    fire = _NO_EVENT
    theta = 1.0
    if armed and g0 > 0.0:
        tol_theta = max(1e-13, 8.0 * 2.2e-16 * abs(t)) / h
        if guard_polynomial(method, h, y, y_new, K, mode, P, C, G):
            ga = G[0]
            hi = -1.0
            ghi = 0.0
            if g1 < 0.0:
                hi = 1.0
                ghi = g1
                gb = guard_value(G, 1.0)
                theta = poly_root(G, 0.0, 1.0, ga, gb, tol_theta) if (
                    ga > 0.0 and gb < 0.0) else 1.0
            else:
                tm, gm = lowest_point(G, -gtol)
                if gm < -gtol:
                    # a dip on the polynomial: is it one of the true guard?
                    gt = _guard_at(method, tm, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp,
                                   auxtmp, counters)
                    if gt < -gtol:
                        hi = tm
                        ghi = gt
                        theta = poly_root(G, 0.0, tm, ga, gm, tol_theta) if ga > 0.0 else tm
            if hi > 0.0:
                fire = _CROSSING
                theta = _confirm_root(method, t, h, y, y_new, K, mode, P, ACT, clock, theta, hi,
                                      g0, ghi, gtol, tol_theta, ytmp, dytmp, auxtmp, counters)
        else:
            theta = _twist_crossing(method, t, h, y, y_new, K, mode, P, ACT, clock, g0, g1, G,
                                    tol_theta, ytmp, dytmp, auxtmp, counters)
            if theta >= 0.0:
                fire = _CROSSING
    if fire == _NO_EVENT and g1 < -gtol:
        fire = _LATE  # the guard left its band on the wrong side: switch now
    if fire == _CROSSING:
        h_ev = theta * h
        # a true step to the event, not the interpolant: the state there is step-accurate
        _step(method, kind, t, y, h_ev, mode, P, ACT, K, y_new, ytmp, aux1, rtol, atol, err_idx,
              counters)
        if kind == MASSLESS:
            _relax_twist(t + h_ev, h_ev, y, y_new, mode, P, ACT, aux1, dytmp, counters)
        if _due(grid, counters, t + h_ev):
            _emit(False, False, method, t, h_ev, y, y_new, K, t, h_ev, y, clock, mode, P, ACT,
                  grid, out, counters, t + h_ev, ytmp, ytmp, dytmp, auxtmp)
        g1, _ = clutch_guard(mode, y_new, K[6], aux1, P)
        return t + h_ev, fire, g1
    t_new = t_end if (clipped and t + h >= t_end) else t + h
    if _due(grid, counters, t_new):
        _emit(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT, grid, out,
              counters, t_new, ytmp, ytmp, dytmp, auxtmp)
    return t_new, fire, g1


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
    # a disengaged elastic output with J3 > 0 runs apart from the input (see _split_output):
    # exactly when it is linear, else on its own clock
    can_split = method == DOPRI5 and P[P_RIGID] == 0.0 and P[P_J3] > 0.0
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
        elif _twist_relaxes(method, mode, P):
            kind = MASSLESS
            err_idx = ERR_MASSLESS
        err = _step(method, kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux1, rtol, atol,
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
                if h_prop < 1e-14 * max(1.0, abs(t)):
                    counters[C_STATUS] = STATUS_STEP_TOO_SMALL
                    break
                continue
            # PI control of the next step (no growth right after a rejection)
            if err == 0.0:
                factor = MAX_FACTOR
            else:
                factor = min(MAX_FACTOR, max(MIN_FACTOR, PI_SAFETY * err ** -PI_ALPHA
                                             * err_old ** PI_BETA))
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
            t_new, fire, g1, armed = _split_output(
                exact, t, h, y, y_new, K, mode, P, ACT, clock, rtol, atol, armed, g0, h_io, grid,
                out, counters, z, z_new, ztmp, ycomb, ytmp, dytmp, auxtmp, C[0], C[1])
            if counters[C_STATUS] != STATUS_OK:
                break
            if fire == _NO_EVENT:
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
            if fire == _CROSSING and g1 > guard_tolerance(mode, y, aux1, P):
                # the true state at the located time has not reached the guard (the dense
                # output's error at loose tolerances): not yet, go on from here
                project(t, y, mode, P, ACT)
                for i in range(n):
                    K[0, i] = dytmp[i]
                for i in OUTPUT_STATES:
                    K[0, i] = 0.0
                g0 = g1
                continue
        else:
            if kind == MASSLESS:
                _relax_twist(t + h, h, y, y_new, mode, P, ACT, aux1, dytmp, counters)
            t_new, fire, g1 = _single_rate(
                method, kind, err_idx, t, h, clipped, t_end, y, y_new, K, mode, P, ACT, clock,
                armed, g0, aux1, rtol, atol, grid, out, counters, ytmp, dytmp, auxtmp, C, G)
            t = t_new
            for i in range(n):
                y[i] = y_new[i]
            if fire == _CROSSING and g1 > guard_tolerance(mode, y, aux1, P):
                fire = _NO_EVENT   # the true state has not reached the guard yet: go on
            if fire == _NO_EVENT:
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
            # (the twist rule's guard already asks whether the clutch can open: s'_free ≥ 0)
            ev_kind = KIND_RELEASE
            mode = DISENGAGED
            if P[P_J3] == 0.0 and P[P_KD] == 0.0 and P[P_RIGID] == 0.0:
                # an undamped massless node carries no torque when open, so no twist: what
                # is left of it (the release's location error) snaps back, its energy lost
                ledger[0] += 0.5 * P[P_C] * y[TWIST] ** 2
                y[TWIST] = 0.0
        else:
            if fire == _LATE:
                ledger[0] += engage_with_impact(t, y, P, ACT)
                ev_kind = KIND_ENGAGE_IMPACT
                mode = ENGAGED
            elif clutch_engages(t, y, P, ACT, dytmp, auxtmp, ytmp):
                ev_kind = KIND_ENGAGE
                mode = ENGAGED
            counters[C_RHS] += 1
        if fire == _LATE and ev_kind != KIND_GRAZE:
            counters[C_LATE] += 1
        project(t, y, mode, P, ACT)
        e = counters[C_EVENTS]
        events[e, E_T] = t
        events[e, E_MODE] = mode
        events[e, E_KIND] = ev_kind
        events[e, E_VALUE] = value
        events[e, E_LATE] = 1.0 if fire == _LATE else 0.0
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
