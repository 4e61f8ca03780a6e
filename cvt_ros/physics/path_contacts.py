"""The N-path clutches' reset map (issue 33; docs/physics.md §9): which clutches are engaged at a
state where some slip or clutch torque is at zero — at t = 0, after a parameter change, at every
located switch.

* **Impact** (``impact``): rockers faster than the node (s_k below its band: a start, a parameter
  change, a catch found late) engage by one plastic impact shared by the contacts, Newton's
  restitution 0 for all of them at once: the impulse LCP Λ ≥ 0, s⁺ ≥ 0, Λ·s⁺ = 0 over the
  contacts, on the same equations as the accelerations (physics/paths.contact_solve with the speed
  jumps −s_k as right-hand sides). Crank and node are two degrees of freedom, so one or two
  clutches take the impulse: generically one, the rocker that is fastest after it. Its kinetic
  energy loss is booked. With one path this is physics/dynamics.engage_with_impact.
* **Complementarity** (``choose_engaged``): over the contacts at zero, the set S whose
  accelerations keep every clutch torque of S ≥ 0 and every other contact's slip rate ≥ 0 (the
  acceleration LCP; enumerated, at most two contacts carry torque). The motion it gives is
  unique; among the sets that give it the present one is kept (a graze switches nothing, no
  chatter), then the smallest. A slip rate within its band of zero is decided by a short probe
  of the motion, as physics/clutch.clutch_engages does (higher-order contacts: a = 0).

A handoff — path k catching the node while path j drives it — is one such decision: at the catch
v_k = v_j, and both cannot stay engaged while the crank turns (u_j ≠ u_k), so {k} is the set:
j releases as k engages, at equal speeds, without an impact.
"""
from .clutch import CONTACT_PROBE_TIME, PROBE_STEPS
from .compiled import kernel
from .layout import (
    AUX_ENERGY,
    MOTOR_CONSTANT_SPEED,
    OMEGA1,
    OMEGA3,
    OMEGA4,
    P_J1,
    P_J2,
    P_J3,
    P_J4,
    P_MOTOR_MODEL,
    P_RIGID,
)
from .paths import (
    A_JUMP,
    A_SLIP,
    A_SLIP_RATE,
    A_SPEED,
    A_TORQUE,
    A_U,
    NO_SET,
    bit,
    contact_solve,
    n_paths,
    paths_project,
    paths_rhs,
    set_size,
    slip_band,
    slip_rate_band,
    torque_band,
)

# A slip rate this many of its bands from zero is decided by the probe, not by its sign: at a
# release from the locked crank every other contact is at zero with a rate ∝ the crank's
# acceleration, which is 0 at the release and, at the located point, the release's location
# error (~1e-8 rad/s² where the band is 1e-10 of the accelerations): its sign is noise there
PROBE_BAND = 1e4

# An open slip that would reach zero within this time [s] is at zero with the one located:
# guards that cross together by structure (a stalled crank: every slip ∝ ω1) are located one
# of them at a time, the others within the location's error of zero on either side
TOGETHER = 1e-9


@kernel
def open_contacts(mode, exclude, P, aux):
    """The open paths whose slip is at zero or below (within its band, or falling to it within
    TOGETHER), except ``exclude``."""
    found = 0
    for k in range(n_paths(P)):
        slip = aux[A_SLIP + k]
        if not (mode | exclude) & bit(k) and (
                slip <= slip_band(k, aux) or slip <= -TOGETHER * aux[A_SLIP_RATE + k]):
            found |= bit(k)
    return found


@kernel
def impact(t, y, mode, exclude, P, ACT, dy, aux):
    """A plastic impact when a rocker (not ``exclude``) is faster than the node by more than its
    band (module text): (the set that takes the impulse, kinetic energy lost [J]); y moved onto
    it, and True. Without such a rocker: (``mode``, 0, False), y unchanged."""
    paths_rhs(t, y, mode, P, ACT, dy, aux)
    n = n_paths(P)
    late = False
    for k in range(n):
        if not exclude & bit(k) and aux[A_SLIP + k] < -slip_band(k, aux):
            late = True
    if not late:
        return mode, 0.0, False
    candidates = (mode | open_contacts(mode, exclude, P, aux)) & ~exclude
    su2 = 0.0
    fastest = -1
    for k in range(n):
        su2 += aux[A_U + k] ** 2
        aux[A_JUMP + k] = -aux[A_SLIP + k]
        if candidates & bit(k) and (fastest < 0 or aux[A_SLIP + k] < aux[A_SLIP + fastest]):
            fastest = k
    j1e = P[P_J1] + P[P_J2] * su2
    rigid = P[P_RIGID] > 0.0
    jn = P[P_J3] + (P[P_J4] if rigid else 0.0)
    speed_source = P[P_MOTOR_MODEL] == MOTOR_CONSTANT_SPEED
    w3 = aux[A_SLIP] + aux[A_SPEED]
    e_before = aux[AUX_ENERGY]
    chosen = NO_SET
    x1 = x2 = 0.0
    for size in range(1, 3):
        for s in range(1, 1 << n):
            if s & ~candidates or set_size(s) != size:
                continue
            x1, x2, ok = contact_solve(s, n, 0.0, j1e, 0.0, jn, speed_source, aux, A_JUMP)
            if ok and _impulse_fits(s, x1, x2, exclude, n, aux):
                chosen = s
                break
        if chosen != NO_SET:
            break
    if chosen == NO_SET:   # (rounding at a degenerate contact) the fastest rocker alone
        chosen = bit(fastest)
        x1, x2, _ = contact_solve(chosen, n, 0.0, j1e, 0.0, jn, speed_source, aux, A_JUMP)
    y[OMEGA1] += x1
    if rigid:
        y[OMEGA4] += x2
    else:
        y[OMEGA3] = w3 + x2
    paths_project(t, y, chosen, P, ACT, aux)
    paths_rhs(t, y, chosen, P, ACT, dy, aux)
    return chosen, e_before - aux[AUX_ENERGY], True


