"""The device core: the transmission as a device advanced one control period at a time. No ROS.

A :class:`Device` owns the simulator of a scene and what a device adds to it: the control period,
the commands in force (checked, refused with a reason), the actual crank length and its rate, the
fault state, the step-time statistics. The node (``device/node.py``) drives it from its run loop;
tests and in-process controllers (``cvt_ros.control``) drive it directly, with no DDS:

    device = Device(load_scene('conveyor', {'solver.method': 'rk4'}), control_period=1e-3)
    device.command_crank_length(0.05)   # acts from the next period on
    period = device.advance()           # one control period: period.row, period.events

A command given between two periods acts on the physics from the start of the next period, so a
run of (command, advance) pairs is the offline core's run with the same commands at the same
steps, bit for bit: ``Simulator.command_crank_length`` / ``set_load_torque`` then
``Simulator.advance(control_period)`` and ``Simulator.sample()``.
"""
import math
import time
from dataclasses import dataclass

import numpy as np

from .. import parameters as params_mod
from ..parameters import NODE_PARAMETERS, PHYSICS_PARAMETERS, ParameterError
from ..physics.drives import crank_actuator
from ..physics.linkage import GrashofError, check_crank_lengths_fit, grashof_bound
from ..solver.clutch_sets import set_changes
from ..solver.fidelity import make_simulator
from ..solver.output import COL
from ..solver.period import PeriodStepper
from ..solver.simulator import SimulationError
from .disturbance import DisturbanceError, load_disturbance

PHYSICS_NAMES = frozenset(s.name for s in PHYSICS_PARAMETERS)
NODE_NAMES = frozenset(s.name for s in NODE_PARAMETERS)
DISTURBANCE = 'disturbance.file'
#: Parameters the device takes at a period boundary (the node queues them for its loop thread):
#: the physics and the disturbance schedule.
PERIOD_NAMES = PHYSICS_NAMES | {DISTURBANCE}
#: The machine's build: a running device keeps its paths (physics/paths.py's state has one
#: rocker per path, phased on the crank).
PATH_NAMES = ('paths.count', 'paths.phase_offsets')
RING_SIZE = 4096   # step times kept for percentiles
NO_EVENTS = ()     # a period without clutch switches (most of them)


class CommandError(ValueError):
    """A refused command: ``topic``, the ``value`` as text, the ``reason`` with the limit."""

    def __init__(self, topic, value, reason):
        super().__init__(f"refused {topic} = {value}: {reason}")
        self.topic = topic
        self.value = value
        self.reason = reason


@dataclass
class Period:
    """One control period: start and end time [s], clutch switches inside it (grazing contacts
    left out), the sample row at its end (``solver.output.COLUMNS``), the actuator's rate at
    its end [m/s]; ``next_event``: switches already published (realtime publishes them at their
    own moments)."""
    t0: float
    t: float
    events: list
    row: np.ndarray
    crank_rate: float = 0.0
    next_event: int = 0


class Ring:
    """The last ``n`` values of a measurement, for percentiles (one writer thread)."""

    def __init__(self, n=RING_SIZE):
        self.buf = np.zeros(n)
        self.count = 0

    def add(self, value):
        self.buf[self.count % len(self.buf)] = value
        self.count += 1

    def clear(self):
        self.count = 0

    def percentiles(self, qs=(50, 99)):
        """Percentiles and the maximum over the kept values (None when empty)."""
        n = min(self.count, len(self.buf))
        if n == 0:
            return None
        data = self.buf[:n].copy()
        return [float(v) for v in np.percentile(data, qs)] + [float(data.max())]


def physics_values(values):
    """The scene parameters of ``values`` (the node's own left out)."""
    return {k: v for k, v in values.items() if k in PHYSICS_NAMES}


def geometry(values):
    return (values['linkage.rocker_length'], values['linkage.coupler_length'],
            values['linkage.pivot_distance'])


def disturbance_schedule(values):
    """The schedule named by ``values['disturbance.file']`` (None when empty), its loads checked
    against ``limits.load_torque``; ParameterError naming the file, line and value otherwise."""
    path = values.get(DISTURBANCE, '')
    if not path:
        return None
    try:
        return load_disturbance(path, values.get('limits.load_torque', math.inf))
    except DisturbanceError as exc:
        raise ParameterError(DISTURBANCE, str(exc)) from None


