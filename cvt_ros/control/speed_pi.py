"""The reference controller: a PI controller of the cycle-mean output speed that drives the crank
length, with anti-windup and a rate limit. No rclpy: the ROS node (control/node.py), the scenario
harness and a user's own tests all call this one law.

Why cycle-mean: the output speed ω4 pulses at the clutch frequency (two switches per crank turn,
~48 Hz on the conveyor); its mean over one crank turn is free of that ripple because the ripple
is periodic in the crank angle φ1. :class:`CycleMeanSpeed` takes that mean over each turn, and
the law runs once per completed turn (~24 times a second on the conveyor; the controller is
still called every control period and answers None in between, which keeps the last command).
A fresh measurement exists only once per turn, so acting more often adds nothing but actuator
re-plans; the turn (~42 ms) is short against the plant's time constant (~0.7 s).

The law (position form, anti-windup after Åström & Hägglund, "Advanced PID Control", §3.5),
once per crank turn of length dt, with e = ω4* − ω̄4:

    v = kp·e + I                                   (desired crank length [m]; I starts at a(0))
    u = clamp(v, a_min, a_max), and u ≥ a_prev while the clutch coasts (see below)
    a = clamp(u, a_prev − rate·dt, a_prev + rate·dt)           (what is commanded)
    I ← I + dt·(ki·e·[a not held back by the rate limit] + (u − v) / t_track)

Tuning (conveyor plant, identified with the core: Δω4/Δa ≈ 1.46 rad/s per mm at a = 40 mm, time
constant τ ≈ 0.7 s, −0.45 rad/s per N·m of load): ki = kp/τ cancels the plant pole, kp sets the
closed-loop time constant T = τ/(kp·K); the defaults give T ≈ 0.35 s. docs/controller.md has the
closed-loop plots.
"""
import math
from dataclasses import dataclass, fields

from ..numbers import NotANumber, real_number

TWO_PI = 2.0 * math.pi


class CycleMeanSpeed:
    """Mean output speed over each crank turn, available when the turn completes.

    ``update(t, phi1, phi4)`` → the mean ω4 [rad/s] of the turn that ended inside this sample
    interval (Δφ4 / Δt between successive crossings of φ1 = φ1(0) + 2πk, located by linear
    interpolation between samples), or None while the turn goes on. When the crank stands (no
    turn within ``max_window`` s) the mean over the last ``max_window`` s is returned instead,
    so a stalled drive still has a measurement.
    """

    def __init__(self, max_window=0.5):
        self.max_window = max_window
        self.reset()

    def reset(self):
        self.value = None
        self._prev = None          # (t, φ1, φ4) of the previous sample
        self._mark = None          # (t, φ4) at the last crossing
        self._turn = 0             # crossings so far
        self._phi1_0 = 0.0
        self._quiet = (-math.inf, -math.inf)   # below both: no crossing, no window (see update)

    def update(self, t, phi1, phi4):
        prev = self._prev
        self._prev = (t, phi1, phi4)
        phi1_quiet, t_quiet = self._quiet
        if phi1 < phi1_quiet and t < t_quiet:
            return None   # most samples: the turn goes on (the checks below, decided early)
        if prev is None:
            self._phi1_0 = phi1
            self._mark = (t, phi4)
            self._set_quiet()
            return None
        value = self._crossing(t, phi1, phi4, prev)
        self._set_quiet()
        return value

    def _set_quiet(self):
        # a margin of 1e-9 (relative, and absolute near 0) below the exact tests of _crossing,
        # far above their rounding: samples in it take the full path, so the early answer
        # never differs from it
        phi1_next = self._phi1_0 + (self._turn + 1) * TWO_PI
        t_window = self._mark[0] + self.max_window
        self._quiet = (phi1_next - 1e-9 * (1.0 + abs(phi1_next)),
                       t_window - 1e-9 * (1.0 + abs(t_window)))

    def _crossing(self, t, phi1, phi4, prev):
        turn = math.floor((phi1 - self._phi1_0) / TWO_PI)
        if turn > self._turn:
            self._turn = turn
            t0, p10, p40 = prev
            target = self._phi1_0 + turn * TWO_PI
            s = (target - p10) / (phi1 - p10) if phi1 > p10 else 1.0
            tc, p4c = t0 + s * (t - t0), p40 + s * (phi4 - p40)
            tm, p4m = self._mark
            self._mark = (tc, p4c)
            if tc > tm:
                self.value = (p4c - p4m) / (tc - tm)
                return self.value
            return None
        tm, p4m = self._mark
        if t - tm >= self.max_window:     # the crank stands or crawls
            self._mark = (t, phi4)
            self._phi1_0 = phi1 - self._turn * TWO_PI
            self.value = (phi4 - p4m) / (t - tm)
            return self.value
        return None


