"""Closed-form linkage (paper eq. 1): constraint satisfied, derivatives, Grashof refusal."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cvt_ros.physics.linkage import (
    GrashofError,
    check_crank_length,
    constraint_partials,
    grashof_bound,
    kinematics,
    rocker_angle,
)

B, D, H = 0.10, 0.20, 0.20


def phi2(phi1, a, sigma=1.0):
    return rocker_angle(phi1, a, B, D, H, sigma)


@given(phi1=st.floats(-20.0, 20.0), a=st.floats(0.0, 0.0999), sigma=st.sampled_from([1.0, -1.0]))
@settings(max_examples=300, deadline=None)
def test_closed_form_satisfies_loop_closure(phi1, a, sigma):
    p2 = phi2(phi1, a, sigma)
    f = constraint_partials(phi1, p2, a, B, H, D)[0]
    assert abs(f) < 1e-14
    # the pin distance |AB| is the coupler length: the geometry, not just the algebra
    ax, ay = a * math.cos(phi1), a * math.sin(phi1)
    bx, by = H + B * math.cos(p2), B * math.sin(p2)
    assert math.hypot(bx - ax, by - ay) == pytest.approx(D, abs=1e-14)


@pytest.mark.parametrize('a', [0.0, 0.01, 0.03, 0.07, 0.095])
def test_derivatives_match_central_differences(a):
    eps_phi, eps_a = 1e-5, 1e-7
    for phi1 in np.linspace(0.0, 2.0 * math.pi, 13):
        c2, s2, u, up, ga, ua, gaa = kinematics(phi1, a, B, D, H, 1.0)
        p = phi2(phi1, a)
        assert c2 == pytest.approx(math.cos(p), abs=1e-13)
        assert s2 == pytest.approx(math.sin(p), abs=1e-13)
        u_fd = (phi2(phi1 + eps_phi, a) - phi2(phi1 - eps_phi, a)) / (2 * eps_phi)
        assert u == pytest.approx(u_fd, rel=1e-7, abs=1e-8)
        u_at = lambda x, aa: kinematics(x, aa, B, D, H, 1.0)[2]  # noqa: E731
        up_fd = (u_at(phi1 + eps_phi, a) - u_at(phi1 - eps_phi, a)) / (2 * eps_phi)
        assert up == pytest.approx(up_fd, rel=1e-6, abs=1e-7)
        if a >= eps_a:
            ga_fd = (phi2(phi1, a + eps_a) - phi2(phi1, a - eps_a)) / (2 * eps_a)
            assert ga == pytest.approx(ga_fd, rel=1e-6, abs=1e-6)
            ua_fd = (u_at(phi1, a + eps_a) - u_at(phi1, a - eps_a)) / (2 * eps_a)
            assert ua == pytest.approx(ua_fd, rel=1e-5, abs=1e-5)
            ga_hi = kinematics(phi1, a + eps_a, B, D, H, 1.0)[4]
            ga_lo = kinematics(phi1, a - eps_a, B, D, H, 1.0)[4]
            gaa_fd = (ga_hi - ga_lo) / (2 * eps_a)
            assert gaa == pytest.approx(gaa_fd, rel=1e-5, abs=1e-4)


def test_u_is_the_papers_ratio_A1_over_A2():
    a = 0.03
    for phi1 in np.linspace(0.1, 6.2, 7):
        p = phi2(phi1, a)
        A1 = a * H * math.sin(phi1) + a * B * math.sin(phi1 - p)
        A2 = B * H * math.sin(p) + a * B * math.sin(phi1 - p)
        assert kinematics(phi1, a, B, D, H, 1.0)[2] == pytest.approx(A1 / A2, rel=1e-12)


def test_rocker_swing_grows_with_crank_length():
    phis = np.linspace(0.0, 2.0 * math.pi, 721)
    swings = [np.ptp([phi2(p, a) for p in phis]) for a in (0.0, 0.01, 0.03, 0.06)]
    assert swings[0] < 1e-15
    assert all(s1 < s2 for s1, s2 in zip(swings, swings[1:], strict=False))


def test_grashof_bound_and_refusal_messages():
    assert grashof_bound(B, D, H) == pytest.approx(0.1)
    assert check_crank_length(0.0, B, D, H) == pytest.approx(0.1)
    for bad in (0.1, 0.2, -0.01, math.nan, math.inf):
        with pytest.raises(GrashofError) as err:
            check_crank_length(bad, B, D, H)
        assert 'crank length' in str(err.value)
    with pytest.raises(GrashofError, match=r'outside \[0, 0.1\)'):
        check_crank_length(0.15, B, D, H)
    with pytest.raises(GrashofError, match='admits no turning crank'):
        check_crank_length(0.01, 0.1, 0.5, 0.2)
