"""The N-path machine with every clutch open (issue 33): the output runs apart, as the one path's
does (slip_watch.py).

With no clutch engaged, J3, the shaft and J4 are the one-path machine's open output (physics.md
§7): linear for a constant plus viscous load, and solved in closed form
(physics/output_exact.py), so its ringing (the conveyor's J3 at 1225 rad/s, the stiff shaft's at
31 600 rad/s) leaves the steps; the input (the crank and every rocker) is stepped alone, at the
crank's pace (steppers.INPUT: the output's rates held at zero).

Every path's slip s_k = ω3 − v_k is watched over the step as slip_watch.py watches the one
path's: a path whose slip a modal lower bound keeps clear of zero over the whole step is not
looked at (slip_watch._slip_floor: the usual free-running step, every path cleared); the others
in looks of ≤ 3 rad of the ringing (0.75 rad near a band, or while a fast real mode lives), each
checked for a fall through zero at its end, a dip inside it by Hermite cubics of the slip with
its exact rates under an error bound (slip_look.split_dip) or, for a path whose clutch has just
released, a rise out of the band and a fall (slip_look.left_band_upwards), else the slip's fall
out of the band's lower edge (paths_watch.locate_band_exit). The rocker speed in a
look is the input step's dense polynomial of v_k; what a look finds is confirmed and located on
the true slip (the linkage's v_k at the dense crank state, paths_watch.open_slip), whose own
extremum is searched for where the two disagree (``_true_beyond``). In the first look where any
path finds something, the earliest path's located catch is the event; the input step is re-taken
to it and the output is set there exactly.
"""
import math

from ..physics.clutch import SLIP_TOLERANCE
from ..physics.compiled import inline_kernel, kernel
from ..physics.layout import N_OUTPUT, OMEGA1, OUTPUT_STATES, P_OUTPUT_RING, Z_OMEGA3
from ..physics.output_exact import modal_coordinates, modes_over, output_at, output_from_modes
from ..physics.paths import V_PATH, bit, n_paths
from .advance_layout import C_SUBSTEPS, CROSSING, FOUND_LATE, NO_EVENT
from .dense_step import root_tolerance
from .paths_steps import paths_step
from .paths_watch import locate_band_exit, locate_path_root, open_slip
from .slip_look import left_band_upwards, omega3_rate, poly_rate, split_dip
from .slip_watch import (
    ARMED_PHASE_STEP,
    EXACT_PHASE_STEP,
    LAG_BOUND,
    _fast_real_modes,
    _modal_jerk_bound,
    _slip_floor,
)
from .steppers import INPUT, dense_coefficients
from .witness import hermite_minimum, hermite_root, poly_value

# the per-path rows of ``looks`` (paths_hybrid.py carves it out of its scratch)
LOOK_SLIP = 0       # the slip at the look's start (the polynomial's, or the true one)
LOOK_RATE = 1       # the rocker speed's rate there (its polynomial's)
LOOK_BAND = 2       # the slip's band there
N_LOOK_ROWS = 3


@inline_kernel
def open_band(v, w3):
    """Half-width of an open path's slip band [rad/s] (physics/clutch.py's, of its speeds)."""
    return SLIP_TOLERANCE * (1.0 + abs(v) + abs(w3))


@kernel
def _true_beyond(k, method, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb, ztmp, m, gm,
                 side, gtol):
    """(σ, slip) where path k's true slip stands beyond its band on one side (side −1: below
    −gtol, +1: above gtol) in a look whose polynomial slip does so at σ = m (the true slip gm
    there), else (−1, gm): golden sections of [0, 1] about m for the true slip's extremum
    (slip_look.true_beyond for one path: the polynomial's point is where it first leaves the
    band, not where the true slip is furthest out)."""
    a = 0.0
    b = 1.0
    fm = side * gm
    while b - a > 1e-9:
        x = m - 0.381966 * (m - a) if m - a > b - m else m + 0.381966 * (b - m)
        gx = open_slip(k, method, x, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb, ztmp)
        if side * gx > gtol:
            return x, gx
        if side * gx > fm:
            if x < m:
                b = m
            else:
                a = m
            m = x
            fm = side * gx
        elif x < m:
            a = x
        else:
            b = x
    return -1.0, gm


