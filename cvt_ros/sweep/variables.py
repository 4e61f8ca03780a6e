"""The varied parameters of a campaign: their names (scene parameters, reference-controller
settings), their values (lists, ranges, explicit cases) checked by each parameter's own spec."""
import difflib
import math
from dataclasses import dataclass, fields

from .. import parameters
from ..control.speed_pi import SpeedPIGains
from ..numbers import NotANumber, real_number
from ..scenario.checks import number
from .errors import CampaignError

SCALES = ('linear', 'log')
MAX_AXIS = 1_000_000            # values on one grid axis
SIGNIFICANT = 12                # digits kept of a generated value (0.060000000000000005 → 0.06)
SCENE_NAMES = tuple(s.name for s in parameters.PHYSICS_PARAMETERS)
GAIN_NAMES = tuple(f.name for f in fields(SpeedPIGains))


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
        return not self.values or all(is_number(v) for v in self.values)

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


def rounded(x):
    """A generated number with SIGNIFICANT digits: the same text in the table on every machine."""
    return float(f"{x:.{SIGNIFICANT}g}")


def shown(value):
    """A value for a message: numbers as written (inf, 1e-05), anything else quoted and cut."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f"{value!r}"
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:60]}…"


def _real(v):
    """A number as a float; inf for an integer beyond the float range (then refused as such)."""
    try:
        return real_number(v)
    except NotANumber:
        return math.inf


def is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def unknown_key(where, key, allowed):
    close = difflib.get_close_matches(str(key), allowed, n=1)
    hint = f" (did you mean {close[0]}?)" if close else ''
    return CampaignError(f"{where}: unknown key {str(key)[:80]!r}{hint}; allowed: "
                         f"{', '.join(allowed)}")


def choice(doc, key, where, choices, default):
    value = doc.get(key, default)
    if value not in choices:
        raise CampaignError(f"{where}: {key}: {shown(value)} is not one of "
                            f"{', '.join(choices)}")
    return value


def check_value(name, value, where):
    """One value of a varied or fixed parameter, checked by its spec; the coerced value."""
    if name.startswith('controller.'):
        setting = name.partition('.')[2]
        if not is_number(value) or not math.isfinite(_real(value)):
            raise CampaignError(f"{where}: {name}: {shown(value)} is not a finite number")
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


def parse_variable(name, body, where, kind, controller, sampling):
    name = check_name(name, where, kind, controller)
    w = f"{where}: {name}"
    if isinstance(body, list):
        body = {'values': body}
    if not isinstance(body, dict):
        raise CampaignError(f"{w}: expected a list of values or a map {{range: [low, high], "
                            f"num: N}} / {{values: [...]}}, got {shown(body)}")
    for key in body:
        if key not in ('values', 'range', 'num', 'scale'):
            raise unknown_key(w, key, ('values', 'range', 'num', 'scale'))
    if ('values' in body) == ('range' in body):
        raise CampaignError(f"{w}: give either values: [...] or range: [low, high]")
    if 'values' in body:
        values = body['values']
        if not isinstance(values, list):
            raise CampaignError(f"{w}: values: expected a list, got {shown(values)}")
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
        raise CampaignError(f"{w}: range: expected [low, high], got {shown(bounds)}")
    for i, b in enumerate(bounds):
        if not is_number(b) or not math.isfinite(_real(b)):
            raise CampaignError(f"{w}: range[{i}]: {shown(b)} is not a finite number")
    spec = parameters.SPECS.get(name)
    if spec is not None and (spec.choices or isinstance(spec.default, str)):
        raise CampaignError(f"{w}: range: {name} takes one of {list(spec.choices)}: list the "
                            f"values instead")
    low, high = (check_value(name, b, f"{w}: range") for b in bounds)
    if not high > low:
        raise CampaignError(f"{w}: range: [{low:g}, {high:g}] is empty (low must be below "
                            f"high; one value: values: [{low:g}])")
    scale = choice(body, 'scale', w, SCALES, 'linear')
    if scale == 'log' and not low > 0:
        raise CampaignError(f"{w}: scale: log needs a range above 0, got [{low:g}, {high:g}]")
    if sampling == 'grid':
        if 'num' not in body:
            raise CampaignError(f"{w}: num: missing (points of the range on the grid)")
        num = number(body['num'], f"{w}: num", 2, MAX_AXIS, integer=True, error=CampaignError)
    elif 'num' in body:
        raise CampaignError(f"{w}: num: {sampling} sampling draws samples: values from the "
                            f"range; num applies to a grid")
    else:
        num = 0
    return Variable(name, low=float(low), high=float(high), num=num, scale=scale)


def parse_cases(body, where, kind, controller, most):
    if not isinstance(body, list) or not body:
        raise CampaignError(f"{where}: cases: expected a non-empty list of maps "
                            f"(parameter: value)")
    if len(body) > most:
        raise CampaignError(f"{where}: cases: {len(body)} cases, more than {most}")
    cases = []
    for i, case in enumerate(body):
        w = f"{where}: cases[{i}]"
        if not isinstance(case, dict) or not case:
            raise CampaignError(f"{w}: expected a map of parameter: value, got "
                                f"{shown(case)}")
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


__all__ = ['GAIN_NAMES', 'SCENE_NAMES', 'Variable', 'check_name', 'check_value', 'choice',
           'is_number', 'parse_cases', 'parse_variable', 'rounded', 'shown', 'unknown_key']