def _check_paths_kept(values, changes):
    """ParameterError unless ``changes`` keep the paths as they are (the same count, the same
    offsets, however spelt: [] is 2π·(k − 1)/N)."""
    if 'paths.count' in changes and changes['paths.count'] != values['paths.count']:
        raise ParameterError('paths.count', _path_refusal('paths.count', changes['paths.count'],
                                                          values))
    if 'paths.phase_offsets' in changes:
        value = changes['paths.phase_offsets']
        try:
            same = params_mod.phase_offsets(dict(values, **{
                'paths.phase_offsets': tuple(float(x) for x in value or ())})) == \
                params_mod.phase_offsets(values)
        except (TypeError, ValueError):
            same = False
        if not same:
            raise ParameterError('paths.phase_offsets',
                                 _path_refusal('paths.phase_offsets', value, values))


def _path_refusal(name, value, values):
    shown = list(value) if not isinstance(value, (int, float, str)) else value
    now = values['paths.count'] if name == 'paths.count' else list(
        params_mod.phase_offsets(values))
    return (f"{shown!r} refused: the paths are the machine's build (each its own crank-rocker "
            f"and one-way clutch, phased on the one crank); a running device neither adds nor "
            f"removes a path nor re-phases one (now {now!r}). Start it again with the new value "
            f"(the node: a params file or `-p {name}:=...`)")


def check_parameter_change(values, changes, present, commanded):
    """The validated values after ``changes``, or ParameterError / GrashofError with the reason.

    ``present``, ``commanded``: the actuator's crank length now and the last accepted command
    [m]; a new geometry must leave room for both (``check_crank_lengths_fit``). A new
    disturbance file (or load limit) is read and checked.
    """
    _check_paths_kept(values, changes)
    new = params_mod.validate(dict(values, **changes))
    if DISTURBANCE in changes or 'limits.load_torque' in changes:
        disturbance_schedule(new)
    if any(name.startswith('linkage.') for name in changes):
        target = new['linkage.crank_length'] if 'linkage.crank_length' in changes else commanded
        try:
            check_crank_lengths_fit((('present', present), ('commanded', target)),
                                    *geometry(new))
        except GrashofError as exc:
            raise GrashofError(f"{', '.join(sorted(changes))}: {exc}", exc.value,
                               exc.limit) from None
    return new


