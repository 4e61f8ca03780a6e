"""The hybrid integration loop: steps, clutch events, resets and samples, all in one compiled call.

``advance`` integrates from t to t_end in the current clutch mode, checks the clutch witness
function after every step, and when it falls through zero locates the crossing on the step's dense
output (Illinois' regula falsi to ~1e-13 s), re-takes a true step exactly to the event, applies the
reset map of the automaton (physics/clutch.py) and goes on in the new mode. Samples on a
caller-given time grid are written from the dense output, so sampling never shortens a step.

The loop never leaves compiled code between events: that, not a faster RHS, is what makes it fast.
"""
import math

import numpy as np

from ..physics.clutch import (
    KIND_ENGAGE,
    KIND_ENGAGE_IMPACT,
    KIND_GRAZE,
    KIND_RELEASE,
    SLIP_TOLERANCE,
    clutch_engages,
    clutch_guard,
    free_slip_rate,
    guard_tolerance,
    uses_twist_release,
)
from ..physics.compiled import inline_kernel, kernel
from ..physics.drives import next_actuator_break
from ..physics.dynamics import (
    disengaged_output_rates,
    engage_with_impact,
    finite_state,
    output_rhs,
    project,
    rhs,
    rocker_speed,
)
from ..physics.layout import (
    AUX_SLIP,
    DISENGAGED,
    ENGAGED,
    N_AUX,
    N_OUTPUT,
    OMEGA3,
    OUTPUT_STATES,
    P_J3,
    P_LINEAR_OUTPUT,
    P_OUTPUT_RATE,
    P_RIGID,
    Z_OMEGA3,
    Z_OMEGA4,
    Z_TWIST,
)
from ..physics.output_exact import modal_coordinates, output_at
from .output import write_sample
from .steppers import (
    DOPRI5,
    DP_ERROR_EXPONENT,
    ERR_FULL,
    ERR_INPUT,
    ERR_OUTPUT,
    FULL,
    INPUT,
    MAX_FACTOR,
    MIN_FACTOR,
    OUTPUT,
    SAFETY,
    dense_state,
    dopri5_step,
    initial_step,
    rk4_step,
)

# settings vector S
S_METHOD = 0
S_RTOL = 1
S_ATOL = 2
S_H_FIXED = 3
S_MAX_STEP = 4
N_SETTINGS = 5

# counters (int64)
C_STEPS = 0
C_REJECTED = 1
C_NEXT_SAMPLE = 2
C_EVENTS = 3
C_STATUS = 4
C_SWITCHES = 5
C_SUBSTEPS = 6
C_ENGAGED_STEPS = 7
N_COUNTERS = 8

STATUS_OK = 0
STATUS_EVENTS_FULL = 1
STATUS_STEP_TOO_SMALL = 2
STATUS_NONFINITE = 3
STATUS_ZENO = 4  # events without the time moving on: the automaton would loop

# events table columns
E_T = 0
E_MODE = 1
E_KIND = 2
E_VALUE = 3
N_EVENT_COLUMNS = 4

MAX_EVENTS_AT_ONE_TIME = 8
EXACT_PHASE_STEP = 0.75  # [rad] of the output's fastest mode between two looks at the slip

_NO_EVENT = 0
_CROSSING = 1
_LATE = 2


@kernel
def _step(method, kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol, err_idx):
    if method == DOPRI5:
        return dopri5_step(kind, t, y, h, mode, P, ACT, K, y_new, ytmp, aux, rtol, atol, err_idx)
    return rk4_step(t, y, h, mode, P, ACT, K, y_new, ytmp, aux)


@inline_kernel
def _guard_at(method, theta, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp):
    dense_state(method, theta, h, y0, y1, K, ytmp)
    rhs(t + theta * h, ytmp, mode, P, ACT, dytmp, auxtmp)
    g, _ = clutch_guard(mode, ytmp, dytmp, auxtmp, P)
    return g


