"""From a campaign to its cases: expansion (grid, explicit list, random, Latin hypercube), the
check of every case as a whole, and the task each case becomes.

Expansion is deterministic: a grid in the file's axis order (the last axis fastest), random and
Latin hypercube draws from ``numpy.random.default_rng(seed)`` (PCG64: the same numbers on every
machine and numpy version) and ``scipy.stats.qmc.LatinHypercube``. Every case is validated
before any runs — parameters.validate on the scene values with the case applied (bounds, the
Grashof bound of its geometry), a scenario reloaded with them, the controller settings checked
together — so a bad case is one CampaignError naming the case and its values.

A case's identity (:attr:`CaseTask.case_id`) is a hash of everything that decides its row: the
complete scene values (or the scenario file's text and the case's changes), duration, sampling,
window and metrics. A table row with that id is that case's result: this is what makes a rerun
skip finished cases (even after the campaign grew new values) and never mix in stale ones.
"""
import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import parameters
from ..control.speed_pi import SpeedPIGains, reference_gains
from ..physics.linkage import GrashofError
from ..scene import SceneError, load_scene
from .errors import CampaignError

FORMAT = 'cvt_ros.sweep/1'    # salt of the case ids: bump when a metric's definition changes


@dataclass(frozen=True, eq=False)
class CaseTask:
    """What a worker needs to run one case (sent through Dask; small: shared parts by reference).

    ``base`` + ``changes`` are the scene values (validated by build_tasks), or ``scenario`` is
    the case's Scenario (its ``controller_settings``: the case's reference-controller settings).
    Any other ``kind`` runs ``function(task, deadline)`` → (figures, warnings): a case a room
    above the sweep defines (a picklable callable: the design tools' operating points).
    """
    index: int
    case_id: str
    variables: dict                  # varied name → value: the row's parameter columns
    kind: str                        # 'scene' | 'scenario'
    base: dict = None
    changes: dict = field(default_factory=dict)
    scenario: object = None
    controller: str = None
    duration: float = 0.0
    sample_dt: float = 0.0
    window: object = 'steady'
    metrics: tuple = ()
    time_budget: float = 600.0
    record: str = ''                 # path of the case's recording (.csv / .mcap), '' for none
    function: object = None          # kind 'call': what runs the case

    @property
    def values(self):
        """The case's complete scene values (scene campaigns)."""
        return parameters.validate({**self.base, **self.changes})


def expand(campaign):
    """The varied values of every case, in case order: a list of {name: value}."""
    if campaign.cases:
        return [dict(case) for case in campaign.cases]
    variables = campaign.variables
    names = [v.name for v in variables]
    if campaign.sampling == 'grid':
        axes = [v.grid() for v in variables]
        return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*axes)]
    rng = np.random.default_rng(campaign.seed)
    if campaign.sampling == 'random':
        u = rng.random((campaign.samples, len(variables)))
    else:
        from scipy.stats import qmc
        u = qmc.LatinHypercube(d=len(variables), rng=rng).random(campaign.samples)
    return [{v.name: v.at(float(x)) for v, x in zip(variables, row, strict=True)} for row in u]


def _relative(campaign, name):
    """A base named relative to the campaign file, if such a file exists; else as given."""
    candidate = campaign.path.parent / name
    return candidate if candidate.is_file() else name


def _case_text(variables):
    return ', '.join(f"{k} = {v!r}" for k, v in variables.items())


def _digest(payload, seen):
    """Case id: sha256 of the canonical JSON of its inputs; a repeat (random draws from a list)
    gets its occurrence number mixed in, so ids stay unique and deterministic."""
    text = json.dumps(payload, sort_keys=True, default=repr)
    count = seen.get(text, 0)
    seen[text] = count + 1
    if count:
        text += f"#{count}"
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def build_tasks(campaign, out_dir=None):
    """Every case of ``campaign`` as a checked :class:`CaseTask` (case order). Raises
    CampaignError naming the first case that cannot run (and how many more cannot)."""
    cases = expand(campaign)
    if campaign.kind == 'scene':
        return _scene_tasks(campaign, cases, out_dir)
    return _scenario_tasks(campaign, cases, out_dir)


