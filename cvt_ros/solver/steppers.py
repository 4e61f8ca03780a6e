"""Explicit Runge-Kutta steppers with dense output, compiled with numba.

Shaped like scipy's ``integrate/_ivp/rk.py``: module-level kernels that take arrays and scratch
buffers. ``K`` holds the stage derivatives of the last step (row 0 = f(t, y),
row 6 = f(t+h, y_new)), which is all the dense output needs.

* Dormand–Prince 5(4) (scipy's RK45 tableau): adaptive, local extrapolation, quartic dense output.
* Classical RK4 with cubic Hermite dense output: the fixed-step real-time mode and the paper's
  method.
"""
import math

import numpy as np

from ..physics.compiled import inline_kernel, kernel
from ..physics.dynamics import output_rhs, rhs
from ..physics.layout import (
    INPUT_DYNAMIC,
    N_DYNAMIC,
    N_OUTPUT_DYNAMIC,
    OUTPUT_STATES,
    TWIST,
    W_DAMPING,
)

DOPRI5 = 0
RK4 = 1

# what a step integrates: the whole hybrid state, or only the disengaged output subsystem
FULL = 0
OUTPUT = 1
INPUT = 2  # the whole state, output subsystem frozen (it is integrated apart, see slip_watch.py)
MASSLESS = 3  # the whole state, a massless damped node's twist (and its damping work) frozen:
#               open, θ' = −(c/k)·θ is solved exactly apart from the step (guard_watch.relax_twist)
# components under error control
ERR_FULL = np.arange(N_DYNAMIC)
ERR_INPUT = np.array(INPUT_DYNAMIC)
ERR_OUTPUT = np.arange(N_OUTPUT_DYNAMIC)
ERR_MASSLESS = np.array([i for i in range(N_DYNAMIC) if i != TWIST])