@inline_kernel
def _output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, with_work):
    """Output subsystem at tau + σ·hs: the exact solution from the step start t (exact), or the
    dense output of the sub-step [tau, tau+hs] that started at z0."""
    Ko, zs, LIN, W = clock
    if exact:
        output_at(tau + sigma * hs - t, zs, P, LIN, W, ztmp, with_work)
    else:
        dense_state(DOPRI5, sigma, hs, z0, z0, Ko, ztmp)


@inline_kernel
def _combine(exact, sigma, t, h, y0, K, tau, hs, z0, clock, P, ycomb, ztmp, with_work):
    """The full state at tau + σ·hs inside a split step: the input subsystem from the main
    step's dense output, the output subsystem from _output_state."""
    tt = tau + sigma * hs
    dense_state(DOPRI5, (tt - t) / h, h, y0, y0, K, ycomb)
    _output_state(exact, sigma, t, tau, hs, z0, clock, P, ztmp, with_work)
    for i in range(N_OUTPUT):
        ycomb[OUTPUT_STATES[i]] = ztmp[i]
    return tt


@inline_kernel
def _split_slip(exact, sigma, t, h, y0, K, tau, hs, z0, clock, P, ACT, ycomb, ztmp):
    """Slip s = ω3 − v at tau + σ·hs inside a split step [rad/s]."""
    tt = _combine(exact, sigma, t, h, y0, K, tau, hs, z0, clock, P, ycomb, ztmp, False)
    return ycomb[OMEGA3] - rocker_speed(tt, ycomb, P, ACT)


@inline_kernel
def _guard_value(split, exact, method, theta, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT,
                 ytmp, dytmp, auxtmp, ztmp):
    if split:
        return _split_slip(exact, theta, t, h, y0, K, tau, hs, z0, clock, P, ACT, ytmp, ztmp)
    return _guard_at(method, theta, t, h, y0, y1, K, mode, P, ACT, ytmp, dytmp, auxtmp)


@inline_kernel
def _hermite_minimum(g0, d0, g1, d1):
    """Interior minimum (θ, value) of the cubic with p(0)=g0, p'(0)=d0, p(1)=g1, p'(1)=d1."""
    c1 = d0
    c2 = -3.0 * g0 - 2.0 * d0 + 3.0 * g1 - d1
    c3 = 2.0 * g0 + d0 - 2.0 * g1 + d1
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


@kernel
def _locate(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, lo, hi, glo,
            ghi, tol_theta, ytmp, dytmp, auxtmp, ztmp):
    """Illinois' regula falsi on g(θ), g(lo) > 0 > g(hi); returns θ just past the root.

    θ runs over the step [t, t+h] (split = False) or over the output sub-step [tau, tau+hs].
    """
    side = 0
    for it in range(200):
        if hi - lo <= tol_theta:
            break
        if it % 4 == 3:
            m = 0.5 * (lo + hi)  # guarantees the bracket shrinks even on a one-sided approach
        else:
            m = hi - ghi * (hi - lo) / (ghi - glo)
            if not (lo < m < hi):
                m = 0.5 * (lo + hi)
        gm = _guard_value(split, exact, method, m, t, h, y0, y1, K, tau, hs, z0, clock, mode, P,
                          ACT, ytmp, dytmp, auxtmp, ztmp)
        if gm > 0.0:
            lo = m
            glo = gm
            if side == 1:
                ghi *= 0.5
            side = 1
        elif gm < 0.0:
            hi = m
            ghi = gm
            if side == -1:
                glo *= 0.5
            side = -1
        else:
            return m
    return hi


