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
the damping loss k·∫(ω3 − ω4)² is taken by composite 8-point Gauss–Legendre on the exact
solution.

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
GAUSS_X, GAUSS_W = np.polynomial.legendre.leggauss(8)
GAUSS_PANEL_PHASE = 1.5  # [rad]: 8 nodes integrate e^{iωt} over 1.5 rad to ~1e-16


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
        inv = np.linalg.inv(V)
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
def _modal_state(tau, LIN, W):
    """(x(τ), ∫₀^τ x) as six floats from the modal coordinates W."""
    c0 = 0j
    c1 = 0j
    c2 = 0j
    i2 = 0j
    for k in range(3):
        lam = LIN[0, k]
        lt = lam * tau
        if abs(lt) < SERIES_LIMIT:
            e = 1.0 + lt * (1.0 + lt * (0.5 + lt * (1.0 / 6.0 + lt / 24.0)))
            f1 = tau * (1.0 + lt * (0.5 + lt * (1.0 / 6.0 + lt / 24.0)))
            f2 = tau * tau * (0.5 + lt * (1.0 / 6.0 + lt * (1.0 / 24.0 + lt / 120.0)))
        else:
            e = np.exp(lt)
            f1 = (e - 1.0) / lam
            f2 = (e - 1.0 - lt) / (lam * lam)
        ck = W[0, k] * e + W[1, k] * f1
        c0 += LIN[1, k] * ck
        c1 += LIN[2, k] * ck
        c2 += LIN[3, k] * ck
        i2 += LIN[3, k] * (W[0, k] * f1 + W[1, k] * f2)
    return c0.real, c1.real, c2.real, i2.real


@inline_kernel
def output_at(tau, z0, P, LIN, W, z, with_work):
    """Output state z (layout Z_*) at τ [s] after the step start where it was z0.

    with_work: also the load work and damping loss since the step start (else left as z0's).
    """
    theta, w3, w4, dphi4 = _modal_state(tau, LIN, W)
    z[Z_TWIST] = theta
    z[Z_OMEGA3] = w3
    z[Z_OMEGA4] = w4
    z[Z_PHI4] = z0[Z_PHI4] + dphi4
    z[Z_W_LOAD] = z0[Z_W_LOAD]
    z[Z_W_DAMPING] = z0[Z_W_DAMPING]
    if with_work:
        drop, loss = _work(tau, z0, P, LIN, W, theta, w3, w4, dphi4)
        z[Z_W_LOAD] = z0[Z_W_LOAD] + drop - loss
        z[Z_W_DAMPING] = z0[Z_W_DAMPING] + loss


@inline_kernel
def _slip_coefficients(m, LIN, W):
    """Mode m's part of ω3 − ω4 as d·(w0·e^{λτ} + wb·F1) = A·e^{λτ} + B: (λ, d·w0, d·wb, A, B)."""
    lam = LIN[0, m]
    dm = LIN[2, m] - LIN[3, m]
    a0 = dm * W[0, m]
    a1 = dm * W[1, m]
    inv = 1.0 / lam if lam != 0.0 else 0j
    return lam, a0, a1, a0 + a1 * inv, -a1 * inv


@inline_kernel
def _slip_mode(x, e, lam, a0, a1, A, B):
    """A mode's part of ω3 − ω4 at τ = x [rad/s], e = e^{λ·x} (the series near λ·x = 0)."""
    lt = lam * x
    if abs(lt) < SERIES_LIMIT:
        return (a0 * (1.0 + lt * (1.0 + lt * (0.5 + lt * (1.0 / 6.0 + lt / 24.0))))
                + a1 * x * (1.0 + lt * (0.5 + lt * (1.0 / 6.0 + lt / 24.0)))).real
    return (A * e + B).real


@kernel
def _work(tau, z0, P, LIN, W, theta, w3, w4, dphi4):
    """(energy drop of the output subsystem, damping loss) over [0, τ] [J]."""
    J3, J4, c, k = P[P_J3], P[P_J4], P[P_C], P[P_KD]
    e0 = 0.5 * (J3 * z0[Z_OMEGA3] ** 2 + J4 * z0[Z_OMEGA4] ** 2 + c * z0[Z_TWIST] ** 2)
    e1 = 0.5 * (J3 * w3 * w3 + J4 * w4 * w4 + c * theta * theta)
    drop = e0 - e1  # = load work + damping loss over [0, τ]
    if k == 0.0:
        return drop, 0.0
    if P[P_LOAD_VISCOUS] == 0.0:
        return drop, drop - P[P_LOAD_TORQUE] * dphi4
    # composite Gauss–Legendre, ≤ GAUSS_PANEL_PHASE rad of the fastest mode per panel, on
    # ω3 − ω4 = Re Σ_m d_m·(w0_m·e^{λτ} + wb_m·F1), d_m = V_ω3,m − V_ω4,m: each node's e^{λτ}
    # from the first panel's by e^{λ·width} per panel (8 + 1 exponentials a mode a step, not
    # 8 a panel; none for the second of a conjugate pair)
    panels = max(1, int(math.ceil(P[P_OUTPUT_RATE] * tau / GAUSS_PANEL_PHASE)))
    width = tau / panels
    l0, a00, a10, A0, B0 = _slip_coefficients(0, LIN, W)
    l1, a01, a11, A1, B1 = _slip_coefficients(1, LIN, W)
    l2, a02, a12, A2, B2 = _slip_coefficients(2, LIN, W)
    pair1 = l1.imag != 0.0 and l1 == l0.conjugate()
    pair2 = l2.imag != 0.0 and l2 == l1.conjugate()
    x0 = abs(l0 * tau) >= SERIES_LIMIT
    x1 = abs(l1 * tau) >= SERIES_LIMIT
    x2 = abs(l2 * tau) >= SERIES_LIMIT
    s0 = np.exp(l0 * width) if x0 else 1.0 + 0j
    s1 = (s0.conjugate() if pair1 else np.exp(l1 * width)) if x1 else 1.0 + 0j
    s2 = (s1.conjugate() if pair2 else np.exp(l2 * width)) if x2 else 1.0 + 0j
    loss = 0.0
    for g in range(GAUSS_X.shape[0]):
        u = 0.5 * (GAUSS_X[g] + 1.0)
        e0 = np.exp(l0 * (width * u)) if x0 else 1.0 + 0j
        e1 = (e0.conjugate() if pair1 else np.exp(l1 * (width * u))) if x1 else 1.0 + 0j
        e2 = (e1.conjugate() if pair2 else np.exp(l2 * (width * u))) if x2 else 1.0 + 0j
        acc = 0.0
        for p in range(panels):
            x = width * (p + u)
            slip = (_slip_mode(x, e0, l0, a00, a10, A0, B0)
                    + _slip_mode(x, e1, l1, a01, a11, A1, B1)
                    + _slip_mode(x, e2, l2, a02, a12, A2, B2))
            acc += slip * slip
            e0 *= s0
            e1 *= s1
            e2 *= s2
        loss += GAUSS_W[g] * acc
    return drop, 0.5 * width * k * loss
