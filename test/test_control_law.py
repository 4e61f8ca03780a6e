"""The reference control law, the step metrics and the sensor/actuator models, checked against
closed forms (no ROS, no device)."""
import math

import numpy as np
import pytest

from cvt_ros.analysis.stepinfo import StepEvent, step_metrics
from cvt_ros.analysis.trace import Trace
from cvt_ros.control.measurement import Measurement
from cvt_ros.control.speed_pi import CycleMeanSpeed, SpeedPI, SpeedPIGains
from cvt_ros.scenario.realism import ActuatorModel, ActuatorSpec, SensorModel, SensorSpec

TWO_PI = 2 * math.pi


def test_cycle_mean_removes_the_ripple_of_the_crank_frequency():
    """ω4 = W + A·sin(φ1): the mean over each turn is exactly W, whatever the phase."""
    est = CycleMeanSpeed()
    w1, W, A = 150.0, 50.0, 5.0
    t = np.arange(0, 0.5, 1e-4)
    phi1 = 0.3 + w1 * t
    phi4 = W * t - A / w1 * np.cos(phi1)           # ∫(W + A sin(w1 t + 0.3)) dt
    means = [m for ti, p1, p4 in zip(t, phi1, phi4, strict=True)
             if (m := est.update(ti, p1, p4)) is not None]
    assert len(means) == int(w1 * 0.5 / TWO_PI - 1e-9)
    assert np.allclose(means[1:], W, rtol=2e-4)     # linear interpolation at the crossings


def test_cycle_mean_of_a_standing_crank_falls_back_to_a_time_window():
    est = CycleMeanSpeed(max_window=0.2)
    out = [est.update(k * 1e-3, 0.0, 2.0 * k * 1e-3) for k in range(400)]
    got = [v for v in out if v is not None]
    assert got and np.allclose(got, 2.0)


class _AlwaysFullPath(CycleMeanSpeed):
    def _set_quiet(self):
        self._quiet = (-math.inf, -math.inf)


def test_cycle_mean_early_answer_is_the_full_paths_to_the_bit():
    """The early "turn goes on" answer only skips work: samples placed just below, on and just
    above each crossing and window end (and hours into a run, where φ1 is large) give the same
    means, to the bit, as the full path on every sample."""
    rng = np.random.default_rng(3)
    for t0, phi0 in ((0.0, 0.3), (3600.0, 150.0 * 3600.0)):
        fast, full = CycleMeanSpeed(max_window=0.05), _AlwaysFullPath(max_window=0.05)
        t, phi1, phi4 = t0, phi0, 0.0
        for k in range(20000):
            # mostly 1 ms steps at 150 rad/s; now and then one that lands within 1e-12 of the
            # next crossing, or a standing crank (the time window)
            step = 0.15 if k % 7 else float(rng.choice([0.15, 1e-12, 0.0]))
            if k % 997 == 0:
                step = (fast._phi1_0 + (fast._turn + 1) * TWO_PI - phi1) * (1 - 1e-16)
            t += 1e-3
            phi1 += max(step, 0.0)
            phi4 += 0.05
            assert fast.update(t, phi1, phi4) == full.update(t, phi1, phi4), k


def _meas(t, phi1, phi4, a, sp, engaged=True):
    return Measurement(t, (phi1, 0.0, 0.0, phi4), (0.0,) * 4, (0.0,) * 4, a, engaged, sp)


def drive(law, speed, turns, a=0.04, sp=55.0, engaged=True, w1=150.0):
    """Feed ``turns`` crank turns at output speed ``speed`` (1 kHz, angles continuous across
    calls); return the commands."""
    t, phi4 = getattr(law, '_state', (0.0, 0.0))
    out = []
    for _ in range(int(turns * TWO_PI / w1 / 1e-3)):
        t += 1e-3
        phi4 += speed * 1e-3
        c = law(_meas(t, w1 * t, phi4, a, sp, engaged))
        if c is not None:
            out.append(c)
    law._state = (t, phi4)
    return out


