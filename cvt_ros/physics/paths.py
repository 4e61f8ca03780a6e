"""The N-path machine (issue 33; docs/physics.md §9): N identical crank-rocker paths on one crank,
phase-shifted by δ_k, each rocker with its own one-way clutch on the common driven member J3.

Every rocker is tied to the crank by its own closed-form linkage (physics/linkage.py, at the
crank angle φ1 + δ_k): v_k = u_k·ω1 + g_a,k·a', v_k' = u_k·ω1' + κ_k. The clutches act between
the rockers and the node (J3, or J3 + J4 behind a rigid shaft) with torques λ_k ≥ 0 on the node
and −λ_k on their rockers. For the set E of engaged clutches (a bitmask: bit k−1 = path k, so
ENGAGED == 1 is path 1):

    J1e·ω1' + Σ_E u_k·λ_k = F1,   J1e = J1 + J2·Σ_all u_k²,   F1 = M1 − J2·Σ_all u_k·κ_k
    Jn·ωn' − Σ_E λ_k      = Fn,   (Jn, Fn) = (J3, −Ts) elastic shaft, (J3 + J4, −M4) rigid
    ωn' − u_k·ω1'         = κ_k   for k ∈ E (the engaged rocker and the node move together)

(an ideal speed source prescribes ω1' = 0 instead of its row: M1 is then the reaction). The node
and the crank are two degrees of freedom, so at most two clutches carry torque at once; two do
only while the crank stands still (v_j = v_k with u_j ≠ u_k needs ω1 = 0 at a constant crank
length): the locked crank of a stalled drive, its torque split between a rocker turning forwards
and one turning backwards (physics.md §9). The solutions for |E| ≤ 2 are written out
(``contact_solve``); a massless node (J3 = 0) needs no special case there.

The one-path machine (physics/dynamics.py) is not this code at N = 1: N = 1 runs the one-path
kernels unchanged, and this core at N = 1 is the independent check of both (test_paths.py).

State: the one-path layout (physics/layout.py; PHI2/OMEGA2 path 1's rocker), then each path's
rocker speed v_k, integrated alongside so that the dense output of a step gives every slip as a
polynomial (solver/paths_watch.py), and put back on the closed form after each step.
"""
import math
import random

from . import layout as L
from .clutch import (
    SLIP_RATE_TOLERANCE,
    SLIP_TOLERANCE,
    TORQUE_TOLERANCE,
)
from .compiled import inline_kernel, kernel
from .drives import crank_actuator, load_torque, motor_torque
from .linkage import kinematics_at, rocker_angle

TWO_PI = 2.0 * math.pi
MAX_PATHS = 8

# --- parameter vector: the one-path P, then N and the phase offsets -------------------------
P_PATHS = L.N_PARAMS            # N
P_OFFSET = L.N_PARAMS + 1       # + k: path k+1's phase offset δ [rad] (its crank angle φ1 + δ)
P_COS_OFFSET = P_OFFSET + MAX_PATHS      # + k: cos δ of path k+1
P_SIN_OFFSET = P_COS_OFFSET + MAX_PATHS  # + k: sin δ of path k+1
P_STAMP = P_SIN_OFFSET + MAX_PATHS       # this P's stamp (``paths_linkage``'s cache key)
N_PATH_PARAMS = P_STAMP + 1
_STAMPS = random.SystemRandom()   # (not the seeded global generator: a stamp never recurs)


def path_parameters(P, offsets):
    """The path count and phase offsets [rad] into P, with each offset's cosine and sine (the
    linkages take the sine and cosine of φ1 once and rotate them: ``path_cos_sin``), and a
    fresh random stamp: a linkage solved under another P is never taken from an aux's cache
    (``paths_linkage``)."""
    P[P_STAMP] = float(1 + _STAMPS.getrandbits(52))
    P[P_PATHS] = len(offsets)
    for k, delta in enumerate(offsets):
        P[P_OFFSET + k] = delta
        P[P_COS_OFFSET + k] = math.cos(delta)
        P[P_SIN_OFFSET + k] = math.sin(delta)

# --- state: the one-path slots, then the rocker speeds ---------------------------------------
V_PATH = L.N_STATE              # + k: v of path k+1 [rad/s]


def n_path_state(n_paths):
    return L.N_STATE + n_paths


