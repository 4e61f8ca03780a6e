"""Frequency response of the cycle-mean plant from sine sweeps on the full hybrid model.

One experiment per frequency f (a stepped sine): from the operating point, the input is
commanded as u0 + A·sin(2πf(t − t0)) — every ``command_dt`` (≥ 50 commands a period), held in
between, as a controller would — for a settling time (5 of the plant's slowest time constants,
at least one period) and then whole periods over at least ``MIN_CYCLES`` crank turns.

Demodulation on the cycle means: over crank turn k (window [a_k, b_k]) the mean of a sinusoid is
exactly a linear combination of S_k = mean sin(ω(t − t0)) and C_k = mean cos(ω(t − t0)) over the
window, so the least-squares fit

    ȳ_k = c0 + c1·(t_k − t̄) + Y_s·S_k + Y_c·C_k          (t_k: the turn's midpoint)

gives the sinusoid's own amplitude and phase, Y = Y_s + j·Y_c (y ≈ Im(Y·e^(jω(t−t0)))), with the
averaging over each turn undone rather than mistaken for lag; c1 takes up a slow drift. The input
is demodulated the same way — the crank length as the actuator actually moved it (the plant is
from the actual crank length: the rate-limited actuator's travel time depends on the amplitude,
which no linear model keeps), the load torque from the commands as the device got them (the
held staircase, its turn means exact) — and G(j2πf) = Y/U. ``distortion`` is the RMS of what
the sinusoid leaves / its amplitude: harmonics of the one-way clutch, a transient not yet gone.

What the cycle mean resolves: it samples the output once per crank turn, at f_c; a turn's mean
suppresses the ripple at f_c and its harmonics exactly, but the ripple's sidebands at f_c ± f
(the input modulates it) alias onto f, attenuated only by the turn's averaging,
|sinc((f_c − f)/f_c)|, which grows as f nears f_c / 2 (the Nyquist rate of one sample per turn).
Sweeps go up to ``DEFAULT_FRACTION`` of f_c by default and are refused beyond
``MAX_FRACTION``.
"""
import math
from dataclasses import dataclass

import numpy as np

from .errors import DesignError
from .experiment import command_interval, drive, record_of, staircase, staircase_means

DEFAULT_FRACTION = 0.2       # of the crank frequency: the default highest sweep frequency
MAX_FRACTION = 0.35          # beyond this fraction of f_c the aliased ripple sidebands bias G
MIN_CYCLES = 20              # crank turns in a measurement at least
SETTLE_TIME_CONSTANTS = 5.0  # the slowest time constant's multiples waited before measuring


@dataclass(frozen=True)
class FrequencyResponse:
    """Measured G(j2πf) of one input to the cycle-mean output speed and motor speed."""
    frequency: np.ndarray        # Hz
    output_speed: np.ndarray     # complex, SI units of the input's plant
    motor_speed: np.ndarray      # complex
    amplitude: np.ndarray        # input amplitude used at each frequency (SI)
    distortion: np.ndarray       # RMS of the residual / sinusoid amplitude (output speed)
    crank_frequency: float       # Hz at the operating point
    fraction: float              # highest frequency / crank frequency

    def to_dict(self, model=None):
        out = {'frequency_hz': self.frequency.tolist(),
               'magnitude': np.abs(self.output_speed).tolist(),
               'phase_deg': np.degrees(np.unwrap(np.angle(self.output_speed))).tolist(),
               'motor_speed_magnitude': np.abs(self.motor_speed).tolist(),
               'motor_speed_phase_deg': np.degrees(np.unwrap(np.angle(self.motor_speed))).tolist(),
               'amplitude': self.amplitude.tolist(), 'distortion': self.distortion.tolist(),
               'crank_frequency_hz': self.crank_frequency,
               'highest_fraction_of_crank_frequency': self.fraction}
        if model is not None:
            out['model_fit_error'] = model_error(self, model)
        return out


def model_error(response, model):
    """RMS over the frequencies of |G_model − G_measured| / |G_measured| (exact dead time)."""
    g = response.output_speed
    return float(np.sqrt(np.mean(np.abs(model.response(response.frequency) - g) ** 2
                                 / np.abs(g) ** 2)))


def check_frequencies(low, high, crank_frequency, points):
    """Refuse sweep frequencies the cycle mean cannot resolve (DesignError names the setting)."""
    limit = MAX_FRACTION * crank_frequency
    if not high <= limit:
        raise DesignError(f"max_frequency = {high:g} Hz is beyond what the cycle mean resolves: "
                          f"the crank turns at {crank_frequency:.4g} Hz at this operating "
                          f"point, one cycle mean per turn, and above {MAX_FRACTION:g} of that "
                          f"({limit:.3g} Hz) the ripple's aliased sidebands bias the response; "
                          f"set max_frequency ≤ {limit:.3g} Hz")
    if not 0.0 < low < high:
        raise DesignError(f"min_frequency = {low:g} Hz must be > 0 and below max_frequency = "
                          f"{high:g} Hz")
    if not 2 <= points <= 200:
        raise DesignError(f"points = {points!r}: a sweep needs 2 … 200 frequencies")


