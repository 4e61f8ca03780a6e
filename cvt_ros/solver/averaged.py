"""The ``averaged`` fidelity: the mean motion of the drive, for long runs (a conveyor start-up).

The full model's mean ratio i = ω̄4/ω̄1 in steady state depends on the crank length, the crank
speed and, through the shaft's compliance, on the load it carries (the drive's "internal
automaticity"). A map i_ss(a, ω1, M) is built once per scene from steady-state runs of the full
model (ideal speed source at ω1, constant load M, mean over whole crank turns) and cached on disk.

Averaged dynamics (two DOF, no clutch events, lossless like the full model without damping):
    M_d = the load torque at which the map's steady ratio equals ω4/ω1 (the map inverted in M);
          0 when the output overruns (ω4/ω1 above the ratio at no load); with a = 0 the clutch is
          a backstop that holds a pulling load at ω4 = 0
    J4·ω4' = M_d − M4(ω4)
    J1e·ω1' = M1(ω1) − M_d·ω4/ω1          (mean power through the transmission is conserved)
with J1e = J1 + (J2 + J3)·⟨u²⟩ the crank inertia plus the rocker side reflected on average.
The shaft's mean twist is M_d/c. Ripple, switches and the twist oscillation are not modelled:
the report states the error of each fidelity against the full model (BENCHMARKS.md).
"""
import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np

from .. import parameters as params_mod
from ..physics import layout as L
from ..physics.compiled import allocating_kernel, kernel
from ..physics.drives import crank_actuator, load_torque, motor_torque, next_actuator_break
from ..physics.linkage import kinematics, rocker_angle
from . import advance_layout as AL
from .output import COL, N_COLUMNS, write_sample
from .simulator import Simulator
from .steppers import rk4_combine, rk4_stage

MAP_VERSION = 1
# what the map depends on; everything else (motor, load law, solver) does not change i_ss
MAP_KEYS = ('linkage.rocker_length', 'linkage.coupler_length', 'linkage.pivot_distance',
            'linkage.assembly_mode', 'inertia.motor', 'inertia.rocker', 'inertia.clutch_driven',
            'inertia.output', 'shaft.stiffness', 'shaft.damping', 'clutch.release')
A_FRACTIONS = (0.0, 0.05, 0.15, 0.3, 0.45, 0.6, 0.75, 0.9)   # of the Grashof bound
SPEED_FRACTIONS = (0.7, 0.85, 1.0)                            # of the nominal crank speed
LOAD_FRACTIONS = (0.0, 0.5, 1.0, 2.0, 4.0)                    # of the load scale
STEP = 2e-3  # [s] RK4 step of the averaged model (its fastest rate is the motor's slip ~ 30/s)


def cache_dir():
    root = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(root) / 'cvt_ros' / 'ratio_maps'


