"""The simulator: the hybrid model, its solver settings and its run-time inputs behind one object.

Used by the offline CLI (``run``: as fast as possible, samples on a uniform grid), by the ROS node
(``advance``: exactly dt per call, events located inside) and by the benchmarks. No ROS here.
"""
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .. import parameters as params_mod
from ..physics import layout as L
from ..physics.clutch import KIND_ENGAGE_IMPACT, KIND_GRAZE, clutch_engages
from ..physics.drives import crank_actuator, hold_profile, replan_into
from ..physics.dynamics import energy_residual, engage_with_impact, project, rhs
from ..physics.linkage import (
    check_crank_length,
    check_crank_lengths_fit,
    grashof_bound,
    inertia_rate_factor,
    kinematics,
    rocker_angle,
)
from ..physics.output_exact import modal_form
from . import advance_layout as AL
from . import hybrid
from .output import COL, COLUMNS, N_COLUMNS, write_sample
from .self_check import stray_band, stray_samples
from .steppers import DOPRI5, RK4

TWO_PI = 2.0 * math.pi
REBASE_TURNS = 64  # fold whole turns of φ1 and φ4 out of the state past this many (precision)
# Fixed-step stability: h·λ_max ≤ this (RK4's stability interval is 2.78 on both axes; 0.5 also
# keeps ≥ 12 steps per period of the fastest mode it integrates). λ_max counts what the fixed step
# integrates itself (stepped_rates), not the open output, which runs apart (slip_watch.py).
RK4_STEP_BY_MODE = 0.5
RK4_STABILITY = 2.0 * math.sqrt(2.0)   # RK4's stability interval on the imaginary axis


class SimulationError(RuntimeError):
    """The integration could not go on (step size underflow or a non-finite state)."""


@dataclass(slots=True)
class ClutchSwitch:
    """A located clutch event: time [s], the clutch's state after it, kind (release / engage /
    engage_impact / graze), the guard where it was placed, and the path (1 … N) whose clutch it
    is. (slots: 72 bytes instead of 150, for runs that keep ~50 switches per simulated second)"""
    t: float
    engaged: bool
    kind: str
    value: float = 0.0
    path: int = 1


@dataclass
class RunResult:
    samples: np.ndarray                  # (n, N_COLUMNS) rows, columns output.COLUMNS
    switches: list = field(default_factory=list)   # ClutchSwitch objects (kept runs only)
    wall_time: float = 0.0
    steps: int = 0
    rejected: int = 0
    energy: dict = field(default_factory=dict)
    # rhs_evaluations, possible_missed_events (late switches: a guard found beyond its band at a
    # step's end), first_possible_missed_event_s, stray_samples (samples outside their mode:
    # self_check.py), first_stray_sample_s, solver (method and step, one line), warnings (texts)
    diagnostics: dict = field(default_factory=dict)
    switch_count: int = 0                # releases and engagements (kept or not)
    graze_count: int = 0                 # grazing contacts (the guard touched zero, no switch)
    columns: tuple = COLUMNS             # the samples' columns (output.path_columns for N ≥ 2)
    switches_per_path: tuple = ()        # releases and engagements of each path's clutch

    def column(self, name):
        return self.samples[:, self.columns.index(name)]


# The arrays the compiled period (period.py) reads live in one float64 and one int64 block, as
# views the Simulator fills in place and never rebinds: the period takes the two blocks instead of
# thirteen arrays (each costs ~45 ns to unbox at the Python boundary, about half a right-hand
# side), and the solver's working arrays come from the float block too (nothing is allocated
# per call: the kernels run without numba's reference counting, physics/compiled.py).
F_Y = 0                                   # state y
F_P = F_Y + L.N_STATE                     # parameters P
F_ACT = F_P + L.N_PARAMS                  # actuator profile ACT, (N_ACT_SEGMENTS, 4)
F_S = F_ACT + 4 * L.N_ACT_SEGMENTS        # solver settings S
F_H = F_S + AL.N_SETTINGS                  # step-size proposals h_io
F_LEDGER = F_H + AL.N_PROPOSALS            # impact losses [J]
F_DY = F_LEDGER + 1                       # a sample's right-hand side and auxiliaries
F_AUX = F_DY + L.N_STATE
F_ROW = F_AUX + L.N_AUX                   # the period's sample row
F_SCRATCH = F_ROW + N_COLUMNS             # the working arrays of an advance call
F_SIZE = F_SCRATCH + AL.N_SCRATCH
I_MS = 0                                  # clutch mode, guard armed
I_COUNTERS = 2
I_SIZE = I_COUNTERS + AL.N_COUNTERS