@kernel
def _emit(split, exact, method, t, h, y0, y1, K, tau, hs, z0, clock, mode, P, ACT, grid, out,
          counters, t_limit, ytmp, ztmp, dytmp, auxtmp):
    """Write every grid sample in (…, t_limit] from the dense output of the step [t, t+h], or,
    inside a split step (split), of its input part and of the output sub-step [tau, tau+hs]."""
    i = counters[C_NEXT_SAMPLE]
    while i < grid.shape[0] and grid[i] <= t_limit:
        if split:
            _combine(exact, (grid[i] - tau) / hs if hs > 0.0 else 1.0, t, h, y0, K, tau, hs, z0,
                     clock, P, ytmp, ztmp, True)
        else:
            dense_state(method, (grid[i] - t) / h if h > 0.0 else 1.0, h, y0, y1, K, ytmp)
        project(grid[i], ytmp, mode, P, ACT)
        rhs(grid[i], ytmp, mode, P, ACT, dytmp, auxtmp)
        write_sample(out[i], grid[i], ytmp, mode, auxtmp)
        i += 1
    counters[C_NEXT_SAMPLE] = i


@inline_kernel
def _due(grid, counters, t_limit):
    """Is a grid sample due in (…, t_limit]? (Checked before the call: most steps have none.)"""
    i = counters[C_NEXT_SAMPLE]
    return i < grid.shape[0] and grid[i] <= t_limit


