"""``cvt-sim tune``: a PI for the reference controller from the identified model, checked on the
full device.

The rule is SIMC (Skogestad, "Simple analytic rules for model reduction and PID controller
tuning", J. Process Control 13, 2003) for a first-order-plus-dead-time plant K·e^(−θs)/(τs + 1)
and a chosen closed-loop time constant τc:

    Kc = τ / (K·(τc + θ_eff)),        τI = min(τ, 4·(τc + θ_eff))

which for the reference controller (:mod:`cvt_ros.control.speed_pi`, u = kp·e + ki·∫e dt) is
kp = Kc [m per rad/s] and ki = Kc / τI [m per rad]. The dead time is the identified plant's θ
plus one crank turn: the controller measures the cycle-mean speed once per turn (on average
half a turn old) and holds its command for a turn (half a turn more). The default τc = τ (SIMC's
smooth choice: as fast closed as open); τc below θ_eff (SIMC's "tight" limit) is refused.

The check runs the controller kit (:mod:`cvt_ros.scenario`, offline back end: the full hybrid
device) on a scenario made for it: the scene from rest with the set point at the operating
point's output speed, held until the loop has settled, then a set-point step small enough that
the proportional kick stays within one turn of the crank rate limit (so the loop is as linear as
the model: a larger step is rate-limited, and slower than any linear prediction). The model's
prediction is python-control's closed loop of the same PI and the FOPDT (dead time as a Padé
approximant of order 3).
"""
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..control.speed_pi import SpeedPIGains
from ..scene import load_scene, resolve
from .errors import DesignError
from .identify import IdentifySettings, identify

RULE = 'SIMC PI (Skogestad 2003)'
PADE_ORDER = 3
BAND = 0.02                  # settling band: ±2 % of the step (as analysis.stepinfo)


@dataclass
class Check:
    """The predicted and the device's closed-loop step (time from the step, deviations added
    back to the operating point)."""
    rule: str
    model: str
    gains: dict
    t_model: np.ndarray
    speed_model: np.ndarray
    crank_model: np.ndarray
    setpoint: np.ndarray
    t_device: np.ndarray
    speed_device: np.ndarray
    crank_device: np.ndarray
    settling_model: float
    settling_device: float
    overshoot_model: float
    overshoot_device: float
    steady_before: bool
    error: str = None

    @property
    def ok(self):
        return self.error is None


@dataclass
class Tuning:
    """The tuned PI, the model it came from, the check."""
    scene: str
    gains: dict              # kp, ki (the scenario's controller: section)
    tau_c: float
    theta_eff: float
    integral_time: float
    plant: object            # the PlantModel
    check: Check
    setpoint_step: float

    def section(self):
        """The scenario-ready ``controller:`` section (YAML text with its provenance)."""
        m = self.plant.inputs['crank_length'].outputs['output_speed'].fopdt
        p = self.plant.operating_point
        return (f"# cvt-sim tune {self.scene}: {RULE} from the FOPDT model at a = "
                f"{p.crank_length:.6g} m, load {p.load_torque:.6g} N·m\n"
                f"#   K = {m.gain:.5g} rad/s per m, τ = {m.time_constant:.4g} s, θ = "
                f"{m.delay:.3g} s (+ one crank turn: θ_eff = {self.theta_eff:.3g} s), "
                f"τc = {self.tau_c:.4g} s, τI = {self.integral_time:.4g} s\n"
                f"controller:\n"
                f"  kp: {self.gains['kp']:.6g}     # m per rad/s of speed error\n"
                f"  ki: {self.gains['ki']:.6g}     # m per rad of integrated error\n")

    def write_section(self, path):
        Path(path).write_text(self.section(), encoding='utf-8')
        return path

    def to_dict(self):
        c = self.check
        return {'scene': self.scene, 'rule': RULE, 'controller': dict(self.gains),
                'tau_c': self.tau_c, 'theta_eff': self.theta_eff,
                'integral_time': self.integral_time, 'setpoint_step': self.setpoint_step,
                'model': self.plant.inputs['crank_length'].outputs['output_speed'].fopdt
                .to_dict(),
                'operating_point': self.plant.operating_point.to_dict(),
                'check': {'settling_time_model': c.settling_model,
                          'settling_time_device': c.settling_device,
                          'overshoot_model': c.overshoot_model,
                          'overshoot_device': c.overshoot_device,
                          'steady_before_step': c.steady_before, 'error': c.error}}

    def format(self):
        c = self.check
        return '\n'.join([
            self.section().rstrip(),
            f"check ({self.setpoint_step:+.4g} rad/s set-point step on the full device, "
            f"controller kit offline): settling (2 %) model {_text(c.settling_model)}, device "
            f"{_text(c.settling_device)}; overshoot model {c.overshoot_model:.1%}, device "
            f"{c.overshoot_device:.1%}"
            + ('' if c.steady_before else ' (the loop had not settled before the step)')])


