"""Campaign files: what a sweep runs — a base scene or scenario, the parameters to vary and how,
the run settings and the metrics to keep — read and checked before any case runs.

A campaign file (YAML; docs/sweeps.md has the full reference)::

    name: conveyor_ratio_map
    scene: conveyor                  # or  scenario: conveyor_setpoint_steps
    overrides: {solver.method: dopri5}        # fixed scene parameters of every case
    duration: 8.0                    # s simulated per case (a scenario has its own)
    vary:                            # one axis per parameter
      linkage.crank_length: {range: [0.01, 0.09], num: 9}     # m
      load.torque: [0.0, 4.0, 8.0, 12.0]                      # N·m, a list
    sampling: grid                   # grid | random | latin_hypercube (with samples:, seed:)
    metrics: [mean_ratio, efficiency, peak_clutch_torque, switches_per_second, energy_residual]

Every value is checked where it is read, by the parameter table's own spec (unit, bounds): a bad
file is one :class:`CampaignError` naming the file, the key, the value and the limit. Cases are
expanded and checked as a whole (the Grashof bound, a scenario's schedules) by
:mod:`cvt_ros.sweep.cases`.
"""
import difflib
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from .. import parameters
from ..control.speed_pi import SpeedPIGains
from ..scenario.checks import number
from ..scene import _yaml_number as yaml_number  # '1e-3' is a number, as ROS reads it
from ..yaml_file import InputFileError, read_yaml
from .metrics import SCENARIO_METRICS, SCENE_METRICS, default_metrics

KEYS = ('name', 'description', 'scene', 'scenario', 'overrides', 'controller', 'duration',
        'sample_dt', 'window', 'vary', 'cases', 'sampling', 'samples', 'seed', 'metrics',
        'time_budget', 'record', 'summary')
SAMPLINGS = ('grid', 'random', 'latin_hypercube')
RECORD_FORMATS = ('none', 'csv', 'mcap')
SCALES = ('linear', 'log')
MAX_DURATION = 86400.0          # s per case
MAX_AXIS = 1_000_000            # values on one grid axis
HARD_MAX_CASES = 10_000_000     # cases in one campaign, --yes or not (the table lives in memory)
DEFAULT_TIME_BUDGET = 600.0     # s of wall time per case
SIGNIFICANT = 12                # digits kept of a generated value (0.060000000000000005 → 0.06)
SCENE_NAMES = tuple(s.name for s in parameters.PHYSICS_PARAMETERS)
GAIN_NAMES = tuple(f.name for f in fields(SpeedPIGains))


class CampaignError(InputFileError):
    """A campaign that cannot be run; the message names the file, the key, the value and why."""


@dataclass(frozen=True)
class Variable:
    """One varied parameter: a list of ``values``, or a ``range`` [low, high] (``num`` points on
    a grid, linear or log ``scale``; drawn uniformly in random and Latin hypercube sampling)."""
    name: str
    values: tuple = ()
    low: float = math.nan
    high: float = math.nan
    num: int = 0
    scale: str = 'linear'

    @property
    def target(self):
        """'controller' (a reference-controller setting) or 'scene' (a scene parameter)."""
        return 'controller' if self.name.startswith('controller.') else 'scene'

    @property
    def key(self):
        """The name inside its target: ``kp`` for ``controller.kp``."""
        return self.name.partition('.')[2] if self.target == 'controller' else self.name

    @property
    def numeric(self):
        return not self.values or all(_is_number(v) for v in self.values)

    def grid(self):
        """The axis of a grid: the list, or ``num`` points from low to high."""
        if self.values:
            return list(self.values)
        if self.num == 1:
            return [self.low]
        return [self.at(k / (self.num - 1)) for k in range(self.num)]

    def at(self, u):
        """The value at fraction u ∈ [0, 1] of the range (or of the list)."""
        if self.values:
            return self.values[min(int(u * len(self.values)), len(self.values) - 1)]
        if self.scale == 'log':
            x = math.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low)))
        else:
            x = self.low + u * (self.high - self.low)
        return rounded(min(max(x, self.low), self.high))