@kernel
def _look_at_path(k, armed, method, t, h, y0, y1, K, tau, hs, x1, zs, LIN, W, clock, P, ACT,
                  Cv, z, z_new, looks, dw3_0, dw3_1, jerk4, lag, ycomb, ztmp, dytmp, auxtmp,
                  counters):
    """Path k over the look [tau, tau + hs] (slip_watch.split_output's checks, for one path of
    N): (σ of its event in the look, fire, the slip at the look's end, its band there).
    looks[LOOK_*, k] hold the look's start; armed: the path's guard has left its band since its
    last switch."""
    g0 = looks[LOOK_SLIP, k]
    v1 = poly_value(Cv, x1)
    dv1 = poly_rate(Cv, x1, h)
    g1 = z_new[Z_OMEGA3] - v1
    gtol = open_band(v1, z_new[Z_OMEGA3])
    d0 = hs * (dw3_0 - looks[LOOK_RATE, k])
    d1 = hs * (dw3_1 - dv1)
    falls_near_zero = g1 < g0 - g1 and g1 < lag
    fire = NO_EVENT
    sigma = 1.0
    hi = 1.0
    lo = 0.0
    if not (armed and g0 > 0.0) and g1 < -gtol:
        # from inside the band (just after its release) to below it: a catch if the slip left
        # the band upwards first, located after that; else found late
        lo = left_band_upwards(True, t, h, tau, hs, z, clock, P, Cv, ztmp, g0, d0, g1, d1, gtol)
        if lo < 0.0:
            gm = open_slip(k, method, 0.5, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb,
                           ztmp)
            lo, _ = _true_beyond(k, method, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb,
                                 ztmp, 0.5, gm, 1.0, gtol)
        if lo > 0.0:
            fire = CROSSING
    elif armed and g0 > 0.0:
        if g1 < 0.0:
            fire = CROSSING
        elif falls_near_zero and open_slip(k, method, 1.0, t, h, y0, y1, K, tau, hs, zs, LIN, W,
                                           P, ACT, ycomb, ztmp) < -gtol:
            fire = CROSSING   # the linkage's slip is below zero already (the interpolant lags)
        else:
            # a dip inside: Hermite cubics with exact rates, refined where their error bound
            # (the modes' and the rocker polynomial's 4th derivatives) could hide one
            m4 = hs ** 4 * (jerk4 + 24.0 * abs(Cv[4]) / h ** 4)
            tm, _ = split_dip(True, t, h, tau, hs, z, clock, P, Cv, ztmp, g0, d0, g1, d1, m4,
                              gtol)
            if tm >= 0.0:
                fire = CROSSING
                hi = tm
    if fire == CROSSING:
        # located on the true slip: the bracket's ends must hold there too
        tol_s = root_tolerance(tau, hs)
        gt_hi = open_slip(k, method, hi, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb,
                          ztmp)
        gt_lo = open_slip(k, method, lo, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb,
                          ztmp)
        if gt_hi >= 0.0 and lo == 0.0:
            # a dip (or a fall by the look's end) of the polynomial slip that the true slip does
            # not share there: its own dip nearby? (from the Hermite cubic's lowest point for
            # a fall by the end)
            m = hi
            gm = gt_hi
            sm = -1.0
            if hi == 1.0:
                xm, _ = hermite_minimum(g0, d0, g1, d1)
                m = xm
                if xm > 0.0:
                    gm = open_slip(k, method, xm, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT,
                                   ycomb, ztmp)
                    if gm < -gtol:
                        sm = xm
            if sm < 0.0 and m > 0.0:
                sm, gm = _true_beyond(k, method, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT,
                                      ycomb, ztmp, m, gm, -1.0, gtol)
            if sm >= 0.0:
                hi = sm
                gt_hi = gm
        elif lo > 0.0 and gt_lo <= gtol:
            sm, gm = _true_beyond(k, method, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb,
                                  ztmp, lo, gt_lo, 1.0, gtol)
            if sm >= 0.0:
                lo = sm
                gt_lo = gm
        if gt_hi < 0.0 < gt_lo:
            start, slope = hermite_root(g0, d0, g1, d1, lo, hi)
            sigma = locate_path_root(True, k, method, t, h, y0, y1, K, 0, P, ACT, tau, hs, zs,
                                     LIN, W, lo, hi, gt_lo, gt_hi, start, slope, tol_s, 0.0,
                                     ycomb, dytmp, auxtmp, ztmp, counters)
        elif gt_hi >= -gtol:
            fire = NO_EVENT   # a dip of the rocker speed's interpolant alone
            if hi == 1.0:
                g1 = gt_hi
        elif lo > 0.0 and gt_lo <= 0.0:
            fire = NO_EVENT   # the true slip never left the band upwards: found late below
        else:
            sigma = lo if gt_lo <= 0.0 else hi
    if fire == NO_EVENT and g1 < -gtol and not (armed and g0 > 0.0):
        # from inside the band to below it, never above it: where the true slip leaves the
        # band downwards (paths_watch.locate_band_exit), not late at the look's end
        gs = open_slip(k, method, 0.0, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb, ztmp)
        ge = open_slip(k, method, 1.0, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb, ztmp)
        tol_s = root_tolerance(tau, hs)
        exit_at = locate_band_exit(True, k, method, t, h, y0, y1, K, 0, P, ACT, tau, hs, zs, LIN,
                                   W, gs, ge, gtol, tol_s, ycomb, dytmp, auxtmp, ztmp, counters)
        if exit_at >= 0.0:
            sigma = exit_at
            fire = CROSSING
    if fire == NO_EVENT and g1 < -gtol:
        fire = FOUND_LATE
    looks[LOOK_RATE, k] = dv1
    return sigma, fire, g1, gtol