@dataclass
class SpeedPIGains:
    """Settings of the reference controller (SI units; lengths in m)."""
    kp: float = 2.0e-3          # m per rad/s of speed error
    ki: float = 4.0e-3          # m per rad of integrated error (m per rad/s·s)
    crank_min: float = 0.0      # m: command limits
    crank_max: float = 0.09     # m
    rate_limit: float = 0.01    # m/s: largest change of the command (≤ the actuator's limit)
    tracking_time: float = 0.1  # s: anti-windup back-calculation time constant

    def check(self):
        """Raise ValueError naming the setting when a value is not usable."""
        for f in fields(self):
            v = getattr(self, f.name)
            try:
                finite = math.isfinite(real_number(v))
            except NotANumber as exc:
                raise ValueError(f"{f.name}: {exc}") from None
            if not finite:
                raise ValueError(f"{f.name}: {v!r} is not a finite number")
        for name in ('kp', 'ki', 'crank_min'):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: {getattr(self, name):g} must be ≥ 0")
        for name in ('rate_limit', 'tracking_time'):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: {getattr(self, name):g} must be > 0")
        if not self.crank_max > self.crank_min:
            raise ValueError(f"crank_max: {self.crank_max:g} m must be above crank_min "
                             f"{self.crank_min:g} m")
        return self


class SpeedPI:
    """Cycle-mean output-speed PI law → crank-length command [m].

    Call with a :class:`~cvt_ros.control.measurement.Measurement` each control period; returns
    the command (None until a first cycle mean exists: the crank keeps its length). Bumpless: the
    integrator starts from the measured crank length at the first command.
    """

    def __init__(self, gains=None, setpoint=None):
        self.gains = (gains or SpeedPIGains()).check()
        self.setpoint = setpoint          # overrides the measurement's set point when not None
        self.speed = CycleMeanSpeed()
        self.reset()

    def reset(self):
        self.speed.reset()
        self.integral = None              # [m]; None: not started
        self.command = None               # last command [m]
        self.t_prev = None
        self.error = math.nan
        self._engaged_in_turn = False

    def __call__(self, m):
        return self.update(m.t, m.position[0], m.position[3], m.crank_length,
                           m.setpoint if self.setpoint is None else self.setpoint,
                           m.clutch_engaged)

    def update(self, t, phi1, phi4, crank_length, setpoint, clutch_engaged=True):
        """One control period from plain numbers (what the ROS node calls)."""
        if clutch_engaged:
            self._engaged_in_turn = True
        w = self.speed.update(t, phi1, phi4)
        if w is None:
            return None
        coasting = not self._engaged_in_turn
        self._engaged_in_turn = False
        g = self.gains
        e = setpoint - w
        if self.integral is None:         # start from where the crank is: I holds its length
            self.command = min(max(crank_length, g.crank_min), g.crank_max)
            self.integral = self.command
            self.t_prev = t
        dt = t - self.t_prev
        self.t_prev = t
        v = g.kp * e + self.integral
        u = min(max(v, g.crank_min), g.crank_max)
        if coasting and u < self.command:
            # the clutch stayed open for a whole turn: the output coasts down under its load and
            # a shorter crank cannot brake it (a one-way clutch only drives). Shortening further
            # would only wind the crank away from where it must be when the clutch takes over
            # again, so the present command is a lower limit like the range limits.
            u = self.command
        step = g.rate_limit * dt
        a = min(max(u, self.command - step), self.command + step)
        # range (and coasting) limits: back-calculation pulls I to what the crank can do;
        # rate limit: conditional integration (no integration while the rate limit holds the
        # command back in the error's direction) — back-calculating a rate limit would unwind I
        # by the whole proportional kick during every large step
        held_back = (a - u) * e < 0.0
        self.integral += dt * ((0.0 if held_back else g.ki * e) + (u - v) / g.tracking_time)
        self.command = a
        self.error = e
        return a


def reference_gains(settings, limits):
    """The reference PI's checked settings: ``settings`` (a scenario's ``controller:`` map)
    within the scenario's crank ``limits`` (min, max, rate). ValueError names the setting when
    the two leave no room (crank_max 0.05 m against limits from 0.06 m)."""
    gains = SpeedPIGains(**settings)
    gains.crank_min = max(gains.crank_min, limits.min)
    gains.crank_max = min(gains.crank_max, limits.max)
    gains.rate_limit = min(gains.rate_limit, limits.rate)
    return gains.check()


def reference_controller(scenario):
    """FACTORY for the harness (``--controller cvt_ros.control.speed_pi:reference_controller``):
    the reference PI with the scenario's crank limits and its ``controller:`` settings."""
    return SpeedPI(reference_gains(scenario.controller_settings, scenario.crank_limits))