_FAILURES = {
    AL.STATUS_STEP_TOO_SMALL: 'the step size fell below the resolution of t (step-size floor)',
    AL.STATUS_NONFINITE: 'non-finite state',
    AL.STATUS_ZENO: 'clutch events without time advancing (Zeno)',
    AL.STATUS_NO_PROGRESS: 'no progress: the step budget of one call was spent',
}
_KIND_NAMES = {0: 'release', 1: 'engage', 2: 'engage_impact', 3: 'graze'}
STEP_BUDGET = 20_000_000      # steps one advance call may take (≥ 20 s of wall time): watchdog
MAX_KEPT_ROWS = 10_000_000    # samples a run keeps in memory (1.8 GB); beyond: stream them
ROWS_PER_BLOCK = 100_000      # samples written per compiled call
RUN_CHUNK = 1.0               # [s] simulated per compiled call of a run (and progress report)
SLOW_STEPS_PER_SECOND = 2e6   # steps per simulated second beyond which a run is warned about
DP5_STABILITY = 3.3           # Dormand–Prince's stability interval, |h·λ| (imaginary axis)


def settings_vector(values, h_fixed):
    S = np.zeros(AL.N_SETTINGS)
    S[AL.S_METHOD] = DOPRI5 if values['solver.method'] == 'dopri5' else RK4
    S[AL.S_RTOL] = values['solver.rtol']
    S[AL.S_ATOL] = values['solver.atol']
    S[AL.S_H_FIXED] = h_fixed
    S[AL.S_MAX_STEP] = values['solver.max_step']
    S[AL.S_STEP_BUDGET] = STEP_BUDGET
    return S


def open_output_rate(values):
    """The open clutch's output modes [1/s]: the J3–J4 ringing (eq. 12) or a massless damped
    node's relaxation c/k. Solved apart from the steps (exactly when linear, else on their own
    clock: slip_watch.py; the node's relaxation exactly), so no fixed step has to resolve them."""
    c = math.inf if values['model.fidelity'] == 'rigid_shaft' else values['shaft.stiffness']
    kd = values['shaft.damping']
    J3, J4 = values['inertia.clutch_driven'], values['inertia.output']
    if not math.isfinite(c):
        return 0.0
    if J3 > 0.0:
        inv = 1.0 / J3 + 1.0 / J4
        return math.sqrt(c * inv) + kd * inv
    return c / kd if kd > 0.0 else 0.0


def stepped_rates(values):
    """(rate [1/s], what) of everything a fixed step integrates itself, fastest first: the
    engaged shaft's twist mode (the clutch's contact), the crank speed, the load's viscous rate,
    the crank's effective-inertia rate."""
    c = math.inf if values['model.fidelity'] == 'rigid_shaft' else values['shaft.stiffness']
    kd = values['shaft.damping']
    J2, J3, J4 = values['inertia.rocker'], values['inertia.clutch_driven'], values['inertia.output']
    crank_speed = max(abs(values['initial.crank_speed']), values['motor.synchronous_speed'])
    rates = [(crank_speed, 'the crank speed')]
    if math.isfinite(c) and J2 + J3 > 0.0:
        inv = 1.0 / J4 + 1.0 / (J2 + J3)    # engaged twist mode, bounded above
        rates.append((math.sqrt(c * inv) + kd * inv, "the engaged clutch's shaft twist mode"))
    rates.append((values['load.viscous'] / J4, "the load's viscous rate"))
    # the rate of the crank's effective inertia, with what an engaged clutch drives rigidly
    # (the output too behind a rigid shaft): an accuracy bound more than a stability one, so
    # counted in full (h·rate ≤ 0.5: ~0.3 % energy error through a heavy output's engagement
    # near the Grashof bound); at the scene's crank length (a crank commanded towards the
    # bound at run time is not re-counted)
    j_driven = J2 + J3 + (J4 if not math.isfinite(c) else 0.0)
    rates.append((crank_speed * inertia_rate_factor(
        values['linkage.crank_length'], values['linkage.rocker_length'],
        values['linkage.coupler_length'], values['linkage.pivot_distance'],
        float(values['linkage.assembly_mode']), values['inertia.motor'], j_driven),
        "the crank's effective-inertia rate"))
    return sorted(rates, reverse=True)


def fastest_rate(values):
    """Largest eigenvalue magnitude λ_max [1/s] of the model (bound): the stepped rates and the
    open output's."""
    return max(stepped_rates(values)[0][0], open_output_rate(values))