def _record_path(campaign, out_dir, index, case_id):
    if campaign.record == 'none' or out_dir is None:
        return ''
    return str(Path(out_dir) / 'recordings' / f"case-{index:06d}-{case_id[:8]}.{campaign.record}")


def _fail(campaign, bad, total):
    index, variables, reason = bad[0]
    more = f" ({len(bad) - 1} more of the {total} cases cannot run either)" if len(bad) > 1 \
        else ''
    return CampaignError(f"{campaign.path}: case {index} ({_case_text(variables)}): "
                         f"{reason}{more}")


#: fewest samples per crank turn the cycle metrics take (peaks, ripple and the crank angle's
#: turns need several; the analysis refuses more than a turn between two samples)
MIN_SAMPLES_PER_TURN = 4


def _too_coarse(sample_dt, values):
    """Why ``sample_dt`` cannot resolve the crank's turns of this case ('' if it can): the
    fastest crank speed its motor model gives (a constant-torque motor: at least its start)."""
    model = values['motor.model']
    speed = {'induction': values['motor.synchronous_speed'],
             'constant_speed': values['motor.speed']}.get(model, 0.0)
    speed = max(abs(speed), abs(values['initial.crank_speed']))
    turn = 2.0 * math.pi / speed if speed > 0 else math.inf
    if sample_dt * MIN_SAMPLES_PER_TURN <= turn:
        return ''
    return (f"sample_dt: {sample_dt:g} s gives fewer than {MIN_SAMPLES_PER_TURN} samples per "
            f"crank turn ({turn:.3g} s at {speed:g} rad/s): the cycle metrics need "
            f"sample_dt ≤ {turn / MIN_SAMPLES_PER_TURN:.2g} s (the shipped campaigns take "
            f"~80 a turn)")


def _check_window(campaign, duration):
    """A metric window that starts at or after the end of the run holds nothing to measure."""
    window = campaign.window
    if window != 'steady' and window and window >= duration:
        raise CampaignError(f"{campaign.path}: window: start {window:g} s is at or after the "
                            f"end of each case's run ({duration:g} s): the metrics would all "
                            f"be NaN")


def _scene_tasks(campaign, cases, out_dir):
    _check_window(campaign, campaign.duration)
    try:
        base = load_scene(_relative(campaign, campaign.base), campaign.overrides)
    except (SceneError, GrashofError, parameters.ParameterError) as exc:
        raise CampaignError(f"{campaign.path}: scene: {exc}") from None
    common = {'kind': 'scene', 'duration': campaign.duration, 'sample_dt': campaign.sample_dt,
              'window': campaign.window, 'metrics': list(campaign.metrics), 'v': FORMAT}
    tasks, bad, seen = [], [], {}
    for index, variables in enumerate(cases):
        try:
            values = parameters.validate({**base, **variables})
        except (parameters.ParameterError, GrashofError) as exc:
            bad.append((index, variables, str(exc)))
            continue
        coarse = _too_coarse(campaign.sample_dt, values)
        if coarse:
            bad.append((index, variables, coarse))
            continue
        case_id = _digest({**common, 'values': values}, seen)
        tasks.append(CaseTask(index, case_id, variables, 'scene', base=base,
                              changes=dict(variables), duration=campaign.duration,
                              sample_dt=campaign.sample_dt, window=campaign.window,
                              metrics=campaign.metrics, time_budget=campaign.time_budget,
                              record=_record_path(campaign, out_dir, index, case_id)))
    if bad:
        raise _fail(campaign, bad, len(cases))
    return tasks


def _check_controller(campaign):
    """The controller's module must be importable here (the workers import it again)."""
    import importlib.util
    module = campaign.controller.partition(':')[0]
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise CampaignError(f"{campaign.path}: controller: {campaign.controller!r}: no module "
                            f"{module!r} on this Python's path (install it here and on every "
                            f"worker)")


