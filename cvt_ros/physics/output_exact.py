"""The disengaged output subsystem solved exactly (physics.md §8).

While the clutch overruns, J3, the shaft and J4 form a linear system when the load is constant
plus viscous (eq. 12 with M4 = T + kv·ω4):

    x = (θ, ω3, ω4),   x' = A·x + b,
    A = [[0, 1, −1], [−c/J3, −k/J3, k/J3], [c/J4, k/J4, −(k + kv)/J4]],   b = (0, 0, −T/J4).

With A = V·diag(λ)·V⁻¹ (computed once per parameter set, ``modal_form``), and w0 = V⁻¹·x0,
wb = V⁻¹·b:  x(τ) = Re V·(w0·e^{λτ} + wb·F1),  ∫x = Re V·(w0·F1 + wb·F2), with
F1 = (e^{λτ} − 1)/λ and F2 = (e^{λτ} − 1 − λτ)/λ² (series near λτ = 0, so the rigid-body
eigenvalue λ = 0 needs no special case). φ4 = φ4(0) + ∫ω4.

Work: the output subsystem's energy E = ½J3·ω3² + ½J4·ω4² + ½c·θ² falls by exactly the load work
plus the damping loss; one of the two comes in closed form (T·Δφ4 when kv = 0, or 0 when k = 0),
the other from the balance, so the energy ledger closes to rounding. With both k and kv non-zero,
the damping loss k·∫(ω3 − ω4)² is in closed form too: ω3 − ω4 = Σ_m d_m·w_m with the modal
coordinates w_m' = λ_m·w_m + wb_m, so it is k·Σ_mn d_m·d_n·∫w_m·w_n, and each ∫w_m·w_n follows from
d/dt(w_m·w_n) = (λ_m + λ_n)·w_m·w_n + wb_m·w_n + wb_n·w_m (``_pair_integral``; a Taylor form
where λ_m + λ_n is too small to divide by: the slow rigid-body mode).

This removes the shaft's stiff mode from the solver while the clutch is open: the input subsystem
steps at its own pace, and the slip is watched on the exact solution.
"""
import math

import numpy as np

from .compiled import inline_kernel, kernel
from .layout import (
    P_C,
    P_J3,
    P_J4,
    P_KD,
    P_LOAD_QUADRATIC,
    P_LOAD_TORQUE,
    P_LOAD_VISCOUS,
    P_OUTPUT_RATE,
    P_RIGID,
    Z_OMEGA3,
    Z_OMEGA4,
    Z_PHI4,
    Z_TWIST,
    Z_W_DAMPING,
    Z_W_LOAD,
)

MAX_CONDITION = 1e8   # eigenvector matrix worse than this (near-defective A): integrate instead
SERIES_LIMIT = 1e-3   # |λτ| below this: Taylor series for e^{λτ}, F1, F2 (error < 1e-16)
LOSS_SERIES_LIMIT = 0.2  # max|λ|·τ below this: the loss by the power series of the slip in τ
LOSS_SERIES_TERMS = 13   # (0.2^13/13! < 1e-17)
PAIR_LIMIT = 1e-2     # |(λ_m + λ_n)·τ| below this: ∫w_m·w_n by series, not by the identity
PHI1_SERIES = 0.05    # |z| below this: φ1(z) = (e^z − 1)/z by its series (10 terms)
GL7_U = (np.polynomial.legendre.leggauss(7)[0] + 1.0) / 2.0   # nodes on [0, 1]
GL7_W = np.polynomial.legendre.leggauss(7)[1] / 2.0           # and weights
INV_FACTORIAL = np.array([1.0 / math.factorial(n) for n in range(12)])


@inline_kernel
def modulus2(z):
    """|z|² of a complex z (abs() calls libm's hypot: overflow-safe, ~4× the cost; the
    modal quantities here are far from overflow)."""
    return z.real * z.real + z.imag * z.imag


@inline_kernel
def _small(z, limit):
    """|z| < limit for a complex z, without the square root."""
    return modulus2(z) < limit * limit


