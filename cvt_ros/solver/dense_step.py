"""An accepted step read through its dense output: the guard at any point of it, the whole state
inside a split step (the input's dense output with the open output's own solution), a guard's
root located on the true guard, and the caller's samples written without shortening the step.

Pieces of the hybrid loop (hybrid.py) that the watches of the guard (guard_watch.py) and of the
open output's slip (slip_watch.py) share.
"""
import math

from ..physics.clutch import clutch_guard
from ..physics.compiled import inline_kernel, kernel
from ..physics.dynamics import project, rhs, rocker_speed
from ..physics.layout import (
    DISENGAGED,
    N_OUTPUT,
    OMEGA3,
    OUTPUT_STATES,
    P_C,
    P_J3,
    P_KD,
    P_RIGID,
    TWIST,
    W_DAMPING,
)
from ..physics.output_exact import output_at
from .advance_layout import C_NEXT_SAMPLE, C_RHS
from .output import write_sample
from .steppers import DOPRI5, dense_state, dopri5_step, rk4_step
from .witness import illinois_point, illinois_update

MAX_SECANTS = 8   # points of the secant phase of locate_root before Illinois takes over


@kernel
def take_step(method, kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol, err_idx,
              counters):
    if method == DOPRI5:
        counters[C_RHS] += 6
        return dopri5_step(kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol, err_idx)
    counters[C_RHS] += 4
    return rk4_step(kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux)


@inline_kernel
def guard_at(method, theta, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp, counters):
    """The guard at t + θ·h from the dense output and one right-hand side (the twist rule).
    An open massless damped node's twist is its exact relaxation, as the step's end and the
    samples have it (the step holds it still): the slip just after a release is ω4 − v."""
    dense_state(method, theta, h, y0, y1, K, ytmp)
    if twist_relaxes(mode, P):
        ytmp[TWIST] = relaxed_twist(y0[TWIST], theta * h, P)
    rhs(t + theta * h, ytmp, mode, P, ACT, dytmp, auxtmp)
    counters[C_RHS] += 1
    g, _ = clutch_guard(mode, ytmp, dytmp, auxtmp, P)
    return g


@inline_kernel
def output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, with_work):
    """Output subsystem at tau + σ·hs: the exact solution from the step start t (exact), or the
    dense output of the sub-step [tau, tau+hs] that started at z0."""
    Ko, zs, LIN, W, _ = clock
    if exact:
        output_at(tau + sigma * hs - t, zs, P, LIN, W, ztmp, with_work)
    else:
        dense_state(DOPRI5, sigma, hs, z0, z0, Ko, ztmp)


@inline_kernel
def split_state(method, exact, sigma, t, h, y0, y1, K, tau, hs, z0, clock, P, ycomb, ztmp,
                with_work):
    """The full state at tau + σ·hs inside a split step: the input subsystem from the main
    step's dense output (y1: the input step's end, for rk4's Hermite cubic), the output
    subsystem from output_state."""
    tt = tau + sigma * hs
    dense_state(method, (tt - t) / h, h, y0, y1, K, ycomb)
    output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, with_work)
    for i in range(N_OUTPUT):
        ycomb[OUTPUT_STATES[i]] = ztmp[i]
    return tt


@inline_kernel
def true_split_slip(method, exact, sigma, t, h, y0, y1, K, tau, hs, z0, clock, P, ACT, ycomb,
                    ztmp):
    """The slip at tau + σ·hs with the rocker speed from the closed-form linkage at the dense
    crank state (what the reset map sees), not from the rocker speed's own dense polynomial."""
    tt = split_state(method, exact, sigma, t, h, y0, y1, K, tau, hs, z0, clock, P, ycomb, ztmp,
                     False)
    return ycomb[OMEGA3] - rocker_speed(tt, ycomb, P, ACT)


@inline_kernel
def _true_guard(split, exact, method, m, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, ytmp,
                dytmp, auxtmp, ztmp, counters):
    """The true guard at θ = m: of the step (the right-hand side) or of the output sub-step."""
    if split:
        return true_split_slip(method, exact, m, t, h, y0, y1, K, tau, hs, z0, clock, P, ACT,
                               ytmp, ztmp)
    return guard_at(method, m, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp, counters)


@inline_kernel
def root_tolerance(t, h):
    """How closely a root is located, as a fraction of a step (or look) h [s] at t [s]: 1e-13 s,
    or 8 ulps of t where those are more (closer is below what t resolves)."""
    return max(1e-13, 8.0 * 2.2e-16 * abs(t)) / h


