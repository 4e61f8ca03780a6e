"""Step responses fitted to low-order models with dead time, as python-control transfer functions.

Two structures, each fitted to the small steps of both directions at once (one linearization):

* FOPDT — first order plus dead time: G(s) = K·e^(−θs) / (τs + 1);
* second order (with a zero) plus dead time: G(s) = K·(τz·s + 1)·e^(−θs) / (τ²s² + 2ζτs + 1).
  The zero is there for the motor speed: a longer crank first loads the motor (its speed dips)
  and later, with the output faster, settles elsewhere — a response no pole pair alone has.

The fit starts from the steps' static gain (their final change / input change) and the time to
63 %. It compares like with like: the model is driven by the input the device had on the fit
grid (the crank length as the actuator moved it, the load torque as commanded), and its output
is averaged over the same crank turns as the device's cycle means (:func:`window_means`). The
residual is scaled by the RMS of the measured response; ``fit_error`` is RMS(model − device) /
RMS(device response) over all cycles of all steps (0 = exact). scipy's ``least_squares`` does the
fitting from several starts; the better of the starts is kept.

``num``/``den`` follow python-control: coefficients in descending powers of s, so
``control.tf(num, den)`` is the rational part; the dead time θ is kept apart (``delay``), exact
in :meth:`FittedModel.response`, a Padé approximant in :meth:`FittedModel.tf` on request.
"""
import cmath
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter

from .experiment import window_means


