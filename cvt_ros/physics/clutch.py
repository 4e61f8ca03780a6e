"""The one-way clutch as a hybrid automaton (physics.md §4): witness functions and their resets.

    ENGAGED ──(release guard falls through 0)──▶ DISENGAGED      reset: none (ω3 = v is continuous)
    DISENGAGED ──(slip s = ω3 − v falls through 0)──▶ ENGAGED    reset: ω3 := v (s = 0, no impact)

Release guard: the clutch torque Tc = J3·v' + Ts (``torque``, default: the clutch cannot pull) or
the paper's torsion twist θ = φ3 − φ4 (``twist``; the two coincide as J3 → 0 on an undamped
shaft). The twist rule releases when θ has fallen to zero *and* the clutch can open, Tc ≤ 0
(complementarity, below): guard max(θ, Tc/c), continuous, in radians. Where the two disagree,
complementarity decides: with θ ≤ 0 a clutch that still pushes (Tc > 0) stays closed until Tc
falls through zero, and once θ ≤ 0 no negative clutch torque is held. (While θ > 0 the paper's
rule holds the clutch whatever Tc: J3's inertia or the damper may pull on it, which is the rule.)
The test used to be the open clutch's slip acceleration s'_free ≥ 0, which is the same for
J3 > 0 but not for a massless damped node, whose open slip jumps at once to −Tc/k: there it held
the clutch with negative twist and Tc down to −301 N·m (issue 32).

Complementarity decides the mode at s = 0 (t = 0, after parameter changes, at a located switch):
engage iff the disengaged dynamics would drive the slip negative, s'_free < 0. For one unilateral
contact this is the same as Tc_engaged = −s'_free / W > 0 (W > 0 the inverse effective inertia at
the contact), so engaging never produces a negative clutch torque and releasing never a negative
slip. A grazing touch (s'_free ≥ 0 at s = 0) does not engage.

Half-open rule: a guard that a segment starts on (|g| ≤ tolerance) is disarmed until it leaves
that band, so the solver cannot loop on the switch point.
"""
from .compiled import inline_kernel, kernel
from .dynamics import rhs
from .layout import (
    AUX_CLUTCH_TORQUE,
    AUX_ROCKER_ACCEL,
    AUX_ROCKER_SPEED,
    AUX_SLIP,
    AUX_SLIP_RATE,
    DISENGAGED,
    ENGAGED,
    OMEGA3,
    OMEGA4,
    P_C,
    P_RELEASE,
    P_RIGID,
    P_TORQUE_SCALE,
    RELEASE_TWIST,
    TWIST,
)

SLIP_TOLERANCE = 1e-10     # relative to the member speeds
TORQUE_TOLERANCE = 1e-10   # relative to the scene's torque scale
TWIST_TOLERANCE = 1e-13    # [rad]
SLIP_RATE_TOLERANCE = 1e-10  # relative to the member accelerations
CONTACT_PROBE_TIME = 1e-6  # [s] one look-ahead step at a higher-order contact
PROBE_STEPS = 3

KIND_RELEASE = 0
KIND_ENGAGE = 1
KIND_ENGAGE_IMPACT = 2
KIND_GRAZE = 3  # slip touched zero without the clutch taking torque: no switch


@inline_kernel
def uses_twist_release(P):
    return P[P_RELEASE] == RELEASE_TWIST and P[P_RIGID] == 0.0


@inline_kernel
def clutch_guard(mode, y, dy, aux, P):
    """Witness value g (switch when g falls through 0) and its time derivative (nan if unknown).

    ENGAGED: Tc [N·m] (or max(θ, Tc/c) [rad] with twist release). DISENGAGED: slip s = ω3 − v
    [rad/s].
    """
    if mode == ENGAGED:
        if uses_twist_release(P):
            return max(y[TWIST], aux[AUX_CLUTCH_TORQUE] / P[P_C]), float('nan')
        return aux[AUX_CLUTCH_TORQUE], float('nan')
    return aux[AUX_SLIP], aux[AUX_SLIP_RATE]


@inline_kernel
def guard_scale(mode, y, aux, P):
    """The size of the guard in this machine: the scene's torque scale [N·m] (ENGAGED, torque
    release; over c [rad] with twist release) or the member speeds [rad/s] (DISENGAGED)."""
    if mode == ENGAGED:
        if uses_twist_release(P):
            return P[P_TORQUE_SCALE] / P[P_C]
        return P[P_TORQUE_SCALE]
    w3 = y[OMEGA3] if P[P_RIGID] == 0.0 else y[OMEGA4]
    return 1.0 + abs(aux[AUX_ROCKER_SPEED]) + abs(w3)


@inline_kernel
def guard_tolerance(mode, y, aux, P):
    """Half-width of the band around g = 0 inside which the guard counts as 'at zero'."""
    if mode == ENGAGED:
        if uses_twist_release(P):
            return TWIST_TOLERANCE
        return TORQUE_TOLERANCE * guard_scale(mode, y, aux, P)
    return SLIP_TOLERANCE * guard_scale(mode, y, aux, P)


@kernel
def free_slip_rate(t, y, P, ACT, dy, aux):
    """s'_free: the slip rate the DISENGAGED dynamics would give at this state [rad/s²]."""
    rhs(t, y, DISENGAGED, P, ACT, dy, aux)
    return aux[AUX_SLIP_RATE]


@kernel
def clutch_engages(t, y, P, ACT, dy, aux, ytmp):
    """Complementarity at s = 0: does the free (disengaged) motion drive the slip negative?

    Decided by the free slip rate; when it vanishes (a higher-order contact: with a = 0 the
    untwisted shaft at t = 0, or the backstop's torque touching zero at the top of every
    oscillation) by its change along a short free motion of PROBE_STEPS Euler steps, so that
    contacts up to third order show.
    """
    rate = free_slip_rate(t, y, P, ACT, dy, aux)
    tol = SLIP_RATE_TOLERANCE * (1.0 + abs(aux[AUX_ROCKER_ACCEL]) + abs(dy[OMEGA3]))
    if rate < -tol:
        return True
    if rate > tol:
        return False
    for i in range(y.shape[0]):
        ytmp[i] = y[i]
    tp = t
    for _ in range(PROBE_STEPS):
        free_slip_rate(tp, ytmp, P, ACT, dy, aux)
        for i in range(y.shape[0]):
            ytmp[i] += CONTACT_PROBE_TIME * dy[i]
        tp += CONTACT_PROBE_TIME
    return free_slip_rate(tp, ytmp, P, ACT, dy, aux) - rate < 0.0
