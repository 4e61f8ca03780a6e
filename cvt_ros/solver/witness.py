"""The clutch witness function along one step: as a polynomial of the step's dense output, its
lowest point inside the step, and its root.

Over a step [t, t+h] the dense output gives every state as a polynomial in θ = (τ − t)/h (degree 4
for Dormand–Prince, 3 for RK4's Hermite interpolant) and its time derivative as the polynomial's
derivative over h. The clutch guards are linear in states and state derivatives (physics/dynamics):

    engaged, elastic shaft:  Tc = J3·v' + c·θ + k·(v − ω4)       (v = ω2, a state)
    engaged, rigid shaft:    Tc = (J3 + J4)·v' + M4(v)            (M4 quadratic in v at most)
    disengaged:              s  = ω3 − v                         (ω3 = ω4 − c·θ/k for J3 = 0)

so the guard along the step is itself a polynomial, known without one more right-hand-side call.
Its lowest point bounds the guard inside the step: a release whose torque dip, or a catch whose
slip dip, starts and ends inside one step is seen (issue 12: the stiff shaft's 450 µs dips inside
~1 ms steps), and the crossing is located on the polynomial by Illinois' regula falsi.
"""
import math

from ..physics.clutch import uses_twist_release
from ..physics.compiled import inline_kernel, kernel
from ..physics.layout import (
    ENGAGED,
    OMEGA2,
    OMEGA3,
    OMEGA4,
    P_C,
    P_J3,
    P_J4,
    P_KD,
    P_LOAD_QUADRATIC,
    P_LOAD_TORQUE,
    P_LOAD_VISCOUS,
    P_RIGID,
    TWIST,
)
from .steppers import dense_coefficients

N_POLY = 9          # coefficients (degree ≤ 8: a quadratic load of a quartic)
# G[N_POLY], G[N_POLY + 1]: a decaying exponential a·e^(−r·θ) on top (a massless damped node's
# ω3 = ω4 − (c/k)·θ0·e^(−(c/k)·τ), solved exactly); a = 0 for none
N_GUARD = N_POLY + 2
SAMPLES = 16        # look-out points of the lowest-point search, plus a parabola through the best
CHORD_BOUND = 0.7   # max over [0, 1] of θ − θ^k for k ≤ 8 (0.65): the polynomial's bow


@inline_kernel
def poly_value(G, x):
    v = 0.0
    for k in range(N_POLY - 1, -1, -1):
        v = v * x + G[k]
    return v


@inline_kernel
def guard_value(G, x):
    """The guard at θ = x: the polynomial and its exponential term."""
    v = poly_value(G, x)
    if G[N_POLY] != 0.0:
        v += G[N_POLY] * math.exp(-G[N_POLY + 1] * x)
    return v


@inline_kernel
def guard_rate(G, x):
    """dG/dθ at θ = x: the polynomial's and its exponential term's."""
    d = 0.0
    for k in range(N_POLY - 1, 0, -1):
        d = d * x + k * G[k]
    if G[N_POLY] != 0.0:
        d -= G[N_POLY] * G[N_POLY + 1] * math.exp(-G[N_POLY + 1] * x)
    return d


