"""``--backend dds``: the device as ``cvt_node`` in a process of its own, over ROS 2.

The node runs on a ROS domain held for this run alone (``cvt_ros.device.domains``; the one
ROS_DOMAIN_ID names when it is set and free, so that ``ros2 topic echo`` in the same shell sees
the run; ``DdsPlant.domain``, printed by ``cvt-sim scenario run``), from a parameters file with
every scene value of the scenario (so it runs exactly the offline model), ``time_mode:
lockstep`` and ``steps_per_command: 1``: each crank_length_cmd advances one control period.
The protocol (docs/lockstep.md):

* start: the node publishes the t = 0 sample on ``state`` (latched); the harness waits for it and
  for its command publishers to be matched — nothing is sent into the void;
* each period: the harness publishes one crank_length_cmd (the controller's, or the one in force
  again: the device does not re-plan an unchanged command) and waits for the sample of the next
  period on ``state``; clutch switches arrive on ``clutch_engaged`` in between (N ≥ 2 paths:
  on ``clutch_states``, each clutch's, stamped with the switch's own time);
* the load schedule is handed to the node up front (parameter ``disturbance.file``: a CSV of
  the periods where the load changes), and the node applies each change at the start of its
  period on the k·period grid — a load command on its own topic would race the crank command
  (two topics have no common order in DDS). Set-point changes live in the controller.

The node records the run (``record.path``), and its recording is the run's trace, streamed
after the run (``DdsPlant.replay``: every period's sample, the clutch switches at their own
simulation times — ``clutch_engaged`` carries no stamp: on the wire a switch is only known to lie
in the period whose sample follows it), and in realtime its /diagnostics too: the node's timing
(missed deadlines, jitter, resyncs) as ``node_timing``.

With ``controller_cmd`` the controller is an external process (e.g. ``cvt_speed_controller``),
started with ROS_DOMAIN_ID of the run and CVT_SETPOINT_FILE naming a CSV of the set point per
control period (the reference controller's ``setpoint_file``); it steps the node itself, the
harness watches the newest samples and takes the whole trace from the node's recording.
``realtime``: the node runs against the wall clock at that real-time factor (HIL rehearsal),
the harness reacts to the newest sample.
"""
import math
import operator
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from ..device import domains
from ..interface import (
    ACTUATOR_JOINT,
    CLUTCH_STATES,
    STATE,
    float64_cdr,
    float64_value,
    joint_state_stamp_ns,
    parse_joint_state_cdr,
)
from ..solver.output import COL, N_COLUMNS
from ..solver.simulator import SimulationError
from .plants import plant_values

START_TIMEOUT_S = 300.0     # node start incl. compiling the kernels on a cold cache, loaded machine
PERIOD_TIMEOUT_S = 30.0     # one lockstep period (a loaded machine stalls, it does not fail)
# the columns a state sample fills, in this order (SampleRows.fill); the rest stay NaN
_FILLED_COLUMNS = ('t', 'phi1', 'phi2', 'phi3', 'phi4', 'omega1', 'omega2', 'omega3', 'omega4',
                   'engaged', 'twist', 'clutch_torque', 'crank_length', 'load_torque',
                   'motor_torque', 'shaft_torque')
assert [COL[c] for c in _FILLED_COLUMNS] == list(range(len(_FILLED_COLUMNS)))
_FILLED = len(_FILLED_COLUMNS)
WAIT_S = 0.05               # one wait for a sample; the liveness checks between waits


# the node's timing in a realtime run, from its last /diagnostics (DiagnosticStatus keys)
TIMING_KEYS = ('missed_deadlines', 'resyncs', 'slipped_s', 'jitter_p50_us', 'jitter_p99_us',
               'jitter_max_us', 'step_time_p50_us', 'step_time_p99_us', 'step_time_max_us',
               'sim_time')


class DdsError(SimulationError):
    """The node or the DDS link failed (the node's log tail is in the message)."""


def lease_domain():
    """A ROS domain for a run's node: the one ROS_DOMAIN_ID names when it is set and no other
    run holds it (what the user's other terminals use), else a free one of its own."""
    wanted = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if wanted.isdigit():
        lease = domains.try_acquire(int(wanted))
        if lease is not None:
            return lease
    return domains.acquire()


def node_parameters(values, period, mode='lockstep', rtf=1.0):
    """The node's parameters for a scenario: every scene value, the time mode, the period."""
    params = {k: v for k, v in values.items()}
    params.update({'time_mode': mode, 'steps_per_command': 1 if mode == 'lockstep' else 0,
                   'publish_rate': 1.0 / period, 'real_time_factor': float(rtf),
                   'record.path': ''})
    return params