# --- auxiliaries: the one-path slots (rocker speed and slip: path 1's; clutch torque: the
# total the clutches pass to the node), then per path (+ k) -----------------------------------
A_U = L.N_AUX                       # u_k = ∂φ2,k/∂φ1
A_GA = A_U + MAX_PATHS            # g_a,k = ∂φ2,k/∂a [rad/m]
A_KAPPA = A_GA + MAX_PATHS        # κ_k: v_k' − u_k·ω1' [rad/s²]
A_SPEED = A_KAPPA + MAX_PATHS     # v_k [rad/s]
A_ACCEL = A_SPEED + MAX_PATHS     # v_k' [rad/s²]
A_TORQUE = A_ACCEL + MAX_PATHS    # λ_k [N·m] (0 when open; an impulse [N·m·s] in ``impact``)
A_SLIP = A_TORQUE + MAX_PATHS     # s_k = ωn − v_k [rad/s]
A_SLIP_RATE = A_SLIP + MAX_PATHS  # s_k' [rad/s²]
A_JUMP = A_SLIP_RATE + MAX_PATHS  # −s_k: the speed jump an impact asks of contact k [rad/s]
A_UP = A_JUMP + MAX_PATHS         # u'_k = ∂u_k/∂φ1 [1/rad]; with u_k, g_a,k and the next two:
A_UA = A_UP + MAX_PATHS           # u_a,k [1/m]          the linkage solved at (φ1, a) of
A_GAA = A_UA + MAX_PATHS          # g_aa,k [rad/m²]      A_LINK (paths_linkage's cache)
A_ROCKER = A_GAA + MAX_PATHS      # cos φ2, sin φ2 of path 1 (its rocker angle) there
A_LINK = A_ROCKER + 2             # φ1, a and P's stamp of that solve
N_PATH_AUX = A_LINK + 3

NO_SET = -1   # ``impact``/``choose_engaged``: no valid set found


@inline_kernel
def bit(k):
    return 1 << k


@inline_kernel
def set_size(mode):
    n = 0
    m = mode
    while m:
        n += m & 1
        m >>= 1
    return n


@inline_kernel
def first_path(mode):
    """The lowest path index in the set ``mode`` (−1 when empty)."""
    k = 0
    m = mode
    while m:
        if m & 1:
            return k
        m >>= 1
        k += 1
    return -1


@inline_kernel
def n_paths(P):
    return int(P[P_PATHS])


@inline_kernel
def path_cos_sin(k, c1, s1, P):
    """(cos, sin) of path k's crank angle φ1 + δ_k from those of φ1: a rotation by δ_k (one
    sine and cosine a linkage solve for all N paths; exact for δ = 0, path 1's default)."""
    cd = P[P_COS_OFFSET + k]
    sd = P[P_SIN_OFFSET + k]
    return c1 * cd - s1 * sd, s1 * cd + c1 * sd


@kernel
def paths_linkage(phi1, w1, a, ad, add, P, aux):
    """Each path's u_k, g_a,k, κ_k, v_k into ``aux`` (closed form at φ1 + δ_k, physics.md §2, §5);
    returns (Σu_k², Σu_k·κ_k): the rockers reflected on the crank. The solve at (φ1, a) is
    kept in ``aux`` (A_U, A_GA, A_UP, A_UA, A_GAA, A_ROCKER) and taken from there at the same
    φ1, a and P: a reset (physics/path_contacts.py), a sample and the projection after a step
    (``take_linkage``) evaluate one state several times."""
    n = n_paths(P)
    if not (aux[A_LINK] == phi1 and aux[A_LINK + 1] == a and aux[A_LINK + 2] == P[P_STAMP]):
        b = P[L.P_B]
        d = P[L.P_D]
        h = P[L.P_H]
        sigma = P[L.P_SIGMA]
        c1 = math.cos(phi1)
        s1 = math.sin(phi1)
        for k in range(n):
            ck, sk = path_cos_sin(k, c1, s1, P)
            c2, s2, u, up, ga, ua, gaa = kinematics_at(ck, sk, a, b, d, h, sigma)
            if k == 0:
                aux[A_ROCKER] = c2
                aux[A_ROCKER + 1] = s2
            aux[A_U + k] = u
            aux[A_UP + k] = up
            aux[A_GA + k] = ga
            aux[A_UA + k] = ua
            aux[A_GAA + k] = gaa
        aux[A_LINK] = phi1
        aux[A_LINK + 1] = a
        aux[A_LINK + 2] = P[P_STAMP]
    su2 = 0.0
    suk = 0.0
    for k in range(n):
        u = aux[A_U + k]
        ga = aux[A_GA + k]
        kappa = (aux[A_UP + k] * w1 * w1 + 2.0 * aux[A_UA + k] * ad * w1
                 + aux[A_GAA + k] * ad * ad + ga * add)
        aux[A_KAPPA + k] = kappa
        aux[A_SPEED + k] = u * w1 + ga * ad
        su2 += u * u
        suk += u * kappa
    return su2, suk


