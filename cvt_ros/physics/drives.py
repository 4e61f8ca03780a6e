"""Motor and load torques (physics.md §5) and the crank-length actuator.

The actuator moves the crank length a(t) towards its command with a trapezoidal velocity profile
(rate limit ``crank_rate_limit`` [m/s], acceleration limit ``crank_accel_limit`` [m/s²]).
A pure rate limit would make a'' impulsive and the rocker speed v = u·ω1 + g_a·a' jump while
engaged; the acceleration limit keeps v continuous. The profile is planned in closed form when a
command arrives, as at most N_ACT_SEGMENTS rows (t_start, a, a', a''); the solver stops its
steps at the row boundaries, where a'' jumps.
"""
import math

import numpy as np
from numba import njit

from .compiled import FASTMATH, inline_kernel
from .layout import (
    ACT_A,
    ACT_ACC,
    ACT_T,
    ACT_V,
    MOTOR_CONSTANT_TORQUE,
    MOTOR_INDUCTION,
    N_ACT_SEGMENTS,
    P_LOAD_QUADRATIC,
    P_LOAD_TORQUE,
    P_LOAD_VISCOUS,
    P_MK,
    P_MOTOR_MODEL,
    P_MOTOR_TORQUE,
    P_SK,
    P_W0,
)


@inline_kernel
def motor_torque(omega1, P):
    """M1(ω1) [N·m] for the induction and constant-torque models.

    Induction motor by Kloss's formula written as M1 = 2·Mk·sk·s / (s² + sk²) with slip
    s = (ω0 − ω1)/ω0: no division by zero at s = 0, generator torque above synchronous speed.
    The ideal speed source has no torque law; its torque is the reaction (see dynamics).
    """
    model = P[P_MOTOR_MODEL]
    if model == MOTOR_INDUCTION:
        w0 = P[P_W0]
        sk = P[P_SK]
        s = (w0 - omega1) / w0
        return 2.0 * P[P_MK] * sk * s / (s * s + sk * sk)
    if model == MOTOR_CONSTANT_TORQUE:
        return P[P_MOTOR_TORQUE]
    return 0.0


@inline_kernel
def load_torque(omega4, P):
    """M4(ω4) [N·m] = constant + viscous·ω4 + quadratic·ω4·|ω4| (conveyor, mixer)."""
    return (P[P_LOAD_TORQUE] + P[P_LOAD_VISCOUS] * omega4
            + P[P_LOAD_QUADRATIC] * omega4 * abs(omega4))


@inline_kernel
def crank_actuator(t, ACT):
    """(a, a', a'') at time t [s] from the planned profile rows."""
    k = 0
    for i in range(1, N_ACT_SEGMENTS):
        if ACT[i, ACT_T] <= t:
            k = i
        else:
            break
    tau = t - ACT[k, ACT_T]
    acc = ACT[k, ACT_ACC]
    v0 = ACT[k, ACT_V]
    return ACT[k, ACT_A] + v0 * tau + 0.5 * acc * tau * tau, v0 + acc * tau, acc


@inline_kernel
def next_actuator_break(t, ACT):
    """First profile row boundary strictly after t [s] (inf when none)."""
    for i in range(1, N_ACT_SEGMENTS):
        if ACT[i, ACT_T] > t:
            return ACT[i, ACT_T]
    return np.inf


def hold_profile(t0, crank_length):
    """A profile that holds a constant crank length from t0 on."""
    act = np.full((N_ACT_SEGMENTS, 4), np.inf)
    act[0] = (t0, crank_length, 0.0, 0.0)
    return act


