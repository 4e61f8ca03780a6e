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
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..scenario.checks import number
from ..scene import shipped_file
from ..yaml_file import numbers_in, read_yaml
from .errors import CampaignError
from .metrics import SCENARIO_METRICS, SCENE_METRICS, default_metrics
from .variables import (
    Variable,
    check_name,
    check_value,
    choice,
    parse_cases,
    parse_variable,
    rounded,
    shown,
    unknown_key,
)

KEYS = ('name', 'description', 'scene', 'scenario', 'overrides', 'controller', 'duration',
        'sample_dt', 'window', 'vary', 'cases', 'sampling', 'samples', 'seed', 'metrics',
        'time_budget', 'record', 'summary')
SAMPLINGS = ('grid', 'random', 'latin_hypercube')
RECORD_FORMATS = ('none', 'csv', 'mcap')
MAX_DURATION = 86400.0          # s per case
HARD_MAX_CASES = 1_000_000      # cases in one campaign, --yes or not (its tasks live in memory)
DEFAULT_TIME_BUDGET = 600.0     # s of wall time per case


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
    window: object = 'steady'        # 'steady' | start time [s] of the metric window (scenario:
    #                                   the steps from then on; 0.0 all of them)
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


def _number(doc, key, where, low, high, default=None, integer=False, open_low=False):
    value = doc.get(key, default)
    if value is None:
        raise CampaignError(f"{where}: {key}: missing")
    return number(value, f"{where}: {key}", low, high, open_low=open_low, integer=integer,
                  error=CampaignError)


def _window(value, where):
    if value == 'steady':
        return 'steady'
    if isinstance(value, dict) and set(value) == {'start'}:
        return _number(value, 'start', f"{where}: window", 0.0, MAX_DURATION)
    raise CampaignError(f"{where}: window: expected 'steady' (the detected steady state) or "
                        f"{{start: T}} (whole crank cycles from T s on), got {shown(value)}")


def _metrics(value, where, kind):
    table = SCENE_METRICS if kind == 'scene' else SCENARIO_METRICS
    if value is None:
        return default_metrics(kind)
    if not isinstance(value, list) or not value:
        raise CampaignError(f"{where}: metrics: expected a non-empty list of names, got "
                            f"{shown(value)}")
    for name in value:
        if name not in table:
            other = SCENARIO_METRICS if kind == 'scene' else SCENE_METRICS
            why = (f"a metric of {'scenario' if kind == 'scene' else 'scene'} campaigns"
                   if name in other else 'unknown metric')
            raise CampaignError(f"{where}: metrics: {shown(name)}: {why}; a {kind} "
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
            raise unknown_key(f"{where}: summary", key, ('x', 'y', 'metrics'))
    for axis in ('x', 'y'):
        if axis in value and value[axis] not in names:
            raise CampaignError(f"{where}: summary: {axis}: {shown(value[axis])} is not a "
                                f"varied parameter ({', '.join(names)})")
    plotted = value.get('metrics', [])
    if not isinstance(plotted, list) or any(m not in metrics for m in plotted):
        raise CampaignError(f"{where}: summary: metrics: {shown(plotted)}: plot metrics kept "
                            f"by the campaign ({', '.join(metrics)})")
    return dict(value)


TEXT_KEYS = ('name', 'description', 'scene', 'scenario', 'controller', 'sampling', 'record')


def resolve_campaign(name):
    """A path, or a shipped campaign's name (config/campaigns/NAME.yaml), as scenes and
    scenarios are named; a missing file stays the path (read_yaml says it is missing)."""
    path = Path(name)
    if path.exists() or path.suffix in ('.yaml', '.yml') or os.sep in str(name):
        return path
    return shipped_file('campaigns', name) or path


def load_campaign(path):
    """The checked :class:`Campaign` of a file or a shipped campaign's name. Raises
    CampaignError."""
    path = resolve_campaign(path)
    doc = read_yaml(path, CampaignError)
    text = path.read_text(encoding='utf-8')
    where = str(path)
    if not isinstance(doc, dict):
        raise CampaignError(f"{where}: expected a map of campaign keys ({', '.join(KEYS)}), got "
                            f"{type(doc).__name__}")
    for key in doc:
        if key not in KEYS:
            raise unknown_key(where, key, KEYS)
    doc = numbers_in(doc, TEXT_KEYS)   # (1e-3 is a number, as in scene files)
    if ('scene' in doc) == ('scenario' in doc):
        raise CampaignError(f"{where}: name either scene: (a plain run of a scene) or scenario: "
                            f"(a controller test scenario) as the base of every case")
    kind = 'scene' if 'scene' in doc else 'scenario'
    base = doc[kind]
    if not isinstance(base, str) or not base:
        raise CampaignError(f"{where}: {kind}: expected a {kind} name or path, got "
                            f"{shown(base)}")
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
                                f"{shown(controller)}")
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
    if kind == 'scenario':
        if 'window' in doc and window == 'steady':
            raise CampaignError(f"{where}: window: scenario metrics are per set-point/load step; "
                                f"{{start: T}} keeps the steps from T s on (e.g. leaves out the "
                                f"start-up from rest), 'steady' does not apply")
        window = 0.0 if window == 'steady' else window
    sampling = choice(doc, 'sampling', where, SAMPLINGS, 'grid')
    if 'vary' in doc and 'cases' in doc:
        raise CampaignError(f"{where}: give vary: (axes) or cases: (an explicit list), not both")
    variables, cases = (), ()
    if 'cases' in doc:
        if 'sampling' in doc:
            raise CampaignError(f"{where}: sampling: applies to vary:, not to explicit cases:")
        cases = parse_cases(doc['cases'], where, kind, controller, HARD_MAX_CASES)
    else:
        vary = doc.get('vary')
        if not isinstance(vary, dict) or not vary:
            raise CampaignError(f"{where}: vary: expected a map of parameter: values/range (at "
                                f"least one), or cases: [...]")
        variables = tuple(parse_variable(k, v, f"{where}: vary", kind, controller, sampling)
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
    record = choice(doc, 'record', where, RECORD_FORMATS, 'none')
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