def map_key(values, speeds, loads):
    payload = {k: values[k] for k in MAP_KEYS}
    payload.update(version=MAP_VERSION, speeds=list(speeds), loads=list(loads))
    text = json.dumps(payload, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _steady_ratio(values, a, w1, load):
    """Mean ω4/ω1 of the full model at crank length a, crank speed w1 and constant load."""
    v = dict(values, **{'linkage.crank_length': a, 'motor.model': 'constant_speed',
                        'motor.speed': w1, 'load.torque': load, 'load.viscous': 0.0,
                        'load.quadratic': 0.0, 'model.fidelity': 'full'})
    sim = Simulator(v)
    if a == 0.0:
        return 0.0
    # start the output near where it will settle (continuation would be faster still)
    phis = np.linspace(0.0, 2 * math.pi, 73)
    swing = [kinematics(p, a, v['linkage.rocker_length'], v['linkage.coupler_length'],
                        v['linkage.pivot_distance'], v['linkage.assembly_mode'])[2] for p in phis]
    guess = max(swing) * w1 * 0.9
    sim.y[L.OMEGA4] = sim.y[L.OMEGA3] = guess
    sim._settle_clutch()
    turn = 2 * math.pi / w1
    sim.advance(40 * turn)
    previous = None
    for _ in range(20):
        phi4 = sim.sample()[4]
        sim.advance(20 * turn)
        ratio = (sim.sample()[4] - phi4) / (20 * turn * w1)
        if previous is not None and abs(ratio - previous) < 1e-4 * max(abs(ratio), 1e-3):
            return ratio
        previous = ratio
    return ratio


class RatioMap:
    """i_ss on the grid (a, ω1, M); ``inertia`` J1e per a."""

    def __init__(self, a, w1, m, ratio, j1e):
        self.a, self.w1, self.m, self.ratio, self.j1e = a, w1, m, ratio, j1e

    @classmethod
    def build(cls, values, progress=None):
        from ..physics.linkage import grashof_bound
        bound = grashof_bound(values['linkage.rocker_length'], values['linkage.coupler_length'],
                              values['linkage.pivot_distance'])
        w_nominal = (values['motor.speed'] if values['motor.model'] == 'constant_speed'
                     else values['motor.synchronous_speed'])
        load_scale = max(1.0, abs(values['load.torque']), values['load.quadratic'] * w_nominal ** 2)
        a = np.array([f * bound for f in A_FRACTIONS])
        w1 = np.array([f * w_nominal for f in SPEED_FRACTIONS])
        m = np.array([f * load_scale for f in LOAD_FRACTIONS])
        ratio = np.zeros((a.size, w1.size, m.size))
        total = ratio.size
        for i, ai in enumerate(a):
            for j, wj in enumerate(w1):
                for k, mk in enumerate(m):
                    ratio[i, j, k] = _steady_ratio(values, ai, wj, mk)
                    if progress:
                        progress((i * w1.size + j) * m.size + k + 1, total)
        j1e = np.array([cls._reflected_inertia(values, ai) for ai in a])
        return cls(a, w1, m, ratio, j1e)

    @staticmethod
    def _reflected_inertia(values, a):
        phis = np.linspace(0.0, 2 * math.pi, 181)[:-1]
        u = np.array([kinematics(p, a, values['linkage.rocker_length'],
                                 values['linkage.coupler_length'], values['linkage.pivot_distance'],
                                 values['linkage.assembly_mode'])[2] for p in phis])
        return values['inertia.motor'] + (values['inertia.rocker']
                                          + values['inertia.clutch_driven']) * float(np.mean(u * u))

    @classmethod
    def for_scene(cls, values, progress=None):
        """The map of this scene: from the cache, or built (and cached)."""
        w_nominal = (values['motor.speed'] if values['motor.model'] == 'constant_speed'
                     else values['motor.synchronous_speed'])
        key = map_key(values, SPEED_FRACTIONS, LOAD_FRACTIONS) + f"-{w_nominal:.6g}"
        path = cache_dir() / f"{key}.npz"
        if path.exists():
            with np.load(path) as d:
                return cls(d['a'], d['w1'], d['m'], d['ratio'], d['j1e'])
        ratio_map = cls.build(values, progress)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix('.tmp.npz')
        np.savez(tmp, a=ratio_map.a, w1=ratio_map.w1, m=ratio_map.m, ratio=ratio_map.ratio,
                 j1e=ratio_map.j1e)
        os.replace(tmp, path)
        return ratio_map


@kernel
def _bracket(grid, x):
    """Index i and weight w with x ≈ grid[i]·(1 − w) + grid[i+1]·w (clamped to the grid)."""
    n = grid.shape[0]
    if x <= grid[0]:
        return 0, 0.0
    if x >= grid[n - 1]:
        return n - 2, 1.0
    i = 0
    while grid[i + 1] < x:
        i += 1
    return i, (x - grid[i]) / (grid[i + 1] - grid[i])


@kernel
def drive_torque(a, w1, w4, m4, A, W1, M, R):
    """Mean torque M_d [N·m] the clutch passes at output speed w4 (map inverted in the load)."""
    if a <= A[0] or w1 <= 0.0:
        return m4 if (w4 <= 0.0 and m4 > 0.0) else 0.0  # neutral: backstop only
    ia, fa = _bracket(A, a)
    iw, fw = _bracket(W1, w1)
    target = w4 / w1
    previous = 0.0
    for k in range(M.shape[0]):
        r = ((1 - fa) * ((1 - fw) * R[ia, iw, k] + fw * R[ia, iw + 1, k])
             + fa * ((1 - fw) * R[ia + 1, iw, k] + fw * R[ia + 1, iw + 1, k]))
        if k == 0:
            if target >= r:
                return 0.0  # faster than the rocker can push: the clutch overruns
        elif target >= r:
            return M[k - 1] + (M[k] - M[k - 1]) * (previous - target) / (previous - r)
        if k == M.shape[0] - 1:  # beyond the map: extend its last slope
            slope = (M[k] - M[k - 1]) / (previous - r) if previous != r else 0.0
            return M[k] + slope * (r - target)
        previous = r
    return 0.0


@kernel
def averaged_rates(t, y, P, ACT, A, W1, M, R, j1e, dy):
    """Derivatives of the averaged model; returns (a, M_d, M1, M4)."""
    a, _, _ = crank_actuator(t, ACT)
    w1 = y[L.OMEGA1]
    w4 = y[L.OMEGA4]
    m4 = load_torque(w4, P)
    md = drive_torque(a, w1, w4, m4, A, W1, M, R)
    if P[L.P_MOTOR_MODEL] == L.MOTOR_CONSTANT_SPEED:
        dw1 = 0.0
        m1 = md * w4 / w1
    else:
        m1 = motor_torque(w1, P)
        dw1 = (m1 - md * w4 / w1) / j1e
    j_out = P[L.P_J4] + P[L.P_J3]
    dw4 = (md - m4) / j_out
    if a <= A[0] and w4 <= 0.0 and dw4 < 0.0:
        dw4 = 0.0  # held by the backstop
    for i in range(dy.shape[0]):
        dy[i] = 0.0
    dy[L.PHI1] = w1
    dy[L.OMEGA1] = dw1
    dy[L.PHI4] = w4
    dy[L.OMEGA4] = dw4
    dy[L.W_MOTOR] = m1 * w1
    dy[L.W_LOAD] = m4 * w4
    return a, md, m1, m4


@allocating_kernel
def averaged_sample(t, y, P, ACT, A, W1, M, R, j1e, aux, ysample):
    """The algebraic members (rocker from the linkage, mean twist) and the AUX values."""
    dy = np.empty(y.shape[0])
    a, md, m1, m4 = averaged_rates(t, y, P, ACT, A, W1, M, R, j1e, dy)
    for i in range(y.shape[0]):
        ysample[i] = y[i]
    b, d, h, sigma = P[L.P_B], P[L.P_D], P[L.P_H], P[L.P_SIGMA]
    ysample[L.PHI2] = rocker_angle(y[L.PHI1], a, b, d, h, sigma)
    _, _, u, _, ga, _, _ = kinematics(y[L.PHI1], a, b, d, h, sigma)
    ysample[L.OMEGA2] = u * y[L.OMEGA1]
    ysample[L.OMEGA3] = y[L.OMEGA4]
    c = P[L.P_C]
    ysample[L.TWIST] = md / c if (P[L.P_RIGID] == 0.0 and c > 0.0) else 0.0
    for i in range(aux.shape[0]):
        aux[i] = 0.0
    aux[L.AUX_CLUTCH_TORQUE] = md
    aux[L.AUX_MOTOR_TORQUE] = m1
    aux[L.AUX_LOAD_TORQUE] = m4
    aux[L.AUX_SHAFT_TORQUE] = md
    aux[L.AUX_CRANK_LENGTH] = a
    aux[L.AUX_ROCKER_SPEED] = ysample[L.OMEGA2]
    aux[L.AUX_ENERGY] = 0.5 * (j1e * y[L.OMEGA1] ** 2 + (P[L.P_J4] + P[L.P_J3]) * y[L.OMEGA4] ** 2)
    return md


@allocating_kernel
def averaged_advance(t, t_end, y, P, ACT, A, W1, M, R, j1e, grid, out, counters):
    """Classical RK4 from t to t_end, stepping onto every sample time and actuator break."""
    n = y.shape[0]
    K = np.empty((4, n))
    ytmp = np.empty(n)
    ysample = np.empty(n)
    aux = np.empty(L.N_AUX)
    while t < t_end:
        i = counters[AL.C_NEXT_SAMPLE]
        t_next = min(t + STEP, t_end, next_actuator_break(t, ACT))
        if i < grid.shape[0] and grid[i] < t_next:
            t_next = grid[i]
        h = t_next - t
        averaged_rates(t, y, P, ACT, A, W1, M, R, j1e, K[0])
        for s in range(1, 4):
            ts = rk4_stage(s, t, y, h, K, ytmp)
            averaged_rates(ts, ytmp, P, ACT, A, W1, M, R, j1e, K[s])
        rk4_combine(y, h, K, y)
        t = t_next
        counters[AL.C_STEPS] += 1
        while i < grid.shape[0] and grid[i] <= t:
            md = averaged_sample(t, y, P, ACT, A, W1, M, R, j1e, aux, ysample)
            write_sample(out[i], grid[i], ysample, L.ENGAGED if md > 0.0 else L.DISENGAGED, aux)
            i += 1
        counters[AL.C_NEXT_SAMPLE] = i
    return t


class AveragedSimulator(Simulator):
    """The Simulator's interface over the averaged model (fidelity ``averaged``).

    Same inputs, outputs and time keeping; no clutch events (``advance`` returns none), the
    clutch column says whether a mean drive torque flows.
    """

    def __init__(self, values, progress=None):
        self.ratio_map = RatioMap.for_scene(params_mod.validate(values or {}), progress)
        super().__init__(values)

    def _configure_steps(self):
        super()._configure_steps()
        m = self.ratio_map
        self.j1e = float(np.interp(self.values['linkage.crank_length'], m.a, m.j1e))

    def _settle_clutch(self):
        self.ms[:] = 0  # no clutch automaton: the mean drive torque decides

    def _call(self, t_end, grid, out, objects=True):
        m = self.ratio_map
        self.t = averaged_advance(self.t, t_end, self.y, self.P, self.ACT, m.a, m.w1, m.m,
                                  m.ratio, self.j1e, grid, out, self.counters)
        return [], AL.STATUS_OK

    def _state_and_aux(self):
        m = self.ratio_map
        aux = np.empty(L.N_AUX)
        ysample = np.empty(L.N_STATE)
        md = averaged_sample(self.t, self.y, self.P, self.ACT, m.a, m.w1, m.m, m.ratio,
                             self.j1e, aux, ysample)
        return ysample, aux, md

    def _aux(self):
        return self._state_and_aux()[1]

    @property
    def engaged(self):
        return self._state_and_aux()[2] > 0.0

    def sample(self):
        ysample, aux, md = self._state_and_aux()
        row = np.empty(N_COLUMNS)
        write_sample(row, self.t, ysample, L.ENGAGED if md > 0.0 else L.DISENGAGED, aux)
        row[COL['phi1']] += self.turns_phi1
        row[COL['phi3']] += self.turns_phi4
        row[COL['phi4']] += self.turns_phi4
        return row
