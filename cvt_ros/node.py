"""The ROS 2 node ``cvt_sim``: the pulse CVT as a real-time virtual device for controller tests.

Interface (names relative, so ``--ros-args -r __ns:=/line1`` puts a second transmission beside the
first; the full reference is docs/node.md):

* subscriptions (std_msgs/Float64, reliable): ``crank_length_cmd`` [m], ``load_torque_cmd`` [N·m]
* publications: ``joint_states`` (sensor_msgs/JointState), ``clutch_engaged`` (std_msgs/Bool,
  transient local), ``/clock`` (rosgraph_msgs/Clock), ``/diagnostics`` (~1 Hz)
* services: ``~/reset`` (Trigger), ``~/pause`` (SetBool), ``~/step`` (Trigger)
* parameters: every scene parameter of ``cvt_ros.parameters.SPECS`` under its dotted name, plus
  the node's own (``NODE_PARAMETERS``: time_mode, real_time_factor, publish_rate, ...)

Threads: the rclpy executor (main thread) runs the callbacks, which only check and queue; one loop
thread owns the Simulator, applies what was queued at the start of the next physics step, advances
by one control period (1/publish_rate of simulation time) and publishes. No physics here: the
node is a thin shell around ``cvt_ros.solver.simulator.Simulator``.
"""
import argparse
import array
import collections
import ctypes
import difflib
import gc
import math
import os
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.utilities import remove_ros_args
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool, Trigger

from . import interface
from . import parameters as params_mod
from .parameters import NODE_PARAMETERS, PHYSICS_PARAMETERS, ParameterError
from .physics.linkage import GrashofError, grashof_bound
from .scene import NODE_NAME, SceneError, read_scene
from .solver.fidelity import make_simulator
from .solver.output import COL
from .solver.simulator import SimulationError

# ---------------------------------------------------------------------------------- constants
DEFAULT_SCENE = 'conveyor'
# rk4 is the node's default solver: fixed sub-steps with events located inside the step, so every
# control period costs the same (dopri5's adaptive steps make the cost per period vary).
REALTIME_SOLVER = 'rk4'

JOINTS = interface.JOINTS   # crank, rocker, clutch_output, output_shaft: J1..J4
_POSITION = [COL[c] for c in ('phi1', 'phi2', 'phi3', 'phi4')]
_VELOCITY = [COL[c] for c in ('omega1', 'omega2', 'omega3', 'omega4')]
# effort: motor torque on the crank, clutch torque on the rocker, shaft torque on the clutch
# output, load torque on the output shaft (signs as in the core's output columns)
_EFFORT = [COL[c] for c in ('motor_torque', 'clutch_torque', 'shaft_torque', 'load_torque')]

SPIN_NS = 100_000              # busy-wait the last 100 µs before a deadline (sleep overshoots)
MAX_SLEEP_S = 0.05             # longest single sleep: stop / pause are seen within this
IDLE_WAIT_S = 0.1              # lockstep / paused: wait for work this long at a time
LAG_LIMIT_NS = 500_000_000     # behind by more than this: give up the backlog, re-anchor
STATS_PERIOD_NS = 250_000_000  # energy balance / snapshot for diagnostics this often
RING_SIZE = 4096               # samples kept for step-time and jitter percentiles
WARN_PERIOD_S = 1.0            # throttled warnings: at most one per topic per second
SERVICE_TIMEOUT_S = 5.0        # a service waits this long for the loop to act
QUEUE_LIMIT = 100_000          # queued requests; beyond this commands are dropped (and counted)
FAST_BATCH = 20                # fast mode: control periods per pass of the loop (less overhead)
TAKE_LIMIT = 1000              # command messages the loop takes per subscription and step
# The loop thread must get the GIL soon after its deadline even while the executor thread is busy
# (a flood of commands): Python's default 5 ms switch interval would be a 5 ms jitter.
GIL_SWITCH_INTERVAL_S = 1e-4
DBL_MAX = sys.float_info.max

# ---------------------------------------------------------------------------------- QoS
# defined once in cvt_ros.interface (the recorder and the replay use the same): joint_states as
# robot_state_publisher, `ros2 topic echo` and PlotJuggler expect; clutch_engaged latched;
# /clock as rclcpp::ClockQoS (best effort, keep last 1)
JOINT_STATES_QOS = interface.joint_states_qos()
CLUTCH_QOS = interface.clutch_qos()
CLOCK_QOS = interface.clock_qos()
DIAGNOSTICS_QOS = interface.diagnostics_qos()
COMMAND_QOS = interface.command_qos()

# ---------------------------------------------------------------------------------- parameters
PHYSICS_NAMES = frozenset(s.name for s in PHYSICS_PARAMETERS)
NODE_NAMES = frozenset(s.name for s in NODE_PARAMETERS)

# parameters rclpy or other layers declare themselves: not warned about as unknown overrides
_FOREIGN_PARAMETERS = ('use_sim_time', 'start_type_description_service')


def ros_value(spec, value):
    """A checked scene value as the Python type its ROS parameter is declared with."""
    kind = type(spec.default)
    if kind is bool:
        return bool(value)
    if kind is int:
        return int(value)
    if kind is float:
        return float(value)
    return str(value)


def _interval(spec):
    lo = '(' if spec.low_open or math.isinf(spec.low) else '['
    hi = ']' if spec.allow_inf else (')' if math.isinf(spec.high) else ']')
    return f"{lo}{spec.low:g}, {spec.high:g}{hi}"