@kernel
def _split_output(exact, t, h, y, y_new, K, mode, P, ACT, clock, rtol, atol, armed, g0, h_io,
                  grid, out, counters, z, z_new, ztmp, ycomb, ytmp, dytmp, auxtmp):
    """The disengaged output subsystem over the accepted input step [t, t+h], apart from it:
    solved exactly (linear output, physics/output_exact.py) or integrated on its own adaptive
    clock; the slip is watched on sub-intervals (sub-steps, or ≤ EXACT_PHASE_STEP rad of the
    output's fastest mode), each checked for a crossing and, by the Hermite cubic, for a dip.

    The output states of y_new are replaced. On a slip crossing (or a slip found beyond the band,
    'late'), the input step is re-taken exactly to that time and the state there is left in
    y_new. Returns (t reached, fire, last slip, armed).
    """
    Ko, zs, LIN, W = clock
    for i in range(N_OUTPUT):
        z[i] = y[OUTPUT_STATES[i]]
        zs[i] = z[i]
    t1 = t + h
    if exact:
        modal_coordinates(z, P, LIN, W)
        n_exact = max(1, int(math.ceil(P[P_OUTPUT_RATE] * h / EXACT_PHASE_STEP)))
        h_out = h / n_exact
        _, dw3_0, _, _, _ = disengaged_output_rates(z[Z_TWIST], z[Z_OMEGA3], z[Z_OMEGA4], P)
    else:
        n_exact = 0
        output_rhs(z, P, Ko[0])
        dw3_0 = Ko[0, Z_OMEGA3]
        h_out = h_io[1]
        if h_out <= 0.0:
            h_out = initial_step(OUTPUT, t, z, mode, P, ACT, Ko[0], rtol, atol, ztmp, dytmp,
                                 ERR_OUTPUT)
    tau = t
    j = 0
    fire = _NO_EVENT
    v0 = z[Z_OMEGA3] - g0  # rocker speed at t
    while tau < t1:
        if exact:
            hs = h_out
            last = j == n_exact - 1
            if last:
                hs = t1 - tau
            output_at(tau + hs - t, zs, P, LIN, W, z_new, False)
            _, dw3_1, _, _, _ = disengaged_output_rates(z_new[Z_TWIST], z_new[Z_OMEGA3],
                                                        z_new[Z_OMEGA4], P)
            factor = 1.0
        else:
            hs = min(h_out, t1 - tau)
            last = tau + hs >= t1
            err = dopri5_step(OUTPUT, tau, z, hs, mode, P, ACT, Ko, z_new, ztmp, auxtmp, rtol,
                              atol, ERR_OUTPUT)
            if not (err <= 1.0):
                h_out = hs * max(MIN_FACTOR, SAFETY * err ** DP_ERROR_EXPONENT) \
                    if err < math.inf else hs * MIN_FACTOR
                if h_out < 1e-14 * max(1.0, abs(tau)):
                    counters[C_STATUS] = STATUS_STEP_TOO_SMALL
                    return tau, fire, g0, armed
                continue
            factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR,
                                                       SAFETY * err ** DP_ERROR_EXPONENT)
            dw3_1 = Ko[6, Z_OMEGA3]
        counters[C_SUBSTEPS] += 1
        t_end_sub = tau + hs
        dense_state(DOPRI5, (t_end_sub - t) / h, h, y, y, K, ycomb)
        v1 = rocker_speed(t_end_sub, ycomb, P, ACT)
        g1 = z_new[Z_OMEGA3] - v1
        gtol = SLIP_TOLERANCE * (1.0 + abs(v1) + abs(z_new[Z_OMEGA3]))
        sigma = 1.0
        hi = 1.0
        ghi = g1
        if armed and g0 > 0.0:
            if g1 < 0.0:
                fire = _CROSSING
            else:
                # both ends positive: a dip inside the sub-interval (grazing)? The rocker is
                # slow on this scale, so its mean acceleration stands in for v'.
                dv = (v1 - v0) / hs
                tm, pm = _hermite_minimum(g0, hs * (dw3_0 - dv), g1, hs * (dw3_1 - dv))
                if pm < 0.0:
                    gm = _split_slip(exact, tm, t, h, y, K, tau, hs, z, clock, P, ACT, ycomb,
                                     ztmp)
                    if gm < 0.0:
                        fire = _CROSSING
                        hi = tm
                        ghi = gm
            if fire == _CROSSING:
                sigma = _locate(True, exact, DOPRI5, t, h, y, y_new, K, tau, hs, z, clock, mode,
                                P, ACT, 0.0, hi, g0, ghi,
                                max(1e-13, 8.0 * 2.2e-16 * abs(tau)) / hs, ycomb, dytmp, auxtmp,
                                ztmp)
        if fire == _NO_EVENT and g1 < -gtol:
            fire = _LATE
        if fire != _NO_EVENT:
            t_ev = tau + sigma * hs
            # true states at the event: the output exactly or by a re-taken sub-step, the input
            # by a re-taken step from t
            if exact:
                output_at(t_ev - t, zs, P, LIN, W, z_new, True)
            else:
                dopri5_step(OUTPUT, tau, z, t_ev - tau, mode, P, ACT, Ko, z_new, ztmp, auxtmp,
                            rtol, atol, ERR_OUTPUT)
            if _due(grid, counters, t_ev):
                _emit(True, exact, DOPRI5, t, h, y, y, K, tau, t_ev - tau, z, clock, mode, P, ACT,
                      grid, out, counters, t_ev, ycomb, ztmp, dytmp, auxtmp)
            if t_ev < t1:
                dopri5_step(INPUT, t, y, t_ev - t, mode, P, ACT, K, y_new, ytmp, auxtmp, rtol,
                            atol, ERR_INPUT)
            for i in range(N_OUTPUT):
                y_new[OUTPUT_STATES[i]] = z_new[i]
            if not exact:
                h_io[1] = h_out
            return t_ev, fire, g1, armed
        if _due(grid, counters, t1 if last else tau + hs):
            _emit(True, exact, DOPRI5, t, h, y, y, K, tau, hs, z, clock, mode, P, ACT, grid, out,
                  counters, t1 if last else tau + hs, ycomb, ztmp, dytmp, auxtmp)
        tau = t1 if last else tau + hs
        j += 1
        for i in range(N_OUTPUT):
            z[i] = z_new[i]
            Ko[0, i] = Ko[6, i]
        g0 = g1
        v0 = v1
        dw3_0 = dw3_1
        if not armed and abs(g1) > gtol:
            armed = True
        if not exact:
            h_out = max(h_out, hs * factor) if last else hs * factor
    if exact:
        output_at(h, zs, P, LIN, W, z, True)  # with the work terms
    else:
        h_io[1] = h_out
    for i in range(N_OUTPUT):
        y_new[OUTPUT_STATES[i]] = z[i]
    return t1, fire, g0, armed


