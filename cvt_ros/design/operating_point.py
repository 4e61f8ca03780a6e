"""The operating point: the scene run from its initial state until its cycle means are steady.

A plant model is a linearization about a steady state, so there must be one: the motor must
turn the crank (an induction motor loaded past its breakdown torque stalls), and the crank must
drive the output (at ``linkage.crank_length`` = 0 the rocker stands still and the one-way clutch
never engages: the output speed does not depend on the crank length there in both directions,
so no linear model exists). Either is refused with the setting to change, as is a run that has
not settled within ``settle_time``.

Steady is decided by :func:`cvt_ros.analysis.steady.find_steady_state` on the cycle means of the
crank speed, output speed and ratio, with a band much tighter than the analysis default (±0.5 %):
the identification steps move the output speed by ~2 % but the motor speed by ~0.05 % (the
conveyor), and a baseline still drifting by a fraction of that would be fitted as plant
response (identify's default band: ±1e-5).
"""
import math
from dataclasses import asdict, dataclass

import numpy as np

from ..analysis.cycles import DRIVEN_RATIO
from ..analysis.steady import find_steady_state
from ..solver.fidelity import make_simulator
from ..solver.output import COL
from .errors import DesignError
from .experiment import drive, record_of

SETTLE_CHUNK = 2.0           # s simulated between two looks for a steady state
STALL_FRACTION = 0.2         # crank slower than this fraction of the motor's own speed: stalled
STEADY_SIGNALS = ('crank_speed', 'output_speed', 'ratio')


@dataclass(frozen=True)
class OperatingPoint:
    """The steady state a plant model is linearized about (SI units; speeds in rad/s)."""
    crank_length: float          # m (actual, cycle mean)
    load_torque: float           # N·m (constant part in force)
    crank_speed: float           # rad/s: the motor speed ω1 (the crank is on the motor shaft)
    output_speed: float          # rad/s: ω4
    ratio: float                 # ω4/ω1
    efficiency: float            # output work / motor work over the steady window
    motor_power: float           # W
    crank_frequency: float       # Hz: crank turns per second (the cycle means' sample rate)
    settled_at: float            # s: start of the steady window of the settling run
    t: float                     # s: simulated time at which the operating point is taken

    def to_dict(self):
        return {k: float(v) for k, v in asdict(self).items()}


def motor_speed_scale(values):
    """The speed the motor turns the crank at without load [rad/s] (stall is judged against it),
    and the parameter that sets it."""
    model = values['motor.model']
    if model == 'induction':
        return values['motor.synchronous_speed'], 'motor.synchronous_speed'
    if model == 'constant_speed':
        return abs(values['motor.speed']), 'motor.speed'
    return max(abs(values['initial.crank_speed']), 1.0), 'initial.crank_speed'


def _stall_text(values, speed, t):
    scale, name = motor_speed_scale(values)
    a, load = values['linkage.crank_length'], values['load.torque']
    what = {'induction': f"motor.breakdown_torque = {values['motor.breakdown_torque']:g} N·m",
            'constant_torque': f"motor.torque = {values['motor.torque']:g} N·m",
            'constant_speed': f"motor.speed = {values['motor.speed']:g} rad/s"}[
        values['motor.model']]
    return (f"the motor stalls at this operating point: the crank turns at {speed:.3g} rad/s "
            f"after {t:.3g} s, below {STALL_FRACTION:.0%} of {name} = {scale:g} rad/s — "
            f"load.torque = {load:g} N·m at linkage.crank_length = {a:g} m asks more than "
            f"the motor gives ({what}): lower load.torque or linkage.crank_length")


def check_drives(values):
    """Refuse a crank length that drives nothing before anything runs."""
    a = values['linkage.crank_length']
    if not a > 0.0:
        raise DesignError(f"linkage.crank_length = {a:g} m is the neutral crank: the rocker "
                          f"stands still and the clutch never drives the output, so the output "
                          f"speed has no linear dependence on the crank length there; choose an "
                          f"operating point with linkage.crank_length > 0")


def settle(values, settle_time, sample_dt, tolerance, min_cycles):
    """Run the scene ``values`` until the cycle means are steady within ±``tolerance`` for
    ``min_cycles`` turns (at most ``settle_time`` s). Returns (the Simulator there, the
    :class:`OperatingPoint`). Raises DesignError (stall, not driven, not settled) and the core's
    SimulationError."""
    check_drives(values)
    sim = make_simulator(values)
    scale, _ = motor_speed_scale(values)
    kept = []          # the last two chunks' samples (a steady window may span both)
    switches = []
    steady = record = None
    while sim.t < settle_time - 1e-9:
        samples, sw = drive(sim, min(SETTLE_CHUNK, settle_time - sim.t), sample_dt)
        kept = (kept[-1:] + [samples]) if not kept else [kept[-1], samples[1:]]
        switches = [s for s in switches if s.t >= kept[0][0, 0]] + list(sw)
        record = record_of(values, np.concatenate(kept), switches)
        cycles = record.cycles
        recent = cycles['crank_speed'][cycles['t_start'] >= samples[0, 0]]
        speed = float(np.mean(recent)) if len(recent) else float(abs(samples[-1, COL['omega1']]))
        if not len(recent) or abs(speed) < STALL_FRACTION * scale:
            raise DesignError(_stall_text(values, speed, sim.t))
        steady = find_steady_state(cycles, tolerance=tolerance, min_cycles=min_cycles,
                                   signals=STEADY_SIGNALS)
        if steady.found:
            break
    if steady is None or not steady.found:
        why = steady.reason if steady is not None else 'no run'
        raise DesignError(f"no steady state within settle_time = {settle_time:g} s ({why}, "
                          f"relative band ±{tolerance:.2g} over {min_cycles} crank turns): a "
                          f"longer settle_time, or a scene that settles (damping, a load that "
                          f"grows with speed)")
    w = record.cycles.window(steady.first, steady.stop)
    if not abs(w['ratio']) >= DRIVEN_RATIO:
        raise DesignError(
            f"the output is not driven at this operating point (ratio {w['ratio']:.2g}, "
            f"output speed {w['output_speed']:.3g} rad/s): at linkage.crank_length = "
            f"{values['linkage.crank_length']:g} m the clutch holds load.torque = "
            f"{values['load.torque']:g} N·m without turning it, and a small change of the crank "
            f"length moves nothing; choose a longer linkage.crank_length or a smaller load")
    crank_length = float(np.mean(record.cycles['crank_length'][steady.first:steady.stop]))
    point = OperatingPoint(crank_length, float(sim.load_torque), w['crank_speed'],
                           w['output_speed'], w['ratio'], w['efficiency'], w['motor_power'],
                           w['crank_speed'] / (2 * math.pi), steady.t_start, sim.t)
    return sim, point


__all__ = ['OperatingPoint', 'STALL_FRACTION', 'check_drives', 'motor_speed_scale', 'settle']
