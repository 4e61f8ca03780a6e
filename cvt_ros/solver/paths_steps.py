"""Steps and samples of the N-path machine (issue 33): the explicit Runge–Kutta steps of
steppers.py (the same Dormand–Prince tableau, classical RK4's stages) over physics/paths.py's
right-hand side, the Hairer–Nørsett–Wanner starting step, and the sample rows with the per-path
columns (output.path_columns).

A step integrates the whole state (``FULL``) or, with every clutch open and the output solved
apart (paths_open.py), the input alone (``INPUT``: the output's rates held at zero, the error
over the crank and rocker states, as steppers.py's kinds)."""
import math

from ..physics.compiled import inline_kernel, kernel
from ..physics.layout import AUX_CRANK_LENGTH, N_OUTPUT, OUTPUT_STATES
from ..physics.output_exact import output_at
from ..physics.paths import (
    A_SPEED,
    A_TORQUE,
    V_PATH,
    bit,
    n_paths,
    path_rocker_angles,
    paths_project,
    paths_rhs,
)
from .advance_layout import C_NEXT_SAMPLE, C_RHS
from .output import COL, N_COLUMNS, write_sample
from .steppers import (
    DOPRI5,
    DP_A,
    DP_B,
    DP_C,
    DP_E,
    ERR_FULL,
    ERR_INPUT,
    FULL,
    INPUT,
    dense_state,
    rk4_combine,
    rk4_stage,
)

_ENGAGED = COL['engaged']
_PHI2 = COL['phi2']


@inline_kernel
def paths_evaluate(kind, t, y, mode, P, ACT, dy, aux):
    """The right-hand side of what a step of ``kind`` integrates (INPUT: the output frozen)."""
    ok = paths_rhs(t, y, mode, P, ACT, dy, aux)
    if kind == INPUT:
        for i in OUTPUT_STATES:
            dy[i] = 0.0
    return ok


@kernel
def paths_step(method, kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol,
               counters):
    """One step from (t, y), K[0] = f(t, y) given (of the same kind): y_new, K[6] =
    f(t + h, y_new) (``aux`` then its auxiliaries); returns Dormand–Prince's RMS error norm
    over the dynamic states (steppers.ERR_FULL, or ERR_INPUT for an INPUT step; the rocker
    speeds follow the crank), 0 for RK4."""
    n = y.shape[0]
    if method != DOPRI5:
        for s in range(1, 4):
            paths_evaluate(kind, rk4_stage(s, t, y, h, K, ytmp), ytmp, mode, P, ACT, K[s], aux)
        rk4_combine(y, h, K, y_new)
        paths_evaluate(kind, t + h, y_new, mode, P, ACT, K[6], aux)
        counters[C_RHS] += 4
        return 0.0
    for s in range(1, 6):
        for i in range(n):
            dot = 0.0
            for j in range(s):
                dot += DP_A[s, j] * K[j, i]
            ytmp[i] = y[i] + h * dot
        paths_evaluate(kind, t + DP_C[s] * h, ytmp, mode, P, ACT, K[s], aux)
    for i in range(n):
        dot = 0.0
        for j in range(6):
            dot += DP_B[j] * K[j, i]
        y_new[i] = y[i] + h * dot
    paths_evaluate(kind, t + h, y_new, mode, P, ACT, K[6], aux)
    counters[C_RHS] += 6
    return _error_norm(False, ERR_INPUT if kind == INPUT else ERR_FULL, h, y, y_new, K, rtol,
                       atol)


@kernel
def paths_euler_step(t, y, h, mode, P, ACT, K, y_new, aux, rtol, atol, counters):
    """An explicit Euler step from (t, y), K[0] = f(t, y) given: y_new, K[6] = f(t + h, y_new)
    (``aux`` there), one right-hand side; returns its local error estimate h/2·(K[6] − K[0])
    (Heun's step against it) in paths_step's norm. For the creep onto a catch
    (paths_hybrid._creep_onto_catch), whose steps are ~1e-10 s at the defaults: a Dormand–Prince
    step there spends six right-hand sides on an error below rounding."""
    n = y.shape[0]
    for i in range(n):
        y_new[i] = y[i] + h * K[0, i]
    paths_evaluate(FULL, t + h, y_new, mode, P, ACT, K[6], aux)
    counters[C_RHS] += 1
    return _error_norm(True, ERR_FULL, h, y, y_new, K, rtol, atol)


@inline_kernel
def _error_norm(euler, err_idx, h, y, y_new, K, rtol, atol):
    """The RMS of a step's error estimates over the states err_idx and every rocker speed (under
    error control as the one path's is: its dense polynomial is what each path's slip is watched
    on, paths_open.py): Dormand–Prince's, or an Euler step's (``euler``)."""
    n = y.shape[0]
    total = 0.0
    for i in err_idx:
        total += _euler_error(i, h, y, y_new, K, rtol, atol) if euler else _scaled_error(
            i, h, y, y_new, K, rtol, atol)
    for i in range(V_PATH, n):
        total += _euler_error(i, h, y, y_new, K, rtol, atol) if euler else _scaled_error(
            i, h, y, y_new, K, rtol, atol)
    return math.sqrt(total / (err_idx.shape[0] + n - V_PATH))


