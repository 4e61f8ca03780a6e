"""Identify the cycle-mean plant at an operating point: step responses fitted to FOPDT and
second-order models, and a frequency response from sine sweeps, for each input.

Inputs: the crank-length command [m] and the load torque [N·m]. Outputs: the cycle-mean output
speed ω̄4 and motor speed ω̄1 [rad/s]. At the operating point (:mod:`.operating_point`: the
scene's crank length and load torque, run to its steady state) each input is stepped by a small
amount up and down from the same state (copies of one Simulator), each step held until the cycle
means have settled again; both directions are fitted at once (:mod:`.fit`), and each direction's
own static gain is kept (``gain_up``, ``gain_down``: a one-way clutch need not be symmetric).
Then stepped sines from ``min_frequency`` to ``max_frequency`` (:mod:`.frequency`) measure
G(j2πf) on the full hybrid model, to check the fitted models where a controller's loop gain
crosses over.

    from cvt_ros.design.identify import identify
    plant = identify('conveyor')                       # or validated scene values
    plant.tf('crank_length')                           # control.TransferFunction (rational part)
    plant.tf('crank_length', pade_order=2)             # with the dead time (Padé)
    plant.state_space()                                # 2×2 control.StateSpace, Padé delays
    plant.to_dict()                                    # what `cvt-sim identify --json` writes

Settings are checked before anything runs where they can be (DesignError names the setting);
the sweep's upper frequency against the crank frequency once the operating point is known.
"""
import copy
import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .. import parameters
from ..physics.linkage import grashof_bound
from ..scene import load_scene
from .errors import DesignError
from .experiment import drive, record_of, window_means
from .fit import StepData, fit_model
from .frequency import DEFAULT_FRACTION, SETTLE_TIME_CONSTANTS, check_frequencies, sweep
from .operating_point import check_drives, settle

INPUTS = ('crank_length', 'load_torque')
OUTPUTS = ('output_speed', 'motor_speed')
#: the CycleTable field each output is read from (the crank is on the motor shaft: ω1)
OUTPUT_FIELDS = {'output_speed': 'output_speed', 'motor_speed': 'crank_speed'}
UNITS = {'crank_length': ('m', 'rad/s per m'), 'load_torque': ('N*m', 'rad/s per N*m')}
MODELS = ('fopdt', 'second_order')
PRE_STEP = 0.2               # s held before a step (its baseline cycles)
STEP_CHUNK = 1.0             # s run between two looks at a step's settling
SETTLED_CHANGE = 0.003       # settled: the last STEP_CHUNK's mean moved < 0.3 % of the peak
MIN_SAMPLES_PER_TURN = 8


@dataclass
class IdentifySettings:
    """How the plant is identified (SI units). None: chosen from the operating point."""
    crank_step: float = None       # m: default 2 % of the crank length (≥ 0.1 mm)
    load_step: float = None        # N·m: default 5 % of |load.torque| (≥ 0.2 N·m)
    sample_dt: float = 1e-3        # s: samples of every experiment
    fit_dt: float = 4e-3           # s: grid of the model fits (a multiple of sample_dt)
    settle_time: float = 60.0      # s: longest run to the operating point
    step_time: float = 30.0        # s: longest hold after a step
    tolerance: float = 1e-5        # steady band of the cycle means (relative)
    steady_cycles: int = 25        # crank turns the steady band must hold
    sweep: bool = True             # measure the frequency response
    min_frequency: float = None    # Hz: default 0.2 × the output speed FOPDT's corner
    max_frequency: float = None    # Hz: default DEFAULT_FRACTION × the crank frequency
    points: int = 8                # frequencies of the sweep (log-spaced)

    def check(self, values):
        """Raise DesignError naming the first setting that cannot work for scene ``values``."""
        def positive(name, high):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 < v <= high):
                raise DesignError(f"{name} = {v!r}: expected a number in (0, {high:g}]")
        for name, high in (('sample_dt', 0.01), ('fit_dt', 0.05), ('settle_time', 3600.0),
                           ('step_time', 3600.0), ('tolerance', 0.05)):
            positive(name, high)
        if self.fit_dt < self.sample_dt:
            raise DesignError(f"fit_dt = {self.fit_dt:g} s must be ≥ sample_dt = "
                              f"{self.sample_dt:g} s")
        if not (isinstance(self.steady_cycles, int) and 3 <= self.steady_cycles <= 10_000):
            raise DesignError(f"steady_cycles = {self.steady_cycles!r}: expected 3 … 10000")
        for name in ('min_frequency', 'max_frequency'):
            if getattr(self, name) is not None:
                positive(name, 1e4)
        a = values['linkage.crank_length']
        bound = grashof_bound(values['linkage.rocker_length'], values['linkage.coupler_length'],
                              values['linkage.pivot_distance'])
        step = self.crank_length_step(values)
        if not (math.isfinite(step) and 0 < step and a + step < bound and a - step > 0):
            raise DesignError(f"crank_step = {step!r} m: the steps a ± crank_step must stay in "
                              f"(0, {bound:g}) m (the Grashof bound) around linkage.crank_length "
                              f"= {a:g} m")
        load, limit = values['load.torque'], values['limits.load_torque']
        step = self.load_torque_step(values)
        if not (math.isfinite(step) and 0 < step and abs(load) + step <= limit):
            raise DesignError(f"load_step = {step!r} N·m: must be > 0 with |load.torque ± "
                              f"load_step| ≤ limits.load_torque = {limit:g} N·m")
        check_sampling(self.sample_dt, values)

    def crank_length_step(self, values):
        if self.crank_step is not None:
            return self.crank_step
        return max(0.02 * values['linkage.crank_length'], 1e-4)

    def load_torque_step(self, values):
        if self.load_step is not None:
            return self.load_step
        return max(0.05 * abs(values['load.torque']), 0.2)


