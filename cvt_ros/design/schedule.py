"""A gain schedule: the plant identified over a grid of operating points, on the sweep engine.

``cvt-sim identify SCENE --grid linkage.crank_length=0.02,0.03,0.04 --grid load.torque=4:12:3``
runs :func:`~cvt_ros.design.identify.identify` at every point of the grid's product as one case
of a campaign on the Dask sweep engine (:mod:`cvt_ros.sweep`: its local cluster or a scheduler,
its runner, its resumable Parquet table — nothing of it rewritten here), then writes
``schedule.csv`` (one row per point: the models' gain, time constant, delay and fit error for
both inputs, the motor speed gains, the operating point's speeds, ratio and efficiency, and the
SIMC PI at τc = τ) and ``schedule.png``.

Before the cluster starts, the first point runs here: its errors surface at once, and its wall
time, times the points, over the workers, must fit the grid's ``time_budget`` (a grid estimated
to need more is refused with the numbers; each point's own budget is the grid's too).
"""
import functools
import hashlib
import itertools
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .. import parameters
from ..scene import load_scene
from ..sweep.campaign import Campaign
from .errors import DesignError
from .identify import IdentifySettings, identify
from .tune import simc

MAX_POINTS = 100_000
FORMAT = 'cvt_ros.design.schedule/1'   # salt of the case ids: bump when a column changes

#: column → (unit, meaning): the schedule's figures per operating point
METRICS = {
    'output_speed': ('rad/s', 'cycle-mean output speed at the operating point'),
    'crank_speed': ('rad/s', 'cycle-mean crank (motor) speed'),
    'ratio': ('-', 'ω̄4/ω̄1'),
    'efficiency': ('-', 'output work / motor work over the steady window'),
    'crank_frequency': ('Hz', 'crank turns per second'),
}
for _input, _unit in (('crank_length', 'rad/s per m'), ('load_torque', 'rad/s per N*m')):
    METRICS.update({
        f'{_input}_gain': (_unit, f'FOPDT gain {_input} → output speed'),
        f'{_input}_time_constant': ('s', f'FOPDT time constant {_input} → output speed'),
        f'{_input}_delay': ('s', f'FOPDT dead time {_input} → output speed'),
        f'{_input}_fit_error': ('-', 'RMS(model − device) / RMS(response), cycle means'),
        f'{_input}_motor_gain': (_unit, f'static gain {_input} → motor speed (best model)'),
    })
METRICS.update({'kp': ('m/(rad/s)', 'SIMC PI at τc = τ (θ + one crank turn)'),
                'ki': ('m/rad', 'SIMC PI at τc = τ (θ + one crank turn)')})


@dataclass(frozen=True, eq=False)
class ScheduleCampaign(Campaign):
    """A campaign of operating points (kind 'call': each case runs :func:`point_figures`); its
    table's columns are :data:`METRICS`."""
    metric_table: dict = field(default_factory=dict)


@dataclass
class ScheduleResult:
    rows: list
    table: Path
    csv: Path
    figure: Path
    wall_time: float


def _values(text, name):
    """NAME=V1,V2,… or NAME=LOW:HIGH:NUM → the checked values."""
    try:
        if ':' in text:
            low, high, num = text.split(':')
            num = int(num)
            if not 1 <= num <= MAX_POINTS:
                raise ValueError(f"NUM = {num} is outside [1, {MAX_POINTS}]")
            low, high = float(low), float(high)
            values = [low] if num == 1 else [low + (high - low) * k / (num - 1)
                                             for k in range(num)]
            values = [float(f"{v:.12g}") for v in values]
        else:
            values = [float(v) for v in text.split(',') if v.strip()]
    except ValueError as exc:
        raise DesignError(f"--grid {name}={text[:80]}: expected V1,V2,… or LOW:HIGH:NUM "
                          f"({exc})") from None
    if not values:
        raise DesignError(f"--grid {name}={text[:80]}: no values")
    spec = parameters.SPECS[name]
    for v in values:
        try:
            spec.check(v)
        except parameters.ParameterError as exc:
            raise DesignError(f"--grid {name}: {exc}") from None
    return values


def parse_grid(texts):
    """``--grid NAME=VALUES`` arguments → [(name, values)] (each value checked by the parameter
    table's spec). Raises DesignError naming the argument."""
    axes, seen = [], set()
    numeric = {s.name for s in parameters.PHYSICS_PARAMETERS
               if not s.choices and not isinstance(s.default, str)}
    for text in texts:
        name, sep, body = str(text).partition('=')
        name = name.strip()
        if not sep:
            raise DesignError(f"--grid {text[:80]!r}: expected NAME=VALUES")
        if name not in numeric:
            raise DesignError(f"--grid {name[:80]!r}: not a numeric scene parameter "
                              f"(cvt-sim params lists them)")
        if name in seen:
            raise DesignError(f"--grid {name}: given twice")
        seen.add(name)
        axes.append((name, _values(body, name)))
    count = math.prod(len(v) for _, v in axes)
    if count > MAX_POINTS:
        raise DesignError(f"--grid: {count:,} operating points, more than {MAX_POINTS:,}")
    return axes


def point_figures(settings, task, deadline):
    """One operating point's row figures (a case of the sweep runner: (figures, warnings))."""
    stages = iter(range(1, 100))

    def stage(text):
        deadline(next(stages), 5)
    plant = identify(task.values, settings=settings, progress=stage)
    return figures_of(plant), []