@kernel
def _single_rate(method, t, h, err, clipped, t_end, y, y_new, K, mode, P, ACT, clock, armed, g0,
                 gd0, aux1, rtol, atol, grid, out, counters, ytmp, dytmp, auxtmp):
    """Witness function over an accepted step of the whole system: crossing (located on the
    dense output, then a true step to it), a dip inside the step (grazing, by the Hermite cubic
    of g and g'), or a guard found beyond its band ('late'). Emits the samples up to the time
    reached and leaves the state there in y_new. Returns (t reached, fire, g at that time)."""
    g1, gd1 = clutch_guard(mode, y_new, K[6], aux1, P)
    gtol = guard_tolerance(mode, y_new, aux1, P)
    fire = _NO_EVENT
    hi = 1.0
    ghi = g1
    if armed and g0 > 0.0:
        if g1 < 0.0:
            fire = _CROSSING
        elif not math.isnan(gd0) and not math.isnan(gd1):
            tm, pm = _hermite_minimum(g0, h * gd0, g1, h * gd1)
            if pm < 0.0:
                gm = _guard_at(method, tm, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp)
                if gm < 0.0:
                    fire = _CROSSING
                    hi = tm
                    ghi = gm
        elif min(g0, g1) < 0.5 * max(g0, g1):
            # the clutch torque has no derivative at hand: where it changes by a factor of two
            # or more across the step (a step that holds a dip to zero does), look at the step's
            # middle, and at the vertex of the parabola through the three values
            # (a dip must leave the tolerance band: a touch at zero, as a backstop holding a
            # load grazes it every oscillation, is not a release)
            gm = _guard_at(method, 0.5, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp, auxtmp)
            if gm < -gtol:
                fire = _CROSSING
                hi = 0.5
                ghi = gm
            else:
                curvature = 2.0 * (g0 - 2.0 * gm + g1)
                if curvature > 0.0:
                    tv = (3.0 * g0 - 4.0 * gm + g1) / (2.0 * curvature)
                    if 0.0 < tv < 1.0:
                        gv = _guard_at(method, tv, t, h, y, y_new, K, mode, P, ACT, ytmp, dytmp,
                                       auxtmp)
                        if gv < -gtol:
                            fire = _CROSSING
                            hi = tv
                            ghi = gv
    if fire == _NO_EVENT and g1 < -gtol:
        fire = _LATE  # the guard left its band on the wrong side: switch now
    if fire == _CROSSING:
        tol_theta = max(1e-13, 8.0 * 2.2e-16 * abs(t)) / h
        theta = _locate(False, False, method, t, h, y, y_new, K, 0.0, 1.0, y, clock, mode, P,
                        ACT, 0.0, hi, g0, ghi, tol_theta, ytmp, dytmp, auxtmp, ytmp)
        h_ev = theta * h
        # a true step to the event, not the interpolant: the state there is step-accurate
        _step(method, FULL, t, y, h_ev, mode, P, ACT, K, y_new, ytmp, aux1, rtol, atol, ERR_FULL)
        if _due(grid, counters, t + h_ev):
            _emit(False, False, method, t, h_ev, y, y_new, K, t, h_ev, y, clock, mode, P, ACT,
                  grid, out, counters, t + h_ev, ytmp, ytmp, dytmp, auxtmp)
        g1, _ = clutch_guard(mode, y_new, K[6], aux1, P)
        return t + h_ev, fire, g1
    t_new = t_end if (clipped and t + h >= t_end) else t + h
    if _due(grid, counters, t_new):
        _emit(False, False, method, t, h, y, y_new, K, t, h, y, clock, mode, P, ACT, grid, out,
              counters, t_new, ytmp, ytmp, dytmp, auxtmp)
    return t_new, fire, g1