@dataclass(frozen=True, eq=False)
class Campaign:
    path: Path
    name: str
    text: str                        # the file as read (kept in the results table)
    kind: str                        # 'scene' | 'scenario'
    base: str                        # scene or scenario name/path (relative to the file's folder)
    overrides: dict = field(default_factory=dict)     # fixed scene parameters
    controller: str = None           # MODULE:FACTORY (scenario); None: the reference controller
    duration: float = None           # s (None: the scenario's own)
    sample_dt: float = 1e-3          # s (scene campaigns: the sample grid of the metrics)
    window: object = 'steady'        # 'steady' | start time [s] of the metric window
    variables: tuple = ()
    cases: tuple = ()                # explicit cases (maps name → value), instead of vary
    sampling: str = 'grid'
    samples: int = 0
    seed: int = 0
    metrics: tuple = ()
    time_budget: float = DEFAULT_TIME_BUDGET
    record: str = 'none'
    summary: dict = field(default_factory=dict)
    description: str = ''

    @property
    def variable_names(self):
        if self.cases:
            return tuple(dict.fromkeys(k for case in self.cases for k in case))
        return tuple(v.name for v in self.variables)

    def case_count(self):
        """Cases this campaign expands to (a grid's product, without expanding it)."""
        if self.cases:
            return len(self.cases)
        if self.sampling != 'grid':
            return self.samples
        count = 1
        for v in self.variables:
            count *= len(v.values) if v.values else v.num
        return count


def rounded(x):
    """A generated number with SIGNIFICANT digits: the same text in the table on every machine."""
    return float(f"{x:.{SIGNIFICANT}g}")


