"""Crank-rocker four-bar linkage (paper eq. 1, physics.md §2), solved in closed form.

O1 at the origin, O2 at (h, 0), angles counter-clockwise from the ray O1→O2. The loop closure

    f(φ1, φ2, a) = a² + b² + h² − d² − 2ah·cos φ1 + 2bh·cos φ2 − 2ab·cos(φ1 − φ2) = 0   (eq. 1)

is solved for φ2 by Freudenstein's method, so the rocker angle is never integrated and cannot
drift. All derivatives the dynamics need come from the implicit function theorem applied to f:
u = ∂φ2/∂φ1 = A1/A2 (the paper's auxiliary functions), u' = ∂u/∂φ1, g_a = ∂φ2/∂a, u_a = ∂u/∂a,
g_aa = ∂²φ2/∂a² (the last three because the crank length moves at run time, physics.md §5).
"""
import math

from .compiled import inline_kernel, kernel


class GrashofError(ValueError):
    """A crank length or geometry for which the crank cannot turn fully (Grashof violated)."""

    def __init__(self, message, value=None, limit=None):
        super().__init__(message)
        self.value = value
        self.limit = limit


def grashof_bound(rocker_length, coupler_length, pivot_distance):
    """Largest crank length [m] (exclusive) for which the crank still turns fully.

    Grashof with the crank shortest: a + max(b, d, h) ≤ (sum of the other two), a ≤ min(b, d, h).
    At equality the linkage folds flat (a toggle with A2 = 0, u = ∞): the bound itself is refused.
    """
    b, d, h = rocker_length, coupler_length, pivot_distance
    # fsum: the exact sum, so that b = 0.1, d = h = 0.2 give 0.1 and not 0.09999999999999998
    return min(b, d, h, math.fsum((b, d, h, -2.0 * max(b, d, h))))


def check_crank_length(crank_length, rocker_length, coupler_length, pivot_distance):
    """Raise GrashofError unless 0 ≤ a < Grashof bound; return the bound [m]."""
    bound = grashof_bound(rocker_length, coupler_length, pivot_distance)
    a = crank_length
    if not math.isfinite(a):
        raise GrashofError(f"crank length {a!r} m is not a finite number", a, bound)
    if bound <= 0.0:
        raise GrashofError(
            f"geometry b={rocker_length}, d={coupler_length}, h={pivot_distance} m admits no "
            f"turning crank (Grashof: need b + d + h − 2·max(b, d, h) > 0)", a, bound)
    if a < 0.0 or a >= bound:
        raise GrashofError(
            f"crank length {a!r} m is outside [0, {bound!r}) m: the crank must be shorter than "
            f"the Grashof bound min(b, d, h, b + d + h − 2·max(b, d, h)) = {bound!r} m of the "
            f"geometry b = {rocker_length!r}, d = {coupler_length!r}, h = {pivot_distance!r} m",
            a, bound)
    return bound


def check_crank_lengths_fit(lengths, rocker_length, coupler_length, pivot_distance):
    """Raise GrashofError unless each crank length of ``lengths`` ((what, a) pairs: the present
    length, the commanded one) fits the geometry; return the bound [m].

    A live geometry change must leave room for where the crank is and where it is heading: the
    one check behind ``Simulator.update_parameters`` and the node's parameter pre-check.
    """
    bound = grashof_bound(rocker_length, coupler_length, pivot_distance)
    for what, a in lengths:
        if not a < bound:
            raise GrashofError(f"the Grashof bound would become {bound!r} m, below the {what} "
                               f"crank length {a!r} m; command a shorter crank first", a, bound)
    return bound


def inertia_rate_factor(a, b, d, h, sigma, j_crank, j_driven, samples=720):
    """max over a crank turn of |d ln J_eff/dφ1| for J_eff = J1 + Jd·u² (the crank's inertia and
    what the rocker drives, reflected): times the crank speed, the rate [1/s] at which the
    crank's effective inertia changes, which a fixed step must resolve (the crank's equation
    J_eff·ω1' = M1 − ½·J_eff'·ω1² gives ω1'/ω1 = −½·(d ln J_eff/dφ1)·ω1 from the linkage alone).
    At most 2.7 for the shipped scenes (near_grashof; their shaft modes are faster still); 87
    for a heavy rigid output (J4 = 33·J1) behind a crank at 99 % of the Grashof bound, where the
    crank hands most of its energy to the output within a millisecond of the engagement (RK4 at
    0.2 ms lost 2 % of it to the energy balance)."""
    if a == 0.0 or j_driven == 0.0:
        return 0.0
    worst = 0.0
    for k in range(samples):
        _, _, u, up, _, _, _ = kinematics(2.0 * math.pi * k / samples, a, b, d, h, sigma)
        worst = max(worst, abs(2.0 * j_driven * u * up) / (j_crank + j_driven * u * u))
    return worst


@kernel
def rocker_angle(phi1, a, b, d, h, sigma):
    """φ2(φ1, a) [rad] from eq. 1 in closed form: P·cos φ2 + Q·sin φ2 = R."""
    c1 = math.cos(phi1)
    p = 2.0 * b * h - 2.0 * a * b * c1
    q = -2.0 * a * b * math.sin(phi1)
    r = -(a * a + b * b + h * h - d * d) + 2.0 * a * h * c1
    ratio = r / math.sqrt(p * p + q * q)
    # |ratio| ≤ 1 for every φ1 of a Grashof crank; clip the last-ulp excursions near the bound.
    if ratio > 1.0:
        ratio = 1.0
    elif ratio < -1.0:
        ratio = -1.0
    return math.atan2(q, p) + sigma * math.acos(ratio)