def resolution_warnings(values, exact_output, h_fixed):
    """Texts that name the setting to change when a scene is stiffer than the explicit method
    can resolve in reasonable time (issue 12): the steps per simulated second its fastest
    resolved mode needs."""
    c = math.inf if values['model.fidelity'] == 'rigid_shaft' else values['shaft.stiffness']
    if values['model.fidelity'] == 'averaged':
        return []
    if values['solver.method'] == 'rk4':
        per_second = 1.0 / h_fixed
        what = f"solver.method rk4 refines its step to {h_fixed:.3g} s"
    else:
        kd = values['shaft.damping']
        J2, J3, J4 = (values['inertia.rocker'], values['inertia.clutch_driven'],
                      values['inertia.output'])
        rate = max(abs(values['initial.crank_speed']), values['motor.synchronous_speed'])
        if math.isfinite(c):
            inv = 1.0 / J4 + (1.0 / (J2 + J3) if J2 + J3 > 0.0 else 0.0)
            rate = max(rate, math.sqrt(c * inv) + kd * inv)   # engaged twist mode
            if not exact_output:                               # the open output, integrated
                rate = max(rate, fastest_rate(values))
        per_second = rate / DP5_STABILITY
        what = (f"its fastest mode (λ ≈ {rate:.3g} 1/s) needs dopri5 steps of "
                f"≤ {1 / per_second:.2g} s")
    if per_second <= SLOW_STEPS_PER_SECOND:
        return []
    return [f"this scene is stiff for an explicit method: {what}, ≥ {per_second:.2g} steps per "
            f"simulated second (seconds of wall time each); shaft.stiffness = {c:g} N·m/rad, "
            f"shaft.damping = {values['shaft.damping']:g} N·m·s/rad, inertia.clutch_driven = "
            f"{values['inertia.clutch_driven']:g} kg·m² set it: a softer or less damped shaft, "
            f"or model.fidelity rigid_shaft / averaged, runs in reasonable time"]


def fixed_step(values, steps_open_output=False):
    """rk4's step for these values: (h_stable, h_fixed, note, warning). h_stable = 0.5/λ for the
    fastest rate the fixed step integrates (stepped_rates; with ``steps_open_output`` the open
    clutch's output modes too: a core that steps them, the N-path one); h_fixed the step taken
    (solver.fixed_step, refined to h_stable with solver.refine_step auto); note: one line saying
    so ('' for dopri5); warning: a step beyond RK4's stability bound kept (refine_step off), or
    ''."""
    rate, what = stepped_rates(values)[0]
    if steps_open_output and open_output_rate(values) > rate:
        rate, what = open_output_rate(values), "the open clutch's output mode"
    h_stable = RK4_STEP_BY_MODE / rate
    asked = values['solver.fixed_step']
    h_fixed = min(asked, h_stable) if values['solver.refine_step'] == 'auto' else asked
    note = warning = ''
    if values['solver.method'] == 'rk4':
        note = f"rk4, fixed step {h_fixed:.3g} s"
        if h_fixed < asked:
            note += (f" (solver.fixed_step {asked:g} s refined: h·λ ≤ {RK4_STEP_BY_MODE:g} for "
                     f"λ = {rate:.3g} 1/s, {what})")
        elif asked * rate > RK4_STABILITY:
            warning = (f"solver.fixed_step {asked:g} s is beyond RK4's stability bound "
                       f"{RK4_STABILITY / rate:.3g} s (2.83/λ, λ = {rate:.3g} 1/s, {what}) and "
                       f"solver.refine_step is off: the run may blow up or miss clutch events; "
                       f"solver.refine_step auto refines it to {h_stable:.3g} s")
    return h_stable, h_fixed, note, warning