@kernel
def open_watch(method, t, h, y, y_new, K, P, ACT, LIN, W, zs, z, z_new, ztmp, stack, Cv, looks,
               armed, g0, rtol, atol, aux1, ytmp, ycomb, dytmp, auxtmp, counters):
    """The open output over the accepted input step [t, t + h] (module text). g0: every path's
    true slip at t; armed: the paths whose slip has left its band since their last switch.
    Returns (t reached, path, fire, armed): with an event (CROSSING, or FOUND_LATE at the end
    of the look that found a slip below its band) the input step re-taken to it (y_new, K[6],
    aux1 there); the output of y_new is the exact one at the time reached, and zs, W the
    output at t and its modal coordinates (for the samples)."""
    n = n_paths(P)
    clock = (K, zs, LIN, W, stack)
    lag = LAG_BOUND * rtol * (1.0 + abs(y[OMEGA1]))
    for i in range(N_OUTPUT):
        zs[i] = y[OUTPUT_STATES[i]]
        z[i] = zs[i]
    t1 = t + h
    modal_coordinates(zs, P, LIN, W)
    modes = modes_over(h, LIN, W)
    output_from_modes(h, zs, P, LIN, modes, z_new, True)
    watch = 0
    for k in range(n):
        dense_coefficients(method, h, y, y_new, K, V_PATH + k, Cv[k])
        if armed & bit(k) and g0[k] > 0.0:
            g1 = z_new[Z_OMEGA3] - poly_value(Cv[k], 1.0)
            gtol = SLIP_TOLERANCE * (1.0 + abs(Cv[k, 0]) + abs(zs[Z_OMEGA3]) + abs(g1)
                                     + abs(g0[k]))
            if _slip_floor(h, g0[k], g1, LIN, W, Cv[k], modes) > 4.0 * gtol:
                continue   # no catch of path k anywhere in the step
        watch |= bit(k)
    counters[C_SUBSTEPS] += 1
    if watch == 0:
        for i in range(N_OUTPUT):
            y_new[OUTPUT_STATES[i]] = z_new[i]
        return t1, -1, NO_EVENT, armed

    ring = P[P_OUTPUT_RING]
    h_out = h / max(1, int(math.ceil(ring * h / ARMED_PHASE_STEP))) if ring > 0.0 else h
    h_near = EXACT_PHASE_STEP / ring if ring > 0.0 else math.inf
    fast_rate, fast_until = _fast_real_modes(t, h, LIN, W,
                                             SLIP_TOLERANCE * (1.0 + abs(zs[Z_OMEGA3])))
    jerk4 = _modal_jerk_bound(LIN, W)
    dw3_0 = omega3_rate(z, P)
    for k in range(n):
        looks[LOOK_SLIP, k] = g0[k]
        looks[LOOK_RATE, k] = poly_rate(Cv[k], 0.0, h)
        looks[LOOK_BAND, k] = open_band(Cv[k, 0], zs[Z_OMEGA3])
    tau = t
    near = False   # a long look ended with a slip near zero: the rest of the step in short ones
    while tau < t1:
        hs = h_out
        if tau < fast_until:
            hs = min(hs, EXACT_PHASE_STEP / fast_rate)
        short = near
        for k in range(n):   # a path near its band: short looks
            if watch & bit(k) and not (armed & bit(k) and
                                       looks[LOOK_SLIP, k] > 2.0 * looks[LOOK_BAND, k]):
                short = True
        if short:
            hs = min(hs, h_near)
        last = tau + hs >= t1 * (1.0 - 1e-15) or t1 - (tau + hs) < 1e-9 * hs
        if last:
            hs = t1 - tau
        output_at(tau + hs - t, zs, P, LIN, W, z_new, False)
        dw3_1 = omega3_rate(z_new, P)
        counters[C_SUBSTEPS] += 1
        x1 = 1.0 if last else (tau + hs - t) / h
        if hs > h_near * 1.000001:
            # a long look where an armed slip falls to (or within the interpolant's lag of)
            # zero: looked at again in short ones (within 3 rad of the ringing a slip can fall
            # through zero, rise and fall again: only the first is the catch)
            for k in range(n):
                g = looks[LOOK_SLIP, k]
                g1 = z_new[Z_OMEGA3] - poly_value(Cv[k], x1)
                if watch & bit(k) and armed & bit(k) and g > 0.0 and g1 < g - g1 and g1 < lag:
                    near = True
            if near:
                continue
        best = math.inf
        path = -1
        fire = NO_EVENT
        for k in range(n):
            if not watch & bit(k):
                continue
            sigma, found, g1, gtol = _look_at_path(
                k, armed & bit(k) != 0, method, t, h, y, y_new, K, tau, hs, x1, zs, LIN, W, clock,
                P, ACT, Cv[k], z, z_new, looks, dw3_0, dw3_1, jerk4, lag, ycomb, ztmp, dytmp,
                auxtmp, counters)
            if found == CROSSING and (fire != CROSSING or sigma < best) or (
                    found == FOUND_LATE and fire == NO_EVENT):
                best, path, fire = sigma, k, found
            looks[LOOK_SLIP, k] = g1
            looks[LOOK_BAND, k] = gtol
            if abs(g1) > gtol:
                armed |= bit(k)
        if fire != NO_EVENT:
            t_ev = tau + best * hs
            output_at(t_ev - t, zs, P, LIN, W, z_new, True)
            if t_ev < t1:
                paths_step(method, INPUT, t, y, t_ev - t, 0, P, ACT, K, y_new, ytmp, aux1, rtol,
                           atol, counters)
            for i in range(N_OUTPUT):
                y_new[OUTPUT_STATES[i]] = z_new[i]
            return t_ev, path, fire, armed
        tau = t1 if last else tau + hs
        for i in range(N_OUTPUT):
            z[i] = z_new[i]
        dw3_0 = dw3_1
    output_at(h, zs, P, LIN, W, z_new, True)   # with the work terms
    for i in range(N_OUTPUT):
        y_new[OUTPUT_STATES[i]] = z_new[i]
    return t1, -1, NO_EVENT, armed