@kernel
def locate_root(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, lo, hi,
                glo, ghi, start, start_slope, tol_theta, offset, ytmp, dytmp, auxtmp, ztmp,
                counters):
    """The root of g(θ) = the true guard + ``offset``, g(lo) > 0 > g(hi); θ just past it (within
    tol_theta). (offset: 0 for the guard's own root; its band for where it leaves the band
    downwards, ``locate_band_exit``.)

    θ runs over the step [t, t+h] (split = False: the guard through the right-hand side) or
    over the output sub-step [tau, tau+hs] (the slip, with the linkage's rocker speed).
    A safeguarded secant: from ``start`` (the root of the guard's polynomial, say; < 0: none) a
    Newton step with ``start_slope`` (its slope there), then secants through the last two
    points while they stay inside the bracket; once a secant step falls below a quarter of the
    tolerance the bracket is closed by one point half a tolerance over the root, instead of
    waiting for the far end to move. Illinois' regula falsi (every 4th point a bisection) takes
    over where a secant leaves the bracket and after MAX_SECANTS points: the search always ends.
    Each point costs a right-hand side (split = False) or a linkage evaluation (split).
    """
    side = 0
    # the point the next secant pivots on: the bracket end nearer the root
    m_prev, g_prev = (lo, glo) if glo < -ghi else (hi, ghi)
    nxt = start
    for it in range(200):
        if hi - lo <= tol_theta:
            break
        if it < MAX_SECANTS and lo < nxt < hi:
            m = nxt
        else:
            m = illinois_point(it, lo, hi, glo, ghi)
        gm = _true_guard(split, exact, method, m, t, h, y0, y1, K, tau, hs, z0, clock, mode, P,
                         ACT, ytmp, dytmp, auxtmp, ztmp, counters) + offset
        lo, hi, glo, ghi, side = illinois_update(m, gm, lo, hi, glo, ghi, side)
        if side == 0 or hi - lo <= tol_theta:
            break
        slope = start_slope if it == 0 and m == start else (gm - g_prev) / (m - m_prev)
        m_prev = m
        g_prev = gm
        nxt = -1.0
        if not slope < 0.0:
            continue
        step = -gm / slope
        if abs(step) < 0.25 * tol_theta:
            # the secant sits on the root: one point half a tolerance over it closes the bracket
            p = m + (0.5 * tol_theta if gm > 0.0 else -0.5 * tol_theta)
            gp = _true_guard(split, exact, method, p, t, h, y0, y1, K, tau, hs, z0, clock, mode,
                             P, ACT, ytmp, dytmp, auxtmp, ztmp, counters) + offset
            lo, hi, glo, ghi, side = illinois_update(p, gp, lo, hi, glo, ghi, side)
            if side == 0:
                break
        else:
            nxt = m + step
    return hi


@kernel
def locate_band_exit(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, g0,
                     g1, band, tol_theta, ytmp, dytmp, auxtmp, ztmp, counters):
    """θ just past where the true guard, inside its band at θ = 0 (g0) and below it at θ = 1
    (g1) without having left it upwards, crosses the band's lower edge −band (as locate_root);
    −1 when g0, g1 do not bracket it. A reset leaves the guard at zero with a first-order rate
    that a higher order can overturn at once: a release on a clutch torque that dips just
    below zero and comes back, whose slip then rises less than its band (1e-10 of the speeds)
    before it falls back; a massless node's catch, whose torque c·θ starts at zero and, on a
    shallow contact, falls again. The switch belongs where the guard leaves its band, as the
    reference makes it (reference.py, half_open), not at the end of the step or look (an impact
    0.23 ms on at a slip of −8e-3 rad/s; a clutch that pulled for up to 3.6 ms, down to
    −0.92 N·m: test_events.py). paths_watch.locate_band_exit does the same for each path."""
    if not g0 + band > 0.0 > g1 + band:
        return -1.0
    return locate_root(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT,
                       0.0, 1.0, g0 + band, g1 + band, -1.0, 0.0, tol_theta, band, ytmp, dytmp,
                       auxtmp, ztmp, counters)


@inline_kernel
def twist_relaxes(mode, P):
    """An open massless damped node: its twist is solved exactly, not stepped (stiff c/k)."""
    return (mode == DISENGAGED and P[P_J3] == 0.0 and P[P_KD] > 0.0
            and P[P_RIGID] == 0.0)


@inline_kernel
def relaxed_twist(theta0, dt, P):
    """The open massless damped node's twist dt after it stood at θ0: θ' = −(c/k)·θ solved
    exactly, θ0·e^(−(c/k)·dt) (the step holds it still; its end, its samples and the guard
    inside it read it from here)."""
    return theta0 * math.exp(-P[P_C] / P[P_KD] * dt)


@kernel
def emit_samples(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, grid, out,
                 counters, t_limit, ytmp, ztmp, dytmp, auxtmp):
    """Write every grid sample in (…, t_limit] from the dense output of the step [t, t+h], or,
    inside a split step (split), of its input part and of the output sub-step [tau, tau+hs]."""
    i = counters[C_NEXT_SAMPLE]
    while i < grid.shape[0] and grid[i] <= t_limit:
        if split:
            split_state(method, exact, (grid[i] - tau) / hs if hs > 0.0 else 1.0, t, h, y0, y1,
                        K, tau, hs, z0, clock, P, ytmp, ztmp, True)
        else:
            dense_state(method, (grid[i] - t) / h if h > 0.0 else 1.0, h, y0, y1, K, ytmp)
            if twist_relaxes(mode, P):
                theta = relaxed_twist(y0[TWIST], grid[i] - t, P)
                ytmp[W_DAMPING] += 0.5 * P[P_C] * (y0[TWIST] ** 2 - theta * theta)
                ytmp[TWIST] = theta
        project(grid[i], ytmp, mode, P, ACT)
        rhs(grid[i], ytmp, mode, P, ACT, dytmp, auxtmp)
        write_sample(out[i], grid[i], ytmp, mode, auxtmp)
        i += 1
    counters[C_NEXT_SAMPLE] = i


@inline_kernel
def sample_due(grid, counters, t_limit):
    """Is a grid sample due in (…, t_limit]? (Checked before the call: most steps have none.)"""
    i = counters[C_NEXT_SAMPLE]
    return i < grid.shape[0] and grid[i] <= t_limit
