"""Every path's clutch guard watched over an accepted step of the N-path machine (issue 33).

A guard per path (physics/paths.py): an engaged path's clutch torque λ_k, an open path's slip
s_k = ωn − v_k, both falling through zero at a switch. Each is watched along the whole step, not
only at its ends, as solver/guard_watch.py watches the one path's: as a polynomial of the step's
dense output (the slip from the node's speed and the rocker speed v_k, both states; a lone
engaged path's torque Jn·ωn' + Ts from the node's speed, the twist and the output speed), its
lowest point bounding a dip through zero and back (witness.py's pieces), a crossing located on
the true guard (one right-hand side per look). With two clutches engaged (the locked crank) the
torques come from a linear solve, not a polynomial: they are looked at N_LOOKS times along the
step instead. Of the crossings of all paths the earliest is the event. A guard that started the
step inside its band (disarmed after a switch) and ends below it is located where it left the band
upwards and fell back through zero, or else where it leaves the band downwards (a higher-order
contact the reset's first-order decision missed: ``locate_band_exit``, as the reference does); a
guard found beyond its band at the step's end with nothing located is 'late' (FOUND_LATE), as for
one path.
"""
import math

from ..physics import layout as L
from ..physics.compiled import inline_kernel, kernel
from ..physics.layout import Z_OMEGA3
from ..physics.output_exact import output_at
from ..physics.paths import (
    A_SLIP,
    A_TORQUE,
    V_PATH,
    bit,
    n_paths,
    path_speed,
    paths_rhs,
    set_size,
    slip_band,
    torque_band,
)
from . import witness
from .advance_layout import C_RHS, CROSSING, FOUND_LATE, NO_EVENT
from .dense_step import MAX_SECANTS, root_tolerance
from .guard_watch import DIP_CHECK
from .steppers import dense_coefficients, dense_state

N_LOOKS = 8   # looks at a guard without a polynomial (two clutches engaged) per step


@kernel
def path_guard(k, mode, aux, P):
    """Path k's witness value and the half-width of its band: its clutch torque [N·m] when
    engaged, its slip [rad/s] when open."""
    if mode & bit(k):
        return aux[A_TORQUE + k], torque_band(P)
    return aux[A_SLIP + k], slip_band(k, aux)


@kernel
def true_path_guard(k, method, theta, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                    counters):
    """Path k's guard at t + θ·h: the dense state through the right-hand side; an open path's
    slip where the node's speed is a state (ω3, or ω4 behind a rigid shaft) from its own
    linkage alone (the right-hand side's value, without the other paths' linkages)."""
    dense_state(method, theta, h, y0, y1, K, ytmp)
    rigid = P[L.P_RIGID] > 0.0
    if not mode & bit(k) and (rigid or mode != 0 or P[L.P_J3] > 0.0):
        node = ytmp[L.OMEGA4] if rigid else ytmp[L.OMEGA3]
        return node - path_speed(k, t + theta * h, ytmp, P, ACT)
    paths_rhs(t + theta * h, ytmp, mode, P, ACT, dytmp, auxtmp)
    counters[C_RHS] += 1
    return path_guard(k, mode, auxtmp, P)[0]