@kernel
def guard_polynomial(method, h, y0, y1, K, mode, P, C, G):
    """Coefficients G of the clutch guard over the last step as a polynomial in θ ∈ [0, 1];
    C: scratch (3, N_POLY). Returns False when the guard is not one: the twist rule's
    max(θ, Tc/c), whose two polynomials are left in C[1] (the twist) and G (Tc/c)."""
    for k in range(N_GUARD):
        G[k] = 0.0
    rigid = P[P_RIGID] > 0.0
    dense_coefficients(method, h, y0, y1, K, OMEGA2, C[0])
    if mode == ENGAGED:
        if rigid:
            jd = (P[P_J3] + P[P_J4]) / h
            for k in range(N_POLY - 1):
                G[k] = jd * (k + 1) * C[0, k + 1] + P[P_LOAD_VISCOUS] * C[0, k]
            G[0] += P[P_LOAD_TORQUE]
            kq = P[P_LOAD_QUADRATIC]
            if kq != 0.0:
                # v·|v| with the sign v has in the middle of the step (v changes sign while
                # engaged only if the rocker stops, where the term is ~0 anyway)
                sq = kq if poly_value(C[0], 0.5) >= 0.0 else -kq
                for i in range(5):
                    for j in range(5):
                        G[i + j] += sq * C[0, i] * C[0, j]
            return True
        dense_coefficients(method, h, y0, y1, K, TWIST, C[1])
        dense_coefficients(method, h, y0, y1, K, OMEGA4, C[2])
        j3 = P[P_J3] / h
        c = P[P_C]
        kd = P[P_KD]
        for k in range(N_POLY):
            G[k] = c * C[1, k] + kd * (C[0, k] - C[2, k])
            if k < N_POLY - 1:
                G[k] += j3 * (k + 1) * C[0, k + 1]
        if uses_twist_release(P):
            for k in range(N_POLY):
                G[k] /= c
            return False
        return True
    if rigid:
        dense_coefficients(method, h, y0, y1, K, OMEGA4, C[1])
    elif P[P_J3] == 0.0:
        dense_coefficients(method, h, y0, y1, K, OMEGA4, C[1])
        if P[P_KD] > 0.0:   # θ relaxes exactly (guard_watch.py): ω3 = ω4 − r·θ0·e^(−r·h·θ)
            r = P[P_C] / P[P_KD]
            G[N_POLY] = -r * y0[TWIST]
            G[N_POLY + 1] = r * h
    else:
        dense_coefficients(method, h, y0, y1, K, OMEGA3, C[1])
    for k in range(N_POLY):
        G[k] = C[1, k] - C[0, k]
    return True


@inline_kernel
def twist_guard_value(C1, G, x):
    """The twist rule's guard max(θ, Tc/c) at θ = x from its two polynomials (guard_polynomial)."""
    return max(poly_value(C1, x), poly_value(G, x))


@kernel
def lowest_point(G, floor):
    """(θ, value) of the polynomial's lowest point inside (0, 1) when it may fall below
    ``floor``; (−1, inf) when its ends and its bow keep it above."""
    g0 = guard_value(G, 0.0)
    g1 = guard_value(G, 1.0)
    bow = abs(G[N_POLY])
    for k in range(2, N_POLY):
        bow += abs(G[k])
    if min(g0, g1) - CHORD_BOUND * bow > floor:
        return -1.0, math.inf
    best_x = -1.0
    best = math.inf
    step = 1.0 / SAMPLES
    for j in range(1, SAMPLES):
        v = guard_value(G, j * step)
        if v < best:
            best = v
            best_x = j * step
    # a fast exponential term: look densely while it lives (≤ 0.5 of its rate apart)
    rate = G[N_POLY + 1]
    if G[N_POLY] != 0.0 and rate > SAMPLES:
        x = 0.5 / rate
        while x < step and abs(G[N_POLY]) * math.exp(-rate * x) > 1e-16 * (1.0 + abs(g1)):
            v = guard_value(G, x)
            if v < best:
                best = v
                best_x = x
            x += 0.5 / rate
        if best_x < step:
            return best_x, best
    # the vertex of the parabola through the best sample and its neighbours
    vl = guard_value(G, best_x - step)
    vr = guard_value(G, best_x + step)
    curvature = vl - 2.0 * best + vr
    if curvature > 0.0:
        x = best_x + 0.5 * step * (vl - vr) / curvature
        if 0.0 < x < 1.0:
            v = guard_value(G, x)
            if v < best:
                best = v
                best_x = x
    return best_x, best


@inline_kernel
def illinois_point(it, lo, hi, glo, ghi):
    """The next point of Illinois' regula falsi in [lo, hi] (every 4th a bisection, so the
    bracket shrinks even on a one-sided approach)."""
    if it % 4 == 3:
        return 0.5 * (lo + hi)
    m = hi - ghi * (hi - lo) / (ghi - glo)
    return m if lo < m < hi else 0.5 * (lo + hi)


@inline_kernel
def illinois_update(m, gm, lo, hi, glo, ghi, side):
    """The bracket (lo, hi, glo, ghi, side) after the guard's value gm at m; side 0 with
    gm == 0 means m is the root. The stale end's value is halved (Illinois)."""
    if gm > 0.0:
        if side == 1:
            ghi *= 0.5
        return m, hi, gm, ghi, 1
    if gm < 0.0:
        if side == -1:
            glo *= 0.5
        return lo, m, glo, gm, -1
    return m, m, gm, gm, 0


