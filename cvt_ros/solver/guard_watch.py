"""The clutch guard watched over an accepted step of the whole system, and the landing on a switch.

The witness function of the clutch automaton (physics/clutch.py) is watched along the whole step,
not only at its ends: as a polynomial of the step's dense output (witness.py), so a guard that
dips through zero and back inside one step is seen. A crossing is located on that polynomial and
confirmed on the true guard (dense_step.locate_root); a true step is then re-taken exactly to it
and, where it lands short by the dense output's error (or past by more than rtol × the guard's
scale), settled onto the guard by Newton steps. A
guard found beyond its band after a step is reported 'late' (FOUND_LATE). A catch that the open
output's slip watch (slip_watch.py) located is settled the same way (creep_onto_catch).

Pieces of the hybrid loop (hybrid.py), which applies the reset map at what these find.
"""
import math

from ..physics.clutch import clutch_guard, guard_scale, guard_tolerance
from ..physics.compiled import inline_kernel, kernel
from ..physics.dynamics import project, rhs
from ..physics.layout import AUX_SLIP, AUX_SLIP_RATE, P_C, TWIST, W_DAMPING
from .advance_layout import C_RHS, CROSSING, FOUND_LATE, NO_EVENT
from .dense_step import (
    emit_samples,
    guard_at,
    locate_band_exit,
    locate_root,
    relaxed_twist,
    root_tolerance,
    sample_due,
    take_step,
)
from .slip_look import poly_rate
from .steppers import DOPRI5, ERR_FULL, FULL, MASSLESS
from .witness import (
    N_POLY,
    SAMPLES,
    first_root,
    guard_polynomial,
    guard_rate,
    guard_value,
    lowest_point,
    poly_root,
    poly_value,
    twist_guard_value,
)

# A root located on the step's dense output is reached by a re-taken step, whose state differs
# from the interpolant by the dense output's own error: at the defaults the release's clutch
# torque there is ~3e-5 N·m, 3000× its band. Where it lands short (half the time) the re-taken
# end is moved on by Newton steps on the guard's polynomial rate, overshooting by a quarter so
# that one step lands past the root (the guard then as far past zero as the landings that
# were not short), instead of a whole new step that finds the root again at its very start.
# Where it lands past by more than rtol × the guard's scale (the scene's torque scale for a
# release: -0.31 N·m at rtol 1e-4 where that is 4e-3) it is moved back the same way, and no
# settling step aims further past than half that. The twist rule's release (guard max(θ, Tc/c),
# scale: the torque scale over c) is moved back only, on the rate of its larger part: it was
# never settled, and landed up to 177 × that bound past (-1.2e-4 rad at rtol 1e-4: the twist
# and Tc/c both below zero, 2 µs late); its landings short are left to a new step, as they were.
SETTLE_STEPS = 3
SETTLE_OVERSHOOT = 1.25
# Only a landing that fell short by a dense output's error is settled (5e4 bands at most on the
# shipped scenes); one further off, or any of a massless node's step (a catch once fell short by
# 0.04 rad/s and Newton carried it to slip -0.01), is left to a new step, as before. A landing
# past is moved back on a massless node's step too (a catch at slip -0.035 at rtol 1e-4, 6 ms
# after a release, its twist long relaxed)
SETTLE_BANDS = 1e5
# a low point of the guard's polynomial inside a step, below this fraction of the guard at the
# step's ends, is read on the true guard too: the polynomial's error can hide a dip under it
DIP_CHECK = 0.1


@kernel
def _confirm_root(method, t, h, y, y_new, K, mode, P, ACT, clock, theta, hi, g0, ghi, gtol,
                  tol_theta, G, ytmp, dytmp, auxtmp, counters):
    """The polynomial's root θ checked on the true guard (one right-hand side): kept when the
    guard there is inside its band, else re-located on the true guard in the bracket the check
    leaves, from a Newton step with the polynomial's slope (G). The reset map's complementarity
    sees the true guard: a release placed where the clutch still pushes would engage again at
    once (chatter at loose tolerances)."""
    if theta >= hi:
        return hi
    gt = guard_at(method, theta, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp, counters)
    if abs(gt) <= gtol:
        return theta
    rate = guard_rate(G, theta)
    start = theta - gt / rate if rate < 0.0 else -1.0
    lo, hi, glo, ghi = (theta, hi, gt, ghi) if gt > 0.0 else (0.0, theta, g0, gt)
    return locate_root(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT, lo,
                       hi, glo, ghi, start, rate, tol_theta, 0.0, ytmp, dytmp, auxtmp, ytmp,
                       counters)