# Dormand–Prince 5(4) (scipy RK45)
DP_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0])
DP_A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [1 / 5, 0.0, 0.0, 0.0, 0.0],
    [3 / 40, 9 / 40, 0.0, 0.0, 0.0],
    [44 / 45, -56 / 15, 32 / 9, 0.0, 0.0],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0.0],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656],
])
DP_B = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84])
DP_E = np.array([-71 / 57600, 0.0, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40])
DP_P = np.array([
    [1.0, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
    [0.0, 0.0, 0.0, 0.0],
    [0.0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799],
    [0.0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
    [0.0, 127303824393 / 49829197408, -318862633887 / 49829197408,
     701980252875 / 199316789632],
    [0.0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
    [0.0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423],
])
DP_ERROR_EXPONENT = -1.0 / 5.0
# the tableau as scalars (numba compiles module floats in as constants; b1 = e1 = 0)
_C1, _C2, _C3, _C4 = DP_C[1:5].tolist()
(_A10,) = DP_A[1, :1].tolist()
_A20, _A21 = DP_A[2, :2].tolist()
_A30, _A31, _A32 = DP_A[3, :3].tolist()
_A40, _A41, _A42, _A43 = DP_A[4, :4].tolist()
_A50, _A51, _A52, _A53, _A54 = DP_A[5, :5].tolist()
_B0, _, _B2, _B3, _B4, _B5 = DP_B.tolist()
_E0, _, _E2, _E3, _E4, _E5, _E6 = DP_E.tolist()
SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 10.0


@inline_kernel
def evaluate(kind, t, y, mode, P, ACT, dy, aux):
    if kind == OUTPUT:
        output_rhs(y, P, dy)
    else:
        rhs(t, y, mode, P, ACT, dy, aux)
        if kind == INPUT:
            for i in OUTPUT_STATES:
                dy[i] = 0.0
        elif kind == MASSLESS:
            dy[TWIST] = 0.0
            dy[W_DAMPING] = 0.0


@kernel
def dopri5_step(kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol, err_idx):
    """One Dormand–Prince step from (t, y) with K[0] = f(t, y) given.

    Writes y_new and K[6] = f(t+h, y_new) (FSAL; ``aux`` then holds its auxiliaries) and returns
    the RMS error norm, scaled by atol + rtol·max(|y|, |y_new|), over the components err_idx.
    """
    # the tableau's stages written out (constant coefficients, no loop over j): LLVM keeps
    # the coefficients in registers and vectorises over the states
    n = y.shape[0]
    for i in range(n):
        ytmp[i] = y[i] + h * (_A10 * K[0, i])
    evaluate(kind, t + _C1 * h, ytmp, mode, P, ACT, K[1], aux)
    for i in range(n):
        ytmp[i] = y[i] + h * (_A20 * K[0, i] + _A21 * K[1, i])
    evaluate(kind, t + _C2 * h, ytmp, mode, P, ACT, K[2], aux)
    for i in range(n):
        ytmp[i] = y[i] + h * (_A30 * K[0, i] + _A31 * K[1, i] + _A32 * K[2, i])
    evaluate(kind, t + _C3 * h, ytmp, mode, P, ACT, K[3], aux)
    for i in range(n):
        ytmp[i] = y[i] + h * (_A40 * K[0, i] + _A41 * K[1, i] + _A42 * K[2, i]
                              + _A43 * K[3, i])
    evaluate(kind, t + _C4 * h, ytmp, mode, P, ACT, K[4], aux)
    for i in range(n):
        ytmp[i] = y[i] + h * (_A50 * K[0, i] + _A51 * K[1, i] + _A52 * K[2, i]
                              + _A53 * K[3, i] + _A54 * K[4, i])
    evaluate(kind, t + h, ytmp, mode, P, ACT, K[5], aux)
    for i in range(n):
        y_new[i] = y[i] + h * (_B0 * K[0, i] + _B2 * K[2, i] + _B3 * K[3, i] + _B4 * K[4, i]
                               + _B5 * K[5, i])
    evaluate(kind, t + h, y_new, mode, P, ACT, K[6], aux)
    total = 0.0
    for i in err_idx:
        e = (_E0 * K[0, i] + _E2 * K[2, i] + _E3 * K[3, i] + _E4 * K[4, i] + _E5 * K[5, i]
             + _E6 * K[6, i])
        scale = atol + rtol * max(abs(y[i]), abs(y_new[i]))
        r = h * e / scale
        total += r * r
    return math.sqrt(total / err_idx.shape[0])


@inline_kernel
def rk4_stage(s, t, y, h, K, ytmp):
    """Classical RK4, stage s = 1, 2, 3: writes the stage's state into ytmp from K[s − 1] and
    returns its time; the caller evaluates its own right-hand side there into K[s]. Every RK4
    in the package (the hybrid model's, the averaged model's) is these stages and rk4_combine."""
    c = 1.0 if s == 3 else 0.5
    for i in range(y.shape[0]):
        ytmp[i] = y[i] + c * h * K[s - 1, i]
    return t + c * h


@inline_kernel
def rk4_combine(y, h, K, y_new):
    """y_new = y + h·(K0 + 2·K1 + 2·K2 + K3)/6 (y_new may be y itself)."""
    for i in range(y.shape[0]):
        y_new[i] = y[i] + h / 6.0 * (K[0, i] + 2.0 * K[1, i] + 2.0 * K[2, i] + K[3, i])


@kernel
def rk4_step(kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux):
    """One RK4 step of the hybrid model (K[0] = f(t, y) given, of the same kind); writes y_new
    and K[6] = f(t+h, y_new) for the dense output. ``kind`` as dopri5_step's: the whole state,
    or with the open output (INPUT) or a massless node's twist (MASSLESS) held still, solved
    apart from the step."""
    for s in range(1, 4):
        evaluate(kind, rk4_stage(s, t, y, h, K, ytmp), ytmp, mode, P, ACT, K[s], aux)
    rk4_combine(y, h, K, y_new)
    evaluate(kind, t + h, y_new, mode, P, ACT, K[6], aux)
    return 0.0


@inline_kernel
def dense_state(method, theta, h, y0, y1, K, out):
    """State at t0 + θ·h (0 ≤ θ ≤ 1) from the last step's dense output."""
    n = y0.shape[0]
    if method == DOPRI5:
        t2 = theta * theta
        t3 = t2 * theta
        t4 = t3 * theta
        for i in range(n):
            q0 = 0.0
            q1 = 0.0
            q2 = 0.0
            q3 = 0.0
            for s in range(7):
                k = K[s, i]
                q0 += k * DP_P[s, 0]
                q1 += k * DP_P[s, 1]
                q2 += k * DP_P[s, 2]
                q3 += k * DP_P[s, 3]
            out[i] = y0[i] + h * (q0 * theta + q1 * t2 + q2 * t3 + q3 * t4)
    else:
        t2 = theta * theta
        t3 = t2 * theta
        h00 = 2.0 * t3 - 3.0 * t2 + 1.0
        h10 = t3 - 2.0 * t2 + theta
        h01 = -2.0 * t3 + 3.0 * t2
        h11 = t3 - t2
        for i in range(n):
            out[i] = h00 * y0[i] + h10 * h * K[0, i] + h01 * y1[i] + h11 * h * K[6, i]


@inline_kernel
def dense_coefficients(method, h, y0, y1, K, i, c):
    """The dense output of component i over the last step as a polynomial in θ ∈ [0, 1]:
    y_i(t0 + θ·h) = Σ_k c[k]·θ^k (c[0..4]; the rest of c is zeroed). Its θ-derivative over h is
    the dense output of y_i' (K[0] at θ = 0, K[6] at θ = 1)."""
    for k in range(c.shape[0]):
        c[k] = 0.0
    c[0] = y0[i]
    if method == DOPRI5:
        for s in range(7):
            k = K[s, i]
            for j in range(4):
                c[j + 1] += h * k * DP_P[s, j]
    else:
        d0 = h * K[0, i]
        d1 = h * K[6, i]
        dy = y1[i] - y0[i]
        c[1] = d0
        c[2] = 3.0 * dy - 2.0 * d0 - d1
        c[3] = -2.0 * dy + d0 + d1


@kernel
def initial_step(kind, t, y, mode, P, ACT, f0, rtol, atol, ytmp, ftmp, aux, err_idx):
    """Hairer–Nørsett–Wanner starting step (as scipy's ``select_initial_step``), order 5
    (ytmp, ftmp, aux: working arrays)."""
    d0 = 0.0
    d1 = 0.0
    for i in err_idx:
        scale = atol + abs(y[i]) * rtol
        d0 += (y[i] / scale) ** 2
        d1 += (f0[i] / scale) ** 2
    n_err = err_idx.shape[0]
    d0 = math.sqrt(d0 / n_err)
    d1 = math.sqrt(d1 / n_err)
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    for i in range(y.shape[0]):
        ytmp[i] = y[i] + h0 * f0[i]
    evaluate(kind, t + h0, ytmp, mode, P, ACT, ftmp, aux)
    d2 = 0.0
    for i in err_idx:
        scale = atol + abs(y[i]) * rtol
        d2 += ((ftmp[i] - f0[i]) / scale) ** 2
    d2 = math.sqrt(d2 / n_err) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** 0.2
    return min(100.0 * h0, h1)
