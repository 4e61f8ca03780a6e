"""Crank-length actuator: time-optimal trapezoid, limits respected, exact arrival, continuity."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cvt_ros.physics.drives import crank_actuator, plan_profile
from cvt_ros.physics.layout import ACT_T

RATE, ACCEL = 0.01, 1.0


@given(a0=st.floats(0.0, 0.09), target=st.floats(0.0, 0.09),
       v0=st.floats(-RATE, RATE), t0=st.floats(0.0, 100.0))
@settings(max_examples=300, deadline=None)
def test_profile_limits_continuity_and_arrival(a0, target, v0, t0):
    act = plan_profile(t0, a0, v0, target, RATE, ACCEL)
    starts = act[:, ACT_T][np.isfinite(act[:, ACT_T])]
    assert starts[0] == t0 and np.all(np.diff(starts) >= 0.0)
    t_arrive = starts[-1]
    # position and speed continuous across every row boundary
    for tb in starts[1:]:
        before = crank_actuator(np.nextafter(tb, -np.inf), act)
        after = crank_actuator(tb, act)
        assert after[0] == pytest.approx(before[0], abs=1e-12)
        assert after[1] == pytest.approx(before[1], abs=1e-9)
    ts = np.linspace(t0, t_arrive + 0.1, 400)
    vals = np.array([crank_actuator(t, act) for t in ts])
    assert np.all(np.abs(vals[:, 1]) <= max(RATE, abs(v0)) * (1 + 1e-9))
    assert np.all(np.abs(vals[:, 2]) <= ACCEL * (1 + 1e-12))
    end = crank_actuator(t_arrive + 1.0, act)
    assert end == (target, 0.0, 0.0)
    # the move stays between the start (or where braking ends) and the target: no overshoot
    lo = min(a0, target) - v0 * v0 / (2 * ACCEL) - 1e-12
    hi = max(a0, target) + v0 * v0 / (2 * ACCEL) + 1e-12
    assert np.all((vals[:, 0] >= lo) & (vals[:, 0] <= hi))


def test_long_move_cruises_at_the_rate_limit():
    act = plan_profile(0.0, 0.02, 0.0, 0.06, RATE, ACCEL)
    t_arrive = act[np.isfinite(act[:, ACT_T]), ACT_T][-1]
    # 0.04 m at 0.01 m/s plus one ramp time 0.01 s (accelerate + brake at 1 m/s²)
    assert t_arrive == pytest.approx(0.04 / RATE + RATE / ACCEL, rel=1e-12)
    assert crank_actuator(2.0, act)[1] == pytest.approx(RATE)
