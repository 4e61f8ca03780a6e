"""Equations of motion of the single-path pulse CVT in each clutch mode (physics.md §3–5).

Two formulations of the input subsystem (crank J1 + rocker J2, plus J3 (and J4) when engaged):

* ``reduced`` — φ2 = φ2(φ1, a(t)) in closed form, one equation for ω1:
      (J1 + Jrock·u²)·ω1' = M1 + u·Q − Jrock·u·κ,   κ = u'·ω1² + 2·u_a·a'·ω1 + g_aa·a'² + g_a·a''
  (paper eqs. 6/9 engaged and 10/11 disengaged with the multiplier eliminated; physics.md §3, §5),
  rocker speed v = u·ω1 + g_a·a', rocker acceleration v' = u·ω1' + κ.
* ``paper`` — the paper's index-reduced DAE in (φ1, φ2): J1·φ1'' = M1 + λ·f1, Jrock·φ2'' = Q + λ·f2,
  and the constraint differentiated twice, f1·φ1'' + f2·φ2'' = −(quadratic terms) − fa·a'' (eqs.
  8/9 engaged, 11 disengaged). It drifts off f = 0 unless stabilized; Baumgarte's terms
  −2α·f' − α²·f are added (α = P_BAUMGARTE).

Jrock and Q are the inertia the rocker carries and the torque on it: engaged, J2 + J3 and −Ts
(elastic shaft) or J2 + J3 + J4 and −M4 (rigid shaft); disengaged, J2 and 0.

Output subsystem (eq. 12): J3·ω3' = −Ts, J4·ω4' = Ts − M4 with Ts = c·θ + k·(ω3 − ω4). J3 = 0
(massless clutch node) and c = ∞ (rigid shaft) are reduced exactly instead of divided by.

Energy (physics.md §4): E = ½ΣJi·ωi² + ½c·θ² changes by ∫M1·ω1 − ∫M4·ω4 − ∫k·(ω3 − ω4)² + ∫P_act,
where P_act = g_a·a'·(Jrock·v' − Q) = −λ·fa·a' is the power of the crank-length actuator.
"""
import math

from .compiled import inline_kernel, kernel
from .drives import crank_actuator, load_torque, motor_torque
from .layout import (
    AUX_ACTUATOR_POWER,
    AUX_CLUTCH_TORQUE,
    AUX_CONSTRAINT,
    AUX_CRANK_LENGTH,
    AUX_ENERGY,
    AUX_FREE_SLIP_RATE,
    AUX_LOAD_TORQUE,
    AUX_MOTOR_TORQUE,
    AUX_ROCKER_ACCEL,
    AUX_ROCKER_SPEED,
    AUX_SHAFT_TORQUE,
    AUX_SLIP,
    AUX_SLIP_RATE,
    ENGAGED,
    FORMULATION_PAPER,
    MOTOR_CONSTANT_SPEED,
    OMEGA1,
    OMEGA2,
    OMEGA3,
    OMEGA4,
    P_B,
    P_BAUMGARTE,
    P_C,
    P_D,
    P_FORMULATION,
    P_H,
    P_J1,
    P_J2,
    P_J3,
    P_J4,
    P_KD,
    P_MOTOR_MODEL,
    P_RIGID,
    P_SIGMA,
    PHI1,
    PHI2,
    PHI4,
    TWIST,
    W_ACTUATOR,
    W_DAMPING,
    W_LOAD,
    W_MOTOR,
    Z_OMEGA3,
    Z_OMEGA4,
    Z_PHI4,
    Z_TWIST,
    Z_W_DAMPING,
    Z_W_LOAD,
)
from .linkage import constraint_partials, kinematics

TWO_PI = 2.0 * math.pi


