"""The open output's slip watch: while the clutch is open, an elastic output (J3 > 0, or a massless
damped node) runs apart from the input over each accepted input step (``split_output``): solved
exactly when it is linear (physics/output_exact.py), else integrated on its own adaptive clock.

The re-engagement guard is the slip s = ω3 − v (output node speed minus rocker speed). It is
watched on sub-intervals of the step, each checked for a crossing and, by Hermite cubics of the
slip with its exact rates under an error bound, for a dip that starts and ends inside it
(slip_look.py); a whole step is skipped when a modal lower bound of the slip proves that no
catch can hide in it (``_slip_floor``). The rocker speed in those looks is the input step's dense
polynomial; a dip or rise it shows is confirmed on the true slip (the linkage's rocker speed),
whose own extremum is searched for where the two disagree.
"""
import math

from ..physics.clutch import SLIP_TOLERANCE
from ..physics.compiled import inline_kernel, kernel
from ..physics.dynamics import output_rhs
from ..physics.layout import (
    N_OUTPUT,
    OMEGA1,
    OMEGA2,
    OUTPUT_STATES,
    P_OUTPUT_RING,
    Z_OMEGA3,
)
from ..physics.output_exact import (
    modal_coordinates,
    modes_over,
    modulus2,
    output_at,
    output_from_modes,
)
from .advance_layout import (
    C_STATUS,
    C_SUBSTEPS,
    CROSSING,
    FOUND_LATE,
    H_OUTPUT,
    NO_EVENT,
    STATUS_STEP_TOO_SMALL,
)
from .dense_step import (
    emit_samples,
    locate_band_exit,
    locate_root,
    root_tolerance,
    sample_due,
    take_step,
    true_split_slip,
)
from .slip_look import (
    left_band_upwards,
    omega3_rate,
    poly_rate,
    split_dip,
    true_beyond,
)
from .steppers import (
    DOPRI5,
    DP_ERROR_EXPONENT,
    ERR_INPUT,
    ERR_OUTPUT,
    INPUT,
    MAX_FACTOR,
    MIN_FACTOR,
    OUTPUT,
    SAFETY,
    dense_coefficients,
    dopri5_step,
    initial_step,
)
from .witness import N_POLY, hermite_minimum, hermite_root, poly_value

# The open output's slip is watched on sub-intervals, in rad of its fastest mode. A look is the
# Hermite cubic of the slip under its error bound (|a|·|λ|⁴·hs⁴/384 for a mode of amplitude a),
# refined where the bound could hide a dip (slip_look.split_dip), so the length trades looks against
# refinements: on the stiff shaft 3 rad (bound 0.21·|a|) took 62 % fewer looks than 0.75 rad
# everywhere and 16–24 % less time, the same switches. Near its band (just after a release, or
# after a crossing of the rocker speed's interpolant alone) a slip is not watched for a crossing
# but for leaving the band (upwards, then a fall; or downwards, located where it leaves it:
# dense_step.locate_band_exit), in short looks. And where a long look's slip falls to zero:
# within 3 rad of a ring it can cross zero three times, and only the first is the catch.
EXACT_PHASE_STEP = 0.75  # [rad] near the band, and while a fast real mode is alive
ARMED_PHASE_STEP = 3.0   # [rad] while the slip is clearly positive (armed, > 2 bands)
OUTPUT_RTOL = 1e-7   # loosest tolerance of the open output integrated on its own clock
# how far the rocker speed's interpolant may lag the linkage's u(φ1)·ω1 inside a step, in rtol ×
# the crank speed: through u'·ω1 the crank angle's error moves the linkage's rocker speed (the
# lag of 0.09 rad/s seen at rtol 1e-4, ω1 150 rad/s, is 6 of these)
LAG_BOUND = 30.0


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
def _true_dip(method, exact, t, h, y, y1, K, tau, hs, z0, clock, P, ACT, ycomb, ztmp, m, gm, g0,
              d0, g1, d1, gtol):
    """(σ, true slip) where the true slip stands below its band in a look whose polynomial
    slip dips or falls below zero at σ = m (the true slip there gm, not below it), else
    (-1, gm): from m, or, for a fall by the look's end (m = 1), from the polynomial's Hermite
    cubic's lowest point inside the look, the true slip's own lowest point
    (slip_look.true_beyond)."""
    if m == 1.0:
        xm, _ = hermite_minimum(g0, d0, g1, d1)
        if not xm > 0.0:
            return -1.0, gm
        gx = true_split_slip(method, exact, xm, t, h, y, y1, K, tau, hs, z0, clock, P, ACT, ycomb,
                             ztmp)
        if gx < -gtol:
            return xm, gx
        m, gm = xm, gx
    return true_beyond(method, exact, t, h, y, y1, K, tau, hs, z0, clock, P, ACT, ycomb, ztmp, m,
                       gm, -1.0, gtol)