def test_pi_acts_once_per_turn_in_the_right_direction_and_within_its_rate_limit():
    g = SpeedPIGains(kp=2e-3, ki=4e-3, rate_limit=0.01)
    law = SpeedPI(g)
    cmds = drive(law, 50.0, 10)                      # 5 rad/s too slow
    assert 8 <= len(cmds) <= 10                      # one command per completed turn
    assert cmds[0] == pytest.approx(0.04)            # bumpless start at the measured length
    steps = np.diff(cmds)
    assert np.all(steps > 0)                         # too slow → longer crank
    turn = TWO_PI / 150.0
    assert np.all(steps <= g.rate_limit * (turn + 1e-3) + 1e-15)


def test_anti_windup_at_the_range_limit():
    """Held at crank_max for a long time with a large error, the law leaves the limit as soon as
    the error changes sign (no wound-up integral to unwind)."""
    g = SpeedPIGains(kp=2e-3, ki=4e-3, crank_max=0.05, rate_limit=1.0)
    law = SpeedPI(g)
    assert max(drive(law, 20.0, 200, sp=80.0)) == pytest.approx(0.05)   # ~8 s at the limit
    assert law.integral <= 0.05 + g.kp * 60.0 + 1e-9
    after = drive(law, 90.0, 3, sp=80.0)              # now 10 rad/s too fast
    assert after[-1] < 0.05


def test_no_shortening_while_the_clutch_coasts():
    """A whole turn without engagement: the output coasts, a shorter crank cannot brake it."""
    law = SpeedPI(SpeedPIGains())
    drive(law, 55.0, 3)
    free = drive(law, 70.0, 5, engaged=False)         # too fast, clutch open
    assert max(free) - min(free) == 0.0
    driven = drive(law, 70.0, 3, engaged=True)
    assert driven[-1] < free[-1]


def test_gains_are_checked():
    with pytest.raises(ValueError, match='kp'):
        SpeedPI(SpeedPIGains(kp=float('nan')))
    with pytest.raises(ValueError, match='crank_max'):
        SpeedPI(SpeedPIGains(crank_min=0.05, crank_max=0.04))


# ------------------------------------------------------------------------------ step metrics
def synthetic_trace(t, y, w1=150.0):
    """A run whose cycle-mean output speed follows y(t) (crank at constant speed)."""
    phi1 = w1 * t
    phi4 = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(t))])
    n = len(t)
    phi = np.column_stack([phi1, np.zeros(n), phi4, phi4])
    omega = np.column_stack([np.full(n, w1), np.zeros(n), y, y])
    return Trace(source='synthetic', kind='test', t=t, phi=phi, omega=omega,
                 effort=np.zeros((n, 4)), twist=np.zeros(n), crank_length=np.full(n, 0.04),
                 switch_t=np.zeros(0), switch_engaged=np.zeros(0, bool), initial_engaged=True,
                 switches_exact=True)


def test_first_order_step_metrics_match_the_closed_form():
    tau, t_s, y0, y1 = 0.5, 1.0, 40.0, 60.0
    t = np.arange(0, 6.0, 1e-3)
    y = np.where(t < t_s, y0, y1 - (y1 - y0) * np.exp(-(t - t_s) / tau))
    ref = np.where(t < t_s, y0, y1)
    steps = step_metrics(synthetic_trace(t, y), t, ref,
                         [StepEvent(0.0, 'start', y0, y0), StepEvent(t_s, 'setpoint', y0, y1)])
    s = steps[1]
    assert s['rise_time'] == pytest.approx(tau * math.log(9), rel=0.02)
    assert s['overshoot'] == 0.0
    # last cycle outside ±2 %: ends within one crank turn (42 ms) after τ·ln 50
    assert tau * math.log(50) <= s['settling_time'] <= tau * math.log(50) + 0.045
    assert 0 < s['steady_state_error'] < 20 * math.exp(-4.5 / tau)   # last 10 %: t − t_s ≥ 4.5 s
    assert s['iae'] == pytest.approx(tau * (y1 - y0), rel=0.02)    # ∫ 20·e^{-t/τ} dt