@inline_kernel
def take_linkage(source, aux, P):
    """``paths_linkage``'s cached solve from the auxiliaries ``source`` into ``aux``: a state
    the last right-hand side was evaluated at (a step's end) is projected without a solve."""
    for k in range(n_paths(P)):
        aux[A_U + k] = source[A_U + k]
        aux[A_GA + k] = source[A_GA + k]
        aux[A_UP + k] = source[A_UP + k]
        aux[A_UA + k] = source[A_UA + k]
        aux[A_GAA + k] = source[A_GAA + k]
    for i in range(A_ROCKER, A_LINK + 3):
        aux[i] = source[i]


@inline_kernel
def path_speed(k, t, y, P, ACT):
    """Path k's rocker speed v_k = u_k·ω1 + g_a,k·a' [rad/s] at (t, y), from the closed form."""
    a, ad, _ = crank_actuator(t, ACT)
    ck, sk = path_cos_sin(k, math.cos(y[L.PHI1]), math.sin(y[L.PHI1]), P)
    _, _, u, _, ga, _, _ = kinematics_at(ck, sk, a, P[L.P_B], P[L.P_D], P[L.P_H], P[L.P_SIGMA])
    return u * y[L.OMEGA1] + ga * ad


@kernel
def contact_solve(mode, n, F1, J1e, Fn, Jn, speed_source, aux, rhs):
    """The engaged-set equations (module text) for the set ``mode`` (at most two paths):
    (ω1', ωn', solvable). Contact k's right-hand side is aux[rhs + k]: κ_k for the
    accelerations; −s_k for the speed jumps of an impact (then F1 = Fn = 0 and the λ_k are
    impulses). λ_k into aux[A_TORQUE + k], 0 outside the set. Not solvable: two contacts whose
    rows coincide (u_j = u_k: two rockers at the same speed ratio, as at a handoff), two behind
    an ideal speed source (one degree of freedom left), three or more."""
    for k in range(n):
        aux[A_TORQUE + k] = 0.0
    size = set_size(mode)
    if size == 0:
        return 0.0 if speed_source else F1 / J1e, Fn / Jn, True
    j = first_path(mode)
    uj = aux[A_U + j]
    rj = aux[rhs + j]
    if size == 1:
        x1 = 0.0 if speed_source else (F1 + uj * Fn - uj * Jn * rj) / (J1e + Jn * uj * uj)
        x2 = uj * x1 + rj
        aux[A_TORQUE + j] = Jn * x2 - Fn
        return x1, x2, True
    if size > 2 or speed_source:
        return math.nan, math.nan, False
    k = first_path(mode & ~bit(j))
    uk = aux[A_U + k]
    du = uj - uk
    if not abs(du) > 1e-12 * (abs(uj) + abs(uk)):
        return math.nan, math.nan, False
    # both rockers at the node's speed: the crank's acceleration is the one that keeps them so
    x1 = (aux[rhs + k] - rj) / du
    x2 = uj * x1 + rj
    total = Jn * x2 - Fn          # λj + λk: what the node needs
    moment = F1 - J1e * x1        # uj·λj + uk·λk: what the crank does not take itself
    aux[A_TORQUE + j] = (moment - uk * total) / du
    aux[A_TORQUE + k] = (uj * total - moment) / du
    return x1, x2, True