def check_sampling(sample_dt, values):
    """A crank turn must hold MIN_SAMPLES_PER_TURN samples (the cycle boundaries)."""
    from .operating_point import motor_speed_scale
    speed = max(motor_speed_scale(values)[0], abs(values['initial.crank_speed']))
    turn = 2.0 * math.pi / speed if speed > 0 else math.inf
    if sample_dt * MIN_SAMPLES_PER_TURN > turn:
        raise DesignError(f"sample_dt = {sample_dt:g} s gives fewer than {MIN_SAMPLES_PER_TURN} "
                          f"samples per crank turn ({turn:.3g} s at {speed:g} rad/s): set "
                          f"sample_dt ≤ {turn / MIN_SAMPLES_PER_TURN:.2g} s")


@dataclass
class OutputModel:
    """One input → one output: the fitted models, each direction's static gain, the steps."""
    fopdt: object
    second_order: object
    gain_up: float
    gain_down: float
    steps: list = field(default_factory=list, repr=False)

    def model(self, kind):
        return getattr(self, kind)

    @property
    def best(self):
        """'fopdt', unless the second-order model fits with less than half its error."""
        return 'second_order' if self.second_order.fit_error < 0.5 * self.fopdt.fit_error \
            else 'fopdt'

    def to_dict(self):
        out = self.fopdt.to_dict()
        out.update(model='fopdt', gain_up=self.gain_up, gain_down=self.gain_down,
                   second_order=self.second_order.to_dict(), best_model=self.best)
        return out


@dataclass
class InputModel:
    """One input's plant: its step size and, per output, an :class:`OutputModel`; the sweep."""
    name: str
    step: float
    outputs: dict
    frequency: object = None

    def to_dict(self, operating_point):
        unit, gain_unit = UNITS[self.name]
        out = {'input_unit': unit, 'gain_unit': gain_unit, 'output': 'output_speed',
               **self.outputs['output_speed'].to_dict(), 'step': self.step,
               'motor_speed': self.outputs['motor_speed'].to_dict(),
               'operating_point': operating_point}
        if self.frequency is not None:
            out['frequency_response'] = self.frequency.to_dict(
                self.outputs['output_speed'].fopdt)
            out['frequency_response']['second_order_fit_error'] = \
                self.frequency.to_dict(self.outputs['output_speed'].second_order)[
                    'model_fit_error']
        return out


