"""Energy balance of a run from its samples and the scene parameters (physics.md §7): the
residual ΔE − (W1 − W4 − Wd), trapezoidal over the samples (it measures the sampling more than
the solver)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .cycles import Integrator
from .trace import Trace

__all__ = ['energy_balance']


def energy_balance(trace: Trace) -> dict[str, Any]:
    """Energy residual over the whole run from the samples and the scene parameters."""
    p = trace.parameters
    if not p:
        return {'available': False, 'reason': 'no scene parameters in the recording (give '
                                              '--scene)'}
    if np.all(np.isnan(trace.effort[:, 0])):
        return {'available': False, 'reason': 'no motor torque in the input (a cvt-sim run CSV '
                                              'with a constant_speed motor, or no --scene)'}
    try:
        J = [float(p[k]) for k in ('inertia.motor', 'inertia.rocker', 'inertia.clutch_driven',
                                   'inertia.output')]
        c = float(p['shaft.stiffness'])
        kd = float(p['shaft.damping'])
    except (KeyError, TypeError, ValueError) as exc:
        return {'available': False, 'reason': f'scene parameters incomplete ({exc})'}
    changed = [k for _, ch in trace.parameter_changes for k in ch
               if k.startswith(('inertia.', 'shaft.', 'motor.', 'model.'))]
    if changed:
        return {'available': False, 'reason': f'parameters changed live ({", ".join(changed)})'}
    fidelity = p.get('model.fidelity', 'full')
    if fidelity == 'averaged':
        return {'available': False, 'reason': 'model.fidelity averaged: the mean-motion model '
                                              'has no cycle-resolved energy'}
    if fidelity == 'rigid_shaft':
        c = math.inf
    t, w, th = trace.t, trace.omega, trace.twist
    m1, m4 = trace.effort[:, 0], trace.effort[:, 3]
    rigid = not math.isfinite(c)
    w3 = w[:, 3] if rigid else w[:, 2]
    # every rocker's J2 (N ≥ 2 paths: each its own, physics.md §9)
    rockers = trace.paths.omega if trace.paths is not None else w[:, 1:2]
    energy = 0.5 * (J[0] * w[:, 0] ** 2 + J[1] * np.sum(rockers ** 2, axis=1) + J[2] * w3 ** 2
                    + J[3] * w[:, 3] ** 2)
    if not rigid:
        energy = energy + 0.5 * c * th ** 2
    integ = Integrator(t)
    w_motor = float(integ.cumulative(m1 * w[:, 0])[-1])
    w_load = float(integ.cumulative(m4 * w[:, 3])[-1])
    w_damp = 0.0 if rigid else float(integ.cumulative(kd * (w3 - w[:, 3]) ** 2)[-1])
    stored = float(energy[-1] - energy[0])
    residual = stored - (w_motor - w_load - w_damp)
    scale = abs(w_motor) + abs(w_load) + abs(w_damp)
    notes = []
    a = trace.crank_length[np.isfinite(trace.crank_length)]
    if len(a) and np.ptp(a) > 1e-7 or any(c.key == 'crank_length_cmd' for c in trace.commands):
        notes.append('the crank length moved: the actuator work is not recorded and is in the '
                     'residual')
    if trace.t[0] < 1e-9:
        notes.append('includes the plastic engagement at t = 0, if any')
    return {'available': True, 'work_motor': w_motor, 'work_load': w_load,
            'dissipated_damping': w_damp, 'stored': stored, 'residual': residual,
            'relative_residual': abs(residual) / scale if scale > 0 else abs(residual),
            'span': (float(t[0]), float(t[-1])), 'notes': notes}

