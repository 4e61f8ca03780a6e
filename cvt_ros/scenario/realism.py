"""Sensor and actuator realism between the device and the controller (all off by default).

Sensors, applied to the controller-facing state in this order each control period:

1. **noise**: Gaussian, standard deviations per signal (``position`` rad, ``velocity`` rad/s,
   ``effort`` N·m, ``crank_length`` m), drawn from one seeded generator in a fixed order, so a
   run is the same to the bit for the same seed in every back end;
2. **quantization** (``counts_per_turn`` N > 0): joint angles in whole counts of 2π/N (floor, as
   an incremental encoder counts), and the joint speeds become what an encoder-based speed
   measurement gives: the count difference over one control period;
3. **transport delay** (``delay`` s, whole control periods): the controller sees the sample of
   ``delay`` ago (the first sample until then);
4. **decimation** (``decimation`` N ≥ 1): a new sample every N-th period, held in between.

Actuator, applied to the controller's crank-length command before the device gets it:
**deadband** (a command that differs from the last one passed on by less than ``deadband`` m is
not passed on) and **backlash** (a play of ``backlash`` m: the crank follows the command only
once the command has crossed the play: x ← clamp(x, c − b/2, c + b/2)).
"""
import collections
import math
from dataclasses import dataclass, fields

import numpy as np

from ..control.measurement import Measurement
from .checks import number

TWO_PI = 2.0 * math.pi
NOISE_BLOCK = 4096      # periods of noise drawn at once (same numbers whatever the block size)
N_NOISE = 13            # 4 positions, 4 velocities, 4 efforts, crank length


@dataclass(frozen=True)
class SensorSpec:
    position_noise: float = 0.0       # rad (standard deviation)
    velocity_noise: float = 0.0       # rad/s
    effort_noise: float = 0.0         # N·m
    crank_length_noise: float = 0.0   # m
    counts_per_turn: int = 0          # encoder counts per turn (0: exact angles)
    delay: float = 0.0                # s, rounded to whole control periods
    decimation: int = 1               # a new sample every N-th control period

    @property
    def enabled(self):
        return self != SensorSpec()


@dataclass(frozen=True)
class ActuatorSpec:
    deadband: float = 0.0             # m
    backlash: float = 0.0             # m

    @property
    def enabled(self):
        return self != ActuatorSpec()


class RealismError(ValueError):
    """A sensor or actuator setting that cannot be used (names the key, value and limit)."""


_SENSOR_KEYS = {
    'noise': {'position': 'position_noise', 'velocity': 'velocity_noise',
              'effort': 'effort_noise', 'crank_length': 'crank_length_noise'},
}
_SENSOR_LIMITS = {'position_noise': 10.0, 'velocity_noise': 1e4, 'effort_noise': 1e5,
                  'crank_length_noise': 1.0, 'delay': 10.0}


def _value(value, key, low, high, integer=False):
    return number(value, key, low, high, integer=integer, error=RealismError)


def parse_sensors(body, key, period):
    """SensorSpec from ``sensors: {noise: {position: .., velocity: ..}, counts_per_turn: ..,
    delay: .., decimation: ..}``."""
    if body is None:
        return SensorSpec()
    if not isinstance(body, dict):
        raise RealismError(f"{key}: expected a map, got {body!r}")
    allowed = ('noise', 'counts_per_turn', 'delay', 'decimation')
    kw = {}
    for name, value in body.items():
        if name not in allowed:
            raise RealismError(f"{key}: unknown key {name!r}; allowed: {', '.join(allowed)}")
        if name == 'noise':
            if not isinstance(value, dict):
                raise RealismError(f"{key}.noise: expected a map of standard deviations")
            for signal, std in value.items():
                field = _SENSOR_KEYS['noise'].get(signal)
                if field is None:
                    raise RealismError(f"{key}.noise: unknown signal {signal!r}; allowed: "
                                       f"{', '.join(_SENSOR_KEYS['noise'])}")
                kw[field] = _value(std, f"{key}.noise.{signal}", 0.0, _SENSOR_LIMITS[field])
        elif name == 'counts_per_turn':
            kw[name] = _value(value, f"{key}.{name}", 0, 2 ** 31, integer=True)
        elif name == 'delay':
            d = _value(value, f"{key}.delay", 0.0, _SENSOR_LIMITS['delay'])
            if abs(d / period - round(d / period)) > 1e-6:
                raise RealismError(f"{key}.delay: {d:g} s is not a whole number of control "
                                   f"periods ({period:g} s)")
            kw[name] = d
        else:
            kw[name] = _value(value, f"{key}.{name}", 1, 1_000_000, integer=True)
    return SensorSpec(**kw)


