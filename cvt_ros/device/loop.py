"""The run loop: one thread that owns the Device, takes the commands, advances and publishes, in
one of three time modes. Plain Python: the node drives it through a small port (publish a sample,
a switch, the present state; wait for commands), and tests may drive it with a port of their own.

* ``realtime``: the period ending at simulation time t is published at wall time
  anchor + (t − anchor_sim)/real_time_factor on the monotonic clock; the next period is computed
  ahead while waiting. Deadlines come from the schedule, never from a sleep's end, so there is no
  drift; late samples go out back to back until the schedule is met again; more than
  LAG_LIMIT_NS behind, the backlog is given up and the schedule re-anchored (a resync).
* ``fast``: as fast as the core and the publishing allow, FAST_BATCH periods per pass; commands
  are looked for at most every FAST_POLL_NS of wall time (a look costs more than a period).
* ``lockstep``: the simulation advances only on ``~/step`` (``step_periods`` each) or by
  ``steps_per_command`` per crank-length command; load commands never advance time.

The loop thread takes every command message itself (``port.wait_commands``: an rcl wait set on
the command subscriptions, not the executor): while the simulation runs free it polls them at the
start of a period (every period in realtime, at most every FAST_POLL_NS in fast mode); while it
is held (lockstep, paused, a fault) it blocks on them, so in lockstep one command message is one
wake-up of this thread, which applies it, advances and publishes — no hand-over between
threads, no executor pass. Services and parameter changes come from the executor thread as queued
requests (applied at the next period boundary, in arrival order, ``wake()`` interrupts a wait);
``~/step`` advances from the executor thread under ``lock``.
"""
import collections
import ctypes
import math
import os
import threading
import time
import traceback

from ..parameters import ParameterError
from ..physics.linkage import GrashofError
from ..solver.simulator import SimulationError
from .core import CommandError
from .diagnostics import Stats

SPIN_NS = 100_000              # busy-wait the last 100 µs before a deadline (sleep overshoots)
MAX_SLEEP_S = 0.05             # longest single sleep: stop / pause are seen within this
IDLE_WAIT_S = 0.1              # lockstep / paused: wait for a command this long at a time
LAG_LIMIT_NS = 500_000_000     # behind by more than this: give up the backlog, re-anchor
STATS_PERIOD_NS = 250_000_000  # energy balance / snapshot for diagnostics this often
WARN_PERIOD_S = 1.0            # throttled warnings: at most one per topic per second
SERVICE_TIMEOUT_S = 5.0        # a service waits this long for the loop to act
FAST_BATCH = 20                # fast mode: control periods per pass of the loop (less overhead)
# fast mode: look for commands at most this often (wall time). A look is an rcl wait with a zero
# timeout, 20-30 µs with Fast DDS (100 µs at Linux's default timer slack), more than the step of
# a 1 ms period (~5 µs): polling every period made it most of fast mode's cost.
FAST_POLL_NS = 1_000_000
#: What realtime mode does when it cannot keep up (reported in /diagnostics, docs/node.md).
REALTIME_POLICY = ('catch up: late samples go out back to back with their own stamps; more than '
                   '0.5 s behind: re-anchor, simulation time slips (resyncs, slipped_s)')