def demodulate(bounds, means, omega, t0):
    """Phasor Y (y ≈ Im(Y·e^(jω(t − t0)))) of turn means ``means`` over windows ``bounds``, and
    the residual's RMS / |Y|."""
    a, b = bounds[:-1] - t0, bounds[1:] - t0
    width = omega * (b - a)
    S = (np.cos(omega * a) - np.cos(omega * b)) / width
    C = (np.sin(omega * b) - np.sin(omega * a)) / width
    mid = 0.5 * (a + b)
    A = np.column_stack([np.ones_like(mid), mid - mid.mean(), S, C])
    coef, *_ = np.linalg.lstsq(A, means, rcond=None)
    Y = complex(coef[2], coef[3])
    rest = means - A @ coef
    return Y, float(np.sqrt(np.mean(rest ** 2)) / max(abs(Y), 1e-300))


def sine_experiment(sim, values, input_name, frequency, amplitude, settle, sample_dt,
                    crank_frequency):
    """Drive a copy-ready ``sim`` (at the operating point; changed in place) with a sine of the
    input; (G output speed, G motor speed, distortion)."""
    period = 1.0 / frequency
    omega = 2.0 * math.pi * frequency
    command_dt = command_interval(period, sample_dt)
    t0 = sim.t
    u0 = sim.crank_length if input_name == 'crank_length' else sim.load_torque

    def signal(t):
        return u0 + amplitude * np.sin(omega * (np.asarray(t) - t0))

    periods_settle = math.ceil(max(settle, period) / period)
    periods_measure = max(2, math.ceil(MIN_CYCLES / crank_frequency / period))
    duration = (periods_settle + periods_measure) * period
    kwargs = {'crank' if input_name == 'crank_length' else 'load': signal}
    samples, switches = drive(sim, duration, sample_dt, command_dt, **kwargs)
    record = record_of(values, samples, switches)
    keep = record.bounds >= t0 + periods_settle * period - 1e-9
    bounds = record.bounds[keep]
    first = int(np.flatnonzero(keep)[0])
    out_means = record.cycles['output_speed'][first:]
    w1_means = record.cycles['crank_speed'][first:]
    if input_name == 'crank_length':   # the actual length: the actuator is not in the plant
        u_means = record.cycles['crank_length'][first:]
    else:                              # the load torque as commanded (held between commands)
        knots = t0 + command_dt * np.arange(int(round(duration / command_dt)) + 1)
        u_means = staircase_means(knots, staircase(t0, command_dt, signal, knots), bounds)
    U, _ = demodulate(bounds, u_means, omega, t0)
    Y, distortion = demodulate(bounds, out_means, omega, t0)
    W, _ = demodulate(bounds, w1_means, omega, t0)
    return Y / U, W / U, distortion


def sweep(sim0, values, input_name, frequencies, amplitude, rate_limits, settle, sample_dt,
          crank_frequency, progress=None):
    """The :class:`FrequencyResponse` of ``input_name`` at ``frequencies`` [Hz] from the
    operating-point simulator ``sim0`` (copied for each frequency, left as it is).
    ``rate_limits``: (rate [u/s], acceleration [u/s²]) the input's sine must stay under (the
    crank actuator's; none for the load); the amplitude shrinks to keep below half of them."""
    import copy
    g_out, g_motor, amps, dist = [], [], [], []
    for k, f in enumerate(frequencies):
        omega = 2.0 * math.pi * f
        A = amplitude
        if rate_limits is not None:
            A = min(A, 0.5 * rate_limits[0] / omega, 0.5 * rate_limits[1] / omega ** 2)
        g, w, d = sine_experiment(copy.deepcopy(sim0), values, input_name, f, A, settle,
                                  sample_dt, crank_frequency)
        g_out.append(g)
        g_motor.append(w)
        amps.append(A)
        dist.append(d)
        if progress is not None:
            progress(k + 1, len(frequencies))
    return FrequencyResponse(np.asarray(frequencies, float), np.array(g_out),
                             np.array(g_motor), np.array(amps), np.array(dist), crank_frequency,
                             float(frequencies[-1]) / crank_frequency)


__all__ = ['DEFAULT_FRACTION', 'FrequencyResponse', 'MAX_FRACTION', 'check_frequencies',
           'demodulate', 'model_error', 'sweep']