@dataclass
class PlantModel:
    """The identified plant at one operating point (see the module text)."""
    scene: str
    values: dict
    operating_point: object
    settings: IdentifySettings
    inputs: dict
    wall_time: float = 0.0

    def tf(self, input='crank_length', output='output_speed', model='fopdt', pade_order=None):
        """The fitted model from ``input`` to ``output`` as a ``control.TransferFunction``
        (the rational part; with ``pade_order`` its dead time as a Padé approximant)."""
        g = self.inputs[input].outputs[output].model(model).tf(pade_order)
        g.input_labels, g.output_labels = [input], [output]
        return g

    def state_space(self, model='fopdt', pade_order=2):
        """Both inputs (crank_length, load_torque) → both outputs (output_speed, motor_speed)
        as one ``control.StateSpace`` (dead times as Padé approximants of ``pade_order``)."""
        import control
        blocks = [self.tf(i, o, model, pade_order) for o in OUTPUTS for i in INPUTS]
        diag = control.append(*[control.ss(b) for b in blocks])
        n_in, n_out = len(INPUTS), len(OUTPUTS)
        fan_in = np.tile(np.eye(n_in), (n_out, 1))             # each input to its blocks
        sum_out = np.kron(np.eye(n_out), np.ones((1, n_in)))   # each output sums its blocks
        return control.ss(diag.A, diag.B @ fan_in, sum_out @ diag.C, sum_out @ diag.D @ fan_in,
                          inputs=list(INPUTS), outputs=list(OUTPUTS))

    def to_dict(self):
        point = self.operating_point.to_dict()
        settings = {k: v for k, v in asdict(self.settings).items()}
        settings.update(crank_step=self.inputs['crank_length'].step,
                        load_step=self.inputs['load_torque'].step)
        out = {'scene': self.scene, 'operating_point': point, 'settings': settings,
               'convention': 'num/den: python-control (descending powers of s), '
                             'G(s) = num/den · exp(-delay·s); gains in SI units; fit_error: '
                             'RMS(model - device) / RMS(device response) over the steps\' '
                             'cycle means'}
        for name in INPUTS:
            out[name] = self.inputs[name].to_dict(point)
        out['wall_time'] = self.wall_time
        return out


def _apply(sim, input_name, value):
    if input_name == 'crank_length':
        sim.command_crank_length(value)
    else:
        sim.set_load_torque(value)


def _step_record(sim0, values, input_name, u0, size, settings):
    """A step of ``size`` from the operating point: the Record (PRE_STEP s of baseline first)
    and the step's time."""
    sim = copy.deepcopy(sim0)
    dt = settings.sample_dt
    grid = max(1, round(settings.fit_dt / dt)) * dt
    pre = math.ceil(PRE_STEP / grid - 1e-9) * grid
    parts, switches = [], []
    samples, sw = drive(sim, pre, dt)
    parts.append(samples)
    switches += sw
    t_step = sim.t
    _apply(sim, input_name, u0 + size)
    held = 0.0
    while True:
        samples, sw = drive(sim, STEP_CHUNK, dt)
        parts.append(samples[1:])
        switches += sw
        held += STEP_CHUNK
        record = record_of(values, np.concatenate(parts), switches)
        if held >= 2 * STEP_CHUNK and _settled(record, t_step):
            return record, t_step
        if held >= settings.step_time - 1e-9:
            raise DesignError(f"the step of {input_name} by {size:+g} has not settled after "
                              f"step_time = {settings.step_time:g} s (the mean of its cycle "
                              f"means still moves by more than {SETTLED_CHANGE:.1%} of the "
                              f"response from one {STEP_CHUNK:g} s to the next): a longer "
                              f"step_time, or a smaller step")


def _settled(record, t_step):
    """The means of the cycle means over the last two STEP_CHUNKs differ by less than
    SETTLED_CHANGE of the response's peak, for both outputs (means of a second of cycles: a
    coarse sample interval's scatter of single cycle means averages out)."""
    mid = record.t_mid
    before = mid < t_step
    last = mid >= mid[-1] - STEP_CHUNK
    previous = (mid >= mid[-1] - 2 * STEP_CHUNK) & ~last & ~before
    if not np.any(previous) or not np.any(before):
        return False
    for name in OUTPUT_FIELDS.values():
        y = record.cycles[name]
        base = float(np.mean(y[before]))
        peak = float(np.max(np.abs(y - base)))
        drift = abs(float(np.mean(y[last]) - np.mean(y[previous])))
        if drift > SETTLED_CHANGE * peak + 1e-9 * abs(base):
            return False
    return True