@kernel
def poly_root(G, lo, hi, glo, ghi, tol):
    """Illinois' regula falsi on the guard G, G(lo) > 0 > G(hi); θ just past the root."""
    side = 0
    for it in range(200):
        if hi - lo <= tol:
            break
        m = illinois_point(it, lo, hi, glo, ghi)
        lo, hi, glo, ghi, side = illinois_update(m, guard_value(G, m), lo, hi, glo, ghi, side)
    return hi


@inline_kernel
def first_root(G, ga, gb, tol):
    """The first root of the guard G in (0, 1), G(0) = ga > 0 > G(1) = gb: Illinois' regula
    falsi between the last look-out point above zero and the first one below. A guard can fall
    through zero, come back and fall again within one step (a release 0.9 ms long inside a
    4.5 ms step at rtol 1e-4); a root searched for over the whole step may be the last fall."""
    lo = 0.0
    glo = ga
    step = 1.0 / SAMPLES
    for j in range(1, SAMPLES):
        v = guard_value(G, j * step)
        if v < 0.0:
            return poly_root(G, lo, j * step, glo, v, tol)
        lo = j * step
        glo = v
    return poly_root(G, lo, 1.0, glo, gb, tol)


@inline_kernel
def hermite_cubic(g0, d0, g1, d1):
    """(c2, c3) of the cubic p(θ) = g0 + d0·θ + c2·θ² + c3·θ³ with p(1) = g1, p'(1) = d1."""
    return -3.0 * g0 - 2.0 * d0 + 3.0 * g1 - d1, 2.0 * g0 + d0 - 2.0 * g1 + d1


@inline_kernel
def hermite_root(g0, d0, g1, d1, lo, hi):
    """A start for a root search in [lo, hi] ⊂ [0, 1]: the root of the cubic with p(0)=g0,
    p'(0)=d0, p(1)=g1, p'(1)=d1 where it falls through zero there (p(lo) > 0 > p(hi)), by Newton
    steps on the cubic kept inside the bracket, and the cubic's slope at it: (θ, dp/dθ), or
    (−1, 0) when the cubic does not bracket a root in [lo, hi]."""
    c2, c3 = hermite_cubic(g0, d0, g1, d1)
    a = lo
    b = hi
    pa = ((c3 * a + c2) * a + d0) * a + g0
    pb = ((c3 * b + c2) * b + d0) * b + g0
    if not (pa > 0.0 > pb):
        return -1.0, 0.0
    x = a - pa * (b - a) / (pb - pa)
    for _ in range(12):
        px = ((c3 * x + c2) * x + d0) * x + g0
        if px == 0.0:
            break
        slope = (3.0 * c3 * x + 2.0 * c2) * x + d0
        if px > 0.0:
            a = x
        else:
            b = x
        step = -px / slope if slope < 0.0 else math.inf
        if abs(step) <= 1e-12:
            if a < x + step < b:
                x += step
            break
        x = x + step if a < x + step < b else 0.5 * (a + b)
    return x, (3.0 * c3 * x + 2.0 * c2) * x + d0


@inline_kernel
def hermite_minimum(g0, d0, g1, d1):
    """Interior minimum (θ, value) of the cubic with p(0)=g0, p'(0)=d0, p(1)=g1, p'(1)=d1."""
    c1 = d0
    c2, c3 = hermite_cubic(g0, d0, g1, d1)
    best_t = -1.0
    best = math.inf
    qa = 3.0 * c3
    qb = 2.0 * c2
    if qa == 0.0:
        if qb != 0.0:
            r = -c1 / qb
            if 0.0 < r < 1.0 and qb > 0.0:
                best_t = r
    else:
        disc = qb * qb - 4.0 * qa * c1
        if disc >= 0.0:
            sq = math.sqrt(disc)
            for r in ((-qb - sq) / (2.0 * qa), (-qb + sq) / (2.0 * qa)):
                if 0.0 < r < 1.0 and 2.0 * qa * r + qb > 0.0:
                    val = ((c3 * r + c2) * r + c1) * r + g0
                    if val < best:
                        best = val
                        best_t = r
    if best_t < 0.0:
        return -1.0, math.inf
    return best_t, ((c3 * best_t + c2) * best_t + c1) * best_t + g0