@kernel
def path_guard_polynomial(k, method, h, y0, y1, K, mode, P, C, G):
    """Coefficients G of path k's guard over the step as a polynomial in θ ∈ [0, 1] (C: scratch
    (3, witness.N_POLY)); False when it is none (two clutches engaged). A lone engaged clutch passes
    λ = Jn·ωn' − Fn: J3·ω3' + c·θ + k·(ω3 − ω4), or (J3 + J4)·ω4' + M4(ω4) behind a rigid
    shaft (ω' the polynomial's θ-derivative over h)."""
    for i in range(witness.N_GUARD):
        G[i] = 0.0
    if not mode & bit(k):
        dense_coefficients(method, h, y0, y1, K, L.OMEGA3, C[0])
        dense_coefficients(method, h, y0, y1, K, V_PATH + k, C[1])
        for i in range(witness.N_POLY):
            G[i] = C[0, i] - C[1, i]
        return True
    if set_size(mode) != 1:
        return False
    rigid = P[L.P_RIGID] > 0.0
    node = L.OMEGA4 if rigid else L.OMEGA3
    dense_coefficients(method, h, y0, y1, K, node, C[0])
    inertia = (P[L.P_J3] + P[L.P_J4] if rigid else P[L.P_J3]) / h
    for i in range(witness.N_POLY - 1):
        G[i] = inertia * (i + 1) * C[0, i + 1]
    if rigid:
        G[0] += P[L.P_LOAD_TORQUE]
        kq = P[L.P_LOAD_QUADRATIC]
        if kq != 0.0:   # ω·|ω| with the sign ω has mid-step (physics: witness.guard_polynomial)
            kq = kq if witness.guard_value(C[0], 0.5) >= 0.0 else -kq
        for i in range(5):
            G[i] += P[L.P_LOAD_VISCOUS] * C[0, i]
            for j in range(5):
                G[i + j] += kq * C[0, i] * C[0, j]
        return True
    dense_coefficients(method, h, y0, y1, K, L.TWIST, C[1])
    dense_coefficients(method, h, y0, y1, K, L.OMEGA4, C[2])
    for i in range(witness.N_POLY):
        G[i] += P[L.P_C] * C[1, i] + P[L.P_KD] * (C[0, i] - C[2, i])
    return True


@kernel
def _look(k, sign, below, method, t, h, y0, y1, K, mode, P, ACT, lo, ytmp, dytmp, auxtmp,
          counters):
    """The first of N_LOOKS even looks after θ = lo where sign·guard < below: (θ, guard,
    θ and guard of the look before); θ = −1 when none."""
    prev = lo
    gprev = 0.0
    for j in range(1, N_LOOKS + 1):
        m = lo + (1.0 - lo) * j / N_LOOKS
        g = true_path_guard(k, method, m, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                            counters)
        if sign * g < below:
            return m, g, prev, gprev
        prev = m
        gprev = g
    return -1.0, 0.0, prev, gprev


@inline_kernel
def open_slip(k, method, sigma, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ycomb, ztmp):
    """Path k's true slip at tau + σ·hs inside a split step [t, t + h] (every clutch open, the
    output apart: paths_open.py): the exact output's ω3 (zs: the output at t, W its modal
    coordinates) less the linkage's rocker speed at the dense crank state."""
    tt = tau + sigma * hs
    dense_state(method, (tt - t) / h, h, y0, y1, K, ycomb)
    output_at(tt - t, zs, P, LIN, W, ztmp, False)
    return ztmp[Z_OMEGA3] - path_speed(k, tt, ycomb, P, ACT)


@inline_kernel
def _guard_at(split, k, method, m, t, h, y0, y1, K, mode, P, ACT, tau, hs, zs, LIN, W, ytmp,
              dytmp, auxtmp, ztmp, counters):
    """Path k's true guard at θ = m of the step (through the right-hand side), or at σ = m of
    a split step's look (the slip, with the linkage's rocker speed)."""
    if split:
        return open_slip(k, method, m, t, h, y0, y1, K, tau, hs, zs, LIN, W, P, ACT, ytmp, ztmp)
    return true_path_guard(k, method, m, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                           counters)