@kernel
def _part_low_point(Cp, end):
    """θ in (0, end) of the lowest point of the polynomial Cp (the look-outs of witness.SAMPLES
    and the vertex of the parabola through the lowest), or -1."""
    step = end / SAMPLES
    best_x = -1.0
    best = math.inf
    for j in range(1, SAMPLES):
        v = poly_value(Cp, j * step)
        if v < best:
            best = v
            best_x = j * step
    vl = poly_value(Cp, best_x - step)
    vr = poly_value(Cp, best_x + step)
    curvature = vl - 2.0 * best + vr
    if curvature > 0.0:
        x = best_x + 0.5 * step * (vl - vr) / curvature
        if 0.0 < x < end and poly_value(Cp, x) < best:
            return x
    return best_x


@kernel
def _parts_cross(H, Q, end):
    """θ in (0, end) where the polynomials H and Q cross with the larger lowest there (their
    difference changing sign between look-outs, then bisected), or -1."""
    step = end / SAMPLES
    best_x = -1.0
    best = math.inf
    a = 0.0
    da = poly_value(H, 0.0) - poly_value(Q, 0.0)
    for j in range(1, SAMPLES + 1):
        b = j * step
        db = poly_value(H, b) - poly_value(Q, b)
        if (da < 0.0) != (db < 0.0):
            lo, hi, dlo = a, b, da
            for _ in range(40):
                m = 0.5 * (lo + hi)
                dm = poly_value(H, m) - poly_value(Q, m)
                if (dm < 0.0) == (dlo < 0.0):
                    lo, dlo = m, dm
                else:
                    hi = m
            x = 0.5 * (lo + hi)
            v = max(poly_value(H, x), poly_value(Q, x))
            if v < best:
                best = v
                best_x = x
        a, da = b, db
    return best_x


@kernel
def _twist_crossing(method, t, h, y, y_new, K, mode, P, ACT, clock, g0, g1, gtol, C, G,
                    tol_theta, ytmp, dytmp, auxtmp, counters):
    """The twist rule's release inside the step: θ where its guard max(twist, Tc/c) first falls
    through zero, located on the true guard, or −1. C[1] and G hold the two polynomials
    (witness.guard_polynomial). Bracketed as the torque rule's guard is: the first look-out
    point below the band (a release and a catch within one step: the first fall, not the
    last); before it, the guard's lowest point (the lowest look-out and its parabola's vertex),
    read on the true guard where it falls below the band or below DIP_CHECK of the ends (the
    polynomials' error can hide a dip under it). The old test looked at the twist's polynomial
    alone and at the true guard only at the step's end: a Tc that dipped through zero inside a
    step with the twist below zero (a 0.2–1.4 ms release) was missed at loose tolerances."""
    lo = 0.0
    hi = -1.0
    best_x = -1.0   # the lowest look-out inside the step, then the vertex of the parabola there
    best = math.inf
    step = 1.0 / SAMPLES
    for j in range(1, SAMPLES + 1):
        x = j * step
        v = twist_guard_value(C[1], G, x)
        if v < -gtol:
            hi = x
            break
        lo = x
        if v < best and j < SAMPLES:
            best = v
            best_x = x
    if best_x > 0.0:
        vl = twist_guard_value(C[1], G, best_x - step)
        vr = twist_guard_value(C[1], G, best_x + step)
        curvature = vl - 2.0 * best + vr
        if curvature > 0.0:
            x = best_x + 0.5 * step * (vl - vr) / curvature
            if 0.0 < x < 1.0 and twist_guard_value(C[1], G, x) < best:
                best_x = x
                best = twist_guard_value(C[1], G, x)
    # and the larger's own low points, which a dip shorter than the look-outs' spacing hides
    # from them: either part's lowest point, or where the two cross (the twist falling through
    # zero while Tc/c rises through it: a 0.24 ms release inside a step at rtol 1e-4)
    end = hi if hi > 0.0 else 1.0
    for part in range(3):
        x = _parts_cross(C[1], G, end) if part == 2 else _part_low_point(
            C[1] if part == 0 else G, end)
        if x > 0.0:
            v = twist_guard_value(C[1], G, x)
            if v < best:
                best = v
                best_x = x
    if best_x > 0.0 and (best < -gtol or best < DIP_CHECK * min(g0, max(g1, 0.0))):
        gt = guard_at(method, best_x, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                      counters)
        if gt < -gtol:
            return locate_root(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P,
                               ACT, 0.0, best_x, g0, gt, -1.0, 0.0, tol_theta, 0.0, ytmp, dytmp,
                               auxtmp, ytmp, counters)
    if hi > 0.0:
        ghi = g1 if hi == 1.0 else guard_at(method, hi, t, h, y, y_new, K, mode, P, ACT, ytmp,
                                             dytmp, auxtmp, counters)
        if ghi < 0.0:
            # from the last look-out above the band if the true guard is above zero there
            glo = g0
            if lo > 0.0:
                glo = guard_at(method, lo, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                               counters)
                if not glo > 0.0:
                    lo = 0.0
                    glo = g0
            return locate_root(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P,
                               ACT, lo, hi, glo, ghi, -1.0, 0.0, tol_theta, 0.0, ytmp, dytmp,
                               auxtmp, ytmp, counters)
    if g1 < -gtol:
        return locate_root(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT,
                           0.0, 1.0, g0, g1, -1.0, 0.0, tol_theta, 0.0, ytmp, dytmp, auxtmp, ytmp,
                           counters)
    return -1.0


