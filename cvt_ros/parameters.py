"""Every parameter of a scene: dotted name, SI unit, default, range, meaning. The one place that
knows parameter names; the scene loader, the CLI's ``--set``, the node's declared ROS parameters
(with descriptors) and the physics parameter vector are all built from this table.

Defaults are the paper's Fig. 2/3 scene (physics.md §6).
"""
import array
import difflib
import math
from dataclasses import dataclass

import numpy as np

from .numbers import NotANumber, real_number
from .physics import layout as L
from .physics.linkage import GrashofError, check_crank_length, grashof_bound
from .physics.paths import MAX_PATHS


class ParameterError(ValueError):
    """A parameter value the physics cannot take; the message names the value and the limit."""

    def __init__(self, name, message):
        super().__init__(f"{name}: {message}")
        self.name = name


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter: name, default, SI unit, meaning and the values it may take.

    Numbers have finite bounds wherever the physics has none of its own: the model is meant for
    drives of this class (inertias of grams·cm² to tonnes·m², torques up to 100 kN·m, speeds up to
    10⁴ rad/s), and a value beyond them (1e300 N·m, a denormal inertia) is an input error, not a
    machine. ``min_positive``: 0 is a meaningful degenerate case (a massless node) but the
    smallest positive value accepted is ``min_positive``; ``allow_inf``: +inf is meaningful (a
    rigid shaft); ``high_name``: the upper bound depends on other parameters (the crank's Grashof
    bound) and is checked by ``validate``.
    """
    name: str
    default: object
    unit: str
    description: str
    low: float = -math.inf      # inclusive bounds for numbers
    high: float = math.inf
    low_open: bool = False      # True: value must be > low
    choices: tuple = ()         # allowed strings (or ints) when not empty
    allow_inf: bool = False     # +inf is a meaningful value (rigid shaft)
    min_positive: float = 0.0   # > 0: values in (0, min_positive) are refused (denormals)
    max_length: int = 4096      # strings: longest accepted
    high_name: str = ''         # names an upper bound that other parameters set

    def range_text(self, high=None):
        """The accepted values as a person reads them: ``[0.001, 10]``, ``0 or [1e-09, 1000]``;
        ``high``: the value of a ``high_name`` bound where it is known (the Grashof bound of a
        geometry: ``[0, 0.1)``)."""
        if self.choices:
            return f"one of {list(self.choices)}"
        if isinstance(self.default, str):
            return f"text of at most {self.max_length} characters"
        if isinstance(self.default, tuple):
            return (f"[] or a list of numbers in [{number_text(self.low)}, "
                    f"{number_text(self.high)}]")
        low = self.min_positive or self.low
        high = (number_text(high) if high is not None
                else self.high_name or number_text(self.high))
        text = (f"{'(' if self.low_open else '['}{number_text(low)}, {high}"
                f"{')' if math.isinf(self.high) else ']'}")
        if self.min_positive:
            text = f"0 or {text}"
        if self.allow_inf:
            text += " or .inf"
        return text

    def contains(self, value):
        """True when the number ``value`` (already a float or int) is in range."""
        if 0 < value < self.min_positive:
            return False
        if self.allow_inf and value == math.inf:
            return True
        if not math.isfinite(value):
            return False
        return not (value < self.low or (self.low_open and value <= self.low)
                    or value > self.high)

    def check(self, value, high=None):
        """Coerce ``value`` to this parameter's type or raise ParameterError with the reason;
        ``high``: the value of a ``high_name`` bound, for the reason's text."""
        if self.choices:
            if isinstance(self.default, int) and not isinstance(value, bool):
                if isinstance(value, float) and value.is_integer():
                    value = int(value)
            if value not in self.choices:
                raise ParameterError(self.name, f"{_short(value)} is not one of "
                                                f"{list(self.choices)}")
            return value
        if isinstance(self.default, str):
            if not isinstance(value, str):
                raise ParameterError(self.name, f"expected text, got {_short(value)}")
            if len(value) > self.max_length or '\x00' in value:
                raise ParameterError(self.name, f"text of {len(value)} characters is not "
                                                f"accepted: {self.range_text()}, no NUL")
            return value
        if isinstance(self.default, tuple):
            return self._check_list(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(self.name, f"expected a number [{self.unit}], got "
                                            f"{_short(value)}")
        unit = '' if self.unit == '-' else f" {self.unit}"
        try:
            number = real_number(value)
        except NotANumber:   # an integer literal beyond the float range
            raise ParameterError(self.name, f"{_short(value)}{unit} is beyond any float; "
                                            f"accepted: {self.range_text(high)}") from None
        if isinstance(self.default, int):
            if isinstance(value, float) and not value.is_integer():
                raise ParameterError(self.name, f"expected a whole number, got {value!r}")
            if not self.contains(number):
                raise ParameterError(self.name, f"{_short(value)}{unit} is outside "
                                                f"{self.range_text(high)}")
            return int(value)
        if math.isnan(number) or (math.isinf(number) and not (self.allow_inf and number > 0)):
            raise ParameterError(self.name, f"{number!r} is not a finite number [{self.unit}]; "
                                            f"accepted: {self.range_text(high)}")
        if not self.contains(number):
            raise ParameterError(self.name, f"{number_text(number)}{unit} is outside "
                                            f"{self.range_text(high)}")
        return number


    def _check_list(self, value):
        """A list of numbers (a ROS double array) → a tuple of floats, each finite and in range.
        None is the empty list (what ROS makes of ``[]`` in a params file: no type to infer)."""
        if value is None:
            return ()
        if isinstance(value, array.array):   # what rclpy gives for a double array
            value = value.tolist()
        if not isinstance(value, (list, tuple)):
            raise ParameterError(self.name, f"expected a list of numbers [{self.unit}] (e.g. "
                                            f"[0, 3.14159]), got {_short(value)}")
        if len(value) > 64:
            raise ParameterError(self.name, f"a list of {len(value)} values is not accepted")
        out = []
        for i, item in enumerate(value):
            if isinstance(item, bool) or not isinstance(item, (int, float)):
                raise ParameterError(self.name, f"item {i} {_short(item)} is not a number")
            try:
                number = float(item)
            except OverflowError:
                number = math.inf
            if not (math.isfinite(number) and self.low <= number <= self.high):
                raise ParameterError(self.name, f"item {i} {_short(item)} {self.unit} is "
                                                f"outside [{number_text(self.low)}, "
                                                f"{number_text(self.high)}] (finite)")
            out.append(number)
        return tuple(out)


def number_text(x):
    """A number as short as reads back exactly: ``0.1``, ``1e-09``, ``0.10000000000000002``."""
    if math.isinf(x):
        return 'inf' if x > 0 else '-inf'
    short = f"{x:g}"
    return short if float(short) == x else repr(float(x))


def _short(value, limit=60):
    """A value for an error message, cut to ``limit`` characters (a 400-digit literal, a list)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters)"


def _spec(name, default, unit, description, **kw):
    return ParameterSpec(name, default, unit, description, **kw)


PHYSICS_PARAMETERS = (
    _spec('linkage.crank_length', 0.03, 'm', 'crank O1A length a: sets the ratio (0 = neutral); '
          'shorter than the Grashof bound min(b, d, h, b + d + h − 2·max(b, d, h))',
          low=0.0, high_name='Grashof bound'),
    _spec('linkage.rocker_length', 0.10, 'm', 'rocker O2B length b', low=1e-3, high=10.0),
    _spec('linkage.coupler_length', 0.20, 'm', 'coupler AB length d', low=1e-3, high=10.0),
    _spec('linkage.pivot_distance', 0.20, 'm', 'frame O1O2 length h', low=1e-3, high=10.0),
    _spec('linkage.assembly_mode', 1, '-', 'branch σ of the closed-form rocker angle',
          choices=(1, -1)),
    _spec('linkage.crank_rate_limit', 0.01, 'm/s', 'crank-length actuator speed limit',
          low=1e-6, high=10.0),
    _spec('linkage.crank_accel_limit', 1.0, 'm/s^2',
          'crank-length actuator acceleration limit (keeps the rocker speed continuous)',
          low=1e-6, high=1e4),
    _spec('inertia.motor', 0.05, 'kg*m^2', 'J1: motor, flywheel and crank', low=1e-6, high=1e4),
    _spec('inertia.rocker', 0.002, 'kg*m^2', 'J2: rocker and driving parts of the clutch',
          low=0.0, high=1e3, min_positive=1e-9),
    _spec('inertia.clutch_driven', 0.001, 'kg*m^2',
          'J3: driven parts of the clutch, shaft input end (0 = massless node)',
          low=0.0, high=1e3, min_positive=1e-9),
    _spec('inertia.output', 0.5, 'kg*m^2', 'J4: driven shaft and everything after it',
          low=1e-6, high=1e4),
    _spec('shaft.stiffness', 500.0, 'N*m/rad', 'torsion shaft stiffness c (.inf = rigid shaft)',
          low=1.0, high=1e9, allow_inf=True),
    _spec('shaft.damping', 0.0, 'N*m*s/rad', 'torsion shaft damping', low=0.0, high=1e5),
    _spec('motor.model', 'induction', '-', 'induction (Kloss) | constant_torque | constant_speed',
          choices=('induction', 'constant_torque', 'constant_speed')),
    _spec('motor.torque', 10.0, 'N*m', 'torque of the constant_torque motor',
          low=-1e5, high=1e5),
    _spec('motor.speed', 150.0, 'rad/s', 'speed of the constant_speed (ideal) source',
          low=-1e4, high=1e4),
    _spec('motor.synchronous_speed', 157.08, 'rad/s', 'induction motor synchronous speed ω0',
          low=1.0, high=1e4),
    _spec('motor.breakdown_torque', 40.0, 'N*m', 'induction motor breakdown torque Mk',
          low=1e-3, high=1e5),
    _spec('motor.breakdown_slip', 0.2, '-', 'induction motor breakdown slip sk',
          low=1e-4, high=1.0),
    _spec('load.torque', 5.0, 'N*m', 'constant load torque on the output (positive pulls back)',
          low=-1e5, high=1e5),
    _spec('load.viscous', 0.0, 'N*m*s/rad', 'viscous load coefficient', low=0.0, high=1e4),
    _spec('load.quadratic', 0.0, 'N*m*s^2/rad^2', 'quadratic (mixer) load coefficient',
          low=0.0, high=1e3),
    _spec('clutch.release', 'torque', '-',
          'release rule: torque (clutch torque falls to 0) | twist (paper: twist falls to 0)',
          choices=('torque', 'twist')),
    _spec('model.formulation', 'reduced', '-',
          'reduced (closed-form linkage) | paper (index-reduced DAE, eqs. 9, 11, 12)',
          choices=('reduced', 'paper')),
    _spec('model.fidelity', 'full', '-',
          'full (4-inertia hybrid) | rigid_shaft (J3 and J4 lumped) | averaged (mean motion '
          'through a calibrated ratio map, for long runs)',
          choices=('full', 'rigid_shaft', 'averaged')),
    _spec('model.baumgarte', 200.0, '1/s', 'constraint stabilization rate of the paper formulation',
          low=0.0, high=1e6),
    _spec('paths.count', 1, '-',
          'N: crank-rocker paths on the one crank, each with its own one-way clutch on the '
          'common driven member J3 (1 = the paper\'s machine; docs/physics.md §9)',
          low=1.0, high=MAX_PATHS),
    _spec('paths.phase_offsets', (), 'rad',
          'phase offset of each path\'s crank: path k runs at φ1 + δ_k; N increasing values '
          'within one turn; [] = 2π·(k − 1)/N',
          low=-7.0, high=13.0),
    _spec('initial.crank_speed', 150.0, 'rad/s', 'crank speed ω1 at t = 0', low=-1e4, high=1e4),
    _spec('solver.method', 'dopri5', '-',
          'dopri5 (adaptive, event-located) | rk4 (fixed step, events located inside the step)',
          choices=('dopri5', 'rk4')),
    # defaults: φ4 within ~1e-7 (relative) of a 1e-12 reference after 10 s of the paper scene,
    # switch times within ~1e-7 s; rtol 1e-8 brings the switch times within 1e-9 s (BENCHMARKS.md)
    _spec('solver.rtol', 2e-6, '-', 'relative tolerance of dopri5', low=1e-14, high=1e-2),
    _spec('solver.atol', 2e-8, '-', 'absolute tolerance of dopri5', low=1e-16, high=1.0),
    _spec('solver.max_step', 0.01, 's', 'largest step of dopri5', low=1e-9, high=10.0),
    _spec('solver.output_subsystem', 'exact', '-',
          'exact: the open clutch\'s linear output (J3, shaft, J4) is solved in closed form; '
          'integrate: on its own adaptive clock (always so for a quadratic load)',
          choices=('exact', 'integrate')),
    _spec('solver.refine_step', 'auto', '-',
          'auto: rk4 sub-steps until h·λmax ≤ 0.5, λmax the fastest rate it must resolve (shaft '
          'modes, crank speed, the linkage\'s inertia rate); '
          'off: exactly solver.fixed_step (for stability experiments: may blow up)',
          choices=('auto', 'off')),
    _spec('solver.fixed_step', 2e-4, 's',
          'largest sub-step of rk4 (the step is refined further if the shaft mode needs it)',
          low=1e-9, high=0.1),
)

# The node's own parameters (cvt_ros/node.py). They live here, free of rclpy, so that one scene
# file can carry them and still configure the offline CLI, which ignores them.
TIME_MODES = ('realtime', 'fast', 'lockstep')
NODE_PARAMETERS = (
    _spec('time_mode', 'realtime', '-',
                  'realtime (wall clock x real_time_factor) | fast (as fast as possible, '
                  'publishing /clock) | lockstep (advances only on ~/step or steps_per_command)',
                  choices=TIME_MODES),
    _spec('real_time_factor', 1.0, '-',
                  'realtime mode: simulated seconds per wall-clock second',
                  low=0.0, high=1000.0, low_open=True),
    _spec('publish_rate', 1000.0, 'Hz',
                  'samples per simulated second; the control period (one physics step, one '
                  'joint_states sample) is 1/publish_rate of simulation time',
                  low=0.0, high=100000.0, low_open=True),
    _spec('realtime_priority', 50, '-',
                  'realtime mode: SCHED_FIFO priority of the simulation loop thread (Linux; '
                  '0 = normal scheduling); without the permission it runs normally, with a '
                  'warning', low=0.0, high=99.0),
    _spec('steps_per_command', 0, '-',
                  'lockstep mode: control periods each crank_length_cmd message advances (0 = '
                  'only ~/step; load_torque_cmd never advances time)',
                  low=0.0, high=1e9),
    _spec('step_periods', 1, '-',
                  'control periods one ~/step call advances (lockstep or paused)',
                  low=1.0, high=1e9),
    _spec('publish_clock', True, '-',
                  'publish /clock (the node is the time source); turn off for all but one '
                  'transmission when several share a ROS graph',
                  choices=(True, False)),
    _spec('limits.load_torque', 1000.0, 'N*m',
                  'largest |load_torque_cmd| accepted; larger commands are refused',
                  low=0.0, high=1e5, low_open=True),
    _spec('disturbance.file', '', '-',
                  'CSV of load torque steps t,load_torque [s, N*m], each applied at the start of '
                  'the first control period k with k*(1/publish_rate) >= t (reproducible '
                  'lockstep disturbances; docs/lockstep.md); empty = none'),
    _spec('joint_prefix', '', '-',
                  'prefix of the joint names in joint_states (e.g. line1_)', max_length=256),
    _spec('record.path', '', '-',
                  'MCAP file to record published and received messages to (empty = off)'),
)

SPECS = {s.name: s for s in PHYSICS_PARAMETERS + NODE_PARAMETERS}
AVERAGED_MIN_SPEED = 1.0   # rad/s: slowest nominal crank speed of the averaged fidelity's map


def register(*specs):
    """Add parameters of another layer (the node, the recorder) to the table."""
    for s in specs:
        SPECS[s.name] = s


def defaults():
    return {name: spec.default for name, spec in SPECS.items()}


def validate(values):
    """Complete ``values`` (dotted name → value) with defaults, coerce and check every entry.

    Unknown names raise ParameterError naming the valid ones. Cross-parameter checks (Grashof,
    the paper formulation's needs) raise ParameterError / GrashofError with value and limit.
    """
    out = defaults()
    bounded = []    # checked once the geometry that sets their bound is known
    for name, value in values.items():
        if name not in SPECS:
            close = difflib.get_close_matches(name, list(SPECS), n=1)
            known = (f"did you mean {close[0]}? (`cvt-sim params` lists every name)" if close
                     else f"valid: {', '.join(sorted(SPECS))}")
            raise ParameterError(name, f"unknown parameter; {known}")
        if SPECS[name].high_name:
            bounded.append(name)
        else:
            out[name] = SPECS[name].check(value)
    for name in bounded:   # (the crank length: its range's text gives the Grashof bound)
        out[name] = SPECS[name].check(values[name], high=grashof_bound(
            out['linkage.rocker_length'], out['linkage.coupler_length'],
            out['linkage.pivot_distance']))
    try:
        check_crank_length(out['linkage.crank_length'], out['linkage.rocker_length'],
                           out['linkage.coupler_length'], out['linkage.pivot_distance'])
    except GrashofError as exc:
        raise GrashofError(f"linkage.crank_length: {exc}", exc.value, exc.limit) from None
    if out['model.formulation'] == 'paper' and out['inertia.rocker'] <= 0.0:
        raise ParameterError('inertia.rocker', 'the paper formulation needs J2 > 0 (it divides by '
                             'the rocker inertia); use model.formulation: reduced')
    if out['model.fidelity'] == 'averaged' and out['motor.model'] == 'constant_speed' \
            and not out['motor.speed'] >= AVERAGED_MIN_SPEED:
        # (its ratio map is made of whole forward crank turns at the nominal speed)
        raise ParameterError('motor.speed', f"{out['motor.speed']:g} rad/s: the averaged "
                             f"fidelity needs a crank turning forward at ≥ "
                             f"{AVERAGED_MIN_SPEED:g} rad/s; use model.fidelity: full")
    _check_paths(out)
    return out


# what the N-path machine does not do, with the reason (docs/physics.md §9)
_ONE_PATH_ONLY = (
    ('model.formulation', 'paper', "the paper's DAE (eqs. 9, 11) is written for one path; "
     "N paths run the reduced formulation (model.formulation: reduced)"),
    ('clutch.release', 'twist', "the paper's twist rule releases the one clutch the shaft "
     "carries; with N paths the clutches share the twist, so each releases by its own torque "
     "(clutch.release: torque)"),
    ('model.fidelity', 'averaged', "the averaged model's ratio map is calibrated on one path; "
     "run N paths with model.fidelity full or rigid_shaft"),
)


def _check_paths(values):
    """paths.phase_offsets against paths.count; what N ≥ 2 does not support."""
    n = values['paths.count']
    offsets = values['paths.phase_offsets']
    if offsets:
        if len(offsets) != n:
            raise ParameterError('paths.phase_offsets', f"{len(offsets)} values for "
                                 f"paths.count = {n}: give one per path, or [] for 2π·(k − 1)/N")
        for i in range(1, n):
            if not offsets[i] > offsets[i - 1]:
                raise ParameterError('paths.phase_offsets', f"values must increase: item {i} "
                                     f"({offsets[i]!r}) is not above item {i - 1} "
                                     f"({offsets[i - 1]!r})")
        if offsets[-1] - offsets[0] >= 2.0 * math.pi:
            raise ParameterError('paths.phase_offsets', f"the offsets span "
                                 f"{offsets[-1] - offsets[0]!r} rad, not less than one turn "
                                 f"(2π = {2.0 * math.pi!r} rad): two paths would coincide")
    if n >= 2:
        for name, value, reason in _ONE_PATH_ONLY:
            if values[name] == value:
                raise ParameterError(name, f"{value} is not available with paths.count = {n}: "
                                           f"{reason}")


def phase_offsets(values):
    """Each path's phase offset δ_k [rad] of validated values (the default 2π·(k − 1)/N)."""
    n = values['paths.count']
    return tuple(values['paths.phase_offsets']) or tuple(2.0 * math.pi * k / n for k in range(n))


def parameter_vector(values):
    """The physics parameter vector P (layout.P_*) from validated values."""
    v = values
    P = np.zeros(L.N_PARAMS)
    P[L.P_A] = v['linkage.crank_length']
    P[L.P_B] = v['linkage.rocker_length']
    P[L.P_D] = v['linkage.coupler_length']
    P[L.P_H] = v['linkage.pivot_distance']
    P[L.P_SIGMA] = v['linkage.assembly_mode']
    P[L.P_J1] = v['inertia.motor']
    P[L.P_J2] = v['inertia.rocker']
    P[L.P_J3] = v['inertia.clutch_driven']
    P[L.P_J4] = v['inertia.output']
    rigid = math.isinf(v['shaft.stiffness']) or v['model.fidelity'] == 'rigid_shaft'
    P[L.P_C] = 0.0 if rigid else v['shaft.stiffness']
    P[L.P_RIGID] = 1.0 if rigid else 0.0
    P[L.P_KD] = v['shaft.damping']
    P[L.P_MOTOR_MODEL] = {'induction': L.MOTOR_INDUCTION, 'constant_torque':
                          L.MOTOR_CONSTANT_TORQUE, 'constant_speed': L.MOTOR_CONSTANT_SPEED}[
        v['motor.model']]
    P[L.P_MOTOR_TORQUE] = v['motor.torque']
    P[L.P_MOTOR_SPEED] = v['motor.speed']
    P[L.P_W0] = v['motor.synchronous_speed']
    P[L.P_MK] = v['motor.breakdown_torque']
    P[L.P_SK] = v['motor.breakdown_slip']
    P[L.P_LOAD_TORQUE] = v['load.torque']
    P[L.P_LOAD_VISCOUS] = v['load.viscous']
    P[L.P_LOAD_QUADRATIC] = v['load.quadratic']
    P[L.P_RELEASE] = L.RELEASE_TORQUE if v['clutch.release'] == 'torque' else L.RELEASE_TWIST
    P[L.P_FORMULATION] = (L.FORMULATION_PAPER if v['model.formulation'] == 'paper'
                          else L.FORMULATION_REDUCED)
    P[L.P_BAUMGARTE] = v['model.baumgarte']
    P[L.P_TORQUE_SCALE] = max(1.0, abs(v['load.torque']), v['motor.breakdown_torque'],
                              abs(v['motor.torque']))
    return P