def _text(seconds):
    return f"{seconds:.3g} s" if math.isfinite(seconds) else 'n/a'


def simc(gain, time_constant, dead_time, tau_c):
    """SIMC PI: (kp, ki, τI) for K·e^(−θs)/(τs+1) and closed-loop time constant τc."""
    kc = time_constant / (gain * (tau_c + dead_time))
    integral_time = min(time_constant, 4.0 * (tau_c + dead_time))
    return kc, kc / integral_time, integral_time


def step_figures(t, y, step):
    """(settling time [s], overshoot [fraction]) of the deviation y(t) answering a step of
    ``step`` at t = 0 (settling: the end of the last sample outside ±2 % of the step)."""
    after = t >= 0
    t, e = t[after], (y[after] - step) / step
    outside = np.flatnonzero(np.abs(e) > BAND)
    settling = math.nan if len(outside) and outside[-1] == len(e) - 1 else \
        (float(t[outside[-1] + 1]) if len(outside) else 0.0)
    return settling, max(0.0, float(np.max(e)))


def predict(model, kp, ki, theta_turn, setpoint_step, t):
    """python-control's closed loop of the PI and the model (dead time θ + θ_turn as a Padé
    approximant): (speed deviation, crank-length deviation) on ``t`` for a set-point step."""
    import control
    plant = model.tf() * control.tf(*control.pade(model.delay + theta_turn, PADE_ORDER))
    pi = control.tf([kp, ki], [1.0, 0.0])
    speed = control.forced_response(control.feedback(pi * plant, 1), t,
                                    np.full(len(t), setpoint_step)).outputs
    crank = control.forced_response(control.feedback(pi, plant), t,
                                    np.full(len(t), setpoint_step)).outputs
    return np.asarray(speed), np.asarray(crank)


def _scenario(values_path, overrides, duration, setpoint, step, at, gains, crank_max, tmp):
    """The check's scenario file (the library's own parser checks it)."""
    import yaml
    doc = {'description': 'cvt-sim tune: closed-loop check of the tuned PI',
           'scene': str(values_path), 'overrides': dict(overrides), 'duration': duration,
           'control_period': 0.001,
           'setpoint': {'initial': setpoint, 'changes': [{'at': at, 'step': setpoint + step}]},
           'crank_limits': {'min': 0.0, 'max': crank_max},
           'controller': dict(gains)}
    path = Path(tmp) / 'tune_check.yaml'
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding='utf-8')
    return path