def _scenario_tasks(campaign, cases, out_dir):
    from ..scenario.harness import plant_values
    from ..scenario.model import ScenarioError, load_scenario, resolve_scenario

    ref = _relative(campaign, campaign.base)
    if campaign.controller is not None:
        _check_controller(campaign)
    timing = {'duration': campaign.duration} if campaign.duration else {}
    try:
        path = resolve_scenario(ref)
        first = load_scenario(path, timing)
        text = path.read_text(encoding='utf-8')
    except (ScenarioError, OSError) as exc:
        raise CampaignError(f"{campaign.path}: scenario: {exc}") from None
    _check_window(campaign, first.duration)
    fixed_scene = {k: v for k, v in campaign.overrides.items() if not k.startswith('controller.')}
    fixed_gains = {k.partition('.')[2]: v for k, v in campaign.overrides.items()
                   if k.startswith('controller.')}
    loaded = {}     # scene changes → the scenario loaded with them (shared by the cases)

    def scenario_for(scene):
        key = json.dumps(scene, sort_keys=True, default=repr)
        if key not in loaded:
            loaded[key] = load_scenario(path, {**timing, 'overrides': {**first.overrides,
                                                                       **scene}})
        return loaded[key]

    common = {'kind': 'scenario', 'scenario': text, 'duration': campaign.duration,
              'controller': campaign.controller, 'metrics': list(campaign.metrics), 'v': FORMAT}
    if campaign.window:
        common['window'] = campaign.window   # (absent when 0: the ids of earlier tables hold)
    tasks, bad, seen = [], [], {}
    for index, variables in enumerate(cases):
        scene = {**fixed_scene, **{k: v for k, v in variables.items()
                                   if not k.startswith('controller.')}}
        gains = {**first.controller_settings, **fixed_gains,
                 **{k.partition('.')[2]: v for k, v in variables.items()
                    if k.startswith('controller.')}}
        try:
            scenario = scenario_for(scene)
            SpeedPIGains(**gains).check()
            if campaign.controller is None:   # the reference PI, within the crank limits
                reference_gains(gains, scenario.crank_limits)
        except ScenarioError as exc:
            bad.append((index, variables, str(exc)))
            continue
        except ValueError as exc:
            bad.append((index, variables, f"controller.{exc}"))
            continue
        plant = plant_values(scenario)
        lost = [k for k, v in scene.items() if plant[k] != v]
        if lost:   # the scenario's own schedule sets it (the load's initial value)
            bad.append((index, variables, f"{lost[0]} = {scene[lost[0]]!r} does not reach the "
                                          f"device: the scenario's schedule sets it to "
                                          f"{plant[lost[0]]!r} (vary it in the scenario file)"))
            continue
        if 'load.torque' in scene and scenario.load.changes:
            # the varied value would hold only until the schedule's first change: rows
            # labelled with a load the run mostly did not have
            bad.append((index, variables, f"load.torque = {scene['load.torque']!r} holds only "
                                          f"until t = {scenario.load.changes[0].at:g} s: the "
                                          f"scenario's load schedule changes it then (vary the "
                                          f"load in the scenario file, or sweep a scenario "
                                          f"without load changes)"))
            continue
        case_id = _digest({**common, 'scene': scene, 'gains': gains}, seen)
        tasks.append(CaseTask(index, case_id, variables, 'scenario',
                              scenario=replace(scenario, controller_settings=gains),
                              controller=campaign.controller,
                              duration=scenario.duration, window=campaign.window,
                              metrics=campaign.metrics,
                              time_budget=campaign.time_budget,
                              record=_record_path(campaign, out_dir, index, case_id)))
    if bad:
        raise _fail(campaign, bad, len(cases))
    return tasks


__all__ = ['CaseTask', 'FORMAT', 'build_tasks', 'expand']