@kernel
def _left_band_upwards(method, t, h, y, y_new, K, mode, P, ACT, clock, g1, gtol, C, G, ytmp,
                       dytmp, auxtmp, counters):
    """A step that began inside the guard's band and ends below it: θ of the crossing down
    after the guard's highest point in the step if the true guard stood above the band there,
    else −1. (The guard's polynomial picks the point; with the twist rule it is the twist's.)"""
    guard_polynomial(method, h, y, y_new, K, mode, P, C, G)
    for k in range(N_POLY + 1):   # the highest point of the guard: the lowest of −guard
        G[k] = -G[k]              # (its exponential term's amplitude too; the rate stays)
    best_x, _ = lowest_point(G, -gtol)
    if best_x < 0.0:
        return -1.0
    gt = guard_at(method, best_x, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp, counters)
    if not gt > gtol:
        return -1.0
    tol_theta = root_tolerance(t, h)
    return locate_root(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT,
                       best_x, 1.0, gt, g1, -1.0, 0.0, tol_theta, 0.0, ytmp, dytmp, auxtmp, ytmp,
                       counters)


@kernel
def creep_onto_catch(t, t_end, y, mode, P, ACT, clock, K, y_new, ytmp, aux1, dytmp, auxtmp, rtol,
                     atol, grid, out, counters):
    """A catch located by the open output's slip watch that the re-taken step reached short of
    (the slip still above its band, by the input's dense output error): short true steps of the
    whole system forward, by Newton on the true slip's rate, overshooting as SETTLE_OVERSHOOT;
    a landing further past zero than the first one fell short is not taken (the run goes on
    from the last short one as before). y is at t; dytmp, aux1 hold f(t, y). Returns (t, slip)
    with y, dytmp, aux1 there."""
    g = aux1[AUX_SLIP]
    g_first = g
    n = y.shape[0]
    if g > SETTLE_BANDS * guard_tolerance(mode, y, aux1, P):
        return t, g
    for _ in range(SETTLE_STEPS):
        rate = aux1[AUX_SLIP_RATE]
        if not rate < 0.0:
            break
        dt = SETTLE_OVERSHOOT * g / -rate
        if not (t + dt > t and t + dt <= t_end):
            break
        for i in range(n):
            K[0, i] = dytmp[i]
        take_step(DOPRI5, FULL, t, y, dt, mode, P, ACT, K, y_new, ytmp, aux1, rtol, atol, ERR_FULL,
                  counters)
        if aux1[AUX_SLIP] < -g_first:
            rhs(t, y, mode, P, ACT, dytmp, aux1)   # too far past: stay, aux1 back at y
            counters[C_RHS] += 1
            break
        if sample_due(grid, counters, t + dt):
            emit_samples(False, False, DOPRI5, t, dt, y, y_new, K, t, dt, y, clock, mode, P, ACT,
                         grid, out, counters, t + dt, ytmp, ytmp, dytmp, auxtmp)
        t += dt
        for i in range(n):
            y[i] = y_new[i]
            dytmp[i] = K[6, i]
        g = aux1[AUX_SLIP]
        if g <= guard_tolerance(mode, y, aux1, P):
            break
    return t, g


@inline_kernel
def relax_twist(t1, h, y, y_new, mode, P, ACT, aux1, dytmp, counters):
    """The open massless damped node over a step: θ = θ0·e^(−(c/k)·h) exactly, the spring's
    energy into the damper; the auxiliaries (the slip) at the step's end refreshed."""
    theta0 = y[TWIST]
    theta1 = relaxed_twist(theta0, h, P)
    y_new[TWIST] = theta1
    y_new[W_DAMPING] = y[W_DAMPING] + 0.5 * P[P_C] * (theta0 * theta0 - theta1 * theta1)
    project(t1, y_new, mode, P, ACT)
    rhs(t1, y_new, mode, P, ACT, dytmp, aux1)
    counters[C_RHS] += 1


