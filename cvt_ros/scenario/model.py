"""Scenario files: what a controller test runs — scene, duration, set-point and load schedules,
crank-length command limits, sensor and actuator realism, seed — read and validated in one place.

A scenario file (YAML; every key but ``scene``, ``duration`` and ``setpoint`` optional)::

    description: conveyor set-point steps 55 → 70 → 45 rad/s
    scene: conveyor                  # a scene name, or a path relative to this file
    overrides: {load.torque: 8.0}    # scene parameters by dotted name
    duration: 20.0                   # s of simulated time
    control_period: 0.001            # s: one device step, one controller call
    seed: 1                          # sensor noise
    setpoint: {initial: 55.0, changes: [{at: 2.0, step: 70.0}]}     # output speed ω4* [rad/s]
    load: {changes: [{at: 12.0, step: 14.0}]}                        # load torque [N·m]
    crank_limits: {min: 0.0, max: 0.09, rate: 0.01}                  # m, m, m/s
    sensors: {noise: {position: 1e-4}, counts_per_turn: 4096, delay: 0.002, decimation: 1}
    actuator: {deadband: 0.0, backlash: 0.0}                         # m
    controller: {kp: 1.4e-3, ki: 2.0e-3}                             # the reference controller

Schedules: cvt_ros/scenario/schedule.py. Every error names the file, the key and the value.
"""
from dataclasses import dataclass, field, fields
from pathlib import Path

from ..control.speed_pi import SpeedPIGains, reference_gains
from ..physics.linkage import grashof_bound
from ..scene import SceneError, config_dirs, load_scene, shipped_file
from ..yaml_file import InputFileError, numbers_in, read_yaml
from .checks import number
from .realism import ActuatorSpec, RealismError, SensorSpec, parse_actuator, parse_sensors
from .schedule import Schedule, ScheduleError, parse_schedule

KEYS = ('description', 'scene', 'overrides', 'duration', 'control_period', 'seed', 'setpoint',
        'load', 'crank_limits', 'sensors', 'actuator', 'controller')
#: keys whose values are text, not numbers (a scene named 1e5 stays a name)
TEXT_KEYS = ('description', 'scene', 'file', 'column', 'time_column')
MAX_DURATION = 86400.0          # s
MAX_PERIODS = 100_000_000       # control periods in one run: a day at 1 ms. A run streams
#   (scenario/stream.py): its buffers are one block, its kept trace at most KEEP_PERIODS samples
#   (~0.2 GB); what still grows is the step window under way, 24 B a crank turn (≤ 1 turn a
#   period: ≤ 2.4 GB here, a day of the conveyor's crank 50 MB) — and the time: a day at 1 ms
#   takes 8 min of CPU with the averaged fidelity, ~35 min with the full model
MIN_PERIODS = 2                 # control periods in one run at least (three samples)
SPEED_LIMIT = 1e4               # rad/s: the parameter table's bound on speeds


class ScenarioError(ValueError):
    """A scenario file that cannot be run; the message names the file, the key and the value."""


@dataclass(frozen=True)
class CrankLimits:
    """Limits of the crank-length command [m, m, m/s]; the harness clamps to them."""
    min: float
    max: float
    rate: float


@dataclass(frozen=True, eq=False)
class Scenario:
    path: Path
    scene: Path
    values: dict                       # validated scene parameters (overrides applied)
    duration: float                    # s
    control_period: float              # s
    setpoint: Schedule                 # rad/s
    load: Schedule                     # N·m
    crank_limits: CrankLimits
    sensors: SensorSpec = SensorSpec()
    actuator: ActuatorSpec = ActuatorSpec()
    seed: int = 0
    description: str = ''
    overrides: dict = field(default_factory=dict)
    controller_settings: dict = field(default_factory=dict)

    @property
    def name(self):
        return self.path.stem

    @property
    def periods(self):
        """Control periods in the run."""
        return int(round(self.duration / self.control_period))

    def input_files(self):
        """The files this scenario reads (itself, its scene, its profiles): never an output."""
        profiles = [c.file for s in (self.setpoint, self.load) for c in s.changes if c.file]
        return [str(self.path), str(self.scene), *profiles]

    def time_grid(self):
        """Start times of the control periods and the end: k·period, k = 0..periods [s]."""
        import numpy as np
        return np.arange(self.periods + 1) * self.control_period


