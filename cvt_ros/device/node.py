"""The ROS 2 node ``cvt_sim``: the ROS wiring of the device (parameters ↔ scene, topics,
services, QoS). The physics is the Device (``core.py``), the time modes the RunLoop (``loop.py``),
the health report ``diagnostics.py``; the full interface is in docs/node.md.

* subscriptions (reliable, keep all): ``load_torque_cmd`` [N·m] and ``crank_length_cmd`` [m]
  (std_msgs/Float64), ``joint_commands`` (sensor_msgs/JointState, topic_based_ros2_control: the
  position of joint ``<joint_prefix>crank_length`` is a crank-length command [m])
* publications: ``joint_states`` (sensor_msgs/JointState: J1..J4 — with N ≥ 2 paths one rocker
  per path, ``rocker_1 … rocker_N`` — and the actuator joint ``crank_length``), ``state`` (the
  same sample, latched: transient local, keep last 1), ``clutch_engaged`` (std_msgs/Bool, any
  clutch engaged, latched), ``clutch_states`` (N ≥ 2: sensor_msgs/JointState, each clutch),
  ``/clock``, ``/diagnostics`` (~1 Hz)
* services: ``~/reset`` (Trigger), ``~/pause`` (SetBool), ``~/step`` (Trigger, ``step_periods``)
* parameters: every parameter of ``cvt_ros.parameters.SPECS`` under its dotted name

Threads: the executor runs the callbacks, which only check and queue; the loop thread owns the
Device and publishes.
"""
import gc
import sys
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import InvalidHandle, ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64
from std_srvs.srv import SetBool, Trigger

from .. import interface
from .. import parameters as params_mod
from ..parameters import ParameterError
from ..physics.linkage import GrashofError
from ..scene import NODE_NAME
from ..solver.output import COL
from .core import NODE_NAMES, PERIOD_NAMES, CommandError, Device
from .descriptors import (
    DEFAULT_SCENE,
    REALTIME_SOLVER,
    closest_name,
    coerce,
    describe,
    node_values,
    ros_value,
)
from .diagnostics import Reporter
from .loop import REALTIME_POLICY, RunLoop
from .subscription_wait import TAKE_LIMIT, RCLError, SubscriptionWait, WaitedApart

CRANK = 'linkage.crank_length'
GEOMETRY = {'linkage.rocker_length', 'linkage.coupler_length', 'linkage.pivot_distance'}
JOINTS = interface.DEVICE_JOINTS   # one path: J1..J4 (crank ... output_shaft), crank_length


def _float64(data, topic):
    """A raw Float64 command's value (the command subscriptions take CDR bytes: an rclpy message
    object costs ~20 µs of the lockstep round trip right after a wake-up); CommandError for
    bytes that are not one."""
    try:
        return interface.float64_value(data)
    except ValueError as exc:
        raise CommandError(topic, f"{len(data)} bytes", str(exc)) from None


class _LoopLogger:
    """The node's logger as the loop thread uses it (warning / error / info), to stderr once the
    context is shut down: SIGINT shuts it down before the loop thread is stopped, and a warning
    logged in between made rcl print 'Failed to publish log message to rosout'."""

    def __init__(self, logger, context):
        self._logger, self._context = logger, context

    def __getattr__(self, level):
        log = getattr(self._logger, level)

        def emit(text):
            if self._context.ok():
                log(text)
            else:
                print(f"[{level.upper()}] [{self._logger.name}]: {text}", file=sys.stderr)
        return emit


class _CommandGroup(WaitedApart):
    """The command subscriptions' callback group: the executor leaves them alone, the loop
    thread takes their messages itself (``CvtSimNode.wait_commands``: its own rcl wait set).
    While the simulation runs free it polls them at the start of each period (a flood costs a
    few µs per message, no fight for the interpreter lock with a busy executor thread); while it
    is held (lockstep, paused) it blocks on them, so a lockstep command is one wake-up of the
    loop thread, which applies it, advances and publishes — no executor pass, no hand-over."""


