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