class Simulator:
    """The pulse CVT as a hybrid dynamical system with event-located integration.

    ``values``: scene parameters by dotted name (validated here). Time t [s] starts at 0.
    One path: a machine of ``paths.count`` ≥ 2 runs on the N-path core, a PathsSimulator
    (paths_simulator.py) with the same interface; fidelity.make_simulator makes either.
    """
    columns = COLUMNS   # of the sample rows (output.py)
    n_paths = 1
    steps_open_output = False   # the open output runs apart from the fixed step (slip_watch.py)

    def __init__(self, values=None, events_capacity=4096):
        self.values = params_mod.validate(values or {})
        if self.values['paths.count'] > 1:
            raise params_mod.ParameterError(
                'paths.count', f"{self.values['paths.count']} paths run on the N-path core: "
                f"make the simulator with solver.fidelity.make_simulator(values) (or "
                f"solver.paths_simulator.PathsSimulator), not Simulator")
        self._events_buf = np.zeros((events_capacity, AL.N_EVENT_COLUMNS))
        self._floats = np.zeros(F_SIZE)
        self._ints = np.zeros(I_SIZE, dtype=np.int64)
        self._make_views()
        self._empty_grid = np.zeros(0)
        self._empty_out = np.zeros((0, N_COLUMNS))
        self.reset()

    _VIEWS = ('y', 'P', 'ACT', 'S', 'h_io', 'ledger', '_scratch', 'ms', 'counters')

    def _make_views(self):
        f = self._floats
        self.y = f[F_Y:F_P]
        self.P = f[F_P:F_ACT]
        self.ACT = f[F_ACT:F_S].reshape(L.N_ACT_SEGMENTS, 4)
        self.S = f[F_S:F_H]
        self.h_io = f[F_H:F_LEDGER]
        self.ledger = f[F_LEDGER:F_DY]      # kinetic energy lost in impacts [J]
        self._scratch = f[F_SCRATCH:F_SIZE]
        self.ms = self._ints[I_MS:I_COUNTERS]
        self.counters = self._ints[I_COUNTERS:]

    def __getstate__(self):
        # copy.deepcopy and pickle copy arrays one by one: the views would come back as arrays
        # of their own, apart from the blocks the compiled period reads; they are made anew
        return {k: v for k, v in self.__dict__.items() if k not in self._VIEWS}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._make_views()

    # ------------------------------------------------------------------ set-up
    def reset(self):
        """Back to the scene's initial state (t = 0)."""
        v = self.values
        self.P[:] = self._parameter_vector(v)
        self.t = 0.0
        self.ACT[:] = hold_profile(0.0, v['linkage.crank_length'])
        self.crank_length_target = v['linkage.crank_length']
        self.load_torque_cmd = None  # run-time load command overriding load.torque, if any
        self.y[:] = 0.0
        w1 = v['motor.speed'] if v['motor.model'] == 'constant_speed' else v['initial.crank_speed']
        self.y[L.OMEGA1] = w1
        self._ints[:] = 0
        self.h_io[:] = 0.0
        self.ledger[:] = 0.0
        self.energy_injected = 0.0  # energy put in by live parameter changes [J]
        self.turns_phi1 = 0.0       # angle folded out of φ1 and φ4 [rad]
        self.turns_phi4 = 0.0
        self.switch_count = 0
        self.path_switch_counts = [0] * self.n_paths   # switches of each path's clutch
        self.event_count = 0        # switches and grazes
        self.first_late_event = None
        self.stray_count = 0        # samples of run() outside their clutch mode (self_check.py)
        self.first_stray = None
        self._configure_steps()
        self._set_rocker_from_linkage()
        self._settle_clutch()
        # the energy the scene starts with: before a start-up impact, whose loss is booked
        self.energy0 = self._energy() + self.ledger[0]
        # compile (or load from the on-disk cache) now, so that no run's wall time includes it
        self._call(self.t, self._empty_grid, self._empty_out)

    @staticmethod
    def _parameter_vector(values):
        return params_mod.parameter_vector(values)

    def _configure_steps(self):
        usable, self.LIN, rate, ring = modal_form(self.P)
        usable = usable and self.values['solver.output_subsystem'] == 'exact'
        self.P[L.P_LINEAR_OUTPUT] = 1.0 if usable else 0.0
        self.P[L.P_OUTPUT_RATE] = rate
        self.P[L.P_OUTPUT_RING] = ring
        self.h_stable, self.h_fixed, self.step_note, warning = fixed_step(
            self.values, self.steps_open_output)
        self.S[:] = settings_vector(self.values, self.h_fixed)
        self.warnings = resolution_warnings(self.values, usable, self.h_fixed)
        if warning:
            self.warnings.append(warning)

    def _set_rocker_from_linkage(self):
        a, ad, _ = crank_actuator(self.t, self.ACT)
        P = self.P
        _, _, u, _, ga, _, _ = kinematics(self.y[L.PHI1], a, P[L.P_B], P[L.P_D], P[L.P_H],
                                          P[L.P_SIGMA])
        self.y[L.PHI2] = rocker_angle(self.y[L.PHI1], a, P[L.P_B], P[L.P_D], P[L.P_H],
                                      P[L.P_SIGMA])
        self.y[L.OMEGA2] = u * self.y[L.OMEGA1] + ga * ad

    def _settle_clutch(self):
        """Clutch mode by complementarity (physics.md §4), with a plastic impact if s < 0."""
        y, P = self.y, self.P
        self.ms[0] = L.DISENGAGED
        project(self.t, y, L.DISENGAGED, P, self.ACT)
        dy = np.empty(L.N_STATE)
        aux = np.empty(L.N_AUX)
        rhs(self.t, y, L.DISENGAGED, P, self.ACT, dy, aux)
        slip = aux[L.AUX_SLIP]
        w3 = y[L.OMEGA4] if P[L.P_RIGID] else y[L.OMEGA3]
        tol = 1e-10 * (1.0 + abs(aux[L.AUX_ROCKER_SPEED]) + abs(w3))
        if slip < -tol:
            self.ledger[0] += engage_with_impact(self.t, y, P, self.ACT)
            self.ms[0] = L.ENGAGED
        elif slip <= tol and clutch_engages(self.t, y, P, self.ACT, dy, aux, np.empty(L.N_STATE)):
            self.ms[0] = L.ENGAGED
        project(self.t, y, int(self.ms[0]), P, self.ACT)
        self.ms[1] = 0  # the new mode's guard starts at zero: half-open rule

    # ------------------------------------------------------------------ inputs
    @property
    def engaged(self):
        return self.ms[0] == L.ENGAGED

    @property
    def load_torque(self):
        """The constant part of the load torque now in force [N·m] (command or scene)."""
        return float(self.P[L.P_LOAD_TORQUE])

    @property
    def crank_length(self):
        return crank_actuator(self.t, self.ACT)[0]

    @property
    def grashof_bound(self):
        return self._crank_bound

    @property
    def values(self):
        """The scene parameters in force (validated; replaced whole, never changed in place)."""
        return self._values

    @values.setter
    def values(self, new):
        self._values = new
        # what each crank command needs (a controller may command every period)
        self._crank_bound = grashof_bound(new['linkage.rocker_length'],
                                          new['linkage.coupler_length'],
                                          new['linkage.pivot_distance'])
        self._crank_limits = (new['linkage.crank_rate_limit'], new['linkage.crank_accel_limit'])

    def command_crank_length(self, target):
        """Move the crank length to ``target`` [m] through the rate-limited actuator.

        Raises GrashofError (value and bound in the message) for a length the linkage cannot take.
        """
        target = float(target)
        if not 0.0 <= target < self._crank_bound:   # (NaN too) the full check says why
            v = self.values
            check_crank_length(target, v['linkage.rocker_length'], v['linkage.coupler_length'],
                               v['linkage.pivot_distance'])
        rate_limit, accel_limit = self._crank_limits
        replan_into(self.ACT, self.t, target, rate_limit, accel_limit, 2.0)
        self.crank_length_target = target

    def set_load_torque(self, torque):
        """Command the constant part of the load torque [N·m] (acts at the next step).

        A run-time input, like the crank-length command: it overrides the scene's
        ``load.torque`` until reset() or a live change of that parameter.
        """
        torque = params_mod.SPECS['load.torque'].check(torque)
        self.load_torque_cmd = torque
        self.P[L.P_LOAD_TORQUE] = torque

    def update_parameters(self, changes):
        """Change parameters live. Raises ParameterError / GrashofError and changes nothing when
        the new set is invalid. A new crank length goes through the actuator; other changes act
        at once, the clutch mode is re-decided, and the stored energy's jump is booked."""
        new = params_mod.validate(dict(self.values, **changes))
        for name in ('paths.count', 'paths.phase_offsets'):
            if name in changes and new[name] != self.values[name]:
                raise params_mod.ParameterError(
                    name, f"{changes[name]!r} refused: a running machine does not grow a path "
                          f"nor re-phase its cranks (now {self.values[name]!r}); start a new "
                          f"simulation (reset) with the scene changed")
        changes = {k: new[k] for k in changes}
        target = changes.pop('linkage.crank_length', None)
        a_now = crank_actuator(self.t, self.ACT)[0]
        geometry = (new['linkage.rocker_length'], new['linkage.coupler_length'],
                    new['linkage.pivot_distance'])
        # the crank as it is now, and where it is heading, must fit the new geometry too
        commanded = self.crank_length_target if target is None else target
        check_crank_lengths_fit((('present', a_now), ('commanded', commanded)), *geometry)
        e_before = self._energy()
        self.values = new
        self.P[:] = self._parameter_vector(new)
        self.P[L.P_A] = a_now
        if 'load.torque' in changes:
            self.load_torque_cmd = None
        elif self.load_torque_cmd is not None:
            self.P[L.P_LOAD_TORQUE] = self.load_torque_cmd
        if 'motor.model' in changes or 'motor.speed' in changes:
            if new['motor.model'] == 'constant_speed':
                self.y[L.OMEGA1] = new['motor.speed']
        self._configure_steps()
        if self.P[L.P_FORMULATION] == L.FORMULATION_PAPER or any(
                k.startswith('linkage.') or k == 'model.formulation' for k in changes):
            self._set_rocker_from_linkage()
        lost = self.ledger[0]
        self._settle_clutch()
        # what the change put in; an impact it causes is booked as such (ledger), not here
        self.energy_injected += self._energy() - e_before + (self.ledger[0] - lost)
        self.h_io[:] = 0.0
        if target is not None:
            self.command_crank_length(target)

    # ------------------------------------------------------------------ integration
    def _call(self, t_end, grid, out, objects=True):
        t = hybrid.advance(self.t, t_end, self.y, self.ms, self.P, self.ACT, self.LIN, self.S,
                           self.h_io, grid, out, self._events_buf, self.counters, self.ledger,
                           self._scratch)
        self.t = t
        return self._finish_call(objects)

    def _finish_call(self, objects):
        """After a compiled call: its events taken, a failure raised."""
        switches = self._take_events(objects)
        status = int(self.counters[AL.C_STATUS])
        if status in _FAILURES:
            raise SimulationError(self._failure_text(status, switches))
        return switches, status

    def _take_events(self, objects=True):
        """The clutch events the compiled loop located since the last call, as ClutchSwitch
        objects (objects False: only the last three, for a failure's message: a streamed run
        keeps none, and one object costs ~1 µs, 250 of them per simulated second on the stiff
        shaft); counts the switches and events, notes the first late event, empties the table."""
        n_ev = int(self.counters[AL.C_EVENTS])
        if n_ev == 0:
            return []
        rows = self._events_buf[:n_ev]
        # one tolist() rather than four numpy scalars per row (~10 000 switches a run)
        switches = self._switches_of((rows if objects else rows[-3:]).tolist())
        switched = int(np.count_nonzero(rows[:, AL.E_KIND] != KIND_GRAZE))
        self.switch_count += switched
        self._count_path_switches(rows, switched)
        self.event_count += n_ev
        late = rows[rows[:, AL.E_LATE] > 0.0]
        if len(late) and self.first_late_event is None:
            self.first_late_event = float(late[0, AL.E_T])
        self.counters[AL.C_EVENTS] = 0
        return switches

    @staticmethod
    def _switches_of(rows):
        """ClutchSwitch objects of event rows (lists of floats)."""
        return [ClutchSwitch(row[AL.E_T], row[AL.E_MODE] == L.ENGAGED,
                             _KIND_NAMES[int(row[AL.E_KIND])], row[AL.E_VALUE]) for row in rows]

    def _count_path_switches(self, rows, switched):
        self.path_switch_counts[0] += switched

    def _failure_text(self, status, switches):
        text = f"integration failed at t = {self.t:.9g} s: {_FAILURES[status]}"
        if status in (AL.STATUS_STEP_TOO_SMALL, AL.STATUS_NO_PROGRESS, AL.STATUS_NONFINITE):
            text += (" — the scene's values drive the model beyond what it can resolve; check "
                     "the largest of load.*, shaft.*, motor.*, inertia.* and initial.crank_speed "
                     "(cvt-sim params shows their ranges)")
            if self.warnings:
                text += f"; {self.warnings[0]}"
        return text + f" (last clutch events: {switches[-3:]})"

    def _advance_to(self, t_end, grid, out, objects=True):
        """Integrate to t_end, draining the event table as often as it fills."""
        switches = []
        while True:
            sw, status = self._call(t_end, grid, out, objects)
            switches += sw
            if status != AL.STATUS_EVENTS_FULL or self.t >= t_end:
                return switches

    def advance(self, dt):
        """Advance by exactly dt [s]; returns the clutch switches located inside the step."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive finite time, got {dt!r}")
        if self.S[AL.S_METHOD] == RK4:
            n = max(1, math.ceil(dt / self.h_fixed - 1e-9))
            self.S[AL.S_H_FIXED] = dt / n
        switches = self._advance_to(self.t + dt, self._empty_grid, self._empty_out)
        self._rebase_angles()
        return switches

    def run(self, duration, sample_dt, progress=None, on_samples=None, keep_samples=True,
            on_switches=None):
        """Integrate for ``duration`` [s], sampling every ``sample_dt`` [s] on the grid
        t0 + k·sample_dt (t0 included; the last sample is exactly t0 + duration when that is on
        the grid).

        Samples are produced in blocks of at most ROWS_PER_BLOCK rows: ``on_samples(block)`` gets
        each block (an array of rows, columns output.COLUMNS) as soon as it is written;
        ``keep_samples`` False keeps none in the result, nor the clutch switches (constant memory
        for any duration: ``switch_count`` / ``graze_count`` count them, ``on_switches(list)``
        gets each call's ClutchSwitch objects), True keeps them all (refused beyond
        MAX_KEPT_ROWS rows: stream them instead).
        Raises SimulationError when the run cannot go on or its energy balance is not finite.
        """
        if not (duration > 0.0 and math.isfinite(duration)):
            raise ValueError(f"duration must be a positive finite time, got {duration!r}")
        if not (sample_dt > 0.0 and math.isfinite(sample_dt)):
            raise ValueError(f"sample dt must be a positive finite time, got {sample_dt!r}")
        t0 = self.t
        t_stop = t0 + duration
        n_last = math.floor(duration / sample_dt + 1e-9)   # index of the last sample
        if not (n_last < 2 ** 53 and t0 + sample_dt > t0):
            raise ValueError(f"sample dt {sample_dt!r} s is too small for a run of "
                             f"{duration!r} s from t = {t0!r} s")
        if keep_samples and n_last + 1 > MAX_KEPT_ROWS:
            raise ValueError(f"a run of {duration:g} s sampled every {sample_dt:g} s has "
                             f"{n_last + 1:.3g} samples, more than the {MAX_KEPT_ROWS:.0e} "
                             f"kept in memory: sample less often or stream them "
                             f"(on_samples, keep_samples=False)")
        first_row = self.sample()[None, :]
        kept = [first_row] if keep_samples else []
        if on_samples is not None:
            on_samples(first_row)
        steps0 = int(self.counters[AL.C_STEPS])
        rej0 = int(self.counters[AL.C_REJECTED])
        rhs0 = int(self.counters[AL.C_RHS])
        late0 = int(self.counters[AL.C_LATE])
        switch0 = self.switch_count
        events0 = self.event_count
        per_path0 = tuple(self.path_switch_counts)
        switches = []
        objects = keep_samples or on_switches is not None
        wall0 = time.perf_counter()
        # each compiled call ends a step at its chunk's end: chunks of fixed length (not of the
        # sample interval or the duration) keep the solution independent of how it is sampled,
        # and a shorter run's samples a prefix of a longer one's
        chunk = min(RUN_CHUNK, ROWS_PER_BLOCK * sample_dt)
        if self.S[AL.S_METHOD] == RK4:   # whole fixed steps per call: the grid is not cut short
            chunk = math.ceil(chunk / self.h_fixed - 1e-9) * self.h_fixed
        k_next = 1   # index of the next sample
        t_next = t0
        band = stray_band(self.values)
        strays, first_stray = 0, None
        while self.t < t_stop:
            t_next = min(t_stop, t_next + chunk)
            k_end = min(n_last, math.floor((t_next - t0) / sample_dt + 1e-9))
            grid = t0 + sample_dt * np.arange(k_next, k_end + 1)
            if k_end == n_last and len(grid):
                grid[-1] = min(grid[-1], t_stop)   # the grid ends exactly at T
            out = np.empty((len(grid), len(self.columns)))
            self.counters[AL.C_NEXT_SAMPLE] = 0
            # rebasing between chunks shifts angles: the rows written in this chunk are
            # corrected by the offsets in force while they were written
            off1, off4 = self.turns_phi1, self.turns_phi4
            located = self._advance_to(t_next, grid, out, objects)
            if located and objects:
                if keep_samples:
                    switches += located
                if on_switches is not None:
                    on_switches(located)
            block = out[:int(self.counters[AL.C_NEXT_SAMPLE])]
            block[:, COL['phi1']] += off1
            block[:, COL['phi3']] += off4
            block[:, COL['phi4']] += off4
            k_next += len(block)
            n_stray, t_stray = stray_samples(block, self.P, band, self.columns)
            if n_stray:
                strays += n_stray
                first_stray = t_stray if first_stray is None else first_stray
                self.stray_count += n_stray
                self.first_stray = t_stray if self.first_stray is None else self.first_stray
            if len(block):
                if keep_samples:
                    kept.append(block)
                if on_samples is not None:
                    on_samples(block)
            self._rebase_angles()
            if progress is not None:
                progress(self.t - t0, duration)
        wall = time.perf_counter() - wall0
        energy = self.energy_balance()
        if not math.isfinite(energy['residual']):
            raise SimulationError(
                f"the energy balance is not finite at t = {self.t:.9g} s (stored energy "
                f"{energy['stored']!r} J, motor work {energy['work_motor']!r} J): the scene's "
                "values overflow the model; check inertia.*, initial.crank_speed and the torques")
        late = int(self.counters[AL.C_LATE]) - late0
        warnings = list(self.warnings)
        if late:
            warnings.append(
                f"{late} clutch switch(es) found only after the step that crossed them (first at "
                f"t = {self.first_late_event:.9g} s): an event may have been missed there; a "
                "tighter solver.rtol or a smaller solver.max_step locates it")
        if strays:
            warnings.append(
                f"{strays} sample(s) stand outside their clutch mode by more than {band:.2g} of "
                f"the guard's scale (first at t = {first_stray:.9g} s: an open clutch's slip or "
                "an engaged clutch's release guard below zero): a clutch event inside a step may "
                "have been missed; a tighter solver.rtol (dopri5) or solver.fixed_step (rk4) "
                "shows whether it is real")
        diagnostics = {'rhs_evaluations': int(self.counters[AL.C_RHS]) - rhs0,
                       'possible_missed_events': late,
                       'first_possible_missed_event_s': self.first_late_event if late else None,
                       'stray_samples': strays, 'first_stray_sample_s': first_stray,
                       'solver': self.self_check()['solver'], 'warnings': warnings}
        samples = np.concatenate(kept) if keep_samples else np.empty((0, len(self.columns)))
        switched = self.switch_count - switch0
        per_path = tuple(int(c) - int(c0) for c, c0 in zip(self.path_switch_counts, per_path0,
                                                            strict=True))
        return RunResult(samples, switches, wall, int(self.counters[AL.C_STEPS]) - steps0,
                         int(self.counters[AL.C_REJECTED]) - rej0, energy, diagnostics,
                         switched, self.event_count - events0 - switched, self.columns, per_path)

    def self_check(self):
        """The solver's self-check since reset() (docs/solver.md): which method and step,
        switches made late at a step's end (a guard found beyond its band: an event inside the
        step that no watch located) and samples of run() outside their clutch mode. For the
        device's /diagnostics, scenario results and recordings' metadata."""
        late = int(self.counters[AL.C_LATE])
        return {'solver': self.step_note or f"dopri5, rtol {self.values['solver.rtol']:g}",
                'possible_missed_events': late,
                'first_possible_missed_event_s': self.first_late_event if late else None,
                'stray_samples': self.stray_count,
                'first_stray_sample_s': self.first_stray}

    def _rebase_angles(self):
        """Fold whole turns out of φ1 and φ4 so their sines keep full precision for hours."""
        y = self.y
        k1 = math.floor(y[L.PHI1] / TWO_PI)
        if abs(k1) >= REBASE_TURNS:
            y[L.PHI1] -= k1 * TWO_PI
            self.turns_phi1 += k1 * TWO_PI
            # the actuator profile does not depend on φ1; the paper's φ2 is periodic in φ1
        k4 = math.floor(y[L.PHI4] / TWO_PI)
        if abs(k4) >= REBASE_TURNS:
            y[L.PHI4] -= k4 * TWO_PI
            self.turns_phi4 += k4 * TWO_PI

    # ------------------------------------------------------------------ outputs
    def _aux(self):
        dy = np.empty(L.N_STATE)
        aux = np.empty(L.N_AUX)
        rhs(self.t, self.y, int(self.ms[0]), self.P, self.ACT, dy, aux)
        return aux

    def _energy(self):
        return float(self._aux()[L.AUX_ENERGY])

    def sample(self):
        """The current state as one row of output.COLUMNS (angles with whole turns restored)."""
        row = np.empty(N_COLUMNS)
        write_sample(row, self.t, self.y, int(self.ms[0]), self._aux())
        row[COL['phi1']] += self.turns_phi1
        row[COL['phi3']] += self.turns_phi4
        row[COL['phi4']] += self.turns_phi4
        return row

    def energy_balance(self):
        """Energy ledger [J] since t = 0 and the balance residual (physics.md §4)."""
        y = self.y
        energy = self._energy()
        w_m, w_l, w_d, w_a = y[L.W_MOTOR], y[L.W_LOAD], y[L.W_DAMPING], y[L.W_ACTUATOR]
        losses = self.ledger[0] - self.energy_injected
        residual = energy_residual(energy, self.energy0, w_m, w_l, w_d, w_a, losses)
        scale = abs(w_m) + abs(w_l) + abs(w_d) + abs(w_a) + abs(losses)
        return {
            'stored': energy - self.energy0, 'work_motor': w_m, 'work_load': w_l,
            'dissipated_damping': w_d, 'work_actuator': w_a, 'impact_loss': self.ledger[0],
            'parameter_changes': self.energy_injected, 'residual': residual,
            'relative_residual': abs(residual) / scale if scale > 0 else abs(residual),
        }


__all__ = ['Simulator', 'SimulationError', 'RunResult', 'ClutchSwitch', 'KIND_ENGAGE_IMPACT']