@inline_kernel
def _twist_guard_rate(C1, G, x):
    """dG/dθ of the twist rule's guard max(θ, Tc/c) at θ = x: the rate of the larger part (its
    two polynomials, witness.guard_polynomial; engaged, neither has an exponential term)."""
    if poly_value(C1, x) > poly_value(G, x):
        return poly_rate(C1, x, 1.0)
    return guard_rate(G, x)


@inline_kernel
def _aim_past(g1, bound):
    """Where a settling Newton step aims the guard: past zero by a quarter of how far the landing
    was off (SETTLE_OVERSHOOT), but by no more than half of how far past zero a switch may be
    placed (bound = rtol × the guard's scale), so that it lands on the switch's side."""
    return -min((SETTLE_OVERSHOOT - 1.0) * abs(g1), 0.5 * bound)


@inline_kernel
def _retake_to(method, kind, err_idx, t, h_ev, y, y_new, K, mode, P, ACT, aux1, rtol, atol, ytmp,
               dytmp, counters):
    """A true step from (t, y) to the event at t + h_ev, not the interpolant: the state there
    (y_new, K[6], aux1) is step-accurate. Returns the guard there."""
    take_step(method, kind, t, y, h_ev, mode, P, ACT, K, y_new, ytmp, aux1, rtol, atol, err_idx,
              counters)
    if kind == MASSLESS:
        relax_twist(t + h_ev, h_ev, y, y_new, mode, P, ACT, aux1, dytmp, counters)
    g1, _ = clutch_guard(mode, y_new, K[6], aux1, P)
    return g1