def describe(spec):
    """The ParameterDescriptor of a scene parameter: description, unit, range or choices.

    A floating-point range is given wherever the spec has a bound; an infinite side becomes
    ±DBL_MAX (rclpy's range check cannot hold inf). A parameter that may be +inf (the rigid shaft)
    has no range and is checked in the on-set callback instead. Open bounds (> 0) are also checked
    there, as rclpy's ranges are closed.
    """
    d = ParameterDescriptor(name=spec.name, description=spec.description)
    kind = type(spec.default)
    if spec.choices:
        d.additional_constraints = f"one of: {', '.join(str(c) for c in spec.choices)}"
        if kind is int:
            values = sorted(spec.choices)
            steps = {b - a for a, b in zip(values, values[1:], strict=False)}
            d.integer_range = [IntegerRange(from_value=values[0], to_value=values[-1],
                                            step=steps.pop() if len(steps) == 1 else 0)]
    elif kind is str:
        d.additional_constraints = 'string'
    else:
        d.additional_constraints = f"unit: {spec.unit}; range: {_interval(spec)}"
        if spec.allow_inf:
            d.additional_constraints += ' (.inf allowed)'
        if kind is int:
            d.integer_range = [IntegerRange(
                from_value=int(spec.low) if math.isfinite(spec.low) else -2**63,
                to_value=int(spec.high) if math.isfinite(spec.high) else 2**63 - 1, step=1)]
        elif not spec.allow_inf and (math.isfinite(spec.low) or math.isfinite(spec.high)):
            d.floating_point_range = [FloatingPointRange(
                from_value=spec.low if math.isfinite(spec.low) else -DBL_MAX,
                to_value=spec.high if math.isfinite(spec.high) else DBL_MAX, step=0.0)]
    return d


def stamp_ns(t):
    """Simulation time [s] → integer nanoseconds."""
    return int(round(t * 1e9))


def _set_stamp(stamp, ns):
    stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)