def _step_data(record, t_step, size, field_name, grid_dt, input_name, u0):
    """StepData of one output of a step record: the fit grid, the input on it, the cycles.

    The crank length's input is the actual length (the actuator's travel, mean over each grid
    interval: the model's hold), so the rate-limited actuator stays out of the plant — its
    travel time depends on the step's size, a dead time no linear model keeps; the load's is
    the command (it acts at once)."""
    t = record.t
    k = max(1, round(grid_dt / (t[1] - t[0])))
    tg = t[::k]
    if input_name == 'crank_length':
        actual = record.column('crank_length') - u0
        u = np.append(window_means(t, actual, tg), actual[-1])
    else:
        u = np.where(tg >= t_step - 1e-9, size, 0.0)
    inside = (record.bounds >= tg[0]) & (record.bounds <= tg[-1])
    first, last = np.flatnonzero(inside)[[0, -1]]
    bounds = record.bounds[first:last + 1]
    y = record.cycles[field_name][first:last]
    base = float(np.mean(y[bounds[1:] <= t_step])) if np.any(bounds[1:] <= t_step) else y[0]
    return StepData(tg, u, bounds, y - base, size, t_step)


def identify(scene, overrides=None, settings=None, progress=None, origins=None):
    """The :class:`PlantModel` of ``scene`` (a name, path, or validated values dict) with
    ``overrides`` at its operating point. ``progress(text)`` hears each stage. Raises
    DesignError and the core's SceneError / ParameterError / GrashofError / SimulationError."""
    start = time.perf_counter()
    if isinstance(scene, dict):
        values, name = parameters.validate({**scene, **(overrides or {})}), 'values'
    else:
        values, name = load_scene(scene, overrides, origins), str(scene)
    settings = settings or IdentifySettings()
    check_drives(values)
    settings.check(values)
    say = progress or (lambda text: None)
    say('settling to the operating point')
    sim0, point = settle(values, settings.settle_time, settings.sample_dt, settings.tolerance,
                         settings.steady_cycles)
    high = settings.max_frequency
    if settings.sweep:
        high = high if high is not None else DEFAULT_FRACTION * point.crank_frequency
        check_frequencies(settings.min_frequency or high / 100, high, point.crank_frequency,
                          settings.points)
    inputs = {}
    for input_name in INPUTS:
        size = (settings.crank_length_step(values) if input_name == 'crank_length'
                else settings.load_torque_step(values))
        u0 = sim0.crank_length if input_name == 'crank_length' else sim0.load_torque
        say(f'steps of {input_name} (±{size:g})')
        records = [_step_record(sim0, values, input_name, u0, sign * size, settings)
                   for sign in (1.0, -1.0)]
        outputs = {}
        for output, field_name in OUTPUT_FIELDS.items():
            steps = [_step_data(r, t, sign * size, field_name, settings.fit_dt, input_name, u0)
                     for (r, t), sign in zip(records, (1.0, -1.0), strict=True)]
            outputs[output] = OutputModel(fit_model('fopdt', steps),
                                          fit_model('second_order', steps),
                                          steps[0].gain, steps[1].gain, steps)
        model = InputModel(input_name, size, outputs)
        if settings.sweep:
            model.frequency = _sweep(sim0, values, model, point, settings, high, say)
        inputs[input_name] = model
    plant = PlantModel(name, values, point, settings, inputs)
    plant.wall_time = time.perf_counter() - start
    return plant


def _sweep(sim0, values, model, point, settings, high, say):
    """The input's frequency response from min_frequency (default: a fifth of the output speed
    FOPDT's corner, at most high / 10) to ``high``; settling waits for the slower FOPDT (a
    second-order fit may hold a slow pole its zero cancels)."""
    fopdt = model.outputs['output_speed'].fopdt
    low = settings.min_frequency
    if low is None:
        low = min(0.2 / (2.0 * math.pi * fopdt.time_constant), high / 10)
    check_frequencies(low, high, point.crank_frequency, settings.points)
    slowest = max(m.fopdt.time_constant for m in model.outputs.values())
    frequencies = np.geomspace(low, high, settings.points)
    rate_limits = None
    if model.name == 'crank_length':
        rate_limits = (values['linkage.crank_rate_limit'], values['linkage.crank_accel_limit'])
    say(f'sine sweep of {model.name}: {settings.points} frequencies, {low:.3g} … {high:.3g} Hz')
    return sweep(sim0, values, model.name, frequencies, model.step, rate_limits,
                 SETTLE_TIME_CONSTANTS * slowest, settings.sample_dt, point.crank_frequency)


__all__ = ['INPUTS', 'OUTPUTS', 'IdentifySettings', 'InputModel', 'OutputModel', 'PlantModel',
           'identify']