@kernel
def locate_path_root(split, k, method, t, h, y0, y1, K, mode, P, ACT, tau, hs, zs, LIN, W, lo,
                     hi, glo, ghi, start, slope, tol_theta, offset, ytmp, dytmp, auxtmp, ztmp,
                     counters):
    """The root of g = path k's true guard + ``offset`` in [lo, hi], g(lo) > 0 > g(hi); θ just
    past it (``_guard_at``: over the step, or over a split step's look). dense_step.locate_root's
    safeguarded secant from ``start`` (the polynomial's or a Hermite cubic's root, with its
    ``slope``; < 0: none), Illinois' regula falsi where a secant leaves the bracket and after
    MAX_SECANTS points."""
    side = 0
    m_prev, g_prev = (lo, glo) if glo < -ghi else (hi, ghi)
    nxt = start
    for it in range(200):
        if hi - lo <= tol_theta:
            break
        m = nxt if it < MAX_SECANTS and lo < nxt < hi else witness.illinois_point(
            it, lo, hi, glo, ghi)
        gm = _guard_at(split, k, method, m, t, h, y0, y1, K, mode, P, ACT, tau, hs, zs, LIN, W,
                       ytmp, dytmp, auxtmp, ztmp, counters) + offset
        lo, hi, glo, ghi, side = witness.illinois_update(m, gm, lo, hi, glo, ghi, side)
        if side == 0 or hi - lo <= tol_theta:
            break
        s = slope if it == 0 and m == start else (gm - g_prev) / (m - m_prev)
        m_prev = m
        g_prev = gm
        nxt = -1.0
        if not s < 0.0:
            continue
        step = -gm / s
        if abs(step) < 0.25 * tol_theta:
            # on the root: one point half a tolerance over it closes the bracket
            p = m + (0.5 * tol_theta if gm > 0.0 else -0.5 * tol_theta)
            gp = _guard_at(split, k, method, p, t, h, y0, y1, K, mode, P, ACT, tau, hs, zs, LIN,
                           W, ytmp, dytmp, auxtmp, ztmp, counters) + offset
            lo, hi, glo, ghi, side = witness.illinois_update(p, gp, lo, hi, glo, ghi, side)
            if side == 0:
                break
            continue
        nxt = m + step
    return hi


@kernel
def locate_band_exit(split, k, method, t, h, y0, y1, K, mode, P, ACT, tau, hs, zs, LIN, W, g0,
                     g1, band, tol_theta, ytmp, dytmp, auxtmp, ztmp, counters):
    """θ just past where path k's true guard, inside its band at θ = 0 (g0) and below it at
    θ = 1 (g1) without having left it upwards, crosses the band's lower edge −band; −1 when
    g0, g1 do not bracket it. Such a guard started at zero after a reset whose first-order
    decision (a rate of the guard ≥ 0) a higher order overturns at once: the slip of a rocker
    whose acceleration matched the node's within 3e-4 after a start impact rose 6e-11 rad/s
    (its band: 1.7e-9), fell through zero 12 ns later and left the band downwards at 36 ns.
    The switch belongs there, where the reference (paths_reference.py) makes it too — not at
    the end of the step (0.1 ms on: a late catch, an impact at −0.023 rad/s)."""
    if not g0 + band > 0.0 > g1 + band:
        return -1.0
    return locate_path_root(split, k, method, t, h, y0, y1, K, mode, P, ACT, tau, hs, zs, LIN,
                            W, 0.0, 1.0, g0 + band, g1 + band, -1.0, 0.0, tol_theta, band, ytmp,
                            dytmp, auxtmp, ztmp, counters)