def _reduce_timer_slack():
    """Linux: 1 ns timer slack for this thread (default 50 µs), so sleeps end on time."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)   # PR_SET_TIMERSLACK
    except (OSError, AttributeError):
        pass


# ---------------------------------------------------------------------------------- helpers
class _Ring:
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


class _Throttle:
    """At most one warning per ``period`` seconds; counts what it held back."""

    def __init__(self, period=WARN_PERIOD_S):
        self.period = period
        self.last = -math.inf
        self.held = 0

    def __call__(self):
        """(log now?, number held back since the last logged one)."""
        now = time.monotonic()
        if now - self.last >= self.period:
            self.last, held, self.held = now, self.held, 0
            return True, held
        self.held += 1
        return False, 0


class _CommandGroup(CallbackGroup):
    """The command subscriptions' callback group. While the simulation runs free (realtime,
    fast) the loop thread takes their messages itself at the start of each physics step, and the
    executor leaves them alone: a flood of commands then costs the loop a few µs per message
    instead of a fight for the interpreter lock with an executor thread busy at 100 %. While the
    simulation is held (paused, lockstep) the executor delivers them as usual. Both paths call
    the same subscription callbacks."""

    def __init__(self):
        super().__init__()
        self.loop_takes = False

    def can_execute(self, entity):
        return not self.loop_takes

    def beginning_execution(self, entity):
        return True

    def ending_execution(self, entity):
        pass


class _Waiter:
    """A service callback waiting for the loop thread to carry out its request."""

    def __init__(self, arg=None):
        self.arg = arg
        self.done = threading.Event()
        self.success = False
        self.message = 'the simulation loop did not answer'

    def finish(self, success, message):
        self.success, self.message = success, message
        self.done.set()


@dataclass
class _Step:
    """One control period computed by the loop: start and end time [s], switches, end sample."""
    t0: float
    t: float
    events: list
    row: np.ndarray
    next_event: int = 0


@dataclass
class _Stats:
    """Counters the loop thread writes and the diagnostics timer reads."""
    samples: int = 0
    missed: int = 0
    resyncs: int = 0
    slipped_ns: int = 0
    lag_ns: int = 0
    switches: int = 0
    last_switch_t: float = math.nan
    commands: int = 0
    refused: int = 0
    dropped: int = 0
    resets: int = 0
    step_ns: _Ring = field(default_factory=_Ring)
    jitter_ns: _Ring = field(default_factory=_Ring)


# ---------------------------------------------------------------------------------- the node
class CvtSimNode(Node):
    """The transmission as a ROS 2 device.

    ``base_scene``: scene name or path whose values fill in every parameter the params file and
    ``-p`` overrides do not set; None = the built-in defaults (as the offline ``cvt-sim run``).
    Raises SceneError when the resulting scene is invalid.
    """

    def __init__(self, base_scene=DEFAULT_SCENE, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self._values = self._scene_values(base_scene)
        self._declare_scene_parameters()
        self.add_pre_set_parameters_callback(self.coerce_parameters_callback)
        self.add_on_set_parameters_callback(self.check_parameters_callback)
        self.add_post_set_parameters_callback(self.apply_parameters_callback)

        v = self._values
        self._mode = v['time_mode']
        self._rtf = v['real_time_factor']
        self._dt = 1.0 / v['publish_rate']
        self._steps_per_command = int(v['steps_per_command'])
        self._priority = int(v['realtime_priority'])
        self._thread_priority = 0   # what the loop thread runs at now
        self._demoted = False       # fell > LAG_LIMIT behind: no SCHED_FIFO until retimed
        self._publish_clock = bool(v['publish_clock'])
        self._load_limit = v['limits.load_torque']
        self._joint_names = [v['joint_prefix'] + j for j in JOINTS]
        self._bound = self._grashof_bound(v)
        self._crank_target = v['linkage.crank_length']   # last accepted crank length [m]
        self._load_command = v['load.torque']            # last accepted load torque [N·m]

        # loop-thread state (the Simulator is touched by the loop thread only)
        self._warm_up()
        self._sim = make_simulator(self._physics_values())
        self._ahead = None          # realtime: the next step, computed but not yet published
        self._resync = True         # realtime: re-anchor the wall-clock schedule
        self._anchor_wall_ns = 0
        self._anchor_sim = 0.0
        self._paused = False
        self._fault = None          # message of a simulation failure (held until ~/reset)
        self._queue = collections.deque()
        self._queue_lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._stats = _Stats()
        self._snapshot = {}
        self._snapshot_ns = 0
        self._last_row = None
        self._published_ns = 0      # simulation time of the last published sample [ns]
        self._throttles = {'crank_length_cmd': _Throttle(), 'load_torque_cmd': _Throttle(),
                           'schedule': _Throttle(), 'queue': _Throttle()}
        self._recorder = None
        self._record_lock = threading.Lock()
        self._diag_prev = None
        self._js = JointState()
        self._js_names = None
        self._clock_msg = ClockMsg()

        self.joint_states_publisher = self.create_publisher(
            JointState, 'joint_states', JOINT_STATES_QOS)
        self.clutch_engaged_publisher = self.create_publisher(Bool, 'clutch_engaged', CLUTCH_QOS)
        self.clock_publisher = self.create_publisher(ClockMsg, '/clock', CLOCK_QOS)
        self.diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        self._command_group = _CommandGroup()
        self.crank_length_cmd_subscription = self.create_subscription(
            Float64, 'crank_length_cmd', self.crank_length_cmd_callback, COMMAND_QOS,
            callback_group=self._command_group)
        self.load_torque_cmd_subscription = self.create_subscription(
            Float64, 'load_torque_cmd', self.load_torque_cmd_callback, COMMAND_QOS,
            callback_group=self._command_group)
        self.reset_service = self.create_service(Trigger, '~/reset', self.reset_callback)
        self.pause_service = self.create_service(SetBool, '~/pause', self.pause_callback)
        self.step_service = self.create_service(Trigger, '~/step', self.step_callback)
        # diagnostics on the steady clock: ~1 Hz of wall time whatever use_sim_time says
        self.diagnostics_timer = self.create_timer(
            1.0, self.diagnostics_timer_callback, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._topic = {   # resolved names (namespace applied), as the recorder stores them
            'joint_states': self.joint_states_publisher.topic_name,
            'clutch_engaged': self.clutch_engaged_publisher.topic_name,
            'clock': self.clock_publisher.topic_name,
            'diagnostics': self.diagnostics_publisher.topic_name,
            'crank_length_cmd': self.crank_length_cmd_subscription.topic_name,
            'load_torque_cmd': self.load_torque_cmd_subscription.topic_name,
        }
        if v['record.path']:
            self._open_recorder(v['record.path'])
        self._thread = threading.Thread(target=self._run_loop, name='cvt_sim_loop', daemon=True)
        self.get_logger().info(
            f"cvt_sim ready: {self._mode} mode, control period {self._dt * 1e3:g} ms of "
            f"simulation time, solver {v['solver.method']}, crank length "
            f"{v['linkage.crank_length']:g} m (Grashof bound {self._bound:g} m), load torque "
            f"{v['load.torque']:g} N*m")

    # ------------------------------------------------------------------ lifecycle
    def start(self):
        """Start the simulation loop thread (after the node is added to an executor)."""
        if not self._thread.is_alive():
            # what start-up allocated stays: keep it out of the collector's full passes
            gc.collect()
            gc.freeze()
            self._thread.start()

    def stop(self, timeout=1.5):
        """Stop the loop thread; returns True if it ended within ``timeout`` [s]."""
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        self._close_recorder()
        return not self._thread.is_alive()

    def destroy_node(self):
        self.stop()
        return super().destroy_node()

    # ------------------------------------------------------------------ scene parameters
    def _scene_values(self, base_scene):
        """Base scene + parameter overrides (params file, -p), validated."""
        raw = {} if base_scene is None else read_scene(base_scene)
        raw.setdefault('solver.method', REALTIME_SOLVER)
        # rclpy keeps the overrides of this node (params files and -p) here; reading them lets
        # the node coerce integers to doubles (`torque: 10`) before declaring with that type.
        overrides = {name: p.value for name, p in getattr(self, '_parameter_overrides',
                                                           {}).items()}
        unknown = []
        for name, value in overrides.items():
            if name in params_mod.SPECS:
                raw[name] = value
            elif name not in _FOREIGN_PARAMETERS and not name.startswith('qos_overrides.'):
                unknown.append(name)
        for name in sorted(unknown):
            close = difflib.get_close_matches(name, params_mod.SPECS, n=1)
            hint = f" (did you mean {close[0]}?)" if close else ''
            self.get_logger().warning(
                f"ignoring parameter {name}: cvt_sim has no such parameter{hint}")
        try:
            return params_mod.validate(raw)
        except (ParameterError, GrashofError) as exc:
            where = f" (base scene {base_scene})" if base_scene else ''
            raise SceneError(f"invalid scene parameters{where}: {exc}") from None

    def _declare_scene_parameters(self):
        for name, spec in params_mod.SPECS.items():
            self.declare_parameter(name, ros_value(spec, self._values[name]), describe(spec),
                                   ignore_override=True)

    def _physics_values(self):
        return {k: v for k, v in self._values.items() if k in params_mod.SPECS}

    @staticmethod
    def _grashof_bound(values):
        return grashof_bound(values['linkage.rocker_length'], values['linkage.coupler_length'],
                             values['linkage.pivot_distance'])

    def _warm_up(self):
        """Load (or compile) the numba kernels before the loop's timing starts."""
        sim = make_simulator(self._physics_values())
        sim.advance(self._dt)
        sim.sample()
        sim.energy_balance()

    def coerce_parameters_callback(self, parameters):
        """`ros2 param set ... load.torque 10` sends an integer: make it the double it means."""
        out = []
        for p in parameters:
            spec = params_mod.SPECS.get(p.name)
            if (spec is not None and type(spec.default) is float
                    and p.type_ == Parameter.Type.INTEGER):
                p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            out.append(p)
        return out

    def check_parameters_callback(self, parameters):
        """Refuse (with the reason) a change the physics cannot take; change nothing here."""
        changes = {p.name: p.value for p in parameters if p.name in params_mod.SPECS}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            self._checked_values(changes)
        except (ParameterError, GrashofError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _checked_values(self, changes):
        new = params_mod.validate(dict(self._values, **changes))
        if any(name.startswith('linkage.') for name in changes):
            # The actuator's present and commanded lengths must fit the new geometry too.
            bound = self._grashof_bound(new)
            row = self._last_row
            present = float(row[COL['crank_length']]) if row is not None else 0.0
            target = new['linkage.crank_length'] if 'linkage.crank_length' in changes \
                else self._crank_target
            for what, a in (('present', present), ('commanded', target)):
                if not a < bound:
                    raise GrashofError(
                        f"{', '.join(sorted(changes))}: the Grashof bound would become "
                        f"{bound:g} m, below the {what} crank length {a:g} m; command a "
                        f"shorter crank first", a, bound)
        return new

    def apply_parameters_callback(self, parameters):
        """Accepted changes: node settings at once, physics queued for the next physics step."""
        changes = {p.name: p.value for p in parameters if p.name in params_mod.SPECS}
        if not changes:
            return
        new = params_mod.validate(dict(self._values, **changes))
        self._values = new
        physics = {k: new[k] for k in changes if k in PHYSICS_NAMES}
        if physics:
            self._bound = self._grashof_bound(new)
            if 'linkage.crank_length' in physics:
                self._crank_target = new['linkage.crank_length']
            if 'load.torque' in physics:
                self._load_command = new['load.torque']
            self._request(('params', physics))
        wake = False
        if 'time_mode' in changes:
            self._mode = new['time_mode']
            wake = True
        if 'real_time_factor' in changes:
            self._rtf = new['real_time_factor']
            wake = True
        if 'publish_rate' in changes:
            self._dt = 1.0 / new['publish_rate']
            wake = True
        if 'steps_per_command' in changes:
            self._steps_per_command = int(new['steps_per_command'])
        if 'realtime_priority' in changes:
            self._priority = int(new['realtime_priority'])
            wake = True
        if 'publish_clock' in changes:
            self._publish_clock = bool(new['publish_clock'])
        if 'limits.load_torque' in changes:
            self._load_limit = new['limits.load_torque']
        if 'joint_prefix' in changes:
            self._joint_names = [new['joint_prefix'] + j for j in JOINTS]
        if 'record.path' in changes:
            self._close_recorder()
            if new['record.path']:
                self._open_recorder(new['record.path'])
        if wake:
            self._resync = True
            self._demoted = False
            self._wake.set()
        if self._mode == 'fast' and not self._publish_clock:
            self.get_logger().warning('fast mode without /clock: consumers with use_sim_time '
                                      'will not follow (set publish_clock true)')

    # ------------------------------------------------------------------ commands
    def crank_length_cmd_callback(self, msg):
        """A crank length [m]: accepted in [0, Grashof bound), else refused (last one stays)."""
        a = msg.data
        self._stats.commands += 1
        self._hand_to_recorder(self._topic['crank_length_cmd'], msg, self._published_ns)
        bound = self._bound
        if math.isfinite(a) and 0.0 <= a < bound:
            self._crank_target = a
            self._request(('crank', a, self._grant()))
            return
        why = 'not a finite number' if not math.isfinite(a) else 'outside the Grashof range'
        self._refuse('crank_length_cmd', f"{a!r} m", f"{why}; limit [0, {bound:g}) m",
                     f"{self._crank_target:g} m")

    def load_torque_cmd_callback(self, msg):
        """A load torque [N·m]: accepted when finite and |M| <= limits.load_torque."""
        m = msg.data
        self._stats.commands += 1
        self._hand_to_recorder(self._topic['load_torque_cmd'], msg, self._published_ns)
        limit = self._load_limit
        if math.isfinite(m) and abs(m) <= limit:
            self._load_command = m
            self._request(('load', m, self._grant()))
            return
        why = 'not a finite number' if not math.isfinite(m) else 'beyond the limit'
        self._refuse('load_torque_cmd', f"{m!r} N*m",
                     f"{why}; limit |M| <= {limit:g} N*m (parameter limits.load_torque)",
                     f"{self._load_command:g} N*m")

    def _grant(self):
        return self._steps_per_command if self._mode == 'lockstep' else 0

    def _refuse(self, topic, value, reason, keeping):
        self._stats.refused += 1
        grant = self._grant()
        if grant:   # the controller's cycle goes on with the last valid command
            self._request(('noop', None, grant))
        log, held = self._throttles[topic]()
        if log:
            more = f" ({held} more refused since the last warning)" if held else ''
            self.get_logger().warning(
                f"refused {topic} = {value}: {reason}; keeping the last valid command "
                f"{keeping}{more}")

    def _request(self, entry):
        """Queue work for the loop thread; consecutive commands of one kind without steps to
        grant collapse into the newest (only the last value matters at the next step)."""
        with self._queue_lock:
            q = self._queue
            if entry[0] in ('crank', 'load') and not entry[2] and q and q[-1][0] == entry[0] \
                    and not q[-1][2]:
                q[-1] = entry
                return
            if len(q) >= QUEUE_LIMIT and entry[0] in ('crank', 'load', 'noop'):
                self._stats.dropped += 1
                log, held = self._throttles['queue']()
                if log:
                    self.get_logger().warning(
                        f"command queue full ({QUEUE_LIMIT}): dropping commands")
                return
            q.append(entry)
        if entry[0] not in ('crank', 'load', 'params') or self._mode == 'lockstep':
            self._wake.set()

    def _pop(self):
        with self._queue_lock:
            return self._queue.popleft() if self._queue else None

    # ------------------------------------------------------------------ services
    def reset_callback(self, request, response):
        """Back to the scene's initial state (t = 0, parameters as currently set)."""
        waiter = self._submit('reset')
        response.success, response.message = waiter.success, waiter.message
        return response

    def pause_callback(self, request, response):
        """data = true: hold the simulation; false: run again (realtime / fast)."""
        waiter = self._submit('pause', bool(request.data))
        response.success, response.message = waiter.success, waiter.message
        return response

    def step_callback(self, request, response):
        """Advance exactly one control period while paused or in lockstep mode."""
        if not (self._paused or self._mode == 'lockstep'):
            response.success = False
            response.message = (f"~/step advances only while paused or in lockstep mode "
                                f"(time_mode is {self._mode}); call ~/pause first")
            return response
        waiter = self._submit('step')
        response.success, response.message = waiter.success, waiter.message
        return response

    def _submit(self, kind, arg=None):
        waiter = _Waiter(arg)
        if not self._thread.is_alive():
            waiter.message = 'the simulation loop is not running'
            return waiter
        self._request((kind, waiter))
        waiter.done.wait(SERVICE_TIMEOUT_S)
        return waiter

    # ------------------------------------------------------------------ the loop
    def _run_loop(self):
        _reduce_timer_slack()
        try:
            self._publish_state()
        except Exception:   # noqa: BLE001 — the context went down before the first sample
            if not self.context.ok():
                return
            raise
        while not self._stop.is_set():
            try:
                self._loop_iteration()
            except Exception as exc:   # noqa: BLE001 — a bug must not silently kill the device
                if self._stop.is_set() or not self.context.ok():
                    break
                self.get_logger().error(f"simulation loop error: {exc!r}\n"
                                        f"{traceback.format_exc()}")
                self._fault = f"internal error: {exc!r}"
                self._ahead = None
        self._finish_waiters('the node is shutting down')

    def _loop_iteration(self):
        self._wake.clear()
        want = self._priority if (self._mode == 'realtime' and not self._paused
                                  and not self._demoted) else 0
        if want != self._thread_priority:
            self._set_thread_priority(want)
        takes = self._running()
        if takes != self._command_group.loop_takes:
            self._command_group.loop_takes = takes
            executor = self.executor
            if executor is not None:
                executor.wake()   # let it rebuild its wait set with / without the commands
        if self._paused or self._mode == 'lockstep' or self._fault:
            self._flush_ahead()
            if not self._serve_held():
                self._wake.wait(IDLE_WAIT_S)
            self._resync = True
        elif self._mode == 'fast':
            self._flush_ahead()
            for _ in range(FAST_BATCH):
                self._serve_running()
                if not self._running():
                    break
                step = self._compute_step()
                if step is None:
                    break
                self._publish_step(step)
            self._resync = True
        else:
            self._realtime_tick()
        now = time.monotonic_ns()
        if now - self._snapshot_ns >= STATS_PERIOD_NS:
            self._take_snapshot(now)

    def _set_thread_priority(self, priority):
        """Loop thread: SCHED_FIFO at ``priority`` (realtime mode), else normal scheduling.
        A thread that runs flat out (fast, lockstep bursts) must not starve the rest."""
        self._thread_priority = priority
        try:
            if priority > 0:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            else:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        except (OSError, AttributeError) as exc:
            if priority > 0:
                self.get_logger().warning(
                    f"no real-time scheduling (SCHED_FIFO priority {priority}: {exc}); the loop "
                    f"runs at normal priority and its jitter depends on the machine's load "
                    f"(set realtime_priority 0 to silence this)")

    def _running(self):
        return not (self._paused or self._fault or self._mode == 'lockstep'
                    or self._stop.is_set())

    def _realtime_tick(self):
        """Publish the step computed ahead at its wall-clock moments, then compute the next.

        Wall time of simulation time t: anchor_wall + (t − anchor_sim)/real_time_factor on the
        monotonic clock. Deadlines follow from the schedule (never from a sleep's end), so there
        is no drift; when late, samples go out back to back, each with its own simulation stamp,
        until the schedule is met again (no jump in the stamps). Behind by more than
        LAG_LIMIT_NS, the backlog is given up: the schedule is re-anchored (counted as a resync).
        """
        self._serve_running()
        if not self._running():
            return
        if self._ahead is None:
            self._ahead = self._compute_step()
            if self._ahead is None:
                return
        step = self._ahead
        if self._resync:
            self._resync = False
            self._anchor_wall_ns = time.monotonic_ns()
            self._anchor_sim = step.t0
        while step.next_event < len(step.events):
            event = step.events[step.next_event]
            if not self._sleep_until(self._wall_ns(event.t)):
                return
            self._publish_switch(event)
            step.next_event += 1
        deadline = self._wall_ns(step.t)
        if not self._sleep_until(deadline):
            return
        late = time.monotonic_ns() - deadline
        self._publish_sample(step.row)
        self._ahead = None
        stats = self._stats
        stats.jitter_ns.add(late)
        stats.lag_ns = late
        period_ns = self._dt / self._rtf * 1e9
        if late >= period_ns:
            stats.missed += 1
            log, held = self._throttles['schedule']()
            if log:
                self.get_logger().warning(
                    f"behind schedule by {late / 1e6:.2f} ms at t = {step.t:.4f} s: catching up "
                    f"({stats.missed} missed deadlines so far)")
        if late > LAG_LIMIT_NS:
            stats.resyncs += 1
            stats.slipped_ns += late
            self._resync = True
            self._anchor_sim = step.t
            # a real-time thread that cannot keep up would starve everything else on its core
            demote = self._thread_priority > 0
            self._demoted = True
            self.get_logger().warning(
                f"{late / 1e9:.3f} s behind schedule: simulation time gives that up and "
                f"re-anchors to the wall clock (stamps stay continuous)"
                + ('; the loop drops to normal scheduling until time_mode, real_time_factor, '
                   'publish_rate or realtime_priority is set again' if demote else ''))

    def _wall_ns(self, t):
        return self._anchor_wall_ns + int((t - self._anchor_sim) / self._rtf * 1e9)

    def _sleep_until(self, deadline_ns):
        """Wait for a monotonic-clock deadline: sleep, then spin the last SPIN_NS.
        False when woken for something else (pause, mode change, reset, stop)."""
        while True:
            remaining = deadline_ns - time.monotonic_ns()
            if remaining <= 0:
                return True
            if self._wake.is_set() or self._stop.is_set():
                return False
            if remaining > SPIN_NS:
                self._wake.wait(min((remaining - SPIN_NS) * 1e-9, MAX_SLEEP_S))

    def _flush_ahead(self):
        """Leaving realtime mode: publish what the simulation has already computed."""
        if self._ahead is not None:
            step, self._ahead = self._ahead, None
            self._publish_step(step)

    def _take_commands(self):
        """Free-running modes: hand the commands that arrived to their callbacks (which check
        them and queue the valid ones), right before the physics step they act on."""
        if not self._command_group.loop_takes:
            return
        for sub in (self.crank_length_cmd_subscription, self.load_torque_cmd_subscription):
            for _ in range(TAKE_LIMIT):
                try:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, sub.raw)
                except InvalidHandle:   # shutting down
                    return
                if taken is None:
                    break
                sub.callback(taken[0])

    def _serve_running(self):
        """Free-running modes: take the commands, apply everything queued."""
        self._take_commands()
        while True:
            entry = self._pop()
            if entry is None:
                return
            self._apply(entry)

    def _serve_held(self):
        """Paused / lockstep: apply queued work in order, advancing where it says so."""
        did = False
        while not self._stop.is_set():
            entry = self._pop()
            if entry is None:
                break
            did = True
            kind = entry[0]
            if kind == 'step':
                waiter = entry[1]
                if self._fault:
                    waiter.finish(False, f"simulation fault: {self._fault}; call ~/reset")
                    continue
                step = self._compute_step()
                if step is None:
                    waiter.finish(False, f"simulation fault: {self._fault}; call ~/reset")
                    continue
                self._publish_step(step)
                waiter.finish(True, self._state_text())
            elif kind in ('crank', 'load', 'noop'):
                self._apply(entry)
                grant = entry[2]
                if grant and self._mode == 'lockstep' and not self._paused:
                    for _ in range(grant):
                        if self._fault or self._stop.is_set():
                            break
                        step = self._compute_step()
                        if step is None:
                            break
                        self._publish_step(step)
            else:
                self._apply(entry)
        return did

    def _apply(self, entry):
        """Carry out one queued request on the Simulator (loop thread only)."""
        kind = entry[0]
        sim = self._sim
        if kind == 'crank':
            try:
                sim.command_crank_length(entry[1])
            except GrashofError as exc:   # the geometry changed after the command was checked
                self.get_logger().warning(f"crank_length_cmd dropped: {exc}")
        elif kind == 'load':
            try:
                sim.set_load_torque(entry[1])
            except ParameterError as exc:
                self.get_logger().warning(f"load_torque_cmd dropped: {exc}")
        elif kind == 'params':
            try:
                sim.update_parameters(entry[1])
            except (ParameterError, GrashofError) as exc:
                self.get_logger().error(f"parameter change not applied: {exc}")
            self._take_snapshot(time.monotonic_ns())
        elif kind == 'reset':
            self._do_reset()
            entry[1].finish(True, f"reset to the scene's initial state: {self._state_text()}")
        elif kind == 'pause':
            waiter = entry[1]
            self._paused = waiter.arg
            if self._paused:
                self._flush_ahead()
            self._resync = True
            waiter.finish(True, f"{'paused' if self._paused else 'running'}: "
                                f"{self._state_text()}")
        elif kind == 'step':
            entry[1].finish(False, 'the simulation is running; call ~/pause first')

    def _do_reset(self):
        self._ahead = None
        if self._recorder is not None:
            self._recorder.mark_reset()  # simulation time restarts at 0; log times go on
        try:
            self._sim = make_simulator(self._physics_values())
            self._fault = None
        except (ParameterError, GrashofError, SimulationError) as exc:
            self._fault = f"reset failed: {exc}"
        v = self._values
        self._crank_target = v['linkage.crank_length']
        self._load_command = v['load.torque']
        self._stats.resets += 1
        self._resync = True
        self._publish_state()
        self._take_snapshot(time.monotonic_ns())

    def _compute_step(self):
        """Advance one control period; None (and a fault) if the integration failed."""
        sim = self._sim
        t0 = sim.t
        c0 = time.perf_counter_ns()
        try:
            switches = sim.advance(self._dt)
        except (SimulationError, ValueError) as exc:
            self._fault = str(exc)
            self.get_logger().error(f"simulation stopped: {exc}; call ~/reset")
            return None
        row = sim.sample()
        self._stats.step_ns.add(time.perf_counter_ns() - c0)
        events = [s for s in switches if s.kind != 'graze']
        return _Step(t0, sim.t, events, row)

    def _finish_waiters(self, message):
        while True:
            entry = self._pop()
            if entry is None:
                return
            if len(entry) == 2 and isinstance(entry[1], _Waiter):
                entry[1].finish(False, message)

    # ------------------------------------------------------------------ publishing
    def _publish_step(self, step):
        for event in step.events[step.next_event:]:
            self._publish_switch(event)
        step.next_event = len(step.events)
        self._publish_sample(step.row)

    def _publish_state(self):
        """The present state: latched clutch state, then a sample (start-up, reset)."""
        msg = Bool(data=bool(self._sim.engaged))
        self.clutch_engaged_publisher.publish(msg)
        self._hand_to_recorder(self._topic['clutch_engaged'], msg, stamp_ns(self._sim.t))
        self._publish_sample(self._sim.sample())

    def _publish_switch(self, event):
        """One clutch switch, at its own simulation time (Bool has no stamp: the switch time is
        in diagnostics as last_switch_time and goes to the recorder with this message)."""
        msg = Bool(data=bool(event.engaged))
        self.clutch_engaged_publisher.publish(msg)
        stats = self._stats
        stats.switches += 1
        stats.last_switch_t = event.t
        self._hand_to_recorder(self._topic['clutch_engaged'], msg, stamp_ns(event.t))

    def _publish_sample(self, row):
        ns = stamp_ns(row[COL['t']])
        msg = self._js
        names = self._joint_names
        if names is not self._js_names:
            msg.name = names
            self._js_names = names
        _set_stamp(msg.header.stamp, ns)
        msg.position = array.array('d', row[_POSITION].tolist())
        msg.velocity = array.array('d', row[_VELOCITY].tolist())
        msg.effort = array.array('d', row[_EFFORT].tolist())
        self.joint_states_publisher.publish(msg)
        self._hand_to_recorder(self._topic['joint_states'], msg, ns)
        if self._publish_clock:
            _set_stamp(self._clock_msg.clock, ns)
            self.clock_publisher.publish(self._clock_msg)
            self._hand_to_recorder(self._topic['clock'], self._clock_msg, ns)
        self._last_row = row
        self._published_ns = ns
        self._stats.samples += 1

    # ------------------------------------------------------------------ recording hook
    def recorded_topics(self):
        """(resolved topic name, message type, QoS profile) of everything the node publishes or
        receives: what a recorder registers (BagWriter.add_topic) before the first message."""
        return [
            (self._topic['joint_states'], JointState, JOINT_STATES_QOS),
            (self._topic['clutch_engaged'], Bool, CLUTCH_QOS),
            (self._topic['clock'], ClockMsg, CLOCK_QOS),
            (self._topic['diagnostics'], DiagnosticArray, DIAGNOSTICS_QOS),
            (self._topic['crank_length_cmd'], Float64, COMMAND_QOS),
            (self._topic['load_torque_cmd'], Float64, COMMAND_QOS),
        ]

    def _open_recorder(self, path):
        """Record everything published and received to ``path`` (parameter record.path) at
        simulation time, through cvt_ros.recording.SimulationRecorder. A path that cannot be
        written is logged and the node runs on without recording; a later I/O error (disk full)
        is logged once and recording stops, the simulation does not."""
        from .recording import RecordingError
        from .recording.recorder import SimulationRecorder
        logger = self.get_logger()
        try:
            self._recorder = SimulationRecorder(
                path, topic_names=dict(self._topic), joint_names=self._joint_names,
                parameters=self._physics_values(), source='cvt_node',
                on_error=lambda exc: logger.error(f"recording to {path} stopped: {exc}; "
                                                  f"the simulation goes on"))
            logger.info(f"recording to {path}")
        except (RecordingError, OSError, ValueError) as exc:
            logger.error(f"record.path = {path!r}: cannot record ({exc}); the simulation "
                         f"goes on without recording")
            self._recorder = None

    def _close_recorder(self):
        recorder, self._recorder = self._recorder, None
        if recorder is not None:
            with self._record_lock:
                recorder.close()

    def _hand_to_recorder(self, topic, msg, t_ns):
        """Every published and received message passes here with its resolved topic name and
        the simulation time [ns] it belongs to: a sample its stamp, a clutch switch the switch's
        own time (std_msgs/Bool has no stamp), a command the time of the last published sample
        when it arrived, diagnostics the same. Called from the loop and the executor threads."""
        recorder = self._recorder
        if recorder is None:
            return
        with self._record_lock:
            recorder.write(topic, msg, t_ns)

    # ------------------------------------------------------------------ diagnostics
    def _take_snapshot(self, now_ns):
        """Loop thread: what the diagnostics report about the simulation, every 250 ms."""
        sim = self._sim
        row = self._last_row
        energy = sim.energy_balance()
        self._snapshot = {
            'wall_ns': now_ns, 't': sim.t, 'switch_count': sim.switch_count,
            'samples': self._stats.samples, 'resets': self._stats.resets,
            'phi1': float(row[COL['phi1']]) if row is not None else 0.0,
            'phi4': float(row[COL['phi4']]) if row is not None else 0.0,
            'crank_length': float(sim.crank_length), 'crank_target': sim.crank_length_target,
            'grashof_bound': float(sim.grashof_bound), 'load_torque': sim.load_torque,
            'engaged': bool(sim.engaged), 'residual': float(energy['residual']),
            'relative_residual': float(energy['relative_residual']),
        }
        self._snapshot_ns = now_ns

    def diagnostics_timer_callback(self):
        """~1 Hz: timing, switching and energy figures as one DiagnosticStatus."""
        snap = self._snapshot
        if not snap:
            return
        stats = self._stats
        now = time.monotonic_ns()
        cur = {'wall_ns': now, 't': snap['t'], 'samples': stats.samples,
               'switch_count': snap['switch_count'], 'missed': stats.missed,
               'resyncs': stats.resyncs, 'refused': stats.refused, 'phi1': snap['phi1'],
               'phi4': snap['phi4'], 'resets': snap['resets'], 'snap_wall_ns': snap['wall_ns']}
        prev = self._diag_prev
        self._diag_prev = cur
        rtf = rate = switch_rate = ratio = math.nan
        window_missed = window_refused = window_resyncs = 0
        if prev is not None and prev['resets'] == cur['resets']:
            wall = (now - prev['wall_ns']) * 1e-9
            snap_wall = (cur['snap_wall_ns'] - prev['snap_wall_ns']) * 1e-9
            dt_sim = cur['t'] - prev['t']
            if snap_wall > 0:
                rtf = dt_sim / snap_wall
            if wall > 0:
                rate = (cur['samples'] - prev['samples']) / wall
            if dt_sim > 0:
                switch_rate = (cur['switch_count'] - prev['switch_count']) / dt_sim
            dphi1 = cur['phi1'] - prev['phi1']
            if dphi1 != 0:
                ratio = (cur['phi4'] - prev['phi4']) / dphi1
            window_missed = cur['missed'] - prev['missed']
            window_refused = cur['refused'] - prev['refused']
            window_resyncs = cur['resyncs'] - prev['resyncs']
        step = stats.step_ns.percentiles() or [math.nan] * 3
        jitter = stats.jitter_ns.percentiles() or [math.nan] * 3
        mode = self._mode
        state = 'fault' if self._fault else ('paused' if self._paused else mode)
        values = [
            ('time_mode', mode), ('state', state),
            ('sim_time', f"{snap['t']:.6f}"),
            ('real_time_factor', f"{rtf:.4g}"),
            ('real_time_factor_target', f"{self._rtf:g}" if mode == 'realtime' else '-'),
            ('publish_rate', f"{rate:.6g}"),
            ('publish_rate_target', f"{self._values['publish_rate'] * self._rtf:g}"
                                    if mode == 'realtime' else '-'),
            ('control_period', f"{self._dt:.9g}"),
            ('samples_published', str(stats.samples)),
            ('missed_deadlines', str(stats.missed)),
            ('missed_deadlines_last_window', str(window_missed)),
            ('lag_ms', f"{stats.lag_ns / 1e6:.3f}"),
            ('resyncs', str(stats.resyncs)),
            ('slipped_s', f"{stats.slipped_ns / 1e9:.3f}"),
            ('step_time_p50_us', f"{step[0] / 1e3:.1f}"),
            ('step_time_p99_us', f"{step[1] / 1e3:.1f}"),
            ('step_time_max_us', f"{step[2] / 1e3:.1f}"),
            ('jitter_p50_us', f"{jitter[0] / 1e3:.1f}"),
            ('jitter_p99_us', f"{jitter[1] / 1e3:.1f}"),
            ('jitter_max_us', f"{jitter[2] / 1e3:.1f}"),
            ('switches_per_second', f"{switch_rate:.4g}"),
            ('switches_total', str(snap['switch_count'])),
            ('last_switch_time', f"{stats.last_switch_t:.6f}"),
            ('clutch_engaged', str(snap['engaged']).lower()),
            ('energy_residual_J', f"{snap['residual']:.6g}"),
            ('energy_relative_residual', f"{snap['relative_residual']:.3g}"),
            ('ratio', f"{ratio:.5g}"),
            ('crank_length_m', f"{snap['crank_length']:.6g}"),
            ('crank_length_target_m', f"{snap['crank_target']:.6g}"),
            ('grashof_bound_m', f"{snap['grashof_bound']:.6g}"),
            ('load_torque_Nm', f"{snap['load_torque']:.6g}"),
            ('commands_received', str(stats.commands)),
            ('commands_refused', str(stats.refused)),
            ('commands_dropped', str(stats.dropped)),
            ('fault', self._fault or ''),
        ]
        if self._fault:
            level, message = DiagnosticStatus.ERROR, f"simulation fault: {self._fault}"
        elif window_missed or window_resyncs:
            level = DiagnosticStatus.WARN
            message = (f"behind schedule: {window_missed} missed deadlines, {window_resyncs} "
                       f"resyncs in the last window")
        elif window_refused:
            level, message = DiagnosticStatus.WARN, f"{window_refused} commands refused"
        else:
            level, message = DiagnosticStatus.OK, f"{state}"
        status = DiagnosticStatus(
            level=level, name=f"{self.get_fully_qualified_name()}: transmission",
            message=message, hardware_id=self.get_fully_qualified_name(),
            values=[KeyValue(key=k, value=v) for k, v in values])
        msg = DiagnosticArray(status=[status])
        _set_stamp(msg.header.stamp, self._published_ns)
        self.diagnostics_publisher.publish(msg)
        self._hand_to_recorder(self._topic['diagnostics'], msg, self._published_ns)

    def _state_text(self):
        sim = self._sim
        return (f"t={sim.t:.9f} s crank_length={float(sim.crank_length):.6g} m "
                f"(target {sim.crank_length_target:.6g} m) "
                f"load_torque={sim.values['load.torque']:.6g} N*m "
                f"engaged={str(bool(sim.engaged)).lower()}")