def modal_form(P):
    """(usable, LIN, fastest rate, fastest oscillation): LIN rows = λ, V (3 rows), V⁻¹ (3 rows),
    complex (7, 3); the rates max|λ| and max|Im λ| [1/s].

    usable is False when the output is not linear (quadratic load), has no J3 mode (J3 = 0 or a
    rigid shaft), or A is too close to defective (or too extreme) for a reliable eigenbasis:
    then the output is integrated.
    """
    lin = np.zeros((7, 3), dtype=np.complex128)
    J3, J4, c, k, kv = P[P_J3], P[P_J4], P[P_C], P[P_KD], P[P_LOAD_VISCOUS]
    if P[P_RIGID] > 0.0 or J3 <= 0.0 or P[P_LOAD_QUADRATIC] != 0.0:
        return False, lin, 0.0, 0.0
    A = np.array([[0.0, 1.0, -1.0],
                  [-c / J3, -k / J3, k / J3],
                  [c / J4, k / J4, -(k + kv) / J4]])
    try:
        if not np.all(np.isfinite(A)):
            return False, lin, 0.0, 0.0
        lam, V = np.linalg.eig(A)
        if not np.all(np.isfinite(lam)) or np.linalg.cond(V) > MAX_CONDITION:
            return False, lin, 0.0, 0.0
        # a conjugate pair (if any) as modes 0 and 1 (positive imaginary part first), exactly
        # conjugate with its rows of V⁻¹, so that mode 1 is mode 0's conjugate to the bit
        order = np.argsort(np.where(lam.imag > 0.0, 0, np.where(lam.imag < 0.0, 1, 2)),
                           kind='stable')
        lam, V = lam[order], V[:, order]
        inv = np.linalg.inv(V)
        if lam[0].imag != 0.0:
            lam[1] = lam[0].conjugate()
            V[:, 1] = V[:, 0].conjugate()
            inv[1] = inv[0].conjugate()
            lam[2], V[:, 2], inv[2] = lam[2].real, V[:, 2].real, inv[2].real   # the real mode
    except np.linalg.LinAlgError:   # inertias at the table's extremes: integrate instead
        return False, lin, 0.0, 0.0
    lin[0] = lam
    lin[1:4] = V
    lin[4:7] = inv
    return True, lin, float(np.max(np.abs(lam))), float(np.max(np.abs(lam.imag)))


@inline_kernel
def modal_coordinates(z, P, LIN, W):
    """W[0] = V⁻¹·x0, W[1] = V⁻¹·b for the output state z at the start of a step."""
    b3 = -P[P_LOAD_TORQUE] / P[P_J4]
    x0 = z[Z_TWIST]
    x1 = z[Z_OMEGA3]
    x2 = z[Z_OMEGA4]
    for i in range(3):
        W[0, i] = LIN[4 + i, 0] * x0 + LIN[4 + i, 1] * x1 + LIN[4 + i, 2] * x2
        W[1, i] = LIN[4 + i, 2] * b3


@inline_kernel
def _mode_over(tau, LIN, W, m):
    """Mode m over [0, τ]: (λ, w(0), wb, w(τ), ∫w, e^{λτ})."""
    lam = LIN[0, m]
    w0 = W[0, m]
    wb = W[1, m]
    lt = lam * tau
    if _small(lt, SERIES_LIMIT):
        e = 1.0 + lt * (1.0 + lt * (0.5 + lt * (1.0 / 6.0 + lt / 24.0)))
        f1 = tau * (1.0 + lt * (0.5 + lt * (1.0 / 6.0 + lt / 24.0)))
        f2 = tau * tau * (0.5 + lt * (1.0 / 6.0 + lt * (1.0 / 24.0 + lt / 120.0)))
    else:
        e = np.exp(lt)
        f1 = (e - 1.0) / lam
        f2 = (e - 1.0 - lt) / (lam * lam)
    return lam, w0, wb, w0 * e + wb * f1, w0 * f1 + wb * f2, e


@inline_kernel
def modes_over(tau, LIN, W):
    """The three modes over [0, τ] (``_mode_over`` each); the second of a conjugate pair (modes 0
    and 1: ``modal_form`` puts a pair first, exactly conjugate) as the first's conjugate, which
    it is to the bit: one complex exponential fewer."""
    m0 = _mode_over(tau, LIN, W, 0)
    if LIN[0, 0].imag != 0.0:
        lam, w0, wb, w1, j, e = m0
        m1 = (lam.conjugate(), w0.conjugate(), wb.conjugate(), w1.conjugate(), j.conjugate(),
              e.conjugate())
    else:
        m1 = _mode_over(tau, LIN, W, 1)
    return m0, m1, _mode_over(tau, LIN, W, 2)


@inline_kernel
def _modal_state(LIN, modes):
    """(x(τ), ∫₀^τ x) as four floats (θ, ω3, ω4, Δφ4) from the modes over [0, τ]."""
    c0 = 0j
    c1 = 0j
    c2 = 0j
    i2 = 0j
    for k in range(3):
        _, _, _, wk, jk, _ = modes[k]
        c0 += LIN[1, k] * wk
        c1 += LIN[2, k] * wk
        c2 += LIN[3, k] * wk
        i2 += LIN[3, k] * jk
    return c0.real, c1.real, c2.real, i2.real


@inline_kernel
def output_at(tau, z0, P, LIN, W, z, with_work):
    """Output state z (layout Z_*) at τ [s] after the step start where it was z0.

    with_work: also the load work and damping loss since the step start (else left as z0's).
    """
    output_from_modes(tau, z0, P, LIN, modes_over(tau, LIN, W), z, with_work)