@kernel
def paths_rhs(t, y, mode, P, ACT, dy, aux):
    """Time derivative dy of the N-path state y with the engaged set ``mode``; fills ``aux``
    (one-path AUX_* slots, then the per-path A_* slots). Returns False (and non-finite rates)
    when the set's equations have no solution (contact_solve)."""
    a, ad, add = crank_actuator(t, ACT)
    J1 = P[L.P_J1]
    J2 = P[L.P_J2]
    J3 = P[L.P_J3]
    J4 = P[L.P_J4]
    c = P[L.P_C]
    kd = P[L.P_KD]
    rigid = P[L.P_RIGID] > 0.0
    speed_source = P[L.P_MOTOR_MODEL] == L.MOTOR_CONSTANT_SPEED
    n = n_paths(P)
    w1 = y[L.OMEGA1]
    theta = y[L.TWIST]
    w4 = y[L.OMEGA4]
    su2, suk = paths_linkage(y[L.PHI1], w1, a, ad, add, P, aux)
    J1e = J1 + J2 * su2
    m1 = 0.0 if speed_source else motor_torque(w1, P)
    F1 = m1 - J2 * suk
    M4 = load_torque(w4, P)
    if rigid:   # the node is J3 and J4 lumped; the load acts on it
        Jn = J3 + J4
        w3 = w4
        ts = 0.0
        Fn = -M4
    else:
        Jn = J3
        w3 = y[L.OMEGA3]
        if mode == 0 and J3 == 0.0:
            # open massless node: no torque on it, c·θ + k·(ω3 − ω4) = 0 (θ ≡ 0 undamped)
            w3 = w4 - c * theta / kd if kd > 0.0 else w4
        ts = c * theta + kd * (w3 - w4)
        Fn = -ts
    ok = True
    if not rigid and mode == 0 and J3 == 0.0:
        for k in range(n):
            aux[A_TORQUE + k] = 0.0
        x1 = 0.0 if speed_source else F1 / J1e
        dw4 = (ts - M4) / J4
        x2 = dw4 - c / kd * (w3 - w4) if kd > 0.0 else dw4   # d/dt of the algebraic ω3
    else:
        x1, x2, ok = contact_solve(mode, n, F1, J1e, Fn, Jn, speed_source, aux, A_KAPPA)
    moment = 0.0
    total = 0.0
    p_act = 0.0
    for k in range(n):
        lam = aux[A_TORQUE + k]
        acc = aux[A_U + k] * x1 + aux[A_KAPPA + k]
        aux[A_ACCEL + k] = acc
        aux[A_SLIP + k] = w3 - aux[A_SPEED + k]
        aux[A_SLIP_RATE + k] = x2 - acc
        dy[V_PATH + k] = acc
        moment += aux[A_U + k] * lam
        total += lam
        # the actuator's power through rocker k: g_a,k·a'·(what the linkage applies to it)
        p_act += aux[A_GA + k] * (J2 * acc + lam)
    p_act *= ad
    if speed_source:
        m1 = J2 * suk + moment     # the source holds ω1' = 0: its torque is the reaction
    if rigid:
        dw4 = x2
        ts = M4 + J4 * dw4
        dy[L.TWIST] = 0.0
        p_damp = 0.0
    else:
        dw4 = (ts - M4) / J4
        dy[L.TWIST] = w3 - w4
        p_damp = kd * (w3 - w4) * (w3 - w4)
    dy[L.PHI1] = w1
    dy[L.OMEGA1] = x1
    dy[L.PHI2] = aux[A_SPEED]
    dy[L.OMEGA2] = aux[A_ACCEL]
    dy[L.OMEGA3] = x2
    dy[L.PHI4] = w4
    dy[L.OMEGA4] = dw4
    dy[L.W_MOTOR] = m1 * w1
    dy[L.W_LOAD] = M4 * w4
    dy[L.W_DAMPING] = p_damp
    dy[L.W_ACTUATOR] = p_act

    energy = 0.5 * (J1 * w1 * w1 + J3 * w3 * w3 + J4 * w4 * w4)
    for k in range(n):
        energy += 0.5 * J2 * aux[A_SPEED + k] ** 2
    if not rigid:
        energy += 0.5 * c * theta * theta
    aux[L.AUX_ROCKER_SPEED] = aux[A_SPEED]
    aux[L.AUX_ROCKER_ACCEL] = aux[A_ACCEL]
    aux[L.AUX_CLUTCH_TORQUE] = total
    aux[L.AUX_MOTOR_TORQUE] = m1
    aux[L.AUX_LOAD_TORQUE] = M4
    aux[L.AUX_SHAFT_TORQUE] = ts
    aux[L.AUX_SLIP] = aux[A_SLIP]
    aux[L.AUX_SLIP_RATE] = aux[A_SLIP_RATE]
    aux[L.AUX_CONSTRAINT] = 0.0
    aux[L.AUX_CRANK_LENGTH] = a
    aux[L.AUX_ACTUATOR_POWER] = p_act
    aux[L.AUX_ENERGY] = energy
    aux[L.AUX_FREE_SLIP_RATE] = aux[A_SLIP_RATE]
    return ok


