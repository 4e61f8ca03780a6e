"""One harness for every back end: a scenario, a controller and a plant, stepped in lockstep.

Each control period k (t_k = k·period):

1. the load schedule's value for period k goes to the plant if it changed (a disturbance never
   advances time; it acts from t_k);
2. the sensor model turns the plant's sample at t_k into the controller-facing Measurement (with
   the set point of the schedule at t_k);
3. the controller answers a crank-length command (or None: keep the last one); the harness checks
   it (a non-finite answer or an exception stops the run with the sim time), clamps it to the
   scenario's crank limits (min, max, rate; counted), passes it through the actuator model and,
   if it changed, to the plant;
4. the plant advances one period and returns its sample at t_{k+1} and the switches inside.

A run that stops early (controller error, simulation failure, Ctrl-C) keeps everything up to that
moment: ``ScenarioRun.error`` says why and when, the trace and the metrics cover what ran.
"""
import importlib
import inspect
import math
import time
import traceback

import numpy as np

from ..control.measurement import ControllerError, Measurement
from ..control.speed_pi import reference_controller
from ..numbers import NotANumber, real_number, shown
from ..solver.output import COL
from ..solver.simulator import SimulationError
from .plants import OfflinePlant, plant_values
from .realism import ActuatorModel, SensorModel
from .result import ScenarioRun
from .stream import RunStream

BACKENDS = ('offline', 'lockstep', 'dds')
CLAMP_TOLERANCE = 1e-12   # m: a limited command counts as clamped beyond rounding
SCHEDULE_CHUNK = 1 << 16  # control periods whose set point and load are sampled at once
REFERENCE = 'cvt_ros.control.speed_pi:reference_controller'
_POS = [COL[c] for c in ('phi1', 'phi2', 'phi3', 'phi4')]
_VEL = [COL[c] for c in ('omega1', 'omega2', 'omega3', 'omega4')]
_EFF = [COL[c] for c in ('motor_torque', 'clutch_torque', 'shaft_torque', 'load_torque')]
_A, _ENG = COL['crank_length'], COL['engaged']
_N_SEEN = COL['shaft_torque'] + 1   # the sample's columns a Measurement is made of
_new_tuple = tuple.__new__


class HarnessError(RuntimeError):
    """The harness cannot start (unknown back end, a controller spec that does not load)."""


def load_controller(spec, scenario):
    """``MODULE:FACTORY`` → the controller ``FACTORY(scenario)`` returns, or ``FACTORY()`` when it
    takes no argument. A class is the controller's type, its constructor's parameters its own
    settings (``MyPI(kp=2e-3, ...)``): it gets the scenario only as a parameter named
    ``scenario``, else it is built with its defaults."""
    module_name, sep, attr = str(spec).partition(':')
    if not sep or not module_name or not attr:
        raise HarnessError(f"--controller {spec!r}: expected MODULE:FACTORY, e.g. {REFERENCE}")
    try:
        module = importlib.import_module(module_name)
    except (Exception, SystemExit) as exc:   # noqa: BLE001 — the user's module's failure
        raise HarnessError(f"--controller {spec!r}: cannot import {module_name}: "
                           f"{shown(exc, 300)}") from None
    factory = module
    for part in attr.split('.'):
        try:
            factory = getattr(factory, part, None)
        except Exception:   # noqa: BLE001 — a module __getattr__ that raises
            factory = None
        if factory is None:
            raise HarnessError(f"--controller {spec!r}: {module_name} has no {attr}")
    try:
        parameters = inspect.signature(factory).parameters
        takes_scenario = 'scenario' in parameters if inspect.isclass(factory) else bool(parameters)
    except (TypeError, ValueError):
        takes_scenario = not inspect.isclass(factory)
    try:
        controller = factory(scenario) if takes_scenario else factory()
    except (Exception, SystemExit) as exc:   # noqa: BLE001
        raise HarnessError(f"--controller {spec!r}: {attr}() raised {shown(exc, 300)}"
                           ) from None
    if not callable(controller):
        raise HarnessError(f"--controller {spec!r}: {attr}() returned {shown(controller)}, "
                           f"not a callable controller(measurement) -> crank length")
    return controller