@kernel
def rhs(t, y, mode, P, ACT, dy, aux):
    """Time derivative dy of state y in clutch ``mode``; fills ``aux`` (layout AUX_*).

    y, dy: float64[N_STATE]; aux: float64[N_AUX]; P: float64[N_PARAMS]; ACT: actuator profile.
    """
    a, ad, add = crank_actuator(t, ACT)
    b = P[P_B]
    d = P[P_D]
    h = P[P_H]
    J1 = P[P_J1]
    J2 = P[P_J2]
    J3 = P[P_J3]
    J4 = P[P_J4]
    c = P[P_C]
    kd = P[P_KD]
    rigid = P[P_RIGID] > 0.0
    engaged = mode == ENGAGED
    paper = P[P_FORMULATION] == FORMULATION_PAPER
    speed_source = P[P_MOTOR_MODEL] == MOTOR_CONSTANT_SPEED

    phi1 = y[PHI1]
    w1 = y[OMEGA1]
    theta = y[TWIST]
    w4 = y[OMEGA4]

    # --- rocker kinematics --------------------------------------------------------------------
    if paper:
        phi2 = y[PHI2]
        v = y[OMEGA2]
        f, f1, f2, fa, f11, f12, f22, f1a, f2a, faa = constraint_partials(phi1, phi2, a, b, h, d)
        u = 0.0
        ga = 0.0
        kappa = 0.0
    else:
        _, _, u, up, ga, ua, gaa = kinematics(phi1, a, b, d, h, P[P_SIGMA])
        v = u * w1 + ga * ad
        kappa = up * w1 * w1 + 2.0 * ua * ad * w1 + gaa * ad * ad + ga * add
        f = 0.0
    if rigid and engaged:
        w4 = v  # the output turns with the rocker; read it from the linkage, not the state
    M4 = load_torque(w4, P)

    # --- what the rocker carries: inertia Jrock and torque Q ----------------------------------
    if engaged:
        if rigid:
            jrock = J2 + J3 + J4
            q = -M4
            ts = 0.0
        else:
            jrock = J2 + J3
            ts = c * theta + kd * (v - w4)
            q = -ts
    else:
        jrock = J2
        q = 0.0
        ts = 0.0

    # --- input subsystem: ω1' and v' ----------------------------------------------------------
    if paper:
        # Solve J1·x1 − f1·λ = M1, Jrock·x2 − f2·λ = Q, f1·x1 + f2·x2 = rc (eqs. 9 and 11).
        fdot = f1 * w1 + f2 * v + fa * ad
        alpha = P[P_BAUMGARTE]
        rc = -(f11 * w1 * w1 + 2.0 * f12 * w1 * v + f22 * v * v + 2.0 * f1a * w1 * ad
               + 2.0 * f2a * v * ad + faa * ad * ad) - fa * add
        rc -= 2.0 * alpha * fdot + alpha * alpha * f  # Baumgarte stabilization
        if speed_source:
            dw1 = 0.0
            dv = rc / f2
            lam = (jrock * dv - q) / f2
            m1 = -f1 * lam
        else:
            m1 = motor_torque(w1, P)
            lam = (rc - f1 * m1 / J1 - f2 * q / jrock) / (f1 * f1 / J1 + f2 * f2 / jrock)
            dw1 = (m1 + f1 * lam) / J1
            dv = (q + f2 * lam) / jrock
        p_act = -lam * fa * ad
        dy[PHI2] = v
        dy[OMEGA2] = dv
    else:
        if speed_source:
            dw1 = 0.0
            m1 = -u * q + jrock * u * kappa
        else:
            m1 = motor_torque(w1, P)
            dw1 = (m1 + u * q - jrock * u * kappa) / (J1 + jrock * u * u)
        dv = u * dw1 + kappa
        p_act = ga * ad * (jrock * dv - q)
        dy[PHI2] = v
        dy[OMEGA2] = dv
    dy[PHI1] = w1
    dy[OMEGA1] = dw1

    # --- output subsystem (eq. 12) ------------------------------------------------------------
    if rigid:
        if engaged:
            w3 = v
            dw4 = dv
            tc = (J3 + J4) * dv + M4
        else:
            w3 = w4
            dw4 = -M4 / (J3 + J4)
            tc = 0.0
        ts = M4 + J4 * dw4
        dy[TWIST] = 0.0
        dy[OMEGA3] = dw4
        dy[OMEGA4] = dw4
        p_damp = 0.0
    else:
        if engaged:
            w3 = v
            dy[OMEGA3] = dv
            tc = J3 * dv + ts
        elif J3 > 0.0:
            w3 = y[OMEGA3]
            _, dy[OMEGA3], _, _, ts = disengaged_output_rates(theta, w3, w4, P)
            tc = 0.0
        else:
            # Massless node: Ts = 0, so c·θ + k·(ω3 − ω4) = 0 (θ ≡ 0 without damping).
            w3 = w4 - c * theta / kd if kd > 0.0 else w4
            ts = 0.0
            tc = 0.0
        dw4 = (ts - M4) / J4
        if not engaged and J3 == 0.0:
            dy[OMEGA3] = dw4
        dy[TWIST] = w3 - w4
        dy[OMEGA4] = dw4
        p_damp = kd * (w3 - w4) * (w3 - w4)
    dy[PHI4] = w4

    # --- work quadratures (energy balance, physics.md §4) -------------------------------------
    dy[W_MOTOR] = m1 * w1
    dy[W_LOAD] = M4 * w4
    dy[W_DAMPING] = p_damp
    dy[W_ACTUATOR] = p_act

    aux[AUX_ROCKER_SPEED] = v
    aux[AUX_ROCKER_ACCEL] = dv
    aux[AUX_CLUTCH_TORQUE] = tc
    aux[AUX_MOTOR_TORQUE] = m1
    aux[AUX_LOAD_TORQUE] = M4
    aux[AUX_SHAFT_TORQUE] = ts
    aux[AUX_SLIP] = w3 - v
    aux[AUX_SLIP_RATE] = dy[OMEGA3] - dv
    aux[AUX_CONSTRAINT] = f
    aux[AUX_CRANK_LENGTH] = a
    aux[AUX_ACTUATOR_POWER] = p_act
    aux[AUX_FREE_SLIP_RATE] = aux[AUX_SLIP_RATE]
    energy = 0.5 * (J1 * w1 * w1 + J2 * v * v + J3 * w3 * w3 + J4 * w4 * w4)
    if not rigid:
        energy += 0.5 * c * theta * theta
    aux[AUX_ENERGY] = energy