@kernel
def split_output(method, exact, t, h, y, y_new, K, mode, P, ACT, clock, rtol, atol, armed, g0, h_io,
                 grid, out, counters, z, z_new, ztmp, ycomb, ytmp, dytmp, auxtmp, Cv, Cz):
    """The disengaged output subsystem over the accepted input step [t, t+h], apart from it:
    solved exactly (linear output, physics/output_exact.py) or integrated on its own adaptive
    clock; the slip is watched on sub-intervals (sub-steps, or ≤ ARMED_PHASE_STEP rad of the
    output's ringing mode, denser near the slip's band and while a fast real mode is alive),
    each checked for a crossing and, by Hermite cubics of the slip and its exact rate under an
    error bound, for a dip.

    The input step was taken by ``method`` (dopri5 or rk4: its dense output gives the rocker
    speed in the looks; y_new holds its end). The output states of y_new are replaced. On a
    slip crossing (or a slip found beyond the band, 'late'), the input step is re-taken exactly
    to that time and the state there is left in y_new. Returns (t reached, fire, last slip,
    armed).
    """
    Ko, zs, LIN, W, _ = clock
    lag = LAG_BOUND * rtol * (1.0 + abs(y[OMEGA1]))   # at the main step's tolerance
    # the integrated output's own tolerance: its ringing decides where the slip crosses zero,
    # and it costs little (four states), so it is held to OUTPUT_RTOL at loose settings
    rtol = min(rtol, OUTPUT_RTOL)
    atol = min(atol, OUTPUT_RTOL * 1e-2)
    for i in range(N_OUTPUT):
        z[i] = y[OUTPUT_STATES[i]]
        zs[i] = z[i]
    t1 = t + h
    dense_coefficients(method, h, y, y_new, K, OMEGA2, Cv)
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
                if sample_due(grid, counters, t1):
                    emit_samples(True, exact, method, t, h, y, y_new, K, t, h, z, clock, mode, P,
                                 ACT, grid, out, counters, t1, ycomb, ztmp, dytmp, auxtmp)
                for i in range(N_OUTPUT):
                    y_new[OUTPUT_STATES[i]] = z_new[i]
                return t1, NO_EVENT, g1, armed
        ring = P[P_OUTPUT_RING]
        n_exact = max(1, int(math.ceil(ring * h / ARMED_PHASE_STEP))) if ring > 0.0 else 1
        h_out = h / n_exact
        if ring > 0.0:
            h_near = EXACT_PHASE_STEP / ring
        fast_rate, fast_until = _fast_real_modes(
            t, h, LIN, W, SLIP_TOLERANCE * (1.0 + abs(z[Z_OMEGA3])))
        dw3_0 = omega3_rate(z, P)
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
    fire = NO_EVENT
    dv0 = poly_rate(Cv, 0.0, h)
    gtol = SLIP_TOLERANCE * (1.0 + abs(Cv[0]) + abs(z[Z_OMEGA3]))   # the slip's band at tau
    factor = 1.0
    near = False   # a look ended at the slip's band: the rest of the step in short looks
    while tau < t1:
        if exact:
            hs = h_out
            if tau < fast_until:
                hs = min(hs, EXACT_PHASE_STEP / fast_rate)
            if near or not (armed and g0 > 2.0 * gtol):
                hs = min(hs, h_near)
            last = tau + hs >= t1 * (1.0 - 1e-15) or t1 - (tau + hs) < 1e-9 * hs
            if last:
                hs = t1 - tau
            output_at(tau + hs - t, zs, P, LIN, W, z_new, False)
            dw3_1 = omega3_rate(z_new, P)
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
        dv1 = poly_rate(Cv, x1, h)
        g1 = z_new[Z_OMEGA3] - v1
        gtol = SLIP_TOLERANCE * (1.0 + abs(v1) + abs(z_new[Z_OMEGA3]))
        # the slip falls to within one more such fall of zero and within how far the rocker
        # speed's interpolant may lag the linkage's
        falls_near_zero = g1 < g0 - g1 and g1 < lag
        if exact and armed and g0 > 0.0 and falls_near_zero and hs > h_near * 1.000001:
            # a long look whose slip falls to (or within the interpolant's lag of) zero: looked
            # at again in short ones, for within ARMED_PHASE_STEP rad of the ringing the slip
            # can fall through zero, rise and fall again, and a search between the look's ends
            # finds any of the three roots (a catch 61 µs long lost, the later one taken)
            near = True
            continue
        sigma = 1.0
        hi = 1.0
        lo = 0.0
        if not (armed and g0 > 0.0) and g1 < -gtol:
            # a look from inside the band (just after a release; or just under it, as in
            # guard_watch.watch_step) to below it: a catch if the slip left the band upwards
            # first (a short open interval: a heavy load's second engagement 0.6 ms after its
            # release), located after that; else found late
            lo = left_band_upwards(exact, t, h, tau, hs, z, clock, P, Cv, ztmp, g0,
                                   hs * (dw3_0 - dv0), g1, hs * (dw3_1 - dv1), gtol)
            if lo < 0.0:
                # the cubic misses a small rise early in a long look (a 5 ms look whose true
                # slip stands at most 0.012 rad/s above the band, 0.3 ms after the release):
                # the true slip's highest point
                gm = true_split_slip(method, exact, 0.5, t, h, y, y_new, K, tau, hs, z, clock, P,
                                     ACT, ycomb, ztmp)
                lo, _ = true_beyond(method, exact, t, h, y, y_new, K, tau, hs, z, clock, P, ACT,
                                    ycomb, ztmp, 0.5, gm, 1.0, gtol)
            if lo > 0.0:
                fire = CROSSING
        elif armed and g0 > 0.0:
            if g1 < 0.0:
                fire = CROSSING
            elif falls_near_zero and true_split_slip(
                    method, exact, 1.0, t, h, y, y_new, K, tau, hs, z, clock, P, ACT, ycomb,
                    ztmp) < -gtol:
                # the polynomial slip falls near zero: its end is read on the linkage too, whose
                # slip may be below zero already (a lag of 0.09 rad/s on a short coupler at
                # rtol 1e-4: the catch was taken a sub-step late, 0.08 rad/s past it)
                fire = CROSSING
            else:
                # both ends positive: a dip inside (a short catch)? Hermite cubics of the slip
                # with its exact rates (ω3' of the output, v' of the input's dense output),
                # refined where their error bound could hide one
                if exact:
                    m4 = hs ** 4 * (jerk4 + v4)
                else:
                    dense_coefficients(DOPRI5, hs, z, z, Ko, Z_OMEGA3, Cz)
                    m4 = 24.0 * abs(Cz[4]) + hs ** 4 * v4
                tm, gm = split_dip(exact, t, h, tau, hs, z, clock, P, Cv, ztmp, g0,
                                   hs * (dw3_0 - dv0), g1, hs * (dw3_1 - dv1), m4, gtol)
                if tm >= 0.0:
                    fire = CROSSING
                    hi = tm
        if fire == CROSSING:
            # located on the true slip (the linkage's rocker speed, as the reset map sees
            # it): the end values must bracket it there too
            tol_s = root_tolerance(tau, hs)
            gt_hi = true_split_slip(method, exact, hi, t, h, y, y_new, K, tau, hs, z, clock, P,
                                    ACT, ycomb, ztmp)
            gt_lo = true_split_slip(method, exact, lo, t, h, y, y_new, K, tau, hs, z, clock, P,
                                    ACT, ycomb, ztmp)
            if gt_hi >= 0.0 and lo == 0.0:
                # a dip of the polynomial slip (or its fall through zero by the look's end)
                # where the true slip is not below zero: is the true slip's own dip nearby?
                # (rtol 1e-4: the polynomial slip at -0.006 rad/s at the look's end, the true
                # slip at +0.006 there and down to -0.028 inside it, for 0.5 ms)
                sm, gm = _true_dip(method, exact, t, h, y, y_new, K, tau, hs, z, clock, P, ACT,
                                   ycomb, ztmp, hi, gt_hi, g0, hs * (dw3_0 - dv0), g1,
                                   hs * (dw3_1 - dv1), gtol)
                if sm >= 0.0:
                    hi = sm
                    gt_hi = gm
            elif lo > 0.0 and gt_lo <= gtol:
                # the polynomial slip left the band upwards at lo, the true slip not there:
                # did it nearby?
                sm, gm = true_beyond(method, exact, t, h, y, y_new, K, tau, hs, z, clock, P, ACT,
                                     ycomb, ztmp, lo, gt_lo, 1.0, gtol)
                if sm >= 0.0:
                    lo = sm
                    gt_lo = gm
            if gt_hi < 0.0 < gt_lo:
                # started at the root of the sub-step's Hermite cubic of the slip (its ends'
                # values and exact rates), with its slope
                start, start_slope = hermite_root(g0, hs * (dw3_0 - dv0), g1, hs * (dw3_1 - dv1),
                                                  lo, hi)
                sigma = locate_root(True, exact, method, t, h, y, y_new, K, tau, hs, z, clock,
                                    mode, P, ACT, lo, hi, gt_lo, gt_hi, start, start_slope,
                                    tol_s, 0.0, ycomb, dytmp, auxtmp, ztmp, counters)
            elif gt_hi >= -gtol:
                fire = NO_EVENT   # a dip of the rocker speed's interpolant alone
                if hi == 1.0:
                    g1 = gt_hi
            elif lo > 0.0 and gt_lo <= 0.0:
                fire = NO_EVENT   # the true slip never left the band upwards: found late
            else:
                sigma = lo if gt_lo <= 0.0 else hi
        if fire == NO_EVENT and g1 < -gtol and not (armed and g0 > 0.0):
            # from inside the band to below it, never above it: where the true slip leaves the
            # band downwards (dense_step.locate_band_exit), not late at the look's end
            tol_s = root_tolerance(tau, hs)
            sigma = locate_band_exit(
                True, exact, method, t, h, y, y_new, K, tau, hs, z, clock, mode, P, ACT,
                true_split_slip(method, exact, 0.0, t, h, y, y_new, K, tau, hs, z, clock, P, ACT,
                                ycomb, ztmp),
                true_split_slip(method, exact, 1.0, t, h, y, y_new, K, tau, hs, z, clock, P, ACT,
                                ycomb, ztmp),
                gtol, tol_s, ycomb, dytmp, auxtmp, ztmp, counters)
            if sigma >= 0.0:
                fire = CROSSING
            else:
                sigma = 1.0
        if fire == NO_EVENT and g1 < -gtol:
            fire = FOUND_LATE
        if fire != NO_EVENT:
            t_ev = tau + sigma * hs
            # true states at the event: the output exactly or by a re-taken sub-step, the input
            # by a re-taken step from t
            if exact:
                output_at(t_ev - t, zs, P, LIN, W, z_new, True)
            else:
                dopri5_step(OUTPUT, tau, z, t_ev - tau, mode, P, ACT, Ko, z_new, ztmp, auxtmp,
                            rtol, atol, ERR_OUTPUT)
            if sample_due(grid, counters, t_ev):
                emit_samples(True, exact, method, t, h, y, y_new, K, tau, t_ev - tau, z, clock,
                             mode, P, ACT, grid, out, counters, t_ev, ycomb, ztmp, dytmp, auxtmp)
            if t_ev < t1:
                take_step(method, INPUT, t, y, t_ev - t, mode, P, ACT, K, y_new, ytmp, auxtmp,
                          rtol, atol, ERR_INPUT, counters)
            for i in range(N_OUTPUT):
                y_new[OUTPUT_STATES[i]] = z_new[i]
            if not exact:
                h_io[H_OUTPUT] = h_out
            return t_ev, fire, g1, armed
        if sample_due(grid, counters, t1 if last else tau + hs):
            emit_samples(True, exact, method, t, h, y, y_new, K, tau, hs, z, clock, mode, P, ACT,
                         grid, out, counters, t1 if last else tau + hs, ycomb, ztmp, dytmp,
                         auxtmp)
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