# ---------------------------------------------------------------------------------- main
def _parser():
    p = argparse.ArgumentParser(
        prog='cvt_node', description='The pulse CVT as a ROS 2 node (cvt_sim). Parameters come '
        'from --ros-args --params-file SCENE.yaml and -p name:=value.')
    p.add_argument('--scene', default=None,
                   help='base scene (name such as conveyor, or a path): fills in every parameter '
                        'not set by --params-file / -p. Default: conveyor, or the built-in '
                        'defaults when a --params-file is given (as cvt-sim run reads it)')
    return p


def main(args=None):
    """Run the node until SIGINT / SIGTERM; returns the exit code (0 on a clean shutdown).

    ``args``: the command line without the program name (None: sys.argv[1:]); ROS arguments
    follow ``--ros-args``. Used by the ``cvt_node`` console script and ``cvt-sim node``.
    """
    argv = list(sys.argv[1:] if args is None else args)
    options = _parser().parse_args(remove_ros_args(['cvt_node'] + argv)[1:])
    if options.scene is not None:
        base = options.scene
    elif '--params-file' in argv:
        base = None
    else:
        base = DEFAULT_SCENE
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    rclpy.init(args=['cvt_node'] + argv)
    try:
        node = CvtSimNode(base_scene=base)
    except (SceneError, ParameterError, GrashofError) as exc:
        print(f"cvt_node: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    node.start()
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.stop()
        executor.shutdown(timeout_sec=0.5)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