@kernel
def advance(t, t_end, y, ms, P, ACT, LIN, S, h_io, grid, out, events, counters, ledger):
    """Integrate the hybrid system from t to t_end [s]; returns the time reached.

    y: state (in/out); ms: int64[2] (clutch mode, guard armed); LIN: modal form of the linear
    output subsystem (physics/output_exact.py); S: settings (S_*);
    h_io: float[2] step-size proposals (main, output sub-steps) carried between calls (≤ 0:
    choose); grid/out: sample times and rows (counters[C_NEXT_SAMPLE] is the next one to fill);
    events: rows (t, new mode, kind, value); ledger: float[1] kinetic energy lost in late
    (impact) engagements [J].
    Stops early with counters[C_STATUS] ≠ 0 when the event table is full or a step fails.
    """
    method = int(S[S_METHOD])
    rtol = S[S_RTOL]
    atol = S[S_ATOL]
    n = y.shape[0]
    K = np.empty((7, n))
    y_new = np.empty(n)
    ytmp = np.empty(n)
    dytmp = np.empty(n)
    aux0 = np.empty(N_AUX)
    aux1 = np.empty(N_AUX)
    auxtmp = np.empty(N_AUX)
    Ko = np.empty((7, N_OUTPUT))
    z = np.empty(N_OUTPUT)
    z_new = np.empty(N_OUTPUT)
    ztmp = np.empty(N_OUTPUT)
    ycomb = np.empty(n)
    # a disengaged elastic output with J3 > 0 runs apart from the input (see _split_output):
    # exactly when it is linear, else on its own clock
    can_split = method == DOPRI5 and P[P_RIGID] == 0.0 and P[P_J3] > 0.0
    exact = P[P_LINEAR_OUTPUT] > 0.0
    clock = (Ko, np.empty(N_OUTPUT), LIN, np.empty((2, 3), dtype=np.complex128))
    mode = ms[0]
    armed = ms[1] == 1
    counters[C_STATUS] = STATUS_OK

    rhs(t, y, mode, P, ACT, K[0], aux0)
    g0, gd0 = clutch_guard(mode, y, K[0], aux0, P)
    armed = armed or abs(g0) > guard_tolerance(mode, y, aux0, P)
    h_prop = h_io[0]
    if method == DOPRI5 and h_prop <= 0.0:
        h_prop = initial_step(FULL, t, y, mode, P, ACT, K[0], rtol, atol, ytmp, dytmp,
                              ERR_FULL)
    t_start = t
    h_fixed = S[S_H_FIXED]
    t_last_event = -math.inf
    stalled = 0

    while t < t_end:
        # ---- step size: error control or the fixed grid, clipped at t_end and actuator breaks
        clipped = False
        if method == DOPRI5:
            h = min(h_prop, S[S_MAX_STEP])
        else:
            k = math.floor((t - t_start) / h_fixed + 1e-9) + 1.0
            h = t_start + k * h_fixed - t
            # a remainder below the grid's rounding, or one that would not move t at all (t of
            # thousands of seconds: its ulp exceeds 1e-9·h), belongs to the next grid step
            if h < max(1e-9 * h_fixed, 8.0 * 2.2e-16 * abs(t)):
                h += h_fixed
        if t + h >= t_end:
            h = t_end - t
            clipped = True
        t_break = next_actuator_break(t, ACT)
        if t + h > t_break:
            h = t_break - t
            clipped = True
        if h <= 0.0:
            break

        split = can_split and mode == DISENGAGED
        err = _step(method, INPUT if split else FULL, t, y, h, mode, P, ACT, K, y_new, ytmp, aux1,
                    rtol, atol, ERR_INPUT if split else ERR_FULL)
        counters[C_STEPS] += 1
        counters[C_ENGAGED_STEPS] += mode
        if method == DOPRI5:
            if not (err <= 1.0) or not finite_state(y_new):
                counters[C_REJECTED] += 1
                factor = max(MIN_FACTOR, SAFETY * err ** DP_ERROR_EXPONENT) if (
                    err < math.inf and finite_state(y_new)) else MIN_FACTOR
                h_prop = h * factor
                if h_prop < 1e-14 * max(1.0, abs(t)):
                    counters[C_STATUS] = STATUS_STEP_TOO_SMALL
                    break
                continue
        elif not finite_state(y_new):
            counters[C_STATUS] = STATUS_NONFINITE
            break

        if split:
            t_new, fire, g1, armed = _split_output(
                exact, t, h, y, y_new, K, mode, P, ACT, clock, rtol, atol, armed, g0, h_io, grid,
                out, counters, z, z_new, ztmp, ycomb, ytmp, dytmp, auxtmp)
            if counters[C_STATUS] != STATUS_OK:
                break
            if fire == _NO_EVENT:
                factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR,
                                                           SAFETY * err ** DP_ERROR_EXPONENT)
                h_prop = max(h_prop, h * factor) if clipped else h * factor
                t = t_end if (clipped and t + h >= t_end) else t_new
                for i in range(n):
                    y[i] = y_new[i]
                    K[0, i] = K[6, i]  # FSAL: the input part is exact (output not used split)
                project(t, y, mode, P, ACT)
                g0 = g1
                gd0 = math.nan
                continue
            t = t_new
            for i in range(n):
                y[i] = y_new[i]
            rhs(t, y, mode, P, ACT, dytmp, aux1)
            g1 = aux1[AUX_SLIP]
        else:
            t_new, fire, g1 = _single_rate(
                method, t, h, err, clipped, t_end, y, y_new, K, mode, P, ACT, clock, armed, g0,
                gd0, aux1, rtol, atol, grid, out, counters, ytmp, dytmp, auxtmp)
            if method == DOPRI5 and fire != _CROSSING:
                factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR,
                                                           SAFETY * err ** DP_ERROR_EXPONENT)
                h_prop = max(h_prop, h * factor) if clipped else h * factor
            t = t_new
            for i in range(n):
                y[i] = y_new[i]
            if fire == _NO_EVENT:
                project(t, y, mode, P, ACT)
                for i in range(n):
                    K[0, i] = K[6, i]
                g0, gd0 = clutch_guard(mode, y, K[0], aux1, P)
                gtol = guard_tolerance(mode, y, aux1, P)
                if not armed and abs(g0) > gtol:
                    armed = True
                continue

        # ---- reset map of the clutch automaton
        kind = KIND_GRAZE
        value = aux1[AUX_SLIP]
        if mode == ENGAGED:
            value = g1  # the release guard where the switch was placed (≈ 0 unless late)
            if uses_twist_release(P) and free_slip_rate(t, y, P, ACT, dytmp, auxtmp) < 0.0:
                kind = KIND_GRAZE  # paper rule: twist is zero but the clutch cannot separate
            else:
                kind = KIND_RELEASE
                mode = DISENGAGED
        else:
            if fire == _LATE:
                ledger[0] += engage_with_impact(t, y, P, ACT)
                kind = KIND_ENGAGE_IMPACT
                mode = ENGAGED
            elif clutch_engages(t, y, P, ACT, dytmp, auxtmp, ytmp):
                kind = KIND_ENGAGE
                mode = ENGAGED
        project(t, y, mode, P, ACT)
        e = counters[C_EVENTS]
        events[e, E_T] = t
        events[e, E_MODE] = mode
        events[e, E_KIND] = kind
        events[e, E_VALUE] = value
        counters[C_EVENTS] = e + 1
        if kind != KIND_GRAZE:
            counters[C_SWITCHES] += 1
        rhs(t, y, mode, P, ACT, K[0], aux0)
        g0, gd0 = clutch_guard(mode, y, K[0], aux0, P)
        # half-open rule: disarmed only while the new guard is still inside its band; a graze
        # leaves the guard where it was, at its root, so it must leave the band first
        armed = kind != KIND_GRAZE and abs(g0) > guard_tolerance(mode, y, aux0, P)
        if t > t_last_event:
            t_last_event = t
            stalled = 0
        else:
            stalled += 1
            if stalled > MAX_EVENTS_AT_ONE_TIME:
                counters[C_STATUS] = STATUS_ZENO
                break
        if counters[C_EVENTS] >= events.shape[0]:
            counters[C_STATUS] = STATUS_EVENTS_FULL
            break
    ms[0] = mode
    ms[1] = 1 if armed else 0
    h_io[0] = h_prop
    return t