def write_params_file(path, params):
    clean = {k: (float(v) if isinstance(v, float) else v) for k, v in params.items()}
    Path(path).write_text(yaml.safe_dump({'cvt_sim': {'ros__parameters': clean}},
                                         sort_keys=True))


class SampleRows:
    """``state`` samples → sample rows (COLUMNS, NaN where a message has no value).

    ``fill(ns, position, velocity, effort)`` (a JointState's stamp [ns] and values, as
    ``interface.JointStateDecoder`` gives them) writes one row into a buffer it owns and returns
    it (the next call rewrites it: copy what you keep). One struct call, no numpy indexing:
    in lockstep this runs between the sample's arrival and the next command, on the round
    trip, right after a wake-up, where numpy's fancy indexing cost ~25 µs. ``order``: the
    device's joints in the message (``interface.joint_order``), ``actuator``: the crank_length
    joint's index (None: NaN)."""

    def __init__(self, order, actuator):
        self._joints = operator.itemgetter(*order)
        self._actuator = actuator
        self._bytes = bytearray(struct.pack(f'<{N_COLUMNS}d', *[math.nan] * N_COLUMNS))
        self.row = np.frombuffer(self._bytes, dtype=np.float64)
        self._pack = struct.Struct(f'<{_FILLED}d').pack_into

    def fill(self, ns, position, velocity, effort, engaged_set=0):
        phi1, phi2, phi3, phi4 = self._joints(position)
        motor, clutch, shaft, load = self._joints(effort)
        crank = math.nan if self._actuator is None else position[self._actuator]
        self._pack(self._bytes, 0, ns * 1e-9, phi1, phi2, phi3, phi4, *self._joints(velocity),
                   1.0 if clutch > 0.0 else 0.0, phi3 - phi4, clutch, crank, load, motor, shaft)
        return self.row


class PathSampleRows(SampleRows):
    """N ≥ 2 paths: rows of ``output.path_columns(N)`` from joint_states' rockers (``rockers``:
    their indices) and the engaged set the clutch_states messages gave (bit k − 1 = path k):
    clutch_torque = the rockers' efforts summed in path order (as the core sums them), engaged
    = any clutch, engaged_k its bit."""

    def __init__(self, order, actuator, rockers):
        super().__init__(order, actuator)
        n = self.n_paths = len(rockers)
        self._rockers = operator.itemgetter(*rockers)
        self._bytes = bytearray(struct.pack(f'<{N_COLUMNS + 4 * n}d',
                                            *[math.nan] * (N_COLUMNS + 4 * n)))
        self.row = np.frombuffer(self._bytes, dtype=np.float64)

    def fill(self, ns, position, velocity, effort, engaged_set=0):
        super().fill(ns, position, velocity, effort)
        n, row = self.n_paths, self.row
        torques = self._rockers(effort)
        total = 0.0
        for torque in torques:
            total += torque
        row[COL['clutch_torque']] = total
        row[COL['engaged']] = 1.0 if engaged_set else 0.0
        row[N_COLUMNS:N_COLUMNS + n] = self._rockers(position)
        row[N_COLUMNS + n:N_COLUMNS + 2 * n] = self._rockers(velocity)
        row[N_COLUMNS + 2 * n:N_COLUMNS + 3 * n] = [engaged_set >> k & 1 for k in range(n)]
        row[N_COLUMNS + 3 * n:] = torques
        return self.row


class ClutchSets:
    """N ≥ 2 paths: clutch_states messages (CDR) → each clutch's switches (t, engaged, path)
    where its state changes from one message to the next, at the later one's stamp (a switch
    message carries the switch's own time); ``mask``: the engaged set now."""

    def __init__(self, n_paths):
        self.n_paths = n_paths
        self.mask = None

    def take(self, data):
        ns, _, _, position, _, _ = parse_joint_state_cdr(data)
        if len(position) != self.n_paths:
            raise DdsError(f"a clutch_states message with {len(position)} clutches, not "
                           f"{self.n_paths}")
        mask = sum(1 << k for k, v in enumerate(position) if v == 1.0)
        before, self.mask = self.mask, mask
        if before is None:
            return []
        return [(ns * 1e-9, bool(mask >> k & 1), k + 1) for k in range(self.n_paths)
                if (mask ^ before) >> k & 1]