# no fast-math: each float operation as written (said explicitly: numba would otherwise compile it
# with the fast-math flags of a compiled caller, replan_into's)
@njit(cache=True, error_model='numpy', fastmath=False)
def plan_into(ACT, t0, a0, v0, target, rate_limit, accel_limit, two):
    """Time-optimal trapezoidal move from (a0 [m], a'0 [m/s]) at t0 [s] to rest at ``target`` [m],
    written into the profile rows ``ACT`` in place (rows beyond the plan: inf).

    Phases: (brake to rest if moving away or unable to stop in time) → accelerate or decelerate
    to the peak speed → cruise → decelerate to rest. ``two`` = 2.0, passed at run time so that
    ``x ** two`` stays libm's pow (a literal 2 would compile to x·x). Compiled so that the device's
    one-call period (solver/period.py) plans a command without leaving compiled code."""
    for i in range(ACT.shape[0]):
        for j in range(4):
            ACT[i, j] = np.inf
    n = 0
    t, a, v = t0, a0, v0
    dist = target - a
    stop = v * v / (2.0 * accel_limit)
    if v != 0.0 and (math.copysign(1.0, v) != math.copysign(1.0, dist) or stop > abs(dist)):
        acc = -math.copysign(accel_limit, v)
        dt = abs(v) / accel_limit
        ACT[n, 0], ACT[n, 1], ACT[n, 2], ACT[n, 3] = t, a, v, acc
        n += 1
        a, v, t = a + v * dt + 0.5 * acc * dt * dt, 0.0, t + dt
        dist = target - a
    if dist != 0.0:
        sgn = math.copysign(1.0, dist)
        speed = abs(v)
        root = math.sqrt((2.0 * accel_limit * abs(dist) + speed * speed) / 2.0)
        peak = root if root < rate_limit else rate_limit     # min(rate_limit, root)
        t_ramp = abs(peak - speed) / accel_limit
        d_ramp = abs(peak * peak - speed * speed) / (2.0 * accel_limit)
        d_brake = peak * peak / (2.0 * accel_limit)
        rest = abs(dist) - d_ramp - d_brake
        d_cruise = 0.0 if 0.0 > rest else rest                # max(rest, 0.0)
        if t_ramp > 0.0:
            acc = sgn * accel_limit * (1.0 if peak > speed else -1.0)
            ACT[n, 0], ACT[n, 1], ACT[n, 2], ACT[n, 3] = t, a, v, acc
            n += 1
            a, v, t = a + v * t_ramp + 0.5 * acc * t_ramp ** two, sgn * peak, t + t_ramp
        if d_cruise > 0.0:
            ACT[n, 0], ACT[n, 1], ACT[n, 2], ACT[n, 3] = t, a, v, 0.0
            n += 1
            t_cruise = d_cruise / peak
            a, t = a + v * t_cruise, t + t_cruise
        ACT[n, 0], ACT[n, 1], ACT[n, 2], ACT[n, 3] = t, a, v, -sgn * accel_limit
        n += 1
        t += peak / accel_limit
    ACT[n, 0], ACT[n, 1], ACT[n, 2], ACT[n, 3] = t, target, 0.0, 0.0


@njit(cache=True, error_model='numpy', fastmath=FASTMATH, _nrt=False)
def replan_into(ACT, t, target, rate_limit, accel_limit, two):
    """A new command at ``t`` [s]: ``plan_into`` from where the profile ``ACT`` has the crank
    then (a, a'), in place. The one planner of every crank command (the Simulator's, the device's
    lockstep period's), one compiled call: offline and lockstep plan the same move to the bit."""
    a, ad, _ = crank_actuator(t, ACT)
    plan_into(ACT, t, a, ad, target, rate_limit, accel_limit, two)


def plan_profile(t0, a0, v0, target, rate_limit, accel_limit):
    """The profile rows of ``plan_into``'s move, in a new array."""
    act = np.empty((N_ACT_SEGMENTS, 4))
    plan_into(act, float(t0), float(a0), float(v0), float(target), float(rate_limit),
              float(accel_limit), 2.0)
    return act


__all__ = ['motor_torque', 'load_torque', 'crank_actuator', 'next_actuator_break',
           'hold_profile', 'plan_into', 'replan_into', 'plan_profile', 'ACT_A', 'ACT_V', 'ACT_T',
           'ACT_ACC']