def parse_actuator(body, key):
    if body is None:
        return ActuatorSpec()
    if not isinstance(body, dict):
        raise RealismError(f"{key}: expected a map, got {body!r}")
    names = [f.name for f in fields(ActuatorSpec)]
    kw = {}
    for name, value in body.items():
        if name not in names:
            raise RealismError(f"{key}: unknown key {name!r}; allowed: {', '.join(names)}")
        kw[name] = _value(value, f"{key}.{name}", 0.0, 0.1)
    return ActuatorSpec(**kw)


class SensorModel:
    """The controller-facing state from the device's true state, one control period at a time.

    ``observe(t, position, velocity, effort, crank_length, engaged, setpoint)`` → Measurement.
    Deterministic: the noise comes from ``numpy.random.default_rng(seed)``.
    """

    def __init__(self, spec, period, seed):
        self.spec = spec
        self.period = period
        self._rng = np.random.default_rng(seed)
        self._noise = None
        self._k = 0
        self._sigma = np.array([spec.position_noise] * 4 + [spec.velocity_noise] * 4
                               + [spec.effort_noise] * 4 + [spec.crank_length_noise])
        self._noisy = bool(np.any(self._sigma > 0))
        self._count = TWO_PI / spec.counts_per_turn if spec.counts_per_turn else 0.0
        self._prev_counts = None
        self._delay = int(round(spec.delay / period))
        self._line = collections.deque(maxlen=self._delay + 1)
        self._held = None

    def observe(self, t, position, velocity, effort, crank_length, engaged, setpoint):
        spec = self.spec
        if self._noisy:
            i = self._k % NOISE_BLOCK
            if i == 0:
                self._noise = self._rng.standard_normal((NOISE_BLOCK, N_NOISE)) * self._sigma
            n = self._noise[i]
            position = tuple(p + n[j] for j, p in enumerate(position))
            velocity = tuple(v + n[4 + j] for j, v in enumerate(velocity))
            effort = tuple(e + n[8 + j] for j, e in enumerate(effort))
            crank_length = crank_length + n[12]
        if self._count:
            counts = tuple(math.floor(p / self._count) for p in position)
            prev = self._prev_counts or counts
            position = tuple(c * self._count for c in counts)
            velocity = tuple((c - c0) * self._count / self.period
                             for c, c0 in zip(counts, prev, strict=True))
            self._prev_counts = counts
        self._k += 1
        sample = (t, position, velocity, effort, crank_length, engaged)
        if self._delay:
            self._line.append(sample)
            sample = self._line[0]
        if spec.decimation > 1:
            if (self._k - 1) % spec.decimation == 0 or self._held is None:
                self._held = sample
            sample = self._held
        return Measurement(*sample, setpoint)


class ActuatorModel:
    """Deadband and backlash on the crank-length command (m in, m out; None passes through)."""

    def __init__(self, spec, initial):
        self.spec = spec
        self.passed = initial        # last command given to the device [m]
        self.position = initial      # backlash output [m]

    def command(self, value):
        if value is None:
            return None
        spec = self.spec
        half = 0.5 * spec.backlash
        if half:
            self.position = min(max(self.position, value - half), value + half)
            value = self.position
        if spec.deadband and abs(value - self.passed) < spec.deadband:
            return None
        self.passed = value
        return value