@kernel
def project(t, y, mode, P, ACT):
    """Put the algebraic states exactly on their constraints (reset map part of every step).

    Reduced formulation: φ2, ω2 from the closed-form linkage. Both: ω3 = rocker speed while
    engaged; θ = 0, ω3 = ω4 for a rigid shaft; ω3 from Ts = 0 for a massless disengaged node.
    """
    a, ad, _ = crank_actuator(t, ACT)
    if P[P_FORMULATION] != FORMULATION_PAPER:
        c2, s2, u, _, ga, _, _ = kinematics(y[PHI1], a, P[P_B], P[P_D], P[P_H], P[P_SIGMA])
        # φ2 from its cosine and sine, on the branch of the integrated φ2 (no inverse cosine)
        phi2 = math.atan2(s2, c2)
        y[PHI2] = phi2 + TWO_PI * math.floor((y[PHI2] - phi2) / TWO_PI + 0.5)
        y[OMEGA2] = u * y[OMEGA1] + ga * ad
    rigid = P[P_RIGID] > 0.0
    if mode == ENGAGED:
        y[OMEGA3] = y[OMEGA2]
        if rigid:
            y[OMEGA4] = y[OMEGA2]
    elif rigid:
        y[OMEGA3] = y[OMEGA4]
    elif P[P_J3] == 0.0:
        kd = P[P_KD]
        y[OMEGA3] = y[OMEGA4] - P[P_C] * y[TWIST] / kd if kd > 0.0 else y[OMEGA4]
    if rigid:
        y[TWIST] = 0.0