class CvtSimNode(Node):
    """The transmission as a ROS 2 device.

    ``base_scene``: scene name or path whose values fill in every parameter the params file and
    ``-p`` overrides do not set; None = the built-in defaults (as the offline ``cvt-sim run``).
    Raises SceneError when the resulting scene is invalid.
    """

    def __init__(self, base_scene=DEFAULT_SCENE, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        values = self._scene_values(base_scene)
        self._scene_name = '' if base_scene is None else str(base_scene)  # for recordings
        for name, spec in params_mod.SPECS.items():
            self.declare_parameter(name, ros_value(spec, values[name]), describe(spec, values),
                                   ignore_override=True)
        self._refusal = None   # a refused set's reason, from the pre-set to the on-set callback
        self.add_pre_set_parameters_callback(self.coerce_parameters_callback)
        self.add_on_set_parameters_callback(self.check_parameters_callback)
        self.add_post_set_parameters_callback(self.apply_parameters_callback)

        self._publish_clock = bool(values['publish_clock'])
        self.n_paths = int(values['paths.count'])   # (the machine's build: never changes)
        self._set_joint_names(values['joint_prefix'])
        self._warm_up(values)
        self.device = Device(values, 1.0 / values['publish_rate'], timing=True)
        # the last accepted commands (executor thread; the loop applies them a step later)
        self._crank_target = values['linkage.crank_length']
        self._load_command = values['load.torque']
        self.loop = RunLoop(self.device, self, _LoopLogger(self.get_logger(), self.context),
                            values)
        self._reporter = Reporter()
        self._recorder = None
        self._record_lock = threading.Lock()
        self._last_seq = {}         # command topic -> last publication sequence number
        self._published_ns = 0      # simulation time of the last published sample [ns]

        self.joint_states_publisher = self.create_publisher(
            JointState, interface.JOINT_STATES, interface.joint_states_qos())
        self.state_publisher = self.create_publisher(
            JointState, interface.STATE, interface.state_qos())
        self.clutch_engaged_publisher = self.create_publisher(
            Bool, interface.CLUTCH_ENGAGED, interface.clutch_qos())
        self.clock_publisher = self.create_publisher(
            ClockMsg, interface.CLOCK, interface.clock_qos())
        # N ≥ 2 paths: each clutch (one path has clutch_engaged alone, as it always had)
        self.clutch_states_publisher = self.create_publisher(
            JointState, interface.CLUTCH_STATES, interface.qos_profile('clutch_states')
        ) if self.n_paths > 1 else None
        self.diagnostics_publisher = self.create_publisher(
            DiagnosticArray, interface.DIAGNOSTICS, interface.diagnostics_qos())
        self._sample_handles = (self.joint_states_publisher.handle, self.state_publisher.handle,
                                self.clock_publisher.handle)
        self._command_group = _CommandGroup()
        # the load subscription first: the loop's wait takes ready messages in this order, so a
        # disturbance that arrived with a crank command acts in that command's period
        self.load_torque_cmd_subscription = self.create_subscription(
            Float64, interface.LOAD_TORQUE_CMD, self.load_torque_cmd_callback,
            interface.command_subscription_qos(), callback_group=self._command_group, raw=True)
        self.crank_length_cmd_subscription = self.create_subscription(
            Float64, interface.CRANK_LENGTH_CMD, self.crank_length_cmd_callback,
            interface.command_subscription_qos(), callback_group=self._command_group, raw=True)
        self.joint_commands_subscription = self.create_subscription(
            JointState, interface.JOINT_COMMANDS, self.joint_commands_callback,
            interface.command_subscription_qos(), callback_group=self._command_group)
        self._command_subscriptions = (self.load_torque_cmd_subscription,
                                       self.crank_length_cmd_subscription,
                                       self.joint_commands_subscription)
        # the loop thread's own wait: the command subscriptions and a guard to wake it
        self._command_wait = SubscriptionWait(self.context, self._command_subscriptions,
                                              TAKE_LIMIT)
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
            'joint_commands': self.joint_commands_subscription.topic_name,
        }
        if self.clutch_states_publisher is not None:
            self._topic['clutch_states'] = self.clutch_states_publisher.topic_name
        if values['record.path']:
            self._open_recorder(values['record.path'])
        self.get_logger().info(
            f"cvt_sim ready: {self.loop.mode} mode, control period {self.device.dt * 1e3:g} ms "
            f"of simulation time, solver {values['solver.method']}, crank length "
            f"{values['linkage.crank_length']:g} m (Grashof bound {self.device.bound:g} m), "
            f"load torque {values['load.torque']:g} N*m")

    def _set_joint_names(self, prefix):
        """The joint names (parameter joint_prefix) of joint_states and clutch_states."""
        self._layout = interface.SampleLayout(self.n_paths, prefix)
        self._joint_names = list(self._layout.names)
        self._actuator_joint = self._joint_names[-1]   # its position in joint_commands

    # ------------------------------------------------------------------ lifecycle
    def start(self):
        """Start the simulation loop thread (after the node is added to an executor)."""
        # what start-up allocated stays: keep it out of the collector's full passes
        gc.collect()
        gc.freeze()
        self.loop.start()

    def stop(self, timeout=1.5):
        """Stop the loop thread; returns True if it ended within ``timeout`` [s]."""
        ended = self.loop.stop(timeout)
        self._close_recorder()
        return ended

    def destroy_node(self):
        self.stop()
        return super().destroy_node()

    # ------------------------------------------------------------------ scene parameters
    def _scene_values(self, base_scene):
        """Base scene + parameter overrides (params file, -p), validated (SceneError)."""
        # rclpy keeps the overrides of this node (params files and -p) here; reading them lets
        # the node coerce integers to doubles (`torque: 10`) before declaring with that type.
        overrides = {name: p.value for name, p in getattr(self, '_parameter_overrides',
                                                           {}).items()}
        return node_values(base_scene, overrides)

    @staticmethod
    def _warm_up(values):
        """Load (or compile) the numba kernels before the loop's timing starts."""
        device = Device(values, 1.0 / values['publish_rate'])
        device.advance()
        device.sim.energy_balance()

    def coerce_parameters_callback(self, parameters):
        """Before rclpy's checks: what `ros2 param set/load` sends, in the declared type (an
        integer for a double, `2e-06` and `inf` that YAML 1.1 reads as text: what `ros2 param
        dump` writes for such values), then checked here, so that a refusal gives the node's
        reason (the Grashof bound, an open bound, the unit) rather than rclpy's range or type
        message: a pre-set callback cannot refuse, so the refused parameters are replaced by
        their present values and check_parameters_callback refuses with the reason. An unknown
        name is refused with the closest one."""
        self._refusal = None
        out = []
        for p in parameters:
            spec = params_mod.SPECS.get(p.name)
            if spec is None:
                if not self.has_parameter(p.name):   # rclpy's own text names no parameter
                    raise ParameterNotDeclaredException(
                        f"{p.name}{closest_name(p.name)}; `cvt-sim params --node` lists them")
                out.append(p)
                continue
            value = coerce(spec, p.value)
            out.append(p if value is p.value else Parameter(p.name, value=value))
        result = self.check_parameters_callback(out)
        if not result.successful:
            self._refusal = result.reason
            out = [self.get_parameter(p.name) if p.name in params_mod.SPECS else p for p in out]
        return out

    def _present_crank_length(self):
        row = self.loop.last_row
        return float(row[COL['crank_length']]) if row is not None else 0.0

    def check_parameters_callback(self, parameters):
        """Refuse (with the reason) a change the physics cannot take; change nothing here."""
        refusal, self._refusal = self._refusal, None   # found by coerce_parameters_callback
        if refusal:
            return SetParametersResult(successful=False, reason=refusal)
        changes = {p.name: p.value for p in parameters if p.name in params_mod.SPECS}
        if not changes:
            return SetParametersResult(successful=True)
        try:
            self.device.check_parameters(changes, self._present_crank_length(),
                                         self._crank_target)
        except (ParameterError, GrashofError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def apply_parameters_callback(self, parameters):
        """Accepted changes: node settings at once, physics queued for the next physics step."""
        changes = {p.name: p.value for p in parameters if p.name in params_mod.SPECS}
        if not changes:
            return
        device, loop = self.device, self.loop
        new = params_mod.validate(dict(device.values, **changes))
        recording = device.values['record.path']
        physics = {k: new[k] for k in changes if k in PERIOD_NAMES}   # at a period boundary
        node = {k: new[k] for k in changes if k in NODE_NAMES and k not in PERIOD_NAMES}
        # the node's settings take effect now; the physics at the loop's next step
        device.set_values(dict(new, **{k: device.values[k] for k in physics}))
        if physics:
            if 'linkage.crank_length' in physics:
                self._crank_target = new['linkage.crank_length']
            if 'load.torque' in physics:
                self._load_command = new['load.torque']
            loop.request(('params', physics))
        if GEOMETRY & set(changes):   # the crank's range: the Grashof bound of the new geometry
            self.set_descriptor(CRANK, describe(params_mod.SPECS[CRANK], new))
        if 'publish_rate' in node:
            device.dt = 1.0 / new['publish_rate']
        if 'steps_per_command' in node:
            loop.steps_per_command = int(new['steps_per_command'])
        if 'step_periods' in node:
            loop.step_periods = int(new['step_periods'])
        if {'time_mode', 'real_time_factor', 'publish_rate', 'realtime_priority'} & set(node):
            loop.retime(new['time_mode'], new['real_time_factor'], int(new['realtime_priority']))
        if 'publish_clock' in node:
            self._publish_clock = bool(new['publish_clock'])
        if 'joint_prefix' in node:
            self._set_joint_names(new['joint_prefix'])
        if 'record.path' in node and new['record.path'] != recording:   # a reload: not again
            self._close_recorder()
            if new['record.path']:
                self._open_recorder(new['record.path'])
        if loop.mode == 'fast' and not self._publish_clock:
            self.get_logger().warning('fast mode without /clock: consumers with use_sim_time '
                                      'will not follow (set publish_clock true)')

    # ------------------------------------------------------------------ commands
    def crank_length_cmd_callback(self, msg, info):
        """A crank length [m]: accepted in [0, Grashof bound), else refused (last one stays)."""
        self._command('crank', 'crank_length_cmd', msg, info, self._crank_length)

    def load_torque_cmd_callback(self, msg, info):
        """A load torque [N·m]: accepted when finite and |M| <= limits.load_torque."""
        self._command('load', 'load_torque_cmd', msg, info, self._load_torque)

    def joint_commands_callback(self, msg, info):
        """topic_based_ros2_control's commands: the position of joint ``crank_length`` (with
        the joint prefix) is a crank-length command, checked and stepped like
        crank_length_cmd; the other joints' entries are ignored."""
        self._command('crank', 'joint_commands', msg, info, self._joint_command)

    def _crank_length(self, data):
        value = _float64(data, 'crank_length_cmd')
        self.device.check_crank_length(value)
        return value

    def _load_torque(self, data):
        value = _float64(data, 'load_torque_cmd')
        self.device.check_load_torque(value)
        return value

    def _joint_command(self, msg):
        name = self._actuator_joint
        try:
            i = msg.name.index(name)
        except ValueError:
            shown = ', '.join(msg.name[:8]) + (' ...' if len(msg.name) > 8 else '')
            raise CommandError('joint_commands', f"names [{shown}]",
                               f"no joint {name!r} (its position is the crank-length command "
                               f"[m])") from None
        try:
            value = interface.joint_command_position(msg.name, msg.position, i)
        except ValueError as exc:
            raise CommandError('joint_commands', *exc.args) from None
        self.device.check_crank_length(value, f'joint_commands {name}')
        return value

    def _command(self, kind, topic, msg, info, read):
        """A command message from any command topic: counted, recorded, checked by ``read``
        (its value, or CommandError with the reason), applied or refused, and in lockstep
        stepped — a refused crank command still advances its periods with the last valid one."""
        loop = self.loop
        loop.stats.commands += 1
        self._count_lost(topic, info)
        self._hand_to_recorder(self._topic[topic], msg, self._published_ns)
        grant = loop.grant(kind)
        try:
            value = read(msg)
        except CommandError as exc:
            loop.stats.refused += 1
            keeping = (f"{self._crank_target:g} m" if kind == 'crank'
                       else f"{self._load_command:g} N*m")
            loop.warn((topic, exc.reason), f"{exc}; keeping the last valid command {keeping}",
                      ' refused')
            kind = value = None   # the controller's cycle goes on with the last valid command
        else:
            if kind == 'crank':
                self._crank_target = value
            else:
                self._load_command = value
        loop.command(kind, value, grant)   # loop thread: applied now, stepped if held

    def _count_lost(self, topic, info):
        """Commands lost before they reached this node (a publisher overwrote its own unsent
        history): gaps in the publisher's sequence numbers, counted while one publisher sends
        (several interleave theirs), reported in /diagnostics (commands_lost) and warned."""
        seq = info.get('publication_sequence_number') if info else None
        if seq is None:
            return
        last = self._last_seq.get(topic)
        self._last_seq[topic] = seq
        if last is None or seq <= last + 1:
            return
        sub = {'crank_length_cmd': self.crank_length_cmd_subscription,
               'load_torque_cmd': self.load_torque_cmd_subscription,
               'joint_commands': self.joint_commands_subscription}[topic]
        if sub.get_publisher_count() != 1:
            return
        lost = seq - last - 1
        self.loop.stats.lost += lost
        self.loop.warn('lost', f"{lost} command messages were lost before reaching the node "
                               f"({self.loop.stats.lost} in all): the publisher's history is "
                               f"shorter than its backlog (publish with keep_all or a deeper "
                               f"history, or wait for each sample in lockstep)")

    def wait_commands(self, timeout_s):
        """Loop thread: wait up to ``timeout_s`` (0: just look) for command messages or
        ``wake()``; hand every message that arrived to its subscription's callback, load
        commands first (a disturbance that came with a crank command acts in its period), at most
        TAKE_LIMIT per subscription. True if any came."""
        return self._command_wait.wait(timeout_s)

    def wake(self):
        """Interrupt the loop thread's wait_commands (a request, a setting, stop)."""
        self._command_wait.wake()

    # ------------------------------------------------------------------ services
    def reset_callback(self, request, response):
        """Back to the scene's initial state (t = 0, parameters as currently set)."""
        self._crank_target = self.device.values['linkage.crank_length']
        self._load_command = self.device.values['load.torque']
        waiter = self.loop.submit('reset')
        response.success, response.message = waiter.success, waiter.message
        return response

    def pause_callback(self, request, response):
        """data = true: hold the simulation; false: run again (realtime / fast)."""
        waiter = self.loop.submit('pause', bool(request.data))
        response.success, response.message = waiter.success, waiter.message
        return response

    def step_callback(self, request, response):
        """Advance step_periods control periods (default 1) while paused or in lockstep mode;
        the response names the state reached (time, crank length, load torque in force)."""
        loop = self.loop
        if not loop.held():
            response.success = False
            response.message = (f"~/step advances only while paused or in lockstep mode "
                                f"(time_mode is {loop.mode}); call ~/pause first")
            return response
        response.success, response.message = loop.step(loop.step_periods)
        return response

    # ------------------------------------------------------------------ the loop's port
    def ok(self):
        return self.context.ok()

    def publish_present(self, period):
        """The present state: latched clutch state, then a sample (start-up, reset); both stay
        latched for late joiners (clutch_engaged, state). N ≥ 2: the engaged set first, as a
        switch message of clutch_states."""
        ns = interface.stamp_ns(period.t)
        if self.n_paths > 1:
            self._publish_clutch_set(self.device.engaged_set, ns)
        msg = Bool(data=bool(period.row[COL['engaged']]))
        self._hand_to_recorder(self._topic['clutch_engaged'], msg, ns)
        self._publish(self.clutch_engaged_publisher, msg)
        self.publish_sample(period.row, period.crank_rate)

    def publish_switch(self, event):
        """One clutch switch, at its own simulation time (Bool has no stamp: the switch time is
        in diagnostics as last_switch_time and goes to the recorder with this message). N ≥ 2:
        ``event`` is a switching instant (solver.clutch_sets.SetChange): the engaged set on
        clutch_states, stamped with it; clutch_engaged only where "any" changed (a handoff
        between paths is no switch of it)."""
        ns = interface.stamp_ns(event.t)
        if self.n_paths > 1:
            self._publish_clutch_set(event.after, ns)
            if not event.any_changed:
                return
        msg = Bool(data=bool(event.engaged))
        self._hand_to_recorder(self._topic['clutch_engaged'], msg, ns)
        self._publish(self.clutch_engaged_publisher, msg)

    def _publish_clutch_set(self, mask, ns):
        """clutch_states of a switch: the engaged set ``mask`` (positions only) at ``ns``."""
        data = self._layout.clutch_switch(mask, ns)
        self._hand_to_recorder(self._topic['clutch_states'], data, ns)
        self._publish_raw(self.clutch_states_publisher, data)

    def _publish_raw(self, publisher, data):
        try:
            with publisher.handle:
                publisher.handle.publish_raw(data)
        except (InvalidHandle, RCLError) as exc:
            if not self._shutting_down(exc):
                raise

    def _publish(self, publisher, msg):
        """Publish, unless the node is shutting down. What was computed is recorded before it is
        published, so a recording never holds a period's switch without its sample."""
        try:
            publisher.publish(msg)
        except (InvalidHandle, RCLError) as exc:
            if not self._shutting_down(exc):
                raise

    def _shutting_down(self, exc):
        """A publish refused because the node is going down: a destroyed publisher
        (InvalidHandle), or rcl's refusal (RCLError) once Ctrl-C took the context down."""
        return isinstance(exc, InvalidHandle) or not self.context.ok()

    def publish_sample(self, row, crank_rate):
        """state, joint_states and /clock of one period's end (``row``: its sample, the
        actuator's rate [m/s]), serialized once (CDR bytes), published through the publishers'
        handles (rclpy's publish() adds a type check per message and nothing else)."""
        values = row.tolist()             # (once, for joint_states and clutch_states)
        ns = round(values[0] * 1e9)       # = interface.stamp_ns(row[0])
        data = self._layout.joint_states(values, crank_rate, ns)
        joint_states, state, clock_handle = self._sample_handles
        clock = None
        try:
            # state first: a lockstep controller waits on it, and a publication matched in
            # another process costs tens of µs (the wake-up of its Fast DDS listener)
            with state:
                state.publish_raw(data)
            with joint_states:
                joint_states.publish_raw(data)
            if self._publish_clock:
                clock = interface.clock_cdr(ns)
                with clock_handle:
                    clock_handle.publish_raw(clock)
        except (InvalidHandle, RCLError) as exc:
            # shutting down: not published, but recorded all the same, as the period's clutch
            # switches are (a recording ends on a whole period)
            if not self._shutting_down(exc):
                raise
        if self.n_paths > 1:   # (after the sample: a lockstep controller waits for that)
            clutches = self._layout.clutch_states(values, ns)
            self._publish_raw(self.clutch_states_publisher, clutches)
            self._hand_to_recorder(self._topic['clutch_states'], clutches, ns)
        if self._recorder is not None:
            self._hand_to_recorder(self._topic['joint_states'], data, ns)
            if self._publish_clock:
                # (made after state went out; made here if shutting down stopped that first)
                self._hand_to_recorder(self._topic['clock'], clock or interface.clock_cdr(ns), ns)
        self._published_ns = ns

    def recording_reset(self):
        if self._recorder is not None:
            self._recorder.mark_reset()

    def recording_parameters(self, changes, t):
        """Live parameter changes taken at simulation time ``t`` [s], into the recording."""
        if self._recorder is not None:
            self._recorder.record_parameters(changes, t)

    # ------------------------------------------------------------------ recording hook
    def recorded_topics(self):
        """(resolved topic name, message type, QoS profile) of everything the node publishes or
        receives: what a recorder registers (BagWriter.add_topic) before the first message."""
        return [
            (self._topic['joint_states'], JointState, interface.joint_states_qos()),
            (self._topic['clutch_engaged'], Bool, interface.clutch_qos()),
            (self._topic['clock'], ClockMsg, interface.clock_qos()),
            (self._topic['diagnostics'], DiagnosticArray, interface.diagnostics_qos()),
            (self._topic['crank_length_cmd'], Float64, interface.command_qos()),
            (self._topic['load_torque_cmd'], Float64, interface.command_qos()),
            (self._topic['joint_commands'], JointState, interface.qos_profile('joint_commands')),
        ] + ([(self._topic['clutch_states'], JointState, interface.qos_profile('clutch_states'))]
             if self.n_paths > 1 else [])

    def _open_recorder(self, path):
        """Record everything published and received to ``path`` (parameter record.path) at
        simulation time, through the recording room's SimulationRecorder. A path that cannot be
        written is logged and the node runs on without recording; a later I/O error (disk full)
        is logged once and recording stops, the simulation does not."""
        from ..recording import RecordingError
        from ..recording.recorder import SimulationRecorder
        logger = self.get_logger()
        try:
            self._recorder = SimulationRecorder(
                path, topic_names=dict(self._topic), joint_names=self._joint_names[:-1],
                parameters=self.device.values, scene=self._scene_name, source='cvt_node',
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
                recorder.record_self_check(self.device.sim.self_check())
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
    def diagnostics_timer_callback(self):
        """~1 Hz: timing, switching and energy figures as one DiagnosticStatus."""
        loop, device = self.loop, self.device
        fault = device.fault
        state = 'fault' if fault else ('paused' if loop.paused else loop.mode)
        report = self._reporter.report(
            loop.snapshot, loop.stats, device.step_ns,
            {'mode': loop.mode, 'state': state, 'real_time_factor': loop.rtf,
             'publish_rate': device.values['publish_rate'], 'control_period': device.dt,
             'fault': fault, 'policy': REALTIME_POLICY if loop.mode == 'realtime' else '-'})
        if report is None:
            return
        level, message, values = report
        name = self.get_fully_qualified_name()
        status = DiagnosticStatus(
            level=bytes([level]), name=f"{name}: transmission", message=message,
            hardware_id=name, values=[KeyValue(key=k, value=v) for k, v in values])
        msg = DiagnosticArray(status=[status])
        interface.set_stamp(msg.header.stamp, self._published_ns)
        self.diagnostics_publisher.publish(msg)
        self._hand_to_recorder(self._topic['diagnostics'], msg, self._published_ns)


__all__ = ['CvtSimNode', 'DEFAULT_SCENE', 'REALTIME_SOLVER']