@dataclass(frozen=True)
class StepData:
    """One step experiment ready to fit: the input deviation ``u`` on the uniform grid ``t``
    (from its value before the step), the cycle windows ``bounds`` inside that grid and the
    measured cycle-mean output deviations ``y`` over them; ``size``: the commanded step."""
    t: np.ndarray
    u: np.ndarray
    bounds: np.ndarray
    y: np.ndarray
    size: float
    t_step: float

    @property
    def gain(self):
        """Static gain of this step alone: the final cycle means' change / the input's change
        (mean of the last fifth of the cycles; the up and down steps differ where the plant
        is not linear)."""
        tail = max(1, len(self.y) // 5)
        return float(np.mean(self.y[-tail:]) / np.mean(self.u[-max(1, len(self.u) // 5):]))


@dataclass(frozen=True)
class FittedModel:
    """A fitted model: rational part ``num``/``den`` (python-control's convention) and dead time
    ``delay`` [s]; ``fit_error``: RMS(model − device) / RMS(device), over the steps' cycles."""
    kind: str                    # 'fopdt' | 'second_order'
    num: tuple
    den: tuple
    delay: float
    fit_error: float

    @property
    def gain(self):
        return self.num[-1] / self.den[-1]

    @property
    def time_constant(self):
        """FOPDT: τ. Second order: the slowest pole's time constant, 1/min|Re p| [s] (a zero
        may cancel it: see ``zero_time_constant``)."""
        if self.kind == 'fopdt':
            return self.den[0] / self.den[1]
        return max(self.time_constants)

    @property
    def time_constants(self):
        """−1/Re p of each pole [s], slowest first."""
        return sorted((float(-1.0 / p.real) for p in np.roots(self.den)), reverse=True)

    def tf(self, pade_order=None):
        """The model as a ``control.TransferFunction``: the rational part, or with the dead time
        as a Padé approximant of ``pade_order``."""
        import control
        g = control.tf(list(self.num), list(self.den))
        if pade_order and self.delay > 0:
            g = g * control.tf(*control.pade(self.delay, pade_order))
        return g

    def response(self, frequency_hz):
        """G(j2πf) with the exact dead time."""
        s = 2j * math.pi * np.asarray(frequency_hz, dtype=float)
        return np.polyval(self.num, s) / np.polyval(self.den, s) * np.exp(-s * self.delay)

    def to_dict(self):
        out = {'gain': float(self.gain), 'time_constant': float(self.time_constant),
               'delay': float(self.delay), 'num': [float(c) for c in self.num],
               'den': [float(c) for c in self.den], 'fit_error': float(self.fit_error)}
        if self.kind == 'second_order':
            tau = math.sqrt(self.den[0])
            del out['time_constant']
            out.update(time_constants=self.time_constants, natural_frequency=1.0 / tau,
                       damping=self.den[1] / (2.0 * tau),
                       zero_time_constant=self.num[0] / self.num[1] if self.num[1] else math.nan)
        return out


def zoh(num, den, h):
    """Step-invariant (zero-order-hold) discretization of num/den (first or second order, no
    pole at 0) at interval ``h``: the coefficients (b, a) of the difference equation in z⁻¹.

    From the sampled step response, G(s)/s = K/s + Σ rᵢ/(s − pᵢ) (+ r₂/(s − p)² for a double
    pole, used where the two poles are within 1e-4 of each other: the split formula cancels
    catastrophically there): b/a = (1 − z⁻¹)·Z{step response}. Scalar formulas: scipy's
    cont2discrete takes a matrix exponential per call, ~100x slower, and a fit makes thousands
    of calls."""
    K = num[-1] / den[-1]
    if len(den) == 2:
        q = math.exp(-den[1] / den[0] * h)
        return np.array([0.0, K * (1.0 - q)]), np.array([1.0, -q])
    A, B, C = den
    n1, n0 = num[-1], (num[-2] if len(num) > 1 else 0.0)
    root = cmath.sqrt(B * B - 4.0 * A * C)
    q = -0.5 * (B + (root if (B * root.conjugate()).real >= 0 else -root))   # no cancellation
    p1, p2 = q / A, C / q
    if abs(p1 - p2) <= 1e-4 * abs(p1):
        p = 0.5 * (p1 + p2).real
        q = math.exp(p * h)
        r2 = (n0 * p + n1) / (p * A)
        r1 = -n1 / (A * p * p)           # d/ds (N(s) / (A·s)) at p
        a1, a2 = -2.0 * q, q * q
        c0, c1 = r1, r2 * h * q - r1 * q
    else:
        q1, q2 = cmath.exp(p1 * h), cmath.exp(p2 * h)
        r1 = (n0 * p1 + n1) / (p1 * (2.0 * A * p1 + B))
        r2 = (n0 * p2 + n1) / (p2 * (2.0 * A * p2 + B))
        a1, a2 = -(q1 + q2).real, (q1 * q2).real
        c0, c1 = (r1 + r2).real, -(r1 * q2 + r2 * q1).real
    return (np.array([K + c0, K * a1 + c1 - c0, K * a2 - c1]), np.array([1.0, a1, a2]))


def simulate(num, den, delay, t, u):
    """Output of num/den·e^(−θs) on the uniform grid t for the input u held on each
    [t_k, t_k+1) — exact for a command held between grid points, as the device gets it (zero
    initial state: u is a deviation, 0 before the step). The delayed input is interpolated:
    for a step on the grid that is the exact hold of the delayed step."""
    h = t[1] - t[0]
    ud = np.interp(t - delay, t, u, left=u[0]) if delay > 0 else u
    b, a = zoh(num, den, h)
    return lfilter(b, a, ud)


class _Parameters:
    """The fit's unconstrained coordinates x ↔ the model's parameters, so that MINPACK's
    Levenberg–Marquardt (method 'lm': a fraction of the trust-region method's overhead per
    iteration) keeps them in range without flat clipped regions where it would stop:
    K = K0·x0; τ = τ0·e^x1 > 0; ζ = e^x2 > 0; τz = τ0·x3; θ = θ_hi·sin²(x_last) in [0, θ_hi].
    (Exponents capped at ±30 against overflow only.)"""

    def __init__(self, kind, K0, tau0, theta_hi):
        self.kind, self.K0, self.tau0 = kind, K0 if K0 else 1.0, tau0
        self.theta_hi = theta_hi

    def model(self, x):
        """(num, den, θ) of coordinates x."""
        K = self.K0 * x[0]
        tau = self.tau0 * math.exp(min(max(x[1], -30.0), 30.0))
        theta = self.theta_hi * math.sin(x[-1]) ** 2
        if self.kind == 'fopdt':
            return (K,), (tau, 1.0), theta
        zeta = math.exp(min(max(x[2], -30.0), 30.0))
        tau_z = self.tau0 * x[3]
        return (K * tau_z, K), (tau * tau, 2.0 * zeta * tau, 1.0), theta

    def start(self, tau, theta, zeta=1.0, tau_z=0.0):
        x_theta = math.asin(math.sqrt(min(max(theta / self.theta_hi, 0.0), 1.0)))
        x = [1.0, math.log(tau / self.tau0)]
        if self.kind == 'second_order':
            x += [math.log(zeta), tau_z / self.tau0]
        return np.array(x + [x_theta])


def _residuals(parameters, steps, scale):
    def residual(x):
        num, den, theta = parameters.model(x)
        parts = []
        for s in steps:
            y = simulate(num, den, theta, s.t, s.u)
            parts.append(window_means(s.t, y, s.bounds) - s.y)
        return np.concatenate(parts) / scale
    return residual


def _first_guess(steps):
    """(gain, time constant, delay) read off the steps: final value / input, time to 63 %."""
    gains = [s.gain for s in steps if math.isfinite(s.gain)]
    K = float(np.mean(gains)) if gains else 1.0
    taus, thetas = [], []
    for s in steps:
        mid = 0.5 * (s.bounds[:-1] + s.bounds[1:]) - s.t_step
        final = np.mean(s.y[-max(1, len(s.y) // 5):])
        if final == 0:
            continue
        frac = s.y / final
        after = mid > 0
        reach = np.flatnonzero(after & (frac >= 0.632))
        start = np.flatnonzero(after & (frac >= 0.05))
        if len(reach):
            taus.append(mid[reach[0]])
        if len(start):
            thetas.append(max(0.0, mid[start[0]]))
    span = steps[0].t[-1] - steps[0].t_step
    tau = float(np.median(taus)) if taus else span / 5
    theta = min(float(np.median(thetas)) if thetas else 0.0, 0.5 * tau)
    return K, max(tau, 1e-3), theta


def fit_model(kind, steps):
    """The best :class:`FittedModel` of structure ``kind`` ('fopdt' | 'second_order') for the
    steps (a list of :class:`StepData`)."""
    scale = math.sqrt(np.mean(np.concatenate([s.y for s in steps]) ** 2)) or 1.0
    K, tau, theta = _first_guess(steps)
    span = min(s.t[-1] - s.t_step for s in steps)
    parameters = _Parameters(kind, K, tau, 0.3 * span)
    residual = _residuals(parameters, steps, scale)
    if kind == 'fopdt':
        starts = [parameters.start(tau, theta)]
    else:   # a response that first goes the other way (the motor speed) needs τz < 0
        starts = [parameters.start(tau / 2, theta, 1.0, 0.0)]
        starts += [parameters.start(t, 0.0, 1.5, sign * t)
                   for t in (span / 30, span / 8) for sign in (-1.0, 1.0)]
    best = None
    for x0 in starts:
        result = least_squares(residual, x0, method='lm', x_scale='jac', max_nfev=300)
        if best is None or result.cost < best.cost:
            best = result
    num, den, theta = parameters.model(best.x)
    error = math.sqrt(2.0 * best.cost / len(best.fun))
    return FittedModel(kind, tuple(float(c) for c in num), tuple(float(c) for c in den),
                       float(theta), error)


__all__ = ['FittedModel', 'StepData', 'fit_model', 'simulate']