def make_plant(backend, scenario, **options):
    if backend == 'offline':
        return OfflinePlant(plant_values(scenario), scenario.control_period)
    if backend == 'lockstep':
        from .lockstep import LockstepPlant
        return LockstepPlant(plant_values(scenario), scenario.control_period, **options)
    if backend == 'dds':
        from .dds import DdsPlant
        return DdsPlant(scenario, **options)
    raise HarnessError(f"unknown back end {backend!r}; one of {', '.join(BACKENDS)}")


def run_scenario(scenario, controller=None, backend='offline', progress=None, plant=None,
                 mcap=None, overwrite=False, keep_samples=None, metrics_since=None, **options):
    """Run ``scenario`` with ``controller`` (a callable, a ``MODULE:FACTORY`` string, or None for
    the reference controller) on ``backend``; returns a :class:`ScenarioRun` (metrics included).
    ``progress(done_s, total_s)`` is called about every 1 % of the run. The run streams
    (scenario/stream.py): ``mcap``, a file to record it to as it goes (``overwrite`` an existing
    one); ``keep_samples`` True keeps every period's sample whatever the length (None: up to
    KEEP_PERIODS periods, a thinned trace beyond); ``metrics_since``, a start time [s] whose
    run-level metrics ``run.metrics_since(t)`` gives besides the whole run's."""
    name = REFERENCE if controller is None else getattr(controller, '__qualname__', None) \
        or type(controller).__name__
    external = options.get('controller_cmd')
    if external:
        if scenario.sensors.enabled or scenario.actuator.enabled:
            raise HarnessError(f"{scenario.path}: sensors/actuator models act between the device "
                               f"and an in-process controller; an external controller "
                               f"(--controller-cmd) reads the device's topics directly")
        name, controller = external, _external
    elif controller is None:
        controller = reference_controller(scenario)
    elif isinstance(controller, str):
        name = controller
        controller = load_controller(controller, scenario)
    if plant is None:
        plant = make_plant(backend, scenario, **options)
    recording = None
    try:
        if mcap is not None:
            from .recording import ScenarioRecording
            realtime = getattr(plant, 'realtime', None)
            recording = ScenarioRecording(scenario, mcap, overwrite, plant.name if not realtime
                                          else f"{plant.name}, realtime {realtime:g}x")
        stream = RunStream(scenario, recording, keep_samples,
                           () if metrics_since is None else (metrics_since,),
                           replay=hasattr(plant, 'replay'))
        return _loop(scenario, controller, plant, str(name), progress, stream)
    finally:
        plant.close()
        if recording is not None:   # (closed by the stream's end; here if the run raised)
            recording.recorder.close()


def _schedule_chunk(scenario, k0):
    """(set points, loads, end): the schedules at periods k0 … end − 1, as Python floats (the
    loop compares and passes them on), end at most SCHEDULE_CHUNK periods on."""
    end = min(k0 + SCHEDULE_CHUNK, scenario.periods + 1)
    t = np.arange(k0, end) * scenario.control_period
    return scenario.setpoint.sample(t).tolist(), scenario.load.sample(t).tolist(), end


def _external(measurement):
    """Stands in for a controller in another process: it commands the device itself."""
    return None