class Device:
    """The transmission as a device. ``values``: validated scene values (``parameters.validate``
    or ``scene.load_scene``; the node's own parameters may be among them, the limit
    ``limits.load_torque`` is taken from them; ``disturbance.file`` names a load schedule,
    ``device/disturbance.py``). ``control_period`` [s]: simulation time per ``advance()``.
    ``timing``: keep each period's compute time in ``step_ns`` (the node's diagnostics).
    Raises ParameterError / GrashofError for values the physics cannot take.

    A period is one compiled call (``solver.period.PeriodStepper``): ``advance()`` returns a
    Period of its own; ``advance_row()`` — the fast path, no Python object per period — returns
    the stepper's row buffer, rewritten by the next period."""

    def __init__(self, values, control_period=1e-3, timing=False):
        if not (control_period > 0.0 and math.isfinite(control_period)):
            raise ValueError(f"control period must be a positive finite time, got "
                             f"{control_period!r}")
        self.values = values
        self._dt = float(control_period)
        self.timing = timing
        self.step_ns = Ring()
        self.sim = self.stepper = None
        # clutch switches inside the last period (grazes left out): ClutchSwitch for one path;
        # for N ≥ 2 one solver.clutch_sets.SetChange per switching instant (the engaged set)
        self.events = NO_EVENTS
        self.n_paths = int(values.get('paths.count', 1))
        self.engaged_set = 0      # N ≥ 2: the engaged clutches (bit k − 1 = path k)
        self.crank_rate = 0.0     # the actuator's rate at the end of the last period [m/s]
        self.disturbance = disturbance_schedule(self.values)
        self.reset()

    @property
    def dt(self):
        """The control period [s] (simulation time per advance)."""
        return self._dt

    @dt.setter
    def dt(self, value):
        self._dt = float(value)
        if self.stepper is not None:
            self.stepper.dt = self._dt

    # ------------------------------------------------------------------ state
    def reset(self):
        """Back to the scene's initial state (t = 0) with the parameters as they are now; the
        commands in force become the parameters' crank length and load torque; clears a fault.
        Raises ParameterError / GrashofError / SimulationError (the fault stays set)."""
        v = self.values
        self.crank_target = v['linkage.crank_length']   # last accepted crank length [m]
        self.load_command = v['load.torque']            # last accepted load torque [N·m]
        self.fault = None
        # the period grid t_k = grid_t0 + k·dt the disturbance schedule is applied on: k counted
        # from the reset (re-anchored when the control period changes)
        self._grid_t0, self._grid_k, self._grid_dt = 0.0, 0, self.dt
        self._next_disturbance = 0   # index of the schedule's next row
        try:
            self.sim = make_simulator(physics_values(v))
        except (ParameterError, GrashofError, SimulationError) as exc:
            self.fault = f"reset failed: {exc}"
            raise
        self.stepper = PeriodStepper(self.sim, self.dt)
        self._sync_engaged_set()

    def _sync_engaged_set(self):
        self.engaged_set = self.sim.engaged_set if self.n_paths > 1 else int(self.sim.engaged)

    @property
    def t(self):
        return self.sim.t

    @property
    def values(self):
        """The device's parameter values (set as a whole: a new geometry, a new bound)."""
        return self._values

    @values.setter
    def values(self, new):
        self._values = dict(new)
        self._bound = grashof_bound(*geometry(self._values))   # checked on every command

    @property
    def bound(self):
        """Grashof bound of the present geometry [m] (crank lengths must stay below it)."""
        return self._bound

    @property
    def load_limit(self):
        return self.values.get('limits.load_torque', math.inf)

    def actuator(self):
        """(actual crank length [m], its rate [m/s]) now."""
        a, ad, _ = crank_actuator(self.sim.t, self.sim.ACT)
        return float(a), float(ad)

    def sample(self):
        """The present state as one row of ``solver.output.COLUMNS``."""
        return self.sim.sample()

    def present_state(self):
        """The present state as a Period of zero length (start-up, reset)."""
        t = self.sim.t
        return Period(t, t, [], self.sim.sample(), self.actuator()[1])

    # ------------------------------------------------------------------ commands
    def check_crank_length(self, a, topic='crank_length_cmd'):
        """Raise CommandError unless ``a`` [m] is a crank length the linkage can take now
        (``topic``: where it came from, for the message)."""
        bound = self.bound
        if math.isfinite(a) and 0.0 <= a < bound:
            return
        why = 'not a finite number' if not math.isfinite(a) else 'outside the Grashof range'
        raise CommandError(topic, f"{a!r} m", f"{why}; limit [0, {bound!r}) m")

    def check_load_torque(self, m):
        """Raise CommandError unless ``m`` [N·m] is finite and within limits.load_torque."""
        limit = self.load_limit
        if math.isfinite(m) and abs(m) <= limit:
            return
        why = 'not a finite number' if not math.isfinite(m) else 'beyond the limit'
        raise CommandError('load_torque_cmd', f"{m!r} N*m",
                           f"{why}; limit |M| <= {limit!r} N*m (parameter limits.load_torque)")

    def command_crank_length(self, a):
        """Move the crank towards ``a`` [m] (rate- and acceleration-limited) from the next period
        on. Raises CommandError (nothing changes) for a length the linkage cannot take.

        The set point in force given again changes nothing (a position servo does not re-plan
        its motion): a lockstep controller that repeats its command each period runs the same
        actuator profile, bit for bit, as one that commands only changes."""
        self.check_crank_length(a)
        if a == self.sim.crank_length_target:
            return
        self.sim.command_crank_length(a)   # (one compiled call: physics.drives.replan_into)
        self.crank_target = a

    def command_load_torque(self, m):
        """Set the constant part of the load torque [N·m] from the next period on. Raises
        CommandError (nothing changes) for a non-finite value or one beyond the limit."""
        self.check_load_torque(m)
        self.sim.set_load_torque(m)
        self.load_command = m

    # ------------------------------------------------------------------ parameters
    def check_parameters(self, changes, present=None, commanded=None):
        """The validated values after ``changes`` (ParameterError / GrashofError otherwise);
        ``present`` / ``commanded`` crank lengths default to the device's own."""
        if present is None:
            present = self.actuator()[0]
        if commanded is None:
            commanded = self.crank_target
        return check_parameter_change(self.values, changes, present, commanded)

    def update_parameters(self, changes):
        """Apply parameter changes now (checked again against the present state); physics ones
        go to the simulator, which books the stored energy's jump."""
        new = self.check_parameters(changes)
        # (the paths: checked to be the same build, however spelt; nothing for the simulator)
        physics = {k: new[k] for k in changes if k in PHYSICS_NAMES and k not in PATH_NAMES}
        if DISTURBANCE in changes:
            # the new schedule from now on: its rows already due apply at the next period (the
            # last of them wins: the value the schedule has in force now)
            self.disturbance = disturbance_schedule(new)
            self._next_disturbance = 0
        if physics:
            self.sim.update_parameters(physics)
            self._sync_engaged_set()   # (a live change re-decides the clutches)
            if 'linkage.crank_length' in physics:
                self.crank_target = new['linkage.crank_length']
            if 'load.torque' in physics:
                self.load_command = new['load.torque']
        self.values = new

    def set_values(self, new):
        """Take already validated values (the node checked them) without touching the physics
        (the node queues physics changes for its loop: ``update_parameters``)."""
        self.values = new

    # ------------------------------------------------------------------ time
    def advance(self):
        """Advance one control period; the Period (its own row), or None (and ``fault`` set)
        if the integration failed. A held fault advances nothing until reset()."""
        t0 = self.sim.t
        row = self.advance_row()
        if row is None:
            return None
        return Period(t0, self.sim.t, list(self.events), row.copy(), self.crank_rate)

    def advance_row(self):
        """Advance one control period, the fast path: the sample row at its end — a buffer
        the next period rewrites (copy what you keep) — or None (and ``fault`` set) if the
        integration failed; ``events``, ``crank_rate`` describe the period."""
        if self.fault:
            return None
        if self._dt != self._grid_dt:   # a new control period: its grid starts here
            self._grid_t0, self._grid_k, self._grid_dt = self.sim.t, 0, self._dt
        if self.disturbance is not None:
            self._apply_disturbance()
        self._grid_k += 1
        stepper = self.stepper
        c0 = time.perf_counter_ns() if self.timing else 0
        try:
            row = stepper.advance()
        except (SimulationError, ValueError) as exc:
            self.fault = str(exc)
            return None
        if self.timing:
            self.step_ns.add(time.perf_counter_ns() - c0)
        switches = stepper.switches
        self.events = [s for s in switches if s.kind != 'graze'] if switches else NO_EVENTS
        if self.events and self.n_paths > 1:
            self.events, self.engaged_set = set_changes(self.events, self.engaged_set)
        self.crank_rate = stepper.crank_rate
        return row

    def _apply_disturbance(self):
        """Rows of the schedule due at this period's start t_k (t <= t_k): the last one wins."""
        times, i = self.disturbance.times, self._next_disturbance
        t_k = self._grid_t0 + self._grid_k * self.dt
        if i >= len(times) or times[i] > t_k:
            return
        while i < len(times) and times[i] <= t_k:
            i += 1
        self._next_disturbance = i
        value = self.disturbance.values[i - 1]
        self.sim.set_load_torque(value)   # checked against limits.load_torque when loaded
        self.load_command = value

    # ------------------------------------------------------------------ reporting
    def state_text(self):
        """One line: time, crank length (actual and target), the load torque in force (the
        last load_torque_cmd, else load.torque), clutch state."""
        sim = self.sim
        return (f"t={sim.t:.9f} s crank_length={float(sim.crank_length):.6g} m "
                f"(target {sim.crank_length_target:.6g} m) "
                f"load_torque={sim.load_torque:.6g} N*m "
                f"engaged={str(bool(sim.engaged)).lower()}")

    def snapshot(self, last_row):
        """What the diagnostics report about the simulation (loop thread, every 250 ms)."""
        sim = self.sim
        energy = sim.energy_balance()
        return {
            't': sim.t, 'switch_count': sim.switch_count,
            'phi1': float(last_row[COL['phi1']]) if last_row is not None else 0.0,
            'phi4': float(last_row[COL['phi4']]) if last_row is not None else 0.0,
            'crank_length': float(sim.crank_length), 'crank_target': sim.crank_length_target,
            'grashof_bound': float(sim.grashof_bound), 'load_torque': sim.load_torque,
            'engaged': bool(sim.engaged), 'residual': float(energy['residual']),
            'n_paths': self.n_paths, 'engaged_set': self.engaged_set,
            'path_switches': tuple(sim.path_switch_counts),
            'relative_residual': float(energy['relative_residual']),
            'self_check': sim.self_check(),
        }


__all__ = ['CommandError', 'Device', 'PATH_NAMES', 'PERIOD_NAMES', 'Period', 'Ring',
           'check_parameter_change', 'disturbance_schedule', 'physics_values']