@inline_kernel
def _partials(a, b, h, c1, s1, c2, s2, c12, s12):
    """The partial derivatives of f (eq. 1) from the angles' cosines and sines:
    (f1, f2, fa, f11, f12, f22, f1a, f2a); f1 = 2·A1, f2 = −2·A2 (paper eq. 6), f_aa = 2."""
    return (2.0 * a * h * s1 + 2.0 * a * b * s12,
            -2.0 * b * h * s2 - 2.0 * a * b * s12,
            2.0 * a - 2.0 * h * c1 - 2.0 * b * c12,
            2.0 * a * h * c1 + 2.0 * a * b * c12,
            -2.0 * a * b * c12,
            -2.0 * b * h * c2 + 2.0 * a * b * c12,
            2.0 * h * s1 + 2.0 * b * s12,
            -2.0 * b * s12)


@inline_kernel
def constraint_partials(phi1, phi2, a, b, h, d):
    """f of eq. 1 and its first and second partial derivatives at (φ1, φ2, a).

    Returns (f, f1, f2, fa, f11, f12, f22, f1a, f2a, faa); f1 = 2·A1, f2 = −2·A2 (paper eq. 6).
    """
    s1 = math.sin(phi1)
    c1 = math.cos(phi1)
    s2 = math.sin(phi2)
    c2 = math.cos(phi2)
    s12 = math.sin(phi1 - phi2)
    c12 = math.cos(phi1 - phi2)
    f = a * a + b * b + h * h - d * d - 2.0 * a * h * c1 + 2.0 * b * h * c2 - 2.0 * a * b * c12
    f1, f2, fa, f11, f12, f22, f1a, f2a = _partials(a, b, h, c1, s1, c2, s2, c12, s12)
    return f, f1, f2, fa, f11, f12, f22, f1a, f2a, 2.0


@inline_kernel
def rocker_cos_sin(phi1, a, b, d, h, sigma):
    """(cos φ2, sin φ2, cos φ1, sin φ1) without inverse trigonometry.

    With ρ² = P² + Q² and φ2 = atan2(Q, P) + σ·arccos(R/ρ):
    cos φ2 = (P·R − σ·Q·√(ρ² − R²))/ρ²,  sin φ2 = (Q·R + σ·P·√(ρ² − R²))/ρ².
    Two transcendental calls per evaluation instead of six: the RHS's hot path.
    """
    return rocker_cos_sin_at(math.cos(phi1), math.sin(phi1), a, b, d, h, sigma)


@inline_kernel
def rocker_cos_sin_at(c1, s1, a, b, d, h, sigma):
    """``rocker_cos_sin`` from cos φ1 and sin φ1: N paths on one crank take the sine and cosine
    of φ1 once and rotate them by each path's offset (physics/paths.py)."""
    p = 2.0 * b * h - 2.0 * a * b * c1
    q = -2.0 * a * b * s1
    r = -(a * a + b * b + h * h - d * d) + 2.0 * a * h * c1
    rho2 = p * p + q * q
    root = math.sqrt(max(rho2 - r * r, 0.0))
    return (p * r - sigma * q * root) / rho2, (q * r + sigma * p * root) / rho2, c1, s1


@inline_kernel
def kinematics(phi1, a, b, d, h, sigma):
    """Rocker angle derivatives for a crank angle φ1 [rad] and crank length a [m].

    Returns (cos φ2, sin φ2, u, u', g_a, u_a, g_aa): u = ∂φ2/∂φ1 = A1/A2, u' = ∂²φ2/∂φ1²,
    g_a = ∂φ2/∂a [rad/m], u_a = ∂²φ2/∂φ1∂a [1/m], g_aa = ∂²φ2/∂a² [rad/m²] (implicit
    differentiation of eq. 1 with the partials of f).
    """
    return kinematics_at(math.cos(phi1), math.sin(phi1), a, b, d, h, sigma)


@inline_kernel
def kinematics_at(c1, s1, a, b, d, h, sigma):
    """``kinematics`` from cos φ1 and sin φ1 (``rocker_cos_sin_at``). Its cosine and sine come
    back through rocker_cos_sin_at, as they did through rocker_cos_sin before the split: the
    compiled one-path right-hand side stays the same to the bit."""
    c2, s2, c1, s1 = rocker_cos_sin_at(c1, s1, a, b, d, h, sigma)
    c12 = c1 * c2 + s1 * s2   # cos(φ1 − φ2)
    s12 = s1 * c2 - c1 * s2   # sin(φ1 − φ2)
    f1, f2, fa, f11, f12, f22, f1a, f2a = _partials(a, b, h, c1, s1, c2, s2, c12, s12)
    faa = 2.0
    u = -f1 / f2
    ga = -fa / f2
    up = -(f11 + 2.0 * f12 * u + f22 * u * u) / f2
    ua = -(f1a + f12 * ga + f2a * u + f22 * u * ga) / f2
    gaa = -(faa + 2.0 * f2a * ga + f22 * ga * ga) / f2
    return c2, s2, u, up, ga, ua, gaa