@kernel
def path_crossing(k, armed, g0, g1, band, method, t, h, y0, y1, K, mode, P, ACT, tol_theta,
                  C, G, ytmp, dytmp, auxtmp, zs, LIN, W, ztmp, counters):
    """Where path k's guard falls through zero inside the step [t, t + h] (module text): (θ of
    the root on the true guard, CROSSING), (1, FOUND_LATE) for a guard beyond its band at the
    end with nothing located, or (−1, NO_EVENT)."""
    poly = path_guard_polynomial(k, method, h, y0, y1, K, mode, P, C, G)
    lo, glo = 0.0, g0
    hi, ghi = -1.0, 0.0
    start, slope = -1.0, 0.0
    if armed and g0 > 0.0:
        if poly:
            if g1 < 0.0:
                hi, ghi = 1.0, g1
                ga, gb = witness.guard_value(G, 0.0), witness.guard_value(G, 1.0)
                if ga > 0.0 > gb:
                    start = witness.first_root(G, ga, gb, tol_theta)
            else:   # a dip through zero and back inside the step
                tm, gm = witness.lowest_point(G, -band)
                if gm < -band or (tm > 0.0 and gm < DIP_CHECK * min(g0, g1)):
                    gt = true_path_guard(k, method, tm, t, h, y0, y1, K, mode, P, ACT, ytmp,
                                         dytmp, auxtmp, counters)
                    if gt < -band:
                        hi, ghi = tm, gt
                        ga = witness.guard_value(G, 0.0)
                        if gm < 0.0 < ga:
                            start = witness.poly_root(G, 0.0, tm, ga, gm, tol_theta)
            if start >= 0.0:
                slope = witness.guard_rate(G, start)
        else:
            m, g, lo, glo = _look(k, 1.0, 0.0, method, t, h, y0, y1, K, mode, P, ACT, 0.0,
                                  ytmp, dytmp, auxtmp, counters)
            if m > 0.0:
                hi, ghi = m, g
            if lo == 0.0:
                glo = g0
    elif g1 < -band:
        # from inside its band (just after a switch) to below it: located if the guard left
        # the band upwards first (a short phase), else late
        if poly:
            for i in range(witness.N_GUARD - 1):
                G[i] = -G[i]            # the highest point: the lowest of −guard
            top, _ = witness.lowest_point(G, -band)
            if top > 0.0:
                gt = true_path_guard(k, method, top, t, h, y0, y1, K, mode, P, ACT, ytmp,
                                     dytmp, auxtmp, counters)
                if gt > band:
                    lo, glo, hi, ghi = top, gt, 1.0, g1
        else:
            top, gt, _, _ = _look(k, -1.0, -band, method, t, h, y0, y1, K, mode, P, ACT, 0.0,
                                  ytmp, dytmp, auxtmp, counters)
            if 0.0 < top < 1.0:
                lo, glo, hi, ghi = top, gt, 1.0, g1
        if hi < 0.0:   # it never left the band upwards: where it leaves it downwards
            theta = locate_band_exit(False, k, method, t, h, y0, y1, K, mode, P, ACT, t, h, zs,
                                     LIN, W, g0, g1, band, tol_theta, ytmp, dytmp, auxtmp,
                                     ztmp, counters)
            if theta >= 0.0:
                return theta, CROSSING
    if hi < 0.0:
        if g1 < -band:
            return 1.0, FOUND_LATE
        return -1.0, NO_EVENT
    if not glo > 0.0 > ghi:
        return -1.0, NO_EVENT
    return locate_path_root(False, k, method, t, h, y0, y1, K, mode, P, ACT, t, h, zs, LIN, W,
                            lo, hi, glo, ghi, start, slope, tol_theta, 0.0, ytmp, dytmp, auxtmp,
                            ztmp, counters), CROSSING


@kernel
def first_crossing(armed, g0, g1, method, t, h, y0, y1, K, mode, P, ACT, aux1, C, G, ytmp,
                   dytmp, auxtmp, zs, LIN, W, ztmp, counters):
    """The earliest switch of any path inside the accepted step: (θ, path, fire); fire
    NO_EVENT when none. g0, g1: every path's guard at the step's start and end (g1 from
    aux1, written here); armed: the paths whose guard has left its band since their last
    switch (half-open rule)."""
    tol_theta = root_tolerance(t, h)
    n = n_paths(P)
    for k in range(n):
        g1[k] = path_guard(k, mode, aux1, P)[0]
    best = math.inf
    path = -1
    fire = NO_EVENT
    for k in range(n):
        band = path_guard(k, mode, aux1, P)[1]
        theta, found = path_crossing(k, armed & bit(k) != 0, g0[k], g1[k], band, method, t, h,
                                     y0, y1, K, mode, P, ACT, tol_theta, C, G, ytmp, dytmp,
                                     auxtmp, zs, LIN, W, ztmp, counters)
        # the earliest located crossing; a late guard only where none is located
        if found == CROSSING and (fire != CROSSING or theta < best) or (
                found == FOUND_LATE and fire == NO_EVENT):
            best, path, fire = theta, k, found
    return best, path, fire