def figures_of(plant):
    """The schedule's columns of a PlantModel."""
    p = plant.operating_point
    out = {'output_speed': p.output_speed, 'crank_speed': p.crank_speed, 'ratio': p.ratio,
           'efficiency': p.efficiency, 'crank_frequency': p.crank_frequency}
    for name, model in plant.inputs.items():
        m = model.outputs['output_speed'].fopdt
        motor = model.outputs['motor_speed']
        out.update({f'{name}_gain': m.gain, f'{name}_time_constant': m.time_constant,
                    f'{name}_delay': m.delay, f'{name}_fit_error': m.fit_error,
                    f'{name}_motor_gain': motor.model(motor.best).gain})
    crank = plant.inputs['crank_length'].outputs['output_speed'].fopdt
    theta = crank.delay + 1.0 / p.crank_frequency
    if crank.gain > 0:
        out['kp'], out['ki'], _ = simc(crank.gain, crank.time_constant, theta,
                                       crank.time_constant)
    else:
        out['kp'] = out['ki'] = math.nan
    return out


def _tasks(campaign, base, points, settings, budget):
    from ..sweep.cases import CaseTask
    function = functools.partial(point_figures, settings)
    tasks = []
    for index, point in enumerate(points):
        payload = json.dumps({'v': FORMAT, 'values': {**base, **point},
                              'settings': asdict(settings)}, sort_keys=True, default=repr)
        case_id = hashlib.sha256(payload.encode()).hexdigest()[:20]
        tasks.append(CaseTask(index, case_id, dict(point), 'call', base=base,
                              changes=dict(point), metrics=tuple(METRICS),
                              time_budget=budget, function=function))
    return tasks


def run_schedule(scene, axes, out_dir, overrides=None, settings=None, *, workers=None,
                 scheduler=None, time_budget=3600.0, say=None, origins=None, on_event=None):
    """Identify ``scene`` at every point of the grid ``axes`` ([(name, values)]) on the sweep
    engine; a :class:`ScheduleResult`. ``on_event``: the sweep engine's progress events
    (:func:`cvt_ros.sweep.cluster.run_campaign`). Raises DesignError (a grid beyond its time
    budget, a point that cannot be a scene), SweepError, TableError."""
    from ..sweep.cluster import open_cluster, plan_campaign, run_campaign
    from .plots import plot_schedule
    say = say or (lambda text: None)
    settings = settings or IdentifySettings()
    base = load_scene(scene, overrides, origins)
    names = [name for name, _ in axes]
    points = [dict(zip(names, combo, strict=True))
              for combo in itertools.product(*(values for _, values in axes))]
    for point in points:   # every point a valid scene (the Grashof bound of its geometry)
        try:
            parameters.validate({**base, **point})
        except Exception as exc:   # noqa: BLE001 — ParameterError, GrashofError: one line
            raise DesignError(f"--grid point {point}: {exc}") from None
    out = Path(out_dir)
    text = (f"# cvt-sim identify {scene} --grid …: a gain schedule (cvt_ros.design.schedule)\n"
            + json.dumps({'scene': str(scene), 'overrides': dict(overrides or {}),
                          'grid': {n: v for n, v in axes}, 'settings': asdict(settings)},
                         indent=1) + '\n')
    campaign = ScheduleCampaign(out / 'campaign.yaml', f"identify {scene}", text, 'call',
                                str(scene), dict(overrides or {}), cases=tuple(points),
                                metrics=tuple(METRICS), time_budget=time_budget,
                                metric_table=METRICS)
    start = time.perf_counter()
    tasks = _tasks(campaign, base, points, settings, time_budget)
    plan = plan_campaign(campaign, out, tasks=tasks)
    if plan.todo:
        say(f"the first of {len(plan.todo)} operating points to run, here (its errors and its "
            f"time)")
        t0 = time.perf_counter()
        try:
            identify(plan.todo[0].values, settings=settings)
        except DesignError:
            pass   # a point without a model is a row of the table, not the grid's fault
        per_point = time.perf_counter() - t0
        lanes = workers or (1 if scheduler else os.cpu_count() or 1)
        estimate = per_point * len(plan.todo) / lanes
        if estimate > time_budget:
            raise DesignError(
                f"--grid: {len(plan.todo)} operating points × {per_point:.3g} s each (the "
                f"first, measured) on {lanes} worker(s) ≈ {estimate:.4g} s, more than "
                f"--time-budget {time_budget:g} s: fewer points, --no-sweep, more --workers, or "
                f"a larger --time-budget")
        say(f"{len(plan.todo)} points on the sweep engine, ~{estimate:.3g} s")
        with open_cluster(scheduler, workers, dashboard=':0') as cluster:
            run = run_campaign(campaign, out, cluster, plan=plan, on_event=on_event)
    else:
        run = run_campaign(campaign, out, None, plan=plan)
    rows = run.rows
    csv = out / 'schedule.csv'
    _write_csv(csv, rows, names)
    figure = plot_schedule(rows, names[0], names[1] if len(names) > 1 else None,
                           out / 'schedule.png')
    return ScheduleResult(rows, run.path, csv, Path(figure), time.perf_counter() - start)


def _write_csv(path, rows, names):
    columns = ['case'] + names + list(METRICS) + ['status', 'error']
    with open(path, 'w', encoding='utf-8') as f:
        f.write(','.join(columns) + '\n')
        for row in rows:
            cells = []
            for c in columns:
                v = row.get(c)
                if isinstance(v, float):
                    cells.append('' if not math.isfinite(v) else f"{v:.9g}")
                else:
                    cells.append('"' + str(v if v is not None else '').replace('"', "'") + '"'
                                 if c == 'error' else str(v))
            f.write(','.join(cells) + '\n')
    return path


__all__ = ['METRICS', 'ScheduleResult', 'figures_of', 'parse_grid', 'point_figures',
           'run_schedule']