def test_second_order_overshoot_matches_the_closed_form():
    zeta, wn, t_s = 0.4, 4.0, 0.5
    t = np.arange(0, 8.0, 1e-3)
    tt = np.clip(t - t_s, 0, None)
    wd = wn * math.sqrt(1 - zeta ** 2)
    unit = 1 - np.exp(-zeta * wn * tt) * (np.cos(wd * tt) + zeta / math.sqrt(1 - zeta ** 2)
                                          * np.sin(wd * tt))
    y = 50 + 10 * unit
    ref = np.where(t < t_s, 50.0, 60.0)
    s = step_metrics(synthetic_trace(t, y), t, ref,
                     [StepEvent(0.0, 'start', 50, 50), StepEvent(t_s, 'setpoint', 50, 60)])[1]
    expect = 100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2))
    assert s['overshoot'] == pytest.approx(expect, rel=0.03)


def test_load_step_reports_deviation_and_recovery():
    t = np.arange(0, 5.0, 1e-3)
    y = np.where(t < 2.0, 55.0, 55.0 - 3.0 * (t - 2.0) * np.exp(1 - (t - 2.0) / 0.2) / 0.2)
    s = step_metrics(synthetic_trace(t, y), t, np.full(len(t), 55.0),
                     [StepEvent(0.0, 'start', 55, 55), StepEvent(2.0, 'load', 8, 14)])[1]
    assert math.isnan(s['rise_time']) and math.isnan(s['overshoot'])
    assert s['max_deviation'] == pytest.approx(3.0, rel=0.02)
    assert 0.5 < s['settling_time'] < 1.5


# ------------------------------------------------------------------------------ realism
def observe_all(spec, n=50, seed=3, period=1e-3):
    model = SensorModel(spec, period, seed)
    out = []
    for k in range(n):
        t = k * period
        out.append(model.observe(t, (150 * t, 0.1, 30 * t, 30 * t), (150.0, 0.0, 30.0, 30.0),
                                 (5.0, 1.0, 1.0, 8.0), 0.04, True, 55.0))
    return out


def test_sensors_off_pass_the_state_through():
    m = observe_all(SensorSpec())[10]
    assert m.t == 0.01 and m.position[0] == 1.5 and m.crank_length == 0.04 and m.setpoint == 55


def test_noise_is_seeded_and_deterministic():
    spec = SensorSpec(position_noise=1e-3, velocity_noise=0.1)
    a, b, c = observe_all(spec), observe_all(spec), observe_all(spec, seed=4)
    assert a == b and a != c
    v = np.array([m.velocity[0] for m in observe_all(spec, n=4000)]) - 150.0
    assert abs(np.std(v) - 0.1) < 0.01


def test_quantization_delay_and_decimation():
    q = observe_all(SensorSpec(counts_per_turn=1000))
    count = TWO_PI / 1000
    assert all(abs(p / count - round(p / count)) < 1e-9 for m in q for p in m.position)
    assert q[20].velocity[0] == pytest.approx(150.0, abs=count / 1e-3)
    d = observe_all(SensorSpec(delay=0.003))
    assert [m.t for m in d[:6]] == pytest.approx([0, 0, 0, 0, 0.001, 0.002])
    h = observe_all(SensorSpec(decimation=4))
    assert [m.t for m in h[:9]] == pytest.approx([0, 0, 0, 0, 0.004, 0.004, 0.004, 0.004,
                                                  0.008])


def test_actuator_deadband_and_backlash():
    dead = ActuatorModel(ActuatorSpec(deadband=1e-4), 0.04)
    assert dead.command(0.04005) is None and dead.command(0.0402) == 0.0402
    play = ActuatorModel(ActuatorSpec(backlash=2e-4), 0.04)
    assert play.command(0.04005) == pytest.approx(0.04)      # inside the play
    assert play.command(0.0403) == pytest.approx(0.0402)     # drags the crank by c − b/2
    assert play.command(0.0402) == pytest.approx(0.0402)     # reversing: the play again
    assert play.command(0.0398) == pytest.approx(0.0399)