@kernel
def watch_step(method, kind, err_idx, t, h, clipped, t_end, y, y_new, K, mode, P, ACT, clock,
               armed, g0, aux1, rtol, atol, grid, out, counters, ytmp, dytmp, auxtmp, C, G):
    """Witness function over an accepted step of the whole system: a crossing or a dip through
    zero anywhere inside the step (on the guard's polynomial, witness.py) is located and a true
    step re-taken to it; a guard found beyond its band at the step's end is 'late'. Emits the
    samples up to the time reached and leaves the state there in y_new. Returns (t reached,
    fire, g at that time)."""
    g1, _ = clutch_guard(mode, y_new, K[6], aux1, P)
    gtol = guard_tolerance(mode, y_new, aux1, P)
    fire = NO_EVENT
    theta = 1.0
    settle = False   # G is the guard's polynomial at the located root: Newton may move it on
    twist = False    # the twist rule's: C[1] and G its two parts, settled back only
    if armed and g0 > 0.0:
        tol_theta = root_tolerance(t, h)
        if guard_polynomial(method, h, y, y_new, K, mode, P, C, G):
            # (with its exponential term: a massless damped node's relaxing twist, which just
            # after a twist release can stand above the slip itself, so that the polynomial
            # alone starts below zero: a catch was then placed at the step's end, 18 rad/s past)
            ga = guard_value(G, 0.0)
            hi = -1.0
            ghi = 0.0
            if g1 < 0.0:
                hi = 1.0
                ghi = g1
                gb = guard_value(G, 1.0)
                if ga > 0.0 and gb < 0.0:
                    theta = first_root(G, ga, gb, tol_theta)
                else:   # the polynomial does not bracket the true guard's fall: located on it
                    theta = locate_root(False, False, method, t, h, y, y_new, K, t, h, y, clock,
                                        mode, P, ACT, 0.0, 1.0, g0, g1, -1.0, 0.0, tol_theta, 0.0,
                                        ytmp, dytmp, auxtmp, ytmp, counters)
            else:
                tm, gm = lowest_point(G, -gtol)
                if gm < -gtol or (tm > 0.0 and gm < DIP_CHECK * min(ga, g1)):
                    # a dip on the polynomial, or a low point that its error could hide one
                    # under (rtol 1e-4: +0.33 N·m on the polynomial where the true clutch torque
                    # was -0.76, a 0.5 ms release missed): is it one of the true guard?
                    gt = guard_at(method, tm, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp,
                                  counters)
                    if gt < -gtol:
                        hi = tm
                        ghi = gt
                        if gm < 0.0:
                            theta = poly_root(G, 0.0, tm, ga, gm, tol_theta) if ga > 0.0 else tm
                        else:
                            theta = locate_root(False, False, method, t, h, y, y_new, K, t, h, y,
                                                clock, mode, P, ACT, 0.0, tm, ga, gt, -1.0, 0.0,
                                                tol_theta, 0.0, ytmp, dytmp, auxtmp, ytmp, counters)
            if hi > 0.0:
                fire = CROSSING
                settle = True
                theta = _confirm_root(method, t, h, y, y_new, K, mode, P, ACT, clock, theta, hi,
                                      g0, ghi, gtol, tol_theta, G, ytmp, dytmp, auxtmp, counters)
        else:
            theta = _twist_crossing(method, t, h, y, y_new, K, mode, P, ACT, clock, g0, g1, gtol,
                                    C, G, tol_theta, ytmp, dytmp, auxtmp, counters)
            if theta >= 0.0:
                fire = CROSSING
                settle = True
                twist = True
    if fire == NO_EVENT and g1 < -gtol and not (armed and g0 > 0.0):
        # from inside the band (just after a switch) to below it: located after where the
        # guard left the band upwards (a short phase: a heavy load's second catch, a short
        # engagement), else where it leaves it downwards. Or from just under the band: a
        # massless damped node's release leaves the slip the release's torque band over the
        # damping below zero (2e-8 rad/s with k = 0.01 N·m·s/rad), and the catch 1.8 ms on was
        # in that first step
        theta = _left_band_upwards(method, t, h, y, y_new, K, mode, P, ACT, clock, g1, gtol,
                                   C, G, ytmp, dytmp, auxtmp, counters)
        if theta < 0.0:
            # never above the band: where the guard leaves it downwards (a contact of higher
            # order than the reset decided by: dense_step.locate_band_exit), not late
            tol_theta = root_tolerance(t, h)
            theta = locate_band_exit(False, False, method, t, h, y, y_new, K, t, h, y, clock,
                                     mode, P, ACT, g0, g1, gtol, tol_theta, ytmp, dytmp, auxtmp,
                                     ytmp, counters)
        if theta >= 0.0:
            fire = CROSSING
    if fire == NO_EVENT and g1 < -gtol:
        fire = FOUND_LATE  # the guard left its band on the wrong side: switch now
    if fire == CROSSING:
        short = -1.0     # θ of the last landing short of the band
        g_first = 0.0    # how far the first one fell short: a landing may be as far past zero
        for it in range(SETTLE_STEPS + 1):
            h_ev = theta * h
            g1 = _retake_to(method, kind, err_idx, t, h_ev, y, y_new, K, mode, P, ACT, aux1, rtol,
                            atol, ytmp, dytmp, counters)
            if not settle:
                break
            gtol1 = guard_tolerance(mode, y_new, aux1, P)
            bound = rtol * guard_scale(mode, y_new, aux1, P)
            if g1 > gtol1:
                if kind == MASSLESS or twist:
                    break   # its landings short are left to a new step (SETTLE_BANDS)
                if short < 0.0:
                    if g1 > SETTLE_BANDS * gtol1:
                        break
                    g_first = g1
                short = theta
                after, before = theta, math.inf    # on
            elif short >= 0.0 and g1 < -g_first:
                # too far past (the polynomial's rate too flat there): back to the last short
                # landing, and on from there by a new step
                h_ev = short * h
                g1 = _retake_to(method, kind, err_idx, t, h_ev, y, y_new, K, mode, P, ACT, aux1,
                                rtol, atol, ytmp, dytmp, counters)
                break
            elif g1 < -bound:
                # past by more than the tolerance allows the guard (the dense output's error at
                # a loose rtol: -0.31 N·m, 14 µs late at rtol 1e-4): back, as a landing short
                # is moved on, but not behind a landing short
                after, before = max(0.0, short), theta
            else:
                break
            # a Newton step on the guard polynomial's rate, aimed just past zero
            rate = _twist_guard_rate(C[1], G, theta) if twist else guard_rate(G, theta)
            if it == SETTLE_STEPS or not rate < 0.0:
                break
            theta_next = min(1.0, theta - (g1 - _aim_past(g1, bound)) / rate)
            if not after < theta_next < before:
                break
            theta = theta_next
        if sample_due(grid, counters, t + h_ev):
            emit_samples(False, False, method, t, h_ev, y, y_new, K, t, h_ev, y, clock, mode, P,
                         ACT, grid, out, counters, t + h_ev, ytmp, ytmp, dytmp, auxtmp)
        return t + h_ev, fire, g1
    t_new = t_end if (clipped and t + h >= t_end) else t + h
    if sample_due(grid, counters, t_new):
        emit_samples(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT, grid,
                     out, counters, t_new, ytmp, ytmp, dytmp, auxtmp)
    return t_new, fire, g1