@kernel
def paths_project(t, y, mode, P, ACT, aux):
    """Put the algebraic states on their constraints (after every step and every reset): the
    rocker speeds and path 1's angle from the closed form; with two clutches engaged the crank
    speed their velocity constraints leave (0 at a constant crank length); the node at the
    engaged rockers' speed; a rigid shaft's or an open massless node's as physics/dynamics.py."""
    a, ad, _ = crank_actuator(t, ACT)
    rigid = P[L.P_RIGID] > 0.0
    if set_size(mode) == 2 and P[L.P_MOTOR_MODEL] != L.MOTOR_CONSTANT_SPEED:
        paths_linkage(y[L.PHI1], 0.0, a, ad, 0.0, P, aux)
        j = first_path(mode)
        k = first_path(mode & ~bit(j))
        du = aux[A_U + j] - aux[A_U + k]
        if du != 0.0:
            y[L.OMEGA1] = (aux[A_GA + k] - aux[A_GA + j]) * ad / du
    paths_linkage(y[L.PHI1], y[L.OMEGA1], a, ad, 0.0, P, aux)
    for k in range(n_paths(P)):
        y[V_PATH + k] = aux[A_SPEED + k]
    # path 1's rocker from the solve at φ1 + δ_1 (its cosine and sine rotated: path_cos_sin)
    phi2 = math.atan2(aux[A_ROCKER + 1], aux[A_ROCKER])   # on the integrated φ2's branch
    y[L.PHI2] = phi2 + TWO_PI * math.floor((y[L.PHI2] - phi2) / TWO_PI + 0.5)
    y[L.OMEGA2] = aux[A_SPEED]
    if mode != 0:
        y[L.OMEGA3] = aux[A_SPEED + first_path(mode)]
        if rigid:
            y[L.OMEGA4] = y[L.OMEGA3]
    elif rigid:
        y[L.OMEGA3] = y[L.OMEGA4]
    elif P[L.P_J3] == 0.0:
        kd = P[L.P_KD]
        y[L.OMEGA3] = y[L.OMEGA4] - P[L.P_C] * y[L.TWIST] / kd if kd > 0.0 else y[L.OMEGA4]
    if rigid:
        y[L.TWIST] = 0.0


@kernel
def path_rocker_angles(y, a, P, out):
    """Each path's rocker angle [rad] into out[k]: the closed form at φ1 + δ_k, on the branch of
    path 1's (the state's φ2, which the projection keeps on its own branch)."""
    b, d, h, sigma = P[L.P_B], P[L.P_D], P[L.P_H], P[L.P_SIGMA]
    turns = 0.0
    for k in range(n_paths(P)):
        phi2 = rocker_angle(y[L.PHI1] + P[P_OFFSET + k], a, b, d, h, sigma)
        if k == 0:
            turns = TWO_PI * math.floor((y[L.PHI2] - phi2) / TWO_PI + 0.5)
        out[k] = phi2 + turns


@inline_kernel
def slip_band(k, aux):
    """Half-width of path k's slip band [rad/s] (physics/clutch.py's, of its own speeds)."""
    w3 = aux[A_SLIP + k] + aux[A_SPEED + k]
    return SLIP_TOLERANCE * (1.0 + abs(aux[A_SPEED + k]) + abs(w3))


@inline_kernel
def torque_band(P):
    """Half-width of a clutch torque's band [N·m] (physics/clutch.py's)."""
    return TORQUE_TOLERANCE * P[L.P_TORQUE_SCALE]


@inline_kernel
def slip_rate_band(k, aux, node_accel):
    return SLIP_RATE_TOLERANCE * (1.0 + abs(aux[A_ACCEL + k]) + abs(node_accel))