@kernel
def engage_with_impact(t, y, P, ACT):
    """Plastic engagement when the rocker is faster than the driven part (s < 0).

    Happens only at t = 0 or after a parameter change, never inside a run (engagement at s = 0 is
    impact-free). The clutch impulse Λ acts between rocker and driven part; the generalized
    momenta (J1 + J2·u²)·ω1 and Jout·ω3 change by −u·Λ and +Λ, and afterwards ω3 = v:
        Λ = (v − ω3) / (u²/(J1 + J2·u²) + 1/Jout).
    Returns the kinetic energy lost [J].
    """
    a, ad, _ = crank_actuator(t, ACT)
    rigid = P[P_RIGID] > 0.0
    j_out = P[P_J3] + (P[P_J4] if rigid else 0.0)
    if P[P_FORMULATION] == FORMULATION_PAPER:
        # u = dφ2/dφ1 at fixed a from the constraint gradient; g_a·a' from f_a.
        _, f1, f2, fa, _, _, _, _, _, _ = constraint_partials(
            y[PHI1], y[PHI2], a, P[P_B], P[P_H], P[P_D])
        u = -f1 / f2
        ga = -fa / f2
    else:
        _, _, u, _, ga, _, _ = kinematics(y[PHI1], a, P[P_B], P[P_D], P[P_H], P[P_SIGMA])
    w1 = y[OMEGA1]
    v = u * w1 + ga * ad
    w3 = y[OMEGA4] if rigid else y[OMEGA3]
    e_before = _kinetic(y[OMEGA1], v, w3, y[OMEGA4], P, rigid)
    j_in = P[P_J1] + P[P_J2] * u * u
    if P[P_MOTOR_MODEL] == MOTOR_CONSTANT_SPEED:
        impulse = (v - w3) * j_out
        dw1 = 0.0
    elif j_out == 0.0:
        impulse = 0.0
        dw1 = 0.0
    else:
        impulse = (v - w3) / (u * u / j_in + 1.0 / j_out)
        dw1 = -u * impulse / j_in
    y[OMEGA1] = w1 + dw1
    v_after = u * y[OMEGA1] + ga * ad
    y[OMEGA2] = v_after
    y[OMEGA3] = v_after
    if rigid:
        y[OMEGA4] = v_after
    e_after = _kinetic(y[OMEGA1], v_after, v_after, y[OMEGA4], P, rigid)
    return e_before - e_after


@kernel
def _kinetic(w1, v, w3, w4, P, rigid):
    if rigid:
        w3 = w4
    return 0.5 * (P[P_J1] * w1 * w1 + P[P_J2] * v * v + P[P_J3] * w3 * w3 + P[P_J4] * w4 * w4)


def energy_residual(energy, energy0, w_motor, w_load, w_damping, w_actuator, losses):
    """Energy balance residual [J]: (E − E0) − (W_motor − W_load − W_damping + W_act − losses)."""
    return (energy - energy0) - (w_motor - w_load - w_damping + w_actuator - losses)


@kernel
def finite_state(y):
    for i in range(y.shape[0]):
        if not math.isfinite(y[i]):
            return False
    return True


@inline_kernel
def disengaged_output_rates(theta, w3, w4, P):
    """The output subsystem while disengaged, J3 > 0, elastic shaft (eq. 12):
    J3·ω3' = −Ts, J4·ω4' = Ts − M4, Ts = c·θ + k·(ω3 − ω4). Returns (θ', ω3', ω4', M4, Ts).

    It does not depend on the input subsystem, which lets the solver integrate it on its own,
    faster clock (solver/slip_watch.py) at the cost of a few flops per step.
    """
    m4 = load_torque(w4, P)
    ts = P[P_C] * theta + P[P_KD] * (w3 - w4)
    return w3 - w4, -ts / P[P_J3], (ts - m4) / P[P_J4], m4, ts


@inline_kernel
def output_rhs(z, P, dz):
    """d/dt of the disengaged output states z = y[OUTPUT_STATES] (layout Z_*)."""
    dtheta, dw3, dw4, m4, _ = disengaged_output_rates(z[Z_TWIST], z[Z_OMEGA3], z[Z_OMEGA4], P)
    dz[Z_TWIST] = dtheta
    dz[Z_OMEGA3] = dw3
    dz[Z_PHI4] = z[Z_OMEGA4]
    dz[Z_OMEGA4] = dw4
    dz[Z_W_LOAD] = m4 * z[Z_OMEGA4]
    dz[Z_W_DAMPING] = P[P_KD] * dtheta * dtheta


@inline_kernel
def rocker_speed(t, y, P, ACT):
    """v [rad/s]: the closed-form u·ω1 + g_a·a' (reduced) or the state ω2 (paper)."""
    if P[P_FORMULATION] == FORMULATION_PAPER:
        return y[OMEGA2]
    a, ad, _ = crank_actuator(t, ACT)
    _, _, u, _, ga, _, _ = kinematics(y[PHI1], a, P[P_B], P[P_D], P[P_H], P[P_SIGMA])
    return u * y[OMEGA1] + ga * ad