def _shown(value):
    """A value for a message: numbers as written (inf, 1e-05), anything else quoted and cut."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value!r}"
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:60]}…"


def _is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _unknown(where, key, allowed):
    close = difflib.get_close_matches(str(key), allowed, n=1)
    hint = f" (did you mean {close[0]}?)" if close else ''
    return CampaignError(f"{where}: unknown key {str(key)[:80]!r}{hint}; allowed: "
                         f"{', '.join(allowed)}")


def _number(doc, key, where, low, high, default=None, integer=False, open_low=False):
    value = doc.get(key, default)
    if value is None:
        raise CampaignError(f"{where}: {key}: missing")
    return number(value, f"{where}: {key}", low, high, open_low=open_low, integer=integer,
                  error=CampaignError)


def _choice(doc, key, where, choices, default):
    value = doc.get(key, default)
    if value not in choices:
        raise CampaignError(f"{where}: {key}: {_shown(value)} is not one of "
                            f"{', '.join(choices)}")
    return value


def check_value(name, value, where):
    """One value of a varied or fixed parameter, checked by its spec; the coerced value."""
    if name.startswith('controller.'):
        setting = name.partition('.')[2]
        if not _is_number(value) or not math.isfinite(value):
            raise CampaignError(f"{where}: {name}: {_shown(value)} is not a finite number")
        try:   # the setting's own bounds (≥ 0, > 0); crank_min < crank_max is checked per case
            SpeedPIGains(**{setting: value}).check()
        except ValueError as exc:
            if str(exc).startswith(f"{setting}:"):
                raise CampaignError(f"{where}: controller.{exc}") from None
        return float(value)
    try:
        return parameters.SPECS[name].check(value)
    except parameters.ParameterError as exc:
        raise CampaignError(f"{where}: {exc}") from None


def check_name(name, where, kind, controller):
    """A variable's name: a physics parameter, or controller.<setting> of the reference
    controller in a scenario campaign."""
    name = str(name)
    if name.startswith('controller.'):
        setting = name.partition('.')[2]
        if kind != 'scenario' or controller is not None:
            raise CampaignError(f"{where}: {name}: controller settings vary the reference "
                                f"controller of a scenario campaign (scenario: …, no "
                                f"controller: key)")
        if setting not in GAIN_NAMES:
            close = difflib.get_close_matches(setting, GAIN_NAMES, n=1)
            hint = f"did you mean controller.{close[0]}? " if close else ''
            raise CampaignError(f"{where}: {name}: unknown controller setting; {hint}allowed: "
                                f"{', '.join('controller.' + g for g in GAIN_NAMES)}")
        return name
    if name in parameters.SPECS and name not in SCENE_NAMES:
        raise CampaignError(f"{where}: {name}: a node parameter; it changes nothing in an "
                            f"offline case (vary physics, model or solver parameters)")
    if name not in SCENE_NAMES:
        close = difflib.get_close_matches(name, SCENE_NAMES + tuple(
            'controller.' + g for g in GAIN_NAMES), n=1)
        hint = f"did you mean {close[0]}? " if close else ''
        raise CampaignError(f"{where}: {name[:80]!r}: unknown parameter; {hint}(`cvt-sim params` "
                            f"lists the scene parameters)")
    return name


def _variable(name, body, where, kind, controller, sampling):
    name = check_name(name, where, kind, controller)
    w = f"{where}: {name}"
    if isinstance(body, list):
        body = {'values': body}
    if not isinstance(body, dict):
        raise CampaignError(f"{w}: expected a list of values or a map {{range: [low, high], "
                            f"num: N}} / {{values: [...]}}, got {_shown(body)}")
    for key in body:
        if key not in ('values', 'range', 'num', 'scale'):
            raise _unknown(w, key, ('values', 'range', 'num', 'scale'))
    if ('values' in body) == ('range' in body):
        raise CampaignError(f"{w}: give either values: [...] or range: [low, high]")
    if 'values' in body:
        values = body['values']
        if not isinstance(values, list):
            raise CampaignError(f"{w}: values: expected a list, got {_shown(values)}")
        if not values:
            raise CampaignError(f"{w}: values: empty list (no case would run)")
        if len(values) > MAX_AXIS:
            raise CampaignError(f"{w}: values: {len(values)} values, more than {MAX_AXIS}")
        for k in ('num', 'scale'):
            if k in body:
                raise CampaignError(f"{w}: {k}: applies to a range, not to values")
        checked = tuple(check_value(name, v, f"{w}: values[{i}]")
                        for i, v in enumerate(values))
        if len(set(map(repr, checked))) < len(checked):
            raise CampaignError(f"{w}: values: {list(checked)} repeats a value (the same case "
                                f"twice)")
        return Variable(name, values=checked)
    bounds = body['range']
    if not (isinstance(bounds, list) and len(bounds) == 2):
        raise CampaignError(f"{w}: range: expected [low, high], got {_shown(bounds)}")
    for i, b in enumerate(bounds):
        if not _is_number(b) or not math.isfinite(b):
            raise CampaignError(f"{w}: range[{i}]: {_shown(b)} is not a finite number")
    spec = parameters.SPECS.get(name)
    if spec is not None and (spec.choices or isinstance(spec.default, str)):
        raise CampaignError(f"{w}: range: {name} takes one of {list(spec.choices)}: list the "
                            f"values instead")
    low, high = (check_value(name, b, f"{w}: range") for b in bounds)
    if not high > low:
        raise CampaignError(f"{w}: range: [{low:g}, {high:g}] is empty (low must be below "
                            f"high; one value: values: [{low:g}])")
    scale = _choice(body, 'scale', w, SCALES, 'linear')
    if scale == 'log' and not low > 0:
        raise CampaignError(f"{w}: scale: log needs a range above 0, got [{low:g}, {high:g}]")
    if sampling == 'grid':
        num = _number(body, 'num', w, 2, MAX_AXIS, None, integer=True)
    elif 'num' in body:
        raise CampaignError(f"{w}: num: {sampling} sampling draws samples: values from the "
                            f"range; num applies to a grid")
    else:
        num = 0
    return Variable(name, low=float(low), high=float(high), num=num, scale=scale)


def _explicit_cases(body, where, kind, controller):
    if not isinstance(body, list) or not body:
        raise CampaignError(f"{where}: cases: expected a non-empty list of maps "
                            f"(parameter: value)")
    if len(body) > HARD_MAX_CASES:
        raise CampaignError(f"{where}: cases: {len(body)} cases, more than {HARD_MAX_CASES}")
    cases = []
    for i, case in enumerate(body):
        w = f"{where}: cases[{i}]"
        if not isinstance(case, dict) or not case:
            raise CampaignError(f"{w}: expected a map of parameter: value, got "
                                f"{_shown(case)}")
        checked = {}
        for name, value in case.items():
            name = check_name(name, w, kind, controller)
            checked[name] = check_value(name, value, w)
        cases.append(checked)
    keys = set(cases[0])
    for i, case in enumerate(cases):
        if set(case) != keys:
            raise CampaignError(f"{where}: cases[{i}]: sets {sorted(case)}, cases[0] sets "
                                f"{sorted(keys)}: every case sets the same parameters")
    seen = {}
    for i, case in enumerate(cases):
        key = repr(sorted(case.items()))
        if key in seen:
            raise CampaignError(f"{where}: cases[{i}]: the same case as cases[{seen[key]}]")
        seen[key] = i
    return tuple(cases)


def _window(value, where):
    if value == 'steady':
        return 'steady'
    if isinstance(value, dict) and set(value) == {'start'}:
        return _number(value, 'start', f"{where}: window", 0.0, MAX_DURATION)
    raise CampaignError(f"{where}: window: expected 'steady' (the detected steady state) or "
                        f"{{start: T}} (whole crank cycles from T s on), got {_shown(value)}")


def _metrics(value, where, kind):
    table = SCENE_METRICS if kind == 'scene' else SCENARIO_METRICS
    if value is None:
        return default_metrics(kind)
    if not isinstance(value, list) or not value:
        raise CampaignError(f"{where}: metrics: expected a non-empty list of names, got "
                            f"{_shown(value)}")
    for name in value:
        if name not in table:
            other = SCENARIO_METRICS if kind == 'scene' else SCENE_METRICS
            why = (f"a metric of {'scenario' if kind == 'scene' else 'scene'} campaigns"
                   if name in other else 'unknown metric')
            raise CampaignError(f"{where}: metrics: {_shown(name)}: {why}; a {kind} "
                                f"campaign keeps: {', '.join(table)}")
    if len(set(value)) < len(value):
        raise CampaignError(f"{where}: metrics: {value} names a metric twice")
    return tuple(value)


def _summary(value, where, names, metrics):
    value = value or {}
    if not isinstance(value, dict):
        raise CampaignError(f"{where}: summary: expected a map {{x, y, metrics}}")
    for key in value:
        if key not in ('x', 'y', 'metrics'):
            raise _unknown(f"{where}: summary", key, ('x', 'y', 'metrics'))
    for axis in ('x', 'y'):
        if axis in value and value[axis] not in names:
            raise CampaignError(f"{where}: summary: {axis}: {_shown(value[axis])} is not a "
                                f"varied parameter ({', '.join(names)})")
    shown = value.get('metrics', [])
    if not isinstance(shown, list) or any(m not in metrics for m in shown):
        raise CampaignError(f"{where}: summary: metrics: {str(shown)[:80]!r}: plot metrics kept "
                            f"by the campaign ({', '.join(metrics)})")
    return dict(value)


TEXT_KEYS = ('name', 'description', 'scene', 'scenario', 'controller', 'sampling', 'record')


def _numbers(node):
    """YAML 1.1 reads 1e-3 and 1.0e5 (no sign, or no dot) as text: numbers, as in scene files."""
    if isinstance(node, dict):
        return {k: v if k in TEXT_KEYS else _numbers(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_numbers(v) for v in node]
    return yaml_number(node)


def load_campaign(path):
    """The checked :class:`Campaign` of a file. Raises CampaignError."""
    path = Path(path)
    doc = read_yaml(path, CampaignError)
    text = path.read_text(encoding='utf-8')
    where = str(path)
    if not isinstance(doc, dict):
        raise CampaignError(f"{where}: expected a map of campaign keys ({', '.join(KEYS)}), got "
                            f"{type(doc).__name__}")
    for key in doc:
        if key not in KEYS:
            raise _unknown(where, key, KEYS)
    doc = _numbers(doc)
    if ('scene' in doc) == ('scenario' in doc):
        raise CampaignError(f"{where}: name either scene: (a plain run of a scene) or scenario: "
                            f"(a controller test scenario) as the base of every case")
    kind = 'scene' if 'scene' in doc else 'scenario'
    base = doc[kind]
    if not isinstance(base, str) or not base:
        raise CampaignError(f"{where}: {kind}: expected a {kind} name or path, got "
                            f"{_shown(base)}")
    name = doc.get('name', path.stem)
    description = doc.get('description', '')
    for key, value in (('name', name), ('description', description)):
        if not isinstance(value, str) or len(value) > 4096:
            raise CampaignError(f"{where}: {key}: expected text (≤ 4096 characters)")
    controller = doc.get('controller')
    if controller is not None:
        if kind != 'scenario':
            raise CampaignError(f"{where}: controller: a controller runs in a scenario campaign "
                                f"(scenario: …); a scene campaign runs the open loop")
        if not isinstance(controller, str) or ':' not in controller:
            raise CampaignError(f"{where}: controller: expected MODULE:FACTORY (e.g. "
                                f"cvt_ros.control.speed_pi:reference_controller), got "
                                f"{_shown(controller)}")
    overrides = doc.get('overrides') or {}
    if not isinstance(overrides, dict):
        raise CampaignError(f"{where}: overrides: expected a map of scene parameters (dotted "
                            f"names)")
    fixed = {}
    for key, value in overrides.items():
        key = check_name(key, f"{where}: overrides", kind, controller)
        fixed[key] = check_value(key, value, f"{where}: overrides")
    if kind == 'scene':
        duration = _number(doc, 'duration', where, 0.0, MAX_DURATION, open_low=True)
        sample_dt = _number(doc, 'sample_dt', where, 1e-6, 1.0, 1e-3, open_low=True)
        if duration / sample_dt > 1e7:
            raise CampaignError(f"{where}: sample_dt: {sample_dt:g} s makes "
                                f"{duration / sample_dt:.3g} samples per case, more than 1e7")
    else:
        duration = (_number(doc, 'duration', where, 0.0, MAX_DURATION, open_low=True)
                    if 'duration' in doc else None)
        if 'sample_dt' in doc:
            raise CampaignError(f"{where}: sample_dt: a scenario samples once per control "
                                f"period (its control_period:)")
        sample_dt = 0.0
    window = _window(doc.get('window', 'steady'), where)
    if kind == 'scenario' and 'window' in doc:
        raise CampaignError(f"{where}: window: scenario metrics are per set-point/load step "
                            f"(the scenario's schedules), not over a window")
    sampling = _choice(doc, 'sampling', where, SAMPLINGS, 'grid')
    if 'vary' in doc and 'cases' in doc:
        raise CampaignError(f"{where}: give vary: (axes) or cases: (an explicit list), not both")
    variables, cases = (), ()
    if 'cases' in doc:
        if 'sampling' in doc:
            raise CampaignError(f"{where}: sampling: applies to vary:, not to explicit cases:")
        cases = _explicit_cases(doc['cases'], where, kind, controller)
    else:
        vary = doc.get('vary')
        if not isinstance(vary, dict) or not vary:
            raise CampaignError(f"{where}: vary: expected a map of parameter: values/range (at "
                                f"least one), or cases: [...]")
        variables = tuple(_variable(k, v, f"{where}: vary", kind, controller, sampling)
                          for k, v in vary.items())
        both = [v.name for v in variables if v.name in fixed]
        if both:
            raise CampaignError(f"{where}: {both[0]}: both fixed (overrides) and varied (vary)")
    samples = 0
    if sampling != 'grid':
        samples = _number(doc, 'samples', where, 1, HARD_MAX_CASES, integer=True)
    elif 'samples' in doc:
        raise CampaignError(f"{where}: samples: applies to random and latin_hypercube "
                            f"sampling; a grid has the product of its axes")
    seed = _number(doc, 'seed', where, 0, 2 ** 63 - 1, 0, integer=True)
    metrics = _metrics(doc.get('metrics'), where, kind)
    budget = _number(doc, 'time_budget', where, 0.0, 1e6, DEFAULT_TIME_BUDGET, open_low=True)
    record = _choice(doc, 'record', where, RECORD_FORMATS, 'none')
    campaign = Campaign(path, name, text, kind, base, fixed, controller, duration, sample_dt,
                        window, variables, cases, sampling, samples, seed, metrics, budget,
                        record, {}, description)
    summary = _summary(doc.get('summary'), where, campaign.variable_names, metrics)
    campaign = replace(campaign, summary=summary)
    if campaign.case_count() > HARD_MAX_CASES:
        raise CampaignError(f"{where}: {campaign.case_count():,} cases, more than any campaign "
                            f"may have ({HARD_MAX_CASES:,}); split it")
    return campaign


__all__ = ['Campaign', 'CampaignError', 'HARD_MAX_CASES', 'Variable', 'load_campaign', 'rounded']