def scenario_dirs():
    return config_dirs('scenarios')


def available_scenarios():
    return sorted({p.stem for d in scenario_dirs() for p in d.glob('*.yaml')})


def resolve_scenario(name):
    """A path, or a shipped scenario's name (config/scenarios/NAME.yaml)."""
    p = Path(name)
    try:
        if p.is_file():
            return p
    except (OSError, ValueError):
        pass
    found = shipped_file('scenarios', name)
    if found is not None:
        return found
    raise ScenarioError(f"scenario {str(name)!r} not found: not a file, and not one of "
                        f"{', '.join(available_scenarios()) or '(none installed)'}")


def _number(doc, key, low, high, default, where, integer=False, open_low=False):
    return number(doc.get(key, default), f"{where}: {key}", low, high, open_low=open_low,
                  integer=integer, error=ScenarioError)


def load_scenario(path, overrides=None):
    """The validated :class:`Scenario` of a file (or a shipped scenario's name). ``overrides``:
    scenario keys replaced before validation (``{'duration': 5.0}``: a shorter duration drops
    the changes after it instead of refusing them). Raises ScenarioError."""
    path = resolve_scenario(path)
    try:
        doc = read_yaml(path)
    except InputFileError as exc:
        raise ScenarioError(str(exc)) from None
    if not isinstance(doc, dict):
        raise ScenarioError(f"{path}: expected a map of scenario keys ({', '.join(KEYS)}), got "
                            f"{type(doc).__name__}")
    overrides = dict(overrides or {})
    doc = numbers_in(dict(doc, **overrides), TEXT_KEYS)   # (1e-3 is a number, as in scene files)
    where = str(path)
    unknown = [k for k in doc if k not in KEYS]
    if unknown:
        import difflib
        close = difflib.get_close_matches(str(unknown[0]), KEYS, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ''
        # an override's typo is the caller's, not the file's
        blamed = f"override of {path}" if unknown[0] in overrides else where
        raise ScenarioError(f"{blamed}: unknown key {unknown[0]!r}{hint}; allowed: "
                            f"{', '.join(KEYS)}")
    for need in ('scene', 'duration', 'setpoint'):
        if need not in doc:
            raise ScenarioError(f"{where}: {need}: missing")
    duration = _number(doc, 'duration', 0.0, MAX_DURATION, None, where, open_low=True)
    period = _number(doc, 'control_period', 1e-5, 0.1, 1e-3, where)
    if duration / period > MAX_PERIODS:
        raise ScenarioError(f"{where}: duration: {duration:g} s is {duration / period:.3g} "
                            f"control periods, more than {MAX_PERIODS:g} (a day at 1 ms): a "
                            f"longer control_period or a shorter duration")
    if duration < MIN_PERIODS * period * (1.0 - 1e-9):   # (the step metrics need samples)
        raise ScenarioError(f"{where}: duration: {duration:g} s is shorter than "
                            f"{MIN_PERIODS} control periods ({period:g} s each)")
    if abs(duration / period - round(duration / period)) > 1e-6:
        raise ScenarioError(f"{where}: duration: {duration:g} s is not a whole number of "
                            f"control periods ({period:g} s)")
    seed = _number(doc, 'seed', 0, 2 ** 63 - 1, 0, where, integer=True)
    description = doc.get('description', '')
    if not isinstance(description, str):
        raise ScenarioError(f"{where}: description: expected text, got {description!r}")

    scene_overrides = doc.get('overrides') or {}
    if not isinstance(scene_overrides, dict):
        raise ScenarioError(f"{where}: overrides: expected a map of scene parameters (dotted "
                            f"names), got {scene_overrides!r}")
    scene = doc['scene']
    if not isinstance(scene, str):
        raise ScenarioError(f"{where}: scene: expected a scene name or path, got {scene!r}")
    scene_path = path.parent / scene
    scene_ref = scene_path if scene_path.is_file() else scene
    try:
        values = load_scene(scene_ref, scene_overrides)
        from ..scene import resolve
        scene_file = resolve(scene_ref)
    except SceneError as exc:
        raise ScenarioError(f"{where}: scene/overrides: {exc}") from None

    base = path.parent
    cut = 'duration' in (overrides or {})     # shortened on purpose: later changes are dropped
    try:
        setpoint = parse_schedule(doc['setpoint'], 'setpoint', duration, None,
                                  (-SPEED_LIMIT, SPEED_LIMIT), 'rad/s', base, cut)
        limit = values['limits.load_torque']
        load = parse_schedule(doc.get('load') or {}, 'load', duration, values['load.torque'],
                              (-limit, limit), 'N*m', base, cut)
        sensors = parse_sensors(doc.get('sensors'), 'sensors', period)
        actuator = parse_actuator(doc.get('actuator'), 'actuator')
    except (ScheduleError, RealismError) as exc:
        raise ScenarioError(f"{where}: {exc}") from None
    limits = _crank_limits(doc.get('crank_limits'), values, where)
    settings = _controller_settings(doc.get('controller'), limits, where)
    return Scenario(path, scene_file, values, duration, period, setpoint, load, limits, sensors,
                    actuator, seed, description, dict(scene_overrides), settings)


def _crank_limits(body, values, where):
    bound = grashof_bound(values['linkage.rocker_length'], values['linkage.coupler_length'],
                          values['linkage.pivot_distance'])
    body = body or {}
    if not isinstance(body, dict):
        raise ScenarioError(f"{where}: crank_limits: expected a map {{min, max, rate}}")
    for k in body:
        if k not in ('min', 'max', 'rate'):
            raise ScenarioError(f"{where}: crank_limits: unknown key {k!r}; allowed: min, max, "
                                f"rate")
    w = f"{where}: crank_limits"
    hi = _number(body, 'max', 0.0, bound, 0.9 * bound, w)
    if hi >= bound:
        raise ScenarioError(f"{w}: max: {hi:g} m must stay below the Grashof bound {bound:g} m")
    lo = _number(body, 'min', 0.0, hi, 0.0, w)
    if not hi > lo:   # (a controller test needs a crank that can move)
        raise ScenarioError(f"{w}: max: {hi:g} m must be above min {lo:g} m")
    rate = _number(body, 'rate', 0.0, 10.0, values['linkage.crank_rate_limit'], w,
                   open_low=True)
    return CrankLimits(lo, hi, rate)


def _controller_settings(body, limits, where):
    body = body or {}
    if not isinstance(body, dict):
        raise ScenarioError(f"{where}: controller: expected a map of reference controller "
                            f"settings")
    names = [f.name for f in fields(SpeedPIGains)]
    for k in body:
        if k not in names:
            raise ScenarioError(f"{where}: controller: unknown setting {k!r}; allowed: "
                                f"{', '.join(names)}")
    try:
        SpeedPIGains(**body).check()
    except ValueError as exc:
        raise ScenarioError(f"{where}: controller.{exc}") from None
    try:   # the settings as the reference controller takes them: within the crank limits
        reference_gains(body, limits)
    except ValueError as exc:
        raise ScenarioError(f"{where}: controller/crank_limits: the reference controller's "
                            f"{exc} (within crank_limits [{limits.min:g}, {limits.max:g}] m)"
                            ) from None
    return dict(body)