def reduce_timer_slack():
    """Linux: 1 ns timer slack for this thread (default 50 µs), so sleeps end on time."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)   # PR_SET_TIMERSLACK
    except (OSError, AttributeError):
        pass


class Throttle:
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


class Waiter:
    """A service call waiting for the loop thread to carry out its request."""

    def __init__(self, arg=None):
        self.arg = arg
        self.done = threading.Event()
        self.success = False
        self.message = 'the simulation loop did not answer'

    def finish(self, success, message):
        self.success, self.message = success, message
        self.done.set()


class RunLoop:
    """The loop thread around a Device. ``port``: what the loop talks through —
    ``publish_sample(row, crank_rate)`` (one period's sample row and the actuator's rate),
    ``publish_switch(event)``, ``publish_present(period)`` (latched clutch state and sample),
    ``wait_commands(timeout_s)`` (wait up to
    ``timeout_s`` for command messages or ``wake()``; hand each to its callback, which calls
    ``command``), ``wake()``, ``recording_reset()``, ``recording_parameters(changes, t)`` (live
    changes taken at simulation time t), ``ok()`` (the ROS context is up).
    ``logger``: warning / error / info.

    ``settings``: time_mode, real_time_factor, steps_per_command, step_periods,
    realtime_priority.
    """

    def __init__(self, device, port, logger, settings):
        self.device = device
        self.port = port
        self.logger = logger
        self.mode = settings['time_mode']
        self.rtf = settings['real_time_factor']
        self.steps_per_command = int(settings['steps_per_command'])
        self.step_periods = int(settings.get('step_periods', 1))
        self.lock = threading.RLock()   # held while a thread works on the device
        self.priority = int(settings['realtime_priority'])
        self.stats = Stats()
        self.snapshot = {}
        self.last_row = None
        self.paused = False
        self._thread_priority = 0   # what the loop thread runs at now
        self._demoted = False       # fell > LAG_LIMIT behind: no SCHED_FIFO until retimed
        self._ahead = None          # realtime: the next period, computed but not yet published
        self._resync = True         # realtime: re-anchor the wall-clock schedule
        self._anchor_wall_ns = 0
        self._anchor_sim = 0.0
        self._snapshot_ns = 0
        self._polled_ns = 0         # fast mode: when the commands were last looked for
        self._queue = collections.deque()
        self._queue_lock = threading.Lock()
        self.wake_event = threading.Event()
        self.stopping = threading.Event()
        self._throttles = collections.defaultdict(Throttle)
        self._thread = threading.Thread(target=self._run, name='cvt_sim_loop', daemon=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self):
        if not self._thread.is_alive():
            self._thread.start()

    def stop(self, timeout=1.5):
        """Stop the loop thread; True if it ended within ``timeout`` [s]."""
        self.stopping.set()
        self.wake()
        if self._thread.is_alive():
            self._thread.join(timeout)
        return not self._thread.is_alive()

    @property
    def alive(self):
        return self._thread.is_alive()

    def wake(self):
        """Interrupt the loop's wait (a request, a new setting, stop)."""
        self.wake_event.set()
        self.port.wake()

    def retime(self, mode=None, rtf=None, priority=None):
        """A timing setting changed (executor thread): take it at the next pass."""
        if mode is not None:
            self.mode = mode
        if rtf is not None:
            self.rtf = rtf
        if priority is not None:
            self.priority = priority
        self._resync = True
        self._demoted = False
        self.wake()

    # ------------------------------------------------------------------ commands
    def grant(self, kind='crank'):
        """Control periods a command message advances now: a crank-length command in lockstep
        with steps_per_command; a load (disturbance) command never advances time."""
        return self.steps_per_command if self.mode == 'lockstep' and kind != 'load' else 0

    def held(self):
        """The simulation is held (lockstep or paused): commands and ~/step advance it."""
        return self.mode == 'lockstep' or self.paused

    def command(self, kind, value, grant):
        """A command message (loop thread, from ``port.wait_commands``): apply it (``kind``
        None: a refused one, the last valid command stays) from the next period on, then, held
        in lockstep, advance ``grant`` periods now."""
        with self.lock:
            if grant and self.held():
                self._drain()   # what the executor queued before it, first
            if kind == 'crank':
                self._command(self.device.command_crank_length, 'crank_length_cmd', value)
            elif kind == 'load':
                self._command(self.device.command_load_torque, 'load_torque_cmd', value)
            if grant and self.mode == 'lockstep' and not self.paused:
                self._advance_periods(grant)   # (~/pause suspends steps_per_command)

    def _command(self, apply, topic, value):
        try:
            apply(value)
        except CommandError as exc:   # the geometry changed after the command was checked
            self.logger.warning(f"{topic} dropped: {exc}")

    def step(self, n):
        """~/step while held (executor thread): advance ``n`` periods now; (success, text)."""
        with self.lock:
            self._drain()
            if self.device.fault or not self._advance_periods(n):
                return False, f"simulation fault: {self.device.fault}; call ~/reset"
            return True, self.device.state_text()

    def _advance_periods(self, n):
        """Held: advance and publish ``n`` periods (the caller holds the lock)."""
        for _ in range(n):
            if self.device.fault or self.stopping.is_set() or not self._period():
                return False
        return True

    def _period(self):
        """Advance one period and publish it, switches first (the caller holds the lock);
        False (fault reported) if the integration failed."""
        device = self.device
        row = device.advance_row()
        if row is None:
            self._report_fault()
            return False
        self._publish_events(device.events)
        self.port.publish_sample(row, device.crank_rate)
        self.last_row = row
        self.stats.samples += 1
        return True

    # ------------------------------------------------------------------ requests
    def request(self, entry):
        """Queue a request (params, reset, pause) for the loop thread, in arrival order."""
        with self._queue_lock:
            self._queue.append(entry)
        self.wake()

    def submit(self, kind, arg=None):
        """A service's request: queue it and wait for the loop to carry it out."""
        waiter = Waiter(arg)
        if not self._thread.is_alive():
            waiter.message = 'the simulation loop is not running'
            return waiter
        self.request((kind, waiter))
        waiter.done.wait(SERVICE_TIMEOUT_S)
        return waiter

    def warn(self, key, text, held_what=''):
        """A throttled warning: at most one per key per second, with the count held back."""
        log, held = self._throttles[key]()
        if log:
            more = f" ({held} more{held_what} since the last warning)" if held else ''
            self.logger.warning(text + more)

    def _pop(self):
        with self._queue_lock:
            return self._queue.popleft() if self._queue else None

    def _drain(self):
        """Carry out everything queued, in order (the caller holds the lock)."""
        while self._queue and not self.stopping.is_set():
            entry = self._pop()
            if entry is not None:
                self._apply(entry)

    # ------------------------------------------------------------------ the loop
    def _run(self):
        reduce_timer_slack()
        try:
            self._publish_present()
        except Exception:   # noqa: BLE001 — the context went down before the first sample
            if not self.port.ok():
                return
            raise
        while not self.stopping.is_set():
            try:
                self._iteration()
            except Exception as exc:   # noqa: BLE001 — a bug must not silently kill the device
                if self.stopping.is_set() or not self.port.ok():
                    break
                self.logger.error(f"simulation loop error: {exc!r}\n{traceback.format_exc()}")
                self.device.fault = f"internal error: {exc!r}"
                self._ahead = None
        self._close_queue('the node is shutting down')

    def _iteration(self):
        self.wake_event.clear()
        want = self.priority if (self.mode == 'realtime' and not self.paused
                                 and not self._demoted) else 0
        if want != self._thread_priority:
            self._set_thread_priority(want)
        if self.paused or self.mode == 'lockstep' or self.device.fault:
            with self.lock:
                self._flush_ahead()
                self._drain()
            self._resync = True
            if not (self._queue or self.stopping.is_set()):
                self.port.wait_commands(IDLE_WAIT_S)   # commands act in ``command``
        elif self.mode == 'fast':
            self._fast_batch()
            self._resync = True
        else:
            self._realtime_tick()
        now = time.monotonic_ns()
        if now - self._snapshot_ns >= STATS_PERIOD_NS:
            self.take_snapshot(now)

    def _fast_batch(self):
        """Fast mode: FAST_BATCH periods back to back; requests taken before each, command
        messages when FAST_POLL_NS of wall time has passed since the last look."""
        with self.lock:
            self._flush_ahead()
            for _ in range(FAST_BATCH):
                if self._queue:
                    self._drain()
                now = time.monotonic_ns()
                if now - self._polled_ns >= FAST_POLL_NS:
                    self._polled_ns = now
                    self.port.wait_commands(0.0)
                if not self.running() or not self._period():
                    break

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
                self.logger.warning(
                    f"no real-time scheduling (SCHED_FIFO priority {priority}: {exc}); the loop "
                    f"runs at normal priority and its jitter depends on the machine's load "
                    f"(set realtime_priority 0 to silence this)")

    def running(self):
        """The simulation runs free (realtime or fast, not paused, no fault, not stopping)."""
        return not (self.paused or self.device.fault or self.mode == 'lockstep'
                    or self.stopping.is_set())

    def _report_fault(self):
        self.logger.error(f"simulation stopped: {self.device.fault}; call ~/reset")

    def _realtime_tick(self):
        """Publish the period computed ahead at its wall-clock moments, then compute the next."""
        with self.lock:
            self._drain()
            self.port.wait_commands(0.0)
            if not self.running():
                return
            if self._ahead is None:
                self._ahead = self.device.advance()
                if self._ahead is None:
                    self._report_fault()
                    return
        period = self._ahead
        if self._resync:
            self._resync = False
            self._anchor_wall_ns = time.monotonic_ns()
            self._anchor_sim = period.t0
        while period.next_event < len(period.events):
            event = period.events[period.next_event]
            if not self._sleep_until(self._wall_ns(event.t)):
                return
            self._publish_switch(event)
            period.next_event += 1
        deadline = self._wall_ns(period.t)
        if not self._sleep_until(deadline):
            return
        late = time.monotonic_ns() - deadline
        self._publish_period(period)
        self._ahead = None
        stats = self.stats
        stats.jitter_ns.add(late)
        stats.lag_ns = late
        if late >= self.device.dt / self.rtf * 1e9:
            stats.missed += 1
            self.warn('schedule', f"behind schedule by {late / 1e6:.2f} ms at t = "
                                  f"{period.t:.4f} s: catching up ({stats.missed} missed "
                                  f"deadlines so far)")
        if late > LAG_LIMIT_NS:
            stats.resyncs += 1
            stats.slipped_ns += late
            self._resync = True
            self._anchor_sim = period.t
            # a real-time thread that cannot keep up would starve everything else on its core
            demote = self._thread_priority > 0
            self._demoted = True
            self.logger.warning(
                f"{late / 1e9:.3f} s behind schedule: simulation time gives that up and "
                f"re-anchors to the wall clock (stamps stay continuous)"
                + ('; the loop drops to normal scheduling until time_mode, real_time_factor, '
                   'publish_rate or realtime_priority is set again' if demote else ''))

    def _wall_ns(self, t):
        return self._anchor_wall_ns + int((t - self._anchor_sim) / self.rtf * 1e9)

    def _sleep_until(self, deadline_ns):
        """Wait for a monotonic-clock deadline: sleep, then spin the last SPIN_NS.
        False when woken for something else (pause, mode change, reset, stop)."""
        while True:
            remaining = deadline_ns - time.monotonic_ns()
            if remaining <= 0:
                return True
            if self.wake_event.is_set() or self.stopping.is_set():
                return False
            if remaining > SPIN_NS:
                self.wake_event.wait(min((remaining - SPIN_NS) * 1e-9, MAX_SLEEP_S))

    def _flush_ahead(self):
        """Leaving realtime mode: publish what the simulation has already computed."""
        if self._ahead is not None:
            period, self._ahead = self._ahead, None
            self._publish_period(period)

    def _apply(self, entry):
        """Carry out one queued request on the Device (loop thread, or the executor thread
        under the lock while held)."""
        kind = entry[0]
        device = self.device
        if kind == 'params':
            try:
                device.update_parameters(entry[1])
            except (ParameterError, GrashofError) as exc:
                self.logger.error(f"parameter change not applied: {exc}")
            else:   # the recording says what changed and when: analysis reads the rest with it
                self.port.recording_parameters(entry[1], device.t)
            self.take_snapshot(time.monotonic_ns())
        elif kind == 'reset':
            self._reset()
            entry[1].finish(True, f"reset to the scene's initial state: "
                                  f"{device.state_text()}")
        elif kind == 'pause':
            waiter = entry[1]
            self.paused = waiter.arg
            if self.paused:
                self._flush_ahead()
            self._resync = True
            waiter.finish(True, f"{'paused' if self.paused else 'running'}: "
                                f"{device.state_text()}")

    def _reset(self):
        self._ahead = None
        self.port.recording_reset()   # simulation time restarts at 0; log times go on
        try:
            self.device.reset()
        except (ParameterError, GrashofError, SimulationError):
            pass   # the device holds the fault until the next reset
        self.stats.resets += 1
        self._resync = True
        self._publish_present()
        self.take_snapshot(time.monotonic_ns())

    def _close_queue(self, message):
        """At the loop's end: parameter changes still queued are carried out at the last
        simulated time (their callers were told they were accepted, so the recording must
        hold them: a stop right after `ros2 param set` lost the change); waiting service
        calls fail with ``message``."""
        while True:
            entry = self._pop()
            if entry is None:
                return
            if entry[0] == 'params':
                with self.lock:
                    self._apply(entry)
            elif len(entry) == 2 and isinstance(entry[1], Waiter):
                entry[1].finish(False, message)

    # ------------------------------------------------------------------ publishing
    def _publish_period(self, period):
        """A computed-ahead period (realtime): its remaining switches, then its sample."""
        self._publish_events(period.events[period.next_event:])
        period.next_event = len(period.events)
        self.port.publish_sample(period.row, period.crank_rate)
        self.last_row = period.row
        self.stats.samples += 1

    def _publish_events(self, events):
        for event in events:
            self._publish_switch(event)

    def _publish_switch(self, event):
        self.port.publish_switch(event)
        self.stats.switches += 1
        self.stats.last_switch_t = event.t

    def _publish_present(self):
        period = self.device.present_state()
        self.port.publish_present(period)
        self.last_row = period.row
        self.stats.samples += 1

    def take_snapshot(self, now_ns):
        """Loop thread: what the diagnostics report about the simulation, every 250 ms."""
        snap = self.device.snapshot(self.last_row)
        snap.update(wall_ns=now_ns, samples=self.stats.samples, resets=self.stats.resets)
        self.snapshot = snap
        self._snapshot_ns = now_ns


__all__ = ['REALTIME_POLICY', 'RunLoop', 'Throttle', 'Waiter', 'reduce_timer_slack']