def tune(scene, overrides=None, settings=None, tau_c=None, setpoint_step=None, duration=None,
         say=None, origins=None):
    """Identify, tune and check; a :class:`Tuning`. Raises DesignError (and identify's)."""
    from ..analysis.steady import find_steady_state
    from ..scenario.harness import run_scenario
    from ..scenario.model import ScenarioError, load_scenario
    say = say or (lambda text: None)
    overrides = dict(overrides or {})
    values = load_scene(scene, overrides, origins)
    settings = settings or IdentifySettings(sweep=False)
    plant = identify(values, None, settings, say)
    model = plant.inputs['crank_length'].outputs['output_speed'].fopdt
    point = plant.operating_point
    turn = 1.0 / point.crank_frequency
    theta_eff = model.delay + turn
    if model.gain <= 0 or model.time_constant <= 0:
        raise DesignError(f"the crank length → output speed model (K = {model.gain:.4g}, τ = "
                          f"{model.time_constant:.4g} s) is not a plant a PI of positive gains "
                          f"can control here")
    tau_c = model.time_constant if tau_c is None else tau_c
    if not (math.isfinite(tau_c) and tau_c >= theta_eff):
        raise DesignError(f"tau_c = {tau_c!r} s is below the effective dead time θ_eff = "
                          f"{theta_eff:.3g} s (the plant's {model.delay:.3g} s + one crank turn "
                          f"{turn:.3g} s): SIMC's tightest tuning is tau_c = θ_eff")
    kp, ki, integral_time = simc(model.gain, model.time_constant, theta_eff, tau_c)
    gains = SpeedPIGains(kp=kp, ki=ki)
    try:
        gains.check()
    except ValueError as exc:
        raise DesignError(f"the tuned controller is not usable: {exc}") from None
    rate = values['linkage.crank_rate_limit']
    if setpoint_step is None:   # the P kick within one turn of the rate limit: a linear loop
        setpoint_step = min(0.02 * point.output_speed, 0.5 * rate * turn / kp)
    if not (math.isfinite(setpoint_step) and setpoint_step != 0):
        raise DesignError(f"setpoint_step = {setpoint_step!r} rad/s: a nonzero number")
    after = duration if duration is not None else 8.0 * tau_c + 4.0 * model.time_constant
    lead = math.ceil(2.0 * point.settled_at + 6.0 * tau_c)
    total = round(lead + after, 3)
    say(f'checking kp = {kp:.3g}, ki = {ki:.3g} on the device: {total:g} s, step at {lead:g} s')
    from ..physics.linkage import grashof_bound
    bound = grashof_bound(values['linkage.rocker_length'], values['linkage.coupler_length'],
                          values['linkage.pivot_distance'])
    with tempfile.TemporaryDirectory(prefix='cvt_tune_') as tmp:
        scene_ref = resolve(scene) if not isinstance(scene, dict) else None
        if scene_ref is None:
            raise DesignError('tune needs a scene name or file (the check is a scenario)')
        path = _scenario(scene_ref.resolve(), overrides, total, point.output_speed,
                         setpoint_step, float(lead), {'kp': kp, 'ki': ki}, 0.9 * bound, tmp)
        try:
            scenario = load_scenario(path)
        except ScenarioError as exc:
            raise DesignError(f"the check's scenario: {exc}") from None
        run = run_scenario(scenario, None, 'offline', keep_samples=True)   # (its whole trace)
    from ..analysis.cycles import cycle_metrics
    cycles, bounds = cycle_metrics(run.trace())   # (N paths: each path's switches, any clutch)
    mid = 0.5 * (bounds[:-1] + bounds[1:])
    before = mid < lead
    steady = find_steady_state(cycles, 0, int(np.count_nonzero(before)), tolerance=2e-3)
    base_speed = float(np.mean(cycles['output_speed'][before][-10:]))
    base_crank = float(np.mean(cycles['crank_length'][before][-10:]))
    t_device = mid - lead
    y_device = cycles['output_speed'] - base_speed
    t_model = np.arange(0.0, after, 1e-3)
    y_model, u_model = predict(model, kp, ki, turn, setpoint_step, t_model)
    s_model, o_model = step_figures(t_model, y_model, setpoint_step)
    s_device, o_device = step_figures(t_device, y_device, setpoint_step)
    window = t_device >= -min(lead, 2.0)
    check = Check(RULE, 'FOPDT', {'kp': kp, 'ki': ki}, t_model, base_speed + y_model,
                  base_crank + u_model, np.full(len(t_model), base_speed + setpoint_step),
                  t_device[window], cycles['output_speed'][window],
                  cycles['crank_length'][window], s_model, s_device, o_model, o_device,
                  steady.found, run.error)
    return Tuning(str(scene), {'kp': kp, 'ki': ki}, tau_c, theta_eff, integral_time, plant,
                  check, setpoint_step)


__all__ = ['Check', 'RULE', 'Tuning', 'predict', 'simc', 'step_figures', 'tune']
