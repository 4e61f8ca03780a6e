"""One look of the open output's slip watch (slip_watch.py): the slip s = ω3 − v over a
sub-interval [tau, tau + hs] of an accepted input step [t, t + h], σ ∈ [0, 1] across the look.

ω3 is the output's (exact, or its own clock's dense output); v, the rocker speed, is the input
step's dense polynomial Cv, or, for the true slip (dense_step.true_split_slip), the linkage's
closed form at the dense crank state. A look is searched for a dip that starts and ends inside it
by Hermite cubics of the polynomial slip under an error bound (``split_dip``), for a rise out of
the band after a release (``left_band_upwards``), and where the polynomial and the true slip
disagree, for the true slip's own extremum (``true_beyond``).
"""
import math

from ..physics.compiled import inline_kernel, kernel
from ..physics.dynamics import disengaged_output_rates
from ..physics.layout import Z_OMEGA3, Z_OMEGA4, Z_TWIST
from .dense_step import output_state, true_split_slip
from .witness import N_POLY, hermite_minimum, poly_value


@inline_kernel
def split_slip(exact, sigma, t, h, tau, hs, z0, clock, P, Cv, ztmp):
    """Slip s = ω3 − v at tau + σ·hs inside a split step [rad/s]: ω3 from the output, v from the
    rocker speed's dense polynomial Cv over the input step."""
    output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, False)
    return ztmp[Z_OMEGA3] - poly_value(Cv, (tau + sigma * hs - t) / h)


@inline_kernel
def poly_rate(C, x, h):
    """d/dt of the polynomial C(θ) over a step h, at θ = x."""
    v = 0.0
    for k in range(N_POLY - 1, 0, -1):
        v = v * x + k * C[k]
    return v / h


@inline_kernel
def omega3_rate(z, P):
    """ω3' of the open output subsystem (J3 > 0) [rad/s²]."""
    _, dw3, _, _, _ = disengaged_output_rates(z[Z_TWIST], z[Z_OMEGA3], z[Z_OMEGA4], P)
    return dw3


@kernel
def split_dip(exact, t, h, tau, hs, z0, clock, P, Cv, ztmp, g0, d0, g1, d1, m4, gtol):
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
            gm = split_slip(exact, sm, t, h, tau, hs, z0, clock, P, Cv, ztmp)
            if gm < -gtol:
                return sm, gm
        if top + 2 >= sa.shape[0] or w < 1e-6:
            continue
        mid = 0.5 * (a + b)
        gmid = split_slip(exact, mid, t, h, tau, hs, z0, clock, P, Cv, ztmp)
        if gmid < -gtol:
            return mid, gmid
        dmid = hs * (omega3_rate(ztmp, P) - poly_rate(Cv, (tau + mid * hs - t) / h, h))
        top += 1
        sa[top], sb[top], ga[top], gb[top], da[top], db[top] = mid, b, gmid, g_b, dmid, d_b
        top += 1
        sa[top], sb[top], ga[top], gb[top], da[top], db[top] = a, mid, g_a, gmid, d_a, dmid
    return -1.0, math.inf


@kernel
def left_band_upwards(exact, t, h, tau, hs, z0, clock, P, Cv, ztmp, g0, d0, g1, d1, gtol):
    """σ in (0, 1) where the slip of a look that ends below its band stood above it (the
    Hermite cubic's highest point, else the look's middle), or -1: the crossing down lies
    after it. g, d: the slip and its σ-rate at both ends."""
    tm, pm = hermite_minimum(-g0, -d0, -g1, -d1)
    if tm > 0.0 and split_slip(exact, tm, t, h, tau, hs, z0, clock, P, Cv, ztmp) > gtol:
        return tm
    if split_slip(exact, 0.5, t, h, tau, hs, z0, clock, P, Cv, ztmp) > gtol:
        return 0.5
    return -1.0


@kernel
def true_beyond(method, exact, t, h, y, y1, K, tau, hs, z0, clock, P, ACT, ycomb, ztmp, m, gm,
                side, gtol):
    """(σ, slip) where the true slip (the linkage's rocker speed) stands beyond its band on one
    side (side -1: below -gtol, +1: above gtol) in a look whose polynomial slip does so at
    σ = m, the true slip there being gm; else (-1, gm). The two slips differ by the rocker
    speed interpolant's error, and the polynomial's point is where it first goes beyond the
    band, not its extremum: the true slip can still be inside the band there and far beyond it
    nearby (rtol 1e-4, a 6 ms step: +0.01 rad/s at the polynomial's dip, -0.30 rad/s 0.3 ms
    later; a 7.5 ms step after a release: the true slip up to +0.012 rad/s 0.3 ms before the
    polynomial's highest point, where it is -0.1 rad/s). So the true slip's extremum on that
    side is searched for by golden sections of [0, 1] about m."""
    a = 0.0
    b = 1.0
    fm = side * gm
    while b - a > 1e-9:
        x = m - 0.381966 * (m - a) if m - a > b - m else m + 0.381966 * (b - m)
        gx = true_split_slip(method, exact, x, t, h, y, y1, K, tau, hs, z0, clock, P, ACT, ycomb,
                             ztmp)
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