@inline_kernel
def output_from_modes(tau, z0, P, LIN, modes, z, with_work):
    """``output_at`` from the modes over [0, τ] a caller has already (``modes_over``)."""
    theta, w3, w4, dphi4 = _modal_state(LIN, modes)
    z[Z_TWIST] = theta
    z[Z_OMEGA3] = w3
    z[Z_OMEGA4] = w4
    z[Z_PHI4] = z0[Z_PHI4] + dphi4
    z[Z_W_LOAD] = z0[Z_W_LOAD]
    z[Z_W_DAMPING] = z0[Z_W_DAMPING]
    if with_work:
        drop, loss = _work(tau, z0, P, LIN, modes, theta, w3, w4, dphi4)
        z[Z_W_LOAD] = z0[Z_W_LOAD] + drop - loss
        z[Z_W_DAMPING] = z0[Z_W_DAMPING] + loss


@inline_kernel
def _phi1(z, e):
    """φ1(z) = (e^z − 1)/z, given e = e^z (its series near 0)."""
    if _small(z, PHI1_SERIES):
        s = INV_FACTORIAL[10] + 0j
        for n in range(9, 0, -1):   # Σ z^j/(j+1)!, j = 0…9, by Horner
            s = s * z + INV_FACTORIAL[n]
        return s
    return (e - 1.0) / z


@inline_kernel
def _pair_series(zm, zn):
    """∫₀¹ u²·φ1(zm·u)·φ1(zn·u) du = Σ_ij zm^i·zn^j / ((i+1)!(j+1)!(i+j+3)), |zm|, |zn| small
    (terms to i + j = 7: the rest is below 1e-18 at PAIR_LIMIT)."""
    total = 0j
    for i in range(7, -1, -1):
        inner = 0j
        for j in range(7 - i, -1, -1):
            inner = inner * zn + INV_FACTORIAL[j + 1] / (i + j + 3.0)
        total = total * zm + inner * INV_FACTORIAL[i + 1]
    return total


@inline_kernel
def _phi2_series(z):
    """φ2(z) = (e^z − 1 − z)/z² by its series, |z| small (terms to z⁷)."""
    s = INV_FACTORIAL[9] + 0j
    for n in range(8, 1, -1):
        s = s * z + INV_FACTORIAL[n]
    return s


@inline_kernel
def _pair_integral(tau, lm, ln, w0m, wbm, w1m, jm, em, w0n, wbn, w1n, jn, en):
    """∫₀^τ w_m·w_n dt for two modal coordinates (w' = λ·w + wb; w0, w1 = w(0), w(τ);
    j = ∫₀^τ w; e = e^{λτ}).

    (λ_m + λ_n)·∫w_m·w_n = [w_m·w_n]₀^τ − wb_m·j_n − wb_n·j_m, exact; its rounding grows as
    1/|(λ_m + λ_n)·τ|, so below PAIR_LIMIT: with w(t) = w0 + w'(0)·t·φ1(λt), the product
    integrated term by term when both λτ are small (the slow rigid-body mode with itself), else
    with w = α·e^{λt} + β (β = −wb/λ, the mode's equilibrium: a lightly damped ringing mode with
    its conjugate)."""
    zm = lm * tau
    zn = ln * tau
    zmn = zm + zn
    if not _small(zmn, PAIR_LIMIT):
        return (w1m * w1n - w0m * w0n - wbm * jn - wbn * jm) / (lm + ln)
    if _small(zm, PAIR_LIMIT) and _small(zn, PAIR_LIMIT):
        dm = lm * w0m + wbm
        dn = ln * w0n + wbn
        return tau * (w0m * w0n + tau * (w0m * dn * _phi2_series(zn) + w0n * dm * _phi2_series(zm)
                                         + tau * dm * dn * _pair_series(zm, zn)))
    bm = -wbm / lm
    bn = -wbn / ln
    am = w0m - bm
    an = w0n - bn
    return tau * (am * an * _phi1(zmn, em * en) + am * bn * _phi1(zm, em)
                  + bm * an * _phi1(zn, en) + bm * bn)


