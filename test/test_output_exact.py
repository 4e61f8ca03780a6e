"""The closed-form disengaged output subsystem against scipy on the same linear ODE."""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cvt_ros.parameters import parameter_vector, validate
from cvt_ros.physics.layout import (
    N_OUTPUT,
    P_OUTPUT_RATE,
    Z_OMEGA3,
    Z_OMEGA4,
    Z_PHI4,
    Z_TWIST,
    Z_W_DAMPING,
    Z_W_LOAD,
)
from cvt_ros.physics.output_exact import modal_coordinates, modal_form, output_at


def reference(values, z0, tau):
    J3, J4 = values['inertia.clutch_driven'], values['inertia.output']
    c, k = values['shaft.stiffness'], values['shaft.damping']
    T, kv = values['load.torque'], values['load.viscous']

    def f(t, z):
        theta, w3, phi4, w4, _, _ = z
        ts = c * theta + k * (w3 - w4)
        m4 = T + kv * w4
        return [w3 - w4, -ts / J3, w4, (ts - m4) / J4, m4 * w4, k * (w3 - w4) ** 2]
    sol = solve_ivp(f, (0.0, tau), z0, method='DOP853', rtol=1e-13, atol=1e-15)
    return sol.y[:, -1]


@pytest.mark.parametrize('changes', [
    {},                                                     # paper: undamped, constant load
    {'shaft.damping': 0.3},                                 # damped, constant load
    {'load.viscous': 0.2},                                  # viscous load
    {'shaft.damping': 0.3, 'load.viscous': 0.2},            # both: Gauss–Legendre loss
    {'shaft.damping': 2.0 * np.sqrt(500.0 * 0.001), 'load.torque': -3.0},  # ~critical
])
def test_closed_form_matches_integration(changes):
    values = validate(changes)
    P = parameter_vector(values)
    usable, lin, rate, _ = modal_form(P)
    assert usable and rate > 0.0
    P[P_OUTPUT_RATE] = rate   # as the Simulator does: sets the quadrature panels
    z0 = np.array([0.01, 30.0, 12.0, 25.0, 1.0, 0.5])
    W = np.zeros((2, 3), dtype=np.complex128)
    modal_coordinates(z0, P, lin, W)
    z = np.empty(N_OUTPUT)
    for tau in (1e-4, 3e-3, 0.02):
        output_at(tau, z0, P, lin, W, z, True)
        ref = reference(values, z0, tau)
        for i, scale in ((Z_TWIST, 0.01), (Z_OMEGA3, 30.0), (Z_PHI4, 12.0), (Z_OMEGA4, 25.0),
                         (Z_W_LOAD, 1.0), (Z_W_DAMPING, 1.0)):
            assert z[i] == pytest.approx(ref[i], abs=1e-10 * scale), (i, tau)


def test_nonlinear_or_degenerate_outputs_are_not_solved_in_closed_form():
    for changes in ({'load.quadratic': 0.01}, {'inertia.clutch_driven': 0.0},
                    {'shaft.stiffness': float('inf')}):
        assert not modal_form(parameter_vector(validate(changes)))[0]


def _loss_in_long_double(tau, lin, W, k, nodes=40):
    """k·∫(ω3 − ω4)² over [0, τ] by Gauss–Legendre on the modal solution in long double: an
    independent check of the closed form (no identity, no series)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    lam = lin[0].astype(np.clongdouble)
    d = (lin[2] - lin[3]).astype(np.clongdouble)
    w0, wb = W[0].astype(np.clongdouble), W[1].astype(np.clongdouble)
    total = np.longdouble(0.0)
    for ti, wi in zip(np.longdouble(tau) * (x.astype(np.longdouble) + 1) / 2, w, strict=True):
        e = np.exp(lam * ti)
        slip = np.sum(d * (w0 * e + wb * (e - 1) / lam)).real
        total += np.longdouble(wi) * slip * slip
    return float(total * np.longdouble(tau) / 2 * np.longdouble(k))


@pytest.mark.parametrize('changes', [
    {'shaft.damping': 0.05, 'load.viscous': 0.05, 'shaft.stiffness': 1500.0,
     'inertia.output': 1.5},                                   # the conveyor: slow rigid mode
    {'shaft.damping': 0.3, 'load.viscous': 0.2},
    {'shaft.damping': 1e-6, 'load.viscous': 1e-6},             # nearly undamped, nearly free
    {'shaft.damping': 2.0 * np.sqrt(500.0 * 0.001), 'load.viscous': 0.5},   # ~critical
    {'shaft.damping': 5.0, 'load.viscous': 1e-4},              # overdamped
    {'shaft.damping': 1e-3, 'load.viscous': 3.0},
])
def test_damping_loss_in_closed_form_matches_long_double_quadrature(changes):
    """The loss k·∫(ω3 − ω4)² (identity, series and short-step forms) within 1e-11 of the
    long-double quadrature (measured: ~2e-12 on the near-critical shaft, whose eigenvectors are
    nearly parallel; ≤ 1e-13 on the others)."""
    values = validate(changes)
    P = parameter_vector(values)
    usable, lin, rate, _ = modal_form(P)
    assert usable
    P[P_OUTPUT_RATE] = rate
    rng = np.random.default_rng(7)
    W = np.zeros((2, 3), dtype=np.complex128)
    z = np.empty(N_OUTPUT)
    for tau in np.geomspace(1e-7, 1e-2, 41):
        z0 = np.array([rng.normal() * 0.01, rng.normal() * 30.0, 12.0, rng.normal() * 30.0,
                       0.0, 0.0])
        modal_coordinates(z0, P, lin, W)
        output_at(tau, z0, P, lin, W, z, True)
        ref = _loss_in_long_double(tau, lin, W, values['shaft.damping'])
        assert z[Z_W_DAMPING] == pytest.approx(ref, rel=1e-11, abs=1e-300), tau