def _loop(scenario, controller, plant, controller_name, progress, stream):
    n = scenario.periods
    dt = scenario.control_period
    # the schedules are sampled a chunk of periods at a time (a day-long run never holds its
    # whole grid as Python floats); the samples and commands go through the stream a block at
    # a time (rows[k - base]: period k), its metrics, recording, plot and kept trace
    setpoints, loads, chunk_end = _schedule_chunk(scenario, 0)
    chunk0 = 0
    limits = scenario.crank_limits
    sensors = SensorModel(scenario.sensors, dt, scenario.seed)
    # without a sensor model the measurement is the sample itself (the model's identity), made
    # as the tuple it is (Measurement's own __new__ is one more Python call per period)
    observe = sensors.observe if scenario.sensors.enabled else None
    row = plant.start()            # (a node process starts here: not in the wall time)
    # (N ≥ 2 paths: the rows carry each path's columns after N_COLUMNS, output.path_columns)
    rows, commands = stream.start(row)
    block, base, switches = stream.block, 0, []
    wall0 = time.perf_counter()
    actuator = ActuatorModel(scenario.actuator, float(row[_A]))
    previous = float(row[_A])      # last command after the limiter [m], and its period
    k_previous = -1                # (the start counts as a command one period before)
    sent = previous                # last command the plant got [m]
    load_now = loads[0]
    clamped = 0
    error = exception = None
    every = max(1, n // 100)
    skips = getattr(plant, 'skips_periods', False)   # realtime: the newest sample only
    k = 0
    try:
        # (locals, not attributes or globals: this loop is a good part of a period's cost)
        step, new_tuple, measurement, n_seen = plant.step, _new_tuple, Measurement, _N_SEEN
        while k < n:
            if k >= chunk_end:
                setpoints, loads, chunk_end = _schedule_chunk(scenario, k)
                chunk0 = k
            j = k - chunk0
            if loads[j] != load_now:
                load_now = loads[j]
                plant.set_load_torque(load_now)
            r = row[:n_seen].tolist()
            # the time as a ROS stamp carries it (whole ns): every back end's controller sees
            # the same number (offline's t is a running sum of periods, dds's a stamp)
            r[0] = round(r[0] * 1e9) * 1e-9
            seen = (r[0], (r[1], r[2], r[3], r[4]), (r[5], r[6], r[7], r[8]),
                    (r[14], r[11], r[15], r[13]), r[12], r[11] > 0.0, setpoints[j])
            m = new_tuple(measurement, seen) if observe is None else observe(*seen)
            try:
                a = controller(m)
            except (Exception, SystemExit) as exc:   # noqa: BLE001 — the user's code
                where = traceback.extract_tb(exc.__traceback__)[-1]   # the raising line
                raise ControllerError(f"the controller raised {shown(exc, 300)} at t = "
                                      f"{r[0]:.6f} s "
                                      f"(period {k}) in {where.filename}:{where.lineno} "
                                      f"({where.name})") from exc
            if a is not None:
                if type(a) is not float:   # (numpy's float64 is one; text and bools are not)
                    try:
                        a = real_number(a)
                    except NotANumber as exc:
                        raise ControllerError(f"the controller returned {shown(a)} at t = "
                                              f"{r[0]:.6f} s (period {k}): not a crank length "
                                              f"[m] ({exc})") from None
                if not math.isfinite(a):
                    raise ControllerError(f"the controller returned {a!r} at t = {r[0]:.6f} s "
                                          f"(period {k}): not a finite crank length")
                reach = limits.rate * (k - k_previous) * dt   # rate limit since the last one
                limited = min(max(a, limits.min, previous - reach), limits.max, previous + reach)
                if abs(limited - a) > CLAMP_TOLERANCE:
                    clamped += 1
                previous, k_previous = limited, k
                commands[k - base] = limited
                passed = actuator.command(limited)
                if passed is not None and passed != sent:
                    sent = passed
                    plant.command_crank_length(passed)
            row, sw = step()
            k_next = min(max(k + 1, int(round(row[0] / dt))), n) if skips else k + 1
            while k_next - base >= block:   # (a realtime run may skip past a whole block)
                stream.flush(base, block, switches)
                base, switches = base + block, []
            rows[k_next - base] = row
            if sw:
                switches.extend(sw)
            if progress is not None and k // every != k_next // every:
                progress(k_next * dt, scenario.duration)
            k = k_next
    except ControllerError as exc:
        error, exception = str(exc), exc.__cause__
    except SimulationError as exc:
        error = f"the simulation failed in period {k}: {exc}"
    except KeyboardInterrupt:
        error = f"interrupted at t = {k * dt:.6f} s (period {k})"
    wall = time.perf_counter() - wall0 - stream.busy   # (the loop's: metrics, recording apart)
    stream.flush(base, k - base + 1, switches)
    if stream.replay_mode:
        # dds: the node's own recording is the trace (every period; each switch at its time)
        stream.replay(plant.replay(k * dt))
    # the solver's self-check where the plant runs in this process (a node over DDS reports it
    # on its /diagnostics and in its own recording)
    self_check = plant.self_check() if hasattr(plant, 'self_check') else None
    return ScenarioRun(scenario=scenario, backend=plant.name, controller=controller_name,
                       clamped=clamped, wall_time=wall, error=error, exception=exception,
                       realtime=getattr(plant, 'realtime', None),
                       domain=getattr(plant, 'domain', None),
                       node_timing=getattr(plant, 'node_timing', None), self_check=self_check,
                       **stream.finish(self_check))