@kernel
def _damping_loss_series(tau, z0, P):
    """k·∫₀^τ (ω3 − ω4)² dt [J] for a short step (max|λ|·τ ≤ LOSS_SERIES_LIMIT) from the slip's
    Taylor series in the physical state, x(t) = Σ t^n/n!·A^(n−1)·(A·x0 + b): no modal basis, so
    none of its rounding (a near-critically damped shaft has nearly parallel eigenvectors).
    The slip is summed at the 7 Gauss–Legendre nodes of [0, τ] as its terms come (exact for
    the square's terms to degree 13; the rest is below 1e-17 at LOSS_SERIES_LIMIT)."""
    J3, J4, c, k, kv = P[P_J3], P[P_J4], P[P_C], P[P_KD], P[P_LOAD_VISCOUS]
    th = z0[Z_TWIST]
    w3 = z0[Z_OMEGA3]
    w4 = z0[Z_OMEGA4]
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = w3 - w4     # the slip at the nodes
    p0 = p1 = p2 = p3 = p4 = p5 = p6 = 1.0          # u_g^n
    # v = A·x + b once, then v ← A·v; its slip times τ^n/n! is the series' n-th term
    ts = c * th + k * (w3 - w4)
    th, w3, w4 = w3 - w4, -ts / J3, (ts - P[P_LOAD_TORQUE] - kv * w4) / J4
    scale = tau
    for n in range(1, LOSS_SERIES_TERMS):
        a = (w3 - w4) * scale
        p0 *= GL7_U[0]
        p1 *= GL7_U[1]
        p2 *= GL7_U[2]
        p3 *= GL7_U[3]
        p4 *= GL7_U[4]
        p5 *= GL7_U[5]
        p6 *= GL7_U[6]
        s0 += a * p0
        s1 += a * p1
        s2 += a * p2
        s3 += a * p3
        s4 += a * p4
        s5 += a * p5
        s6 += a * p6
        scale *= tau / (n + 1.0)
        ts = c * th + k * (w3 - w4)
        th, w3, w4 = w3 - w4, -ts / J3, (ts - kv * w4) / J4
    total = (GL7_W[0] * s0 * s0 + GL7_W[1] * s1 * s1 + GL7_W[2] * s2 * s2 + GL7_W[3] * s3 * s3
             + GL7_W[4] * s4 * s4 + GL7_W[5] * s5 * s5 + GL7_W[6] * s6 * s6)
    return k * tau * total


@kernel
def _damping_loss(tau, P, LIN, modes):
    """k·∫₀^τ (ω3 − ω4)² dt [J] = k·Σ_mn d_m·d_n·∫w_m·w_n, d = V_ω3 − V_ω4 (module text).
    With a conjugate pair (modes 0, 1) and the real mode 2, the terms of mode 1 are the
    conjugates of mode 0's: 4 pair integrals instead of 6."""
    l0, a0, b0, c0, j0, e0 = modes[0]
    l1, a1, b1, c1, j1, e1 = modes[1]
    l2, a2, b2, c2, j2, e2 = modes[2]
    d0 = LIN[2, 0] - LIN[3, 0]
    d1 = LIN[2, 1] - LIN[3, 1]
    d2 = LIN[2, 2] - LIN[3, 2]
    i00 = d0 * d0 * _pair_integral(tau, l0, l0, a0, b0, c0, j0, e0, a0, b0, c0, j0, e0)
    i22 = d2 * d2 * _pair_integral(tau, l2, l2, a2, b2, c2, j2, e2, a2, b2, c2, j2, e2)
    i01 = d0 * d1 * _pair_integral(tau, l0, l1, a0, b0, c0, j0, e0, a1, b1, c1, j1, e1)
    i02 = d0 * d2 * _pair_integral(tau, l0, l2, a0, b0, c0, j0, e0, a2, b2, c2, j2, e2)
    if LIN[0, 0].imag != 0.0:
        total = 2.0 * i00.real + i22.real + 2.0 * (i01.real + 2.0 * i02.real)
    else:
        i11 = d1 * d1 * _pair_integral(tau, l1, l1, a1, b1, c1, j1, e1, a1, b1, c1, j1, e1)
        i12 = d1 * d2 * _pair_integral(tau, l1, l2, a1, b1, c1, j1, e1, a2, b2, c2, j2, e2)
        total = (i00 + i11 + i22 + 2.0 * (i01 + i02 + i12)).real
    return P[P_KD] * total


@kernel
def _work(tau, z0, P, LIN, modes, theta, w3, w4, dphi4):
    """(energy drop of the output subsystem, damping loss) over [0, τ] [J]."""
    J3, J4, c, k = P[P_J3], P[P_J4], P[P_C], P[P_KD]
    e0 = 0.5 * (J3 * z0[Z_OMEGA3] ** 2 + J4 * z0[Z_OMEGA4] ** 2 + c * z0[Z_TWIST] ** 2)
    e1 = 0.5 * (J3 * w3 * w3 + J4 * w4 * w4 + c * theta * theta)
    drop = e0 - e1  # = load work + damping loss over [0, τ]
    if k == 0.0:
        return drop, 0.0
    if P[P_LOAD_VISCOUS] == 0.0:
        return drop, drop - P[P_LOAD_TORQUE] * dphi4
    if P[P_OUTPUT_RATE] * tau <= LOSS_SERIES_LIMIT:
        return drop, _damping_loss_series(tau, z0, P)
    return drop, _damping_loss(tau, P, LIN, modes)