class DdsPlant:
    """The harness's view of ``cvt_node`` (see the module docstring)."""
    name = 'dds'

    @property
    def skips_periods(self):
        return bool(self.realtime or self.external)

    def __init__(self, scenario, controller_cmd=None, realtime=None, domain=None, log=None):
        self.period = scenario.control_period
        self.scenario = scenario
        self.n_paths = int(scenario.values.get('paths.count', 1))
        self.clutch_sets = ClutchSets(self.n_paths) if self.n_paths > 1 else None
        self.external = controller_cmd
        self.realtime = realtime
        self._own_lease = domain is None
        self.lease = lease_domain() if domain is None else domain
        self.domain = self.lease.domain
        self.node_timing = None     # realtime: the node's timing (TIMING_KEYS), from its recording
        self.tmp = tempfile.TemporaryDirectory(prefix='cvt_scenario_')
        self.log = log or open(os.path.join(self.tmp.name, 'node.log'), 'w+')
        # realtime too starts in lockstep: the t = 0 sample and the handshake first, then the
        # harness switches time_mode (a live parameter) and the wall clock takes over
        params_file = os.path.join(self.tmp.name, 'scene.yaml')
        params = node_parameters(plant_values(scenario), self.period, 'lockstep', realtime or 1.0)
        # the node's own recording: the switches at their times; realtime, external controller:
        # the whole trace (the harness sees the newest samples only)
        self.recording = os.path.join(self.tmp.name, 'run.mcap')
        params['record.path'] = self.recording
        # the load schedule goes to the node up front (parameter disturbance.file): it applies
        # each change at the start of its period on the k·period grid, as offline does
        self.disturbance = self._write_disturbance(scenario)
        if self.disturbance:
            params['disturbance.file'] = self.disturbance
        write_params_file(params_file, params)
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.lease.domain),
                        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        self.env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
        self.env.pop('ROS_STATIC_PEERS', None)
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'cvt_ros.device', '--ros-args', '--params-file', params_file],
            env=self.env, stdout=self.log, stderr=subprocess.STDOUT, pass_fds=[self.lease.fd])
        self.controller_proc = None
        self._setup_ros()

    def _write_disturbance(self, scenario):
        """CSV ``t,load_torque`` of the periods where the load schedule changes ('' if it
        never does)."""
        grid = scenario.time_grid()
        load = scenario.load.sample(grid)
        change = np.flatnonzero(np.diff(load) != 0) + 1
        if not len(change):
            return ''
        path = os.path.join(self.tmp.name, 'disturbance.csv')
        np.savetxt(path, np.column_stack([grid[change], load[change]]), delimiter=',',
                   header='t,load_torque', comments='', fmt='%.17g')
        return path

    # ------------------------------------------------------------------ ROS side
    def _setup_ros(self):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64

        from .. import interface
        from ..device.subscription_wait import SubscriptionWait
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.lease.domain)
        self.node = rclpy.create_node('cvt_scenario_harness', context=self.context)
        self.samples = []          # state messages not yet taken (CDR bytes)
        self.switch_states = []    # clutch_engaged values (N ≥ 2: clutch_states CDR) not taken
        # raw: the samples' bytes, read by one struct call (rclpy's message objects cost ~12 µs
        # each, a good part of what a lockstep round trip spends in this process)
        self._decoder = interface.JointStateDecoder()
        state = self.node.create_subscription(JointState, STATE, self.samples.append,
                                              interface.state_qos(), raw=True)
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        every = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)   # each message is a switch
        if self.n_paths > 1:   # each clutch, its switches stamped (clutch_engaged is any one);
            # latched: the t = 0 set, whenever this subscription matched
            latched = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            clutch = self.node.create_subscription(JointState, CLUTCH_STATES,
                                                   self.switch_states.append, latched, raw=True)
        else:
            clutch = self.node.create_subscription(
                Bool, interface.CLUTCH_ENGAGED,
                lambda m: self.switch_states.append(bool(m.data)), every)
        # waiting for a sample: on these two alone, not through an executor pass (a lockstep
        # period is one round trip; the executor's pass would be most of it). Switches first:
        # those published before a sample are taken with it.
        self._sample_wait = SubscriptionWait(self.context, (clutch, state))
        self.crank_publisher = self.node.create_publisher(Float64, interface.CRANK_LENGTH_CMD,
                                                          interface.command_qos())
        self._live = False
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.rows = None           # SampleRows, from the first sample
        self._last_ns = -1
        self._command = None
        self._sent = None
        self._engaged = None

    def _spin_until(self, done, timeout, what, samples_only=False):
        """Serve ROS until ``done()`` (``samples_only``: take only the node's samples and
        switches, on their own wait set; else spin the executor: services, parameters)."""
        end = time.monotonic() + timeout
        while not done():
            # a lockstep sample ends the wait at once: the processes and the clock are looked
            # at when a wait did not bring what is waited for, not on every period
            if samples_only and self._sample_wait.wait(WAIT_S) and done():
                return
            if self.proc.poll() is not None:
                raise DdsError(f"cvt_node ended (exit {self.proc.returncode}) while waiting for "
                               f"{what}:\n{self.node_log()}")
            if self.controller_proc is not None and self.controller_proc.poll() is not None:
                raise DdsError(f"the controller process ended (exit "
                               f"{self.controller_proc.returncode}) while waiting for {what}")
            if time.monotonic() > end:
                raise DdsError(f"no {what} within {timeout:g} s:\n{self.node_log()}")
            if not samples_only:
                self.executor.spin_once(timeout_sec=0.05)

    def node_log(self, lines=15):
        self.log.flush()
        self.log.seek(0)
        return ''.join(self.log.readlines()[-lines:])

    def _next_sample(self):
        """The next sample on ``state`` newer than the last one (row, switches since): in
        lockstep the next period's; in realtime the newest (periods in between are skipped, as
        a real-time controller skips what it was too slow for; ``skips_periods``). The row is
        ``self.rows``' buffer: the next sample rewrites it."""
        samples = self.samples

        def fresh():   # (a single writer's samples arrive in order: the newest is the last)
            return samples and joint_state_stamp_ns(samples[-1]) > self._last_ns
        if not fresh():
            # lockstep: one wait brings the next period's sample; the liveness checks only if
            # it did not
            self._sample_wait.wait(WAIT_S)
            if not fresh():
                self._spin_until(fresh,
                                 PERIOD_TIMEOUT_S if self._last_ns >= 0 else START_TIMEOUT_S,
                                 'sample from cvt_node', samples_only=True)
        data = samples[-1]
        samples.clear()
        try:
            ns, position, velocity, effort = self._decoder.decode(data)
        except ValueError as exc:
            raise DdsError(f"a state message that is not a JointState: {exc}") from None
        if self.rows is None:
            self.rows = self._sample_rows()
        if self.clutch_sets is not None:
            switches = []
            for data in self.switch_states:
                switches += self.clutch_sets.take(data)
            self.switch_states.clear()
            self._last_ns = ns
            return self.rows.fill(ns, position, velocity, effort, self.clutch_sets.mask or 0), \
                switches
        row = self.rows.fill(ns, position, velocity, effort)
        switches = []
        if self.switch_states:
            for engaged in self.switch_states:
                if self._engaged is not None and engaged != self._engaged:
                    switches.append((row[0], engaged))   # time: the period's end
                self._engaged = engaged
            self.switch_states.clear()
        self._last_ns = ns
        return row, switches

    def _sample_rows(self):
        """The rows of this node's samples (their joint layout, from the first one)."""
        from ..interface import joint_order, rocker_order
        names = self._decoder.names
        order = joint_order(names)
        if order is None:
            raise DdsError(f"state without the device's joints: {names}")
        hits = [i for i, n in enumerate(names) if n.endswith(ACTUATOR_JOINT)]
        actuator = hits[0] if len(hits) == 1 else None
        if self.n_paths > 1:
            rockers = rocker_order(names)
            if len(rockers) != self.n_paths:
                raise DdsError(f"state with {len(rockers)} rockers for {self.n_paths} paths: "
                               f"{names}")
            return PathSampleRows(order, actuator, rockers)
        return SampleRows(order, actuator)

    # ------------------------------------------------------------------ plant protocol
    def start(self):
        self._spin_until(lambda: self.crank_publisher.get_subscription_count() > 0,
                         START_TIMEOUT_S, "cvt_node's command subscription")
        if self.clutch_sets is not None:   # N ≥ 2: the t = 0 engaged set (latched) first
            self._spin_until(lambda: self.switch_states, START_TIMEOUT_S,
                             "cvt_node's clutch_states", samples_only=True)
        row, _ = self._next_sample()
        self._engaged = bool(row[COL['engaged']])    # switches: messages that change it
        self._command = float(row[COL['crank_length']])
        if self.external:
            self._start_controller()
        if self.realtime:
            self._go_realtime()
        return row

    def _go_realtime(self):
        """Switch the node to realtime mode (a live parameter change) after the handshake."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters
        client = self.node.create_client(SetParameters, '/cvt_sim/set_parameters')
        self._spin_until(client.service_is_ready, START_TIMEOUT_S, "cvt_node's parameters")
        request = SetParameters.Request(parameters=[Parameter(
            name='time_mode', value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                   string_value='realtime'))])
        future = client.call_async(request)
        self._live = True
        self._spin_until(future.done, PERIOD_TIMEOUT_S, 'the switch to realtime')
        result = future.result().results[0]
        if not result.successful:
            raise DdsError(f"cvt_node refused realtime mode: {result.reason}")

    def _start_controller(self):
        path = os.path.join(self.tmp.name, 'setpoint.csv')
        grid = self.scenario.time_grid()
        np.savetxt(path, np.column_stack([grid, self.scenario.setpoint.sample(grid)]),
                   delimiter=',', header='t,setpoint', comments='', fmt='%.17g')
        env = dict(self.env, CVT_SETPOINT_FILE=path)
        self.controller_proc = subprocess.Popen(
            self.external, shell=True, env=env, stdout=self.log, stderr=subprocess.STDOUT,
            start_new_session=True)

    def set_load_torque(self, torque):
        """Nothing to send: the node has the schedule (``disturbance.file``)."""

    def command_crank_length(self, length):
        self._command = float(length)

    def step(self):
        if not self.external and (not self._live or self._command != self._sent):
            # lockstep: this advances one period (its CDR bytes: no rclpy message object)
            self.crank_publisher.publish(float64_cdr(self._command))
            self._sent = self._command
        return self._next_sample()

    def replay(self, t_end):
        """The run from the node's own recording up to ``t_end`` [s] (it stops the node: SIGINT
        finishes the file), in time order: ('sample', row), ('switch', (t, engaged)),
        ('diagnostics', (t, CDR bytes)) and an external controller's ('command', (t, value)),
        logged at the sample it answered. The harness saw the samples too (lockstep) or only
        the newest (realtime, external controller), and each switch only with the sample after
        it. Realtime also sets ``node_timing`` (from the last /diagnostics)."""
        from ..recording.reader import read_messages
        self._stop(self.proc)
        end_ns = round(t_end * 1e9)
        engaged, last_diagnostics = None, None
        # N ≥ 2 paths: each clutch's switches, stamped, from clutch_states
        sets = ClutchSets(self.n_paths) if self.n_paths > 1 else None
        topics = ['/clutch_states' if sets else '/clutch_engaged', '/joint_states',
                  '/crank_length_cmd', '/diagnostics']
        for m in read_messages(self.recording, topics, strict=False):
            if m.log_time_ns > end_ns:
                break
            if m.topic == '/crank_length_cmd':
                if self.external:
                    yield 'command', (m.log_time_ns * 1e-9, float64_value(m.data))
                continue
            if m.topic == '/diagnostics':   # (realtime, external: the node's timing)
                if self.skips_periods:
                    last_diagnostics = m.data
                    yield 'diagnostics', (m.log_time_ns * 1e-9, m.data)
                continue
            if m.topic == '/clutch_states':   # (t, engaged, path), each clutch's
                for switch in sets.take(m.data):
                    yield 'switch', switch
                continue
            if m.topic == '/clutch_engaged':
                state = m.data[-1] == 1
                if engaged is not None and state != engaged:   # (repeats are not switches)
                    yield 'switch', (m.log_time_ns * 1e-9, state)
                engaged = state
                continue
            sample = self._decoder.decode(m.data)
            if self.rows is None:   # (the joint layout, if no sample was seen)
                self.rows = self._sample_rows()
            yield 'sample', self.rows.fill(*sample, *((sets.mask or 0,) if sets else ()))
        if self.realtime and last_diagnostics is not None:
            self.node_timing = node_timing(last_diagnostics)

    @staticmethod
    def _stop(proc):
        if proc is not None and proc.poll() is None:
            try:
                proc.send_signal(signal.SIGINT)
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def close(self):
        if self.controller_proc is not None and self.controller_proc.poll() is None:
            try:
                os.killpg(self.controller_proc.pid, signal.SIGINT)
                self.controller_proc.wait(10)
            except (subprocess.TimeoutExpired, ProcessLookupError):
                os.killpg(self.controller_proc.pid, signal.SIGKILL)
                self.controller_proc.wait()
        self._stop(self.proc)
        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            self.context.try_shutdown()
        if self._own_lease:
            self.lease.release()
        self.tmp.cleanup()


def node_timing(diagnostics_cdr):
    """The node's timing (TIMING_KEYS → float) from one /diagnostics message (CDR bytes)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message
    timing = {}
    for status in deserialize_message(diagnostics_cdr, DiagnosticArray).status:
        for kv in status.values:
            if kv.key in TIMING_KEYS and kv.key not in timing:
                try:
                    timing[kv.key] = float(kv.value)
                except ValueError:
                    pass
    return timing or None


__all__ = ['DdsError', 'DdsPlant', 'SampleRows', 'TIMING_KEYS', 'lease_domain', 'node_parameters',
           'node_timing', 'write_params_file']