@kernel
def _impulse_fits(s, x1, x2, exclude, n, aux):
    """Impulses Λ ≥ 0 in the set s, and no other rocker faster than the node after them."""
    for k in range(n):
        if s & bit(k):
            if aux[A_TORQUE + k] < 0.0:
                return False
        elif not exclude & bit(k) and (aux[A_SLIP + k] + x2 - aux[A_U + k] * x1
                                       < -slip_band(k, aux)):
            return False
    return True


@kernel
def _set_fits(t, y, s, candidates, P, ACT, aux, ytmp, dytmp):
    """Complementarity for the set s among the contacts ``candidates``, at the state moved onto
    s (ytmp): its clutch torques ≥ 0 and the other contacts' slip rates ≥ 0, each within its
    band; a rate inside its band is decided by a short probe of the motion with s engaged (it
    must not fall by more than its band)."""
    for i in range(y.shape[0]):
        ytmp[i] = y[i]
    paths_project(t, ytmp, s, P, ACT, aux)
    if not paths_rhs(t, ytmp, s, P, ACT, dytmp, aux):
        return False
    n = n_paths(P)
    for k in range(n):
        if s & bit(k) and aux[A_TORQUE + k] < -torque_band(P):
            return False
    probe = 0
    for k in range(n):
        if candidates & bit(k) and not s & bit(k):
            rate = aux[A_SLIP_RATE + k]
            band = PROBE_BAND * slip_rate_band(k, aux, dytmp[OMEGA3])
            if rate < -band:
                return False
            if rate <= band:
                probe |= bit(k)
                aux[A_JUMP + k] = rate   # (the probe's start; paths_rhs leaves these slots)
    if probe == 0:
        return True
    tp = t
    for _ in range(PROBE_STEPS):
        paths_rhs(tp, ytmp, s, P, ACT, dytmp, aux)
        for i in range(y.shape[0]):
            ytmp[i] += CONTACT_PROBE_TIME * dytmp[i]
        tp += CONTACT_PROBE_TIME
    paths_rhs(tp, ytmp, s, P, ACT, dytmp, aux)
    for k in range(n):
        if probe & bit(k) and (aux[A_SLIP_RATE + k] - aux[A_JUMP + k]
                               < -slip_rate_band(k, aux, dytmp[OMEGA3])):
            return False
    return True


@kernel
def choose_engaged(t, y, prefer, candidates, P, ACT, aux, ytmp, dytmp):
    """The acceleration LCP over the contacts at zero (module text): ``prefer`` if it fits, else
    the smallest set of ``candidates`` that does (at most two paths, one behind an ideal speed
    source); NO_SET when none does (rounding at a degenerate contact: the caller keeps its
    set)."""
    if _set_fits(t, y, prefer, candidates, P, ACT, aux, ytmp, dytmp):
        return prefer
    largest = 1 if P[P_MOTOR_MODEL] == MOTOR_CONSTANT_SPEED else 2
    for size in range(largest + 1):
        if size == 2:
            # a stalled crank meets every contact at once (all slips ∝ ω1), and any pair of
            # rockers turning opposite ways may hold it: the same motion, another torque split.
            # The pair of the fastest forward and backward rocker first: it holds whenever any
            # pair does, and no other rocker outruns the node when the crank leaves it
            pair = _extreme_pair(candidates, P, aux)
            if pair != prefer and set_size(pair) == 2 and _set_fits(
                    t, y, pair, candidates, P, ACT, aux, ytmp, dytmp):
                return pair
        for s in range(1 << n_paths(P)):
            if s == prefer or s & ~candidates or set_size(s) != size:
                continue
            if _set_fits(t, y, s, candidates, P, ACT, aux, ytmp, dytmp):
                return s
    return NO_SET


@kernel
def _extreme_pair(candidates, P, aux):
    """The candidates of the largest and the smallest u_k, as a set."""
    top = -1
    bottom = -1
    for k in range(n_paths(P)):
        if candidates & bit(k):
            if top < 0 or aux[A_U + k] > aux[A_U + top]:
                top = k
            if bottom < 0 or aux[A_U + k] < aux[A_U + bottom]:
                bottom = k
    return bit(top) | bit(bottom) if top >= 0 else 0


@kernel
def settle_contacts(t, y, mode, exclude, strike, P, ACT, dy, aux, ytmp, dytmp):
    """The engaged set at a state where a guard is at zero (module text): if ``strike``, an
    impact where a rocker other than those of ``exclude`` (a bitmask: a clutch that has just
    released) is faster than the node, then complementarity over the contacts at zero, the
    present set preferred. (A located catch does not strike: its slip is at zero within the
    location's error, which the projection onto the new set takes up, as for one path.)
    Returns (new set, the set that took an impact's impulse or 0, energy lost [J]); y projected
    onto the new set, dy and aux its rates there."""
    new, loss, struck = mode, 0.0, False
    if strike:
        new, loss, struck = impact(t, y, mode, exclude, P, ACT, dy, aux)
    struck = new & ~mode if struck else 0
    paths_rhs(t, y, new, P, ACT, dy, aux)
    candidates = new | open_contacts(new, exclude, P, aux)
    if candidates != new or struck:   # (a struck clutch whose torque would pull lets go)
        chosen = choose_engaged(t, y, new, candidates, P, ACT, aux, ytmp, dytmp)
        if chosen != NO_SET:
            new = chosen
    paths_project(t, y, new, P, ACT, aux)
    paths_rhs(t, y, new, P, ACT, dy, aux)
    return new, struck, loss