@inline_kernel
def _euler_error(i, h, y, y_new, K, rtol, atol):
    """The Euler step's error estimate of state i, squared, in atol + rtol·|y|."""
    r = 0.5 * h * (K[6, i] - K[0, i]) / (atol + rtol * max(abs(y[i]), abs(y_new[i])))
    return r * r


@inline_kernel
def _scaled_error(i, h, y, y_new, K, rtol, atol):
    """Dormand–Prince's error estimate of state i over the step, squared, in atol + rtol·|y|."""
    e = 0.0
    for j in range(7):
        e += DP_E[j] * K[j, i]
    r = h * e / (atol + rtol * max(abs(y[i]), abs(y_new[i])))
    return r * r


@inline_kernel
def _scaled_rms(kind, v, y, rtol, atol):
    """The RMS over the error-controlled states of v scaled by atol + rtol·|y|."""
    err_idx = ERR_INPUT if kind == INPUT else ERR_FULL
    total = 0.0
    for i in err_idx:
        total += (v[i] / (atol + abs(y[i]) * rtol)) ** 2
    return math.sqrt(total / err_idx.shape[0])


@kernel
def paths_initial_step(kind, t, y, mode, P, ACT, f0, rtol, atol, ytmp, ftmp, aux):
    """The Hairer–Nørsett–Wanner starting step of order 5 (as steppers.initial_step) for a
    step of ``kind`` (f0 its rates at y): a first guess from the sizes of y and y', corrected by
    the change of y' over it."""
    size = _scaled_rms(kind, y, y, rtol, atol)
    rate = _scaled_rms(kind, f0, y, rtol, atol)
    h0 = 0.01 * size / rate if size >= 1e-5 and rate >= 1e-5 else 1e-6
    for i in range(y.shape[0]):
        ytmp[i] = y[i] + h0 * f0[i]
    paths_evaluate(kind, t + h0, ytmp, mode, P, ACT, ftmp, aux)
    for i in range(y.shape[0]):
        ftmp[i] -= f0[i]
    top = max(rate, _scaled_rms(kind, ftmp, y, rtol, atol) / h0)
    h1 = max(1e-6, h0 * 1e-3) if top <= 1e-15 else (0.01 / top) ** 0.2
    return min(100.0 * h0, h1)


@kernel
def write_paths_sample(row, t, y, mode, aux, P):
    """One output row (output.path_columns): the one-path columns (phi2, omega2: path 1's
    rocker; engaged: any clutch; clutch_torque: what all pass to the node), then per path
    phi2_k, omega2_k, engaged_k, clutch_torque_k."""
    write_sample(row, t, y, mode, aux)
    row[_ENGAGED] = 1.0 if mode != 0 else 0.0
    n = n_paths(P)
    path_rocker_angles(y, aux[AUX_CRANK_LENGTH], P, row[N_COLUMNS:N_COLUMNS + n])
    row[_PHI2] = row[N_COLUMNS]   # path 1's rocker: one value (joint_states' rocker_1), not two
    for k in range(n):
        row[N_COLUMNS + n + k] = aux[A_SPEED + k]
        row[N_COLUMNS + 2 * n + k] = 1.0 if mode & bit(k) else 0.0
        row[N_COLUMNS + 3 * n + k] = aux[A_TORQUE + k]


@kernel
def emit_paths_samples(method, t, h, y0, y1, K, mode, P, ACT, grid, out, counters, t_limit,
                       ytmp, dytmp, auxtmp, split, zs, LIN, W, ztmp):
    """Every grid sample in (…, t_limit] from the dense output of the step [t, t + h]; a
    split step's output (``split``) from its exact solution since the step's start (zs there,
    W its modal coordinates: paths_open.py)."""
    i = counters[C_NEXT_SAMPLE]
    while i < grid.shape[0] and grid[i] <= t_limit:
        dense_state(method, (grid[i] - t) / h if h > 0.0 else 1.0, h, y0, y1, K, ytmp)
        if split:
            output_at(grid[i] - t, zs, P, LIN, W, ztmp, True)
            for j in range(N_OUTPUT):
                ytmp[OUTPUT_STATES[j]] = ztmp[j]
        paths_project(grid[i], ytmp, mode, P, ACT, auxtmp)
        paths_rhs(grid[i], ytmp, mode, P, ACT, dytmp, auxtmp)
        write_paths_sample(out[i], grid[i], ytmp, mode, auxtmp, P)
        i += 1
    counters[C_NEXT_SAMPLE] = i
