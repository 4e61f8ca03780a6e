"""One case, run where a Dask worker (or any caller) runs it: :func:`run_case` → one table row.

A case never raises: whatever stops it becomes its row's ``status`` ``failed`` with the kind of
failure and the reason, so the campaign goes on.

* ``timeout`` — its wall time passed the campaign's ``time_budget``. Checked cooperatively
  where the run reports progress (every ≤ 2 % of a scene run's span, every 1 % of a scenario's
  periods), so a case stops within one such slice of its budget; the core's own step budget
  (solver/simulator.py: STEP_BUDGET) ends a single call that cannot progress.
* ``diverged`` — the integration could not go on (SimulationError: step-size floor, non-finite
  state, Zeno) or, in a scenario, the simulation failed in a control period.
* ``controller`` — the controller raised or answered something that is not a crank length.
* ``error`` — anything else the case raised (its type and message).
* ``killed`` — (set by the orchestrator) the case's worker process died every time it ran it.
"""
import math
import time

from ..solver.simulator import SimulationError
from .metrics import scenario_metrics, scene_metrics

STATUS_COLUMNS = ('status', 'failure', 'error', 'warnings', 'wall_time')
MAX_TEXT = 2000   # characters of an error or warnings text kept in the table


class CaseTimeout(Exception):
    """The case ran past its time budget."""


class CaseFailure(Exception):
    """A scenario run that stopped early: ``kind`` ('diverged' | 'controller'), the reason."""

    def __init__(self, kind, text):
        super().__init__(text)
        self.kind = kind


def _deadline(budget, start):
    """A progress callback that raises CaseTimeout once the wall time passes ``budget``."""
    def check(done, total):
        elapsed = time.perf_counter() - start
        if elapsed > budget:
            raise CaseTimeout(f"exceeded its time budget of {budget:g} s of wall time "
                              f"({elapsed:.3g} s, at t = {done:.4g} s of {total:g} s simulated)")
    return check


def _cut(text):
    text = str(text)
    return text if len(text) <= MAX_TEXT else f"{text[:MAX_TEXT]}… ({len(text)} characters)"


def empty_figures(task):
    """The figure columns of a case that produced none (NaN, and no window)."""
    figures = dict.fromkeys(task.metrics, math.nan)
    if task.kind == 'scene':
        figures.update(steady=None, window_start=math.nan)
    return figures


def _run_scene(task, deadline):
    from ..solver.fidelity import make_simulator
    values = task.values
    sim = make_simulator(values)
    result = sim.run(task.duration, task.sample_dt, progress=deadline)
    figures, warnings = scene_metrics(values, result, task.duration, task.window, task.metrics)
    if task.record:
        warnings += _record_scene(task, sim, result)
    return figures, warnings


def _record_scene(task, sim, result):
    from pathlib import Path
    Path(task.record).parent.mkdir(parents=True, exist_ok=True)
    if task.record.endswith('.csv'):
        from ..solver.offline import write_csv
        write_csv(task.record, result.samples)
        return []
    from ..recording.recorder import write_run
    _, error = write_run(task.record, sim, result, scene=f"sweep case {task.index}",
                         overwrite=True, source='cvt-sim sweep')
    return [f"recording {task.record}: {error}"] if error else []


def _run_scenario(task, deadline):
    from ..recording.errors import RecordingError
    from ..scenario.harness import make_plant, run_scenario
    mcap = task.record if task.record and not task.record.endswith('.csv') else None
    if task.record:
        from pathlib import Path
        Path(task.record).parent.mkdir(parents=True, exist_ok=True)

    def run_case_scenario(mcap):
        plant = make_plant('offline', task.scenario)
        # (the recording is written as the run goes; a CSV needs every sample kept)
        return plant, run_scenario(task.scenario, task.controller, 'offline',
                                   progress=deadline, plant=plant, mcap=mcap, overwrite=True,
                                   metrics_since=task.window,
                                   keep_samples=True if task.record and not mcap else None)
    warnings = []
    try:
        plant, run = run_case_scenario(mcap)
    except RecordingError as exc:   # (the file cannot be made: the case runs unrecorded)
        warnings.append(f"recording {task.record}: {exc}")
        mcap = None
        plant, run = run_case_scenario(None)
    if mcap and run.recording_error is not None:
        warnings.append(f"recording {task.record}: {run.recording_error}")
    elif task.record and mcap is None and task.record.endswith('.csv'):
        from ..solver.offline import write_csv
        write_csv(task.record, run.samples)
    if run.error:
        kind = 'diverged' if run.error.startswith('the simulation failed') else 'controller'
        raise CaseFailure(kind, run.error)
    energy = plant.sim.energy_balance() if hasattr(plant.sim, 'energy_balance') else {}
    figures = scenario_metrics(run, energy, task.metrics, since=task.window)
    since = task.window or 0.0   # (NaN figures: the table's warnings say why)
    if not any(s['t'] >= since - 1e-9 for s in run.steps):
        warnings.append(f"no set-point or load step from {since:g} s on (the run ends at "
                        f"{run.duration:g} s): the step metrics are NaN")
    elif all(v != v for k, v in figures.items() if k != 'energy_residual'):
        warnings.append(f"no step metric could be computed from {since:g} s on")
    return figures, warnings


def run_case(task):
    """Run one case; its table row (a dict: case, case_id, the varied values, the figures, then
    status, failure, error, warnings, wall_time)."""
    start = time.perf_counter()
    row = {'case': task.index, 'case_id': task.case_id, **task.variables}
    status, failure, error, warnings = 'ok', '', '', []
    figures = None
    try:
        runner = {'scene': _run_scene, 'scenario': _run_scenario}.get(task.kind, task.function)
        figures, warnings = runner(task, _deadline(task.time_budget, start))
    except CaseTimeout as exc:
        failure, error = 'timeout', str(exc)
    except SimulationError as exc:
        failure, error = 'diverged', str(exc)
    except CaseFailure as exc:
        failure, error = exc.kind, str(exc)
    except Exception as exc:   # noqa: BLE001 — one case's fault must not end the campaign
        failure, error = 'error', f"{type(exc).__name__}: {exc}"
    if failure:
        status, figures = 'failed', empty_figures(task)
    row.update(figures)
    row.update(status=status, failure=failure, error=_cut(error),
               warnings=_cut('; '.join(dict.fromkeys(warnings))),
               wall_time=time.perf_counter() - start)
    return row


def run_cases(tasks):
    """Run a batch of cases (one Dask task); their rows."""
    return [run_case(task) for task in tasks]


def killed_row(task, text):
    """The row of a case whose worker died every time it ran it (Dask's KilledWorker)."""
    row = {'case': task.index, 'case_id': task.case_id, **task.variables, **empty_figures(task)}
    row.update(status='failed', failure='killed', error=_cut(text), warnings='',
               wall_time=math.nan)
    return row


__all__ = ['CaseFailure', 'CaseTimeout', 'STATUS_COLUMNS', 'killed_row', 'run_case', 'run_cases']
