"""Benchmark of the device (not a test): the throughput and timing targets of issue 10, measured
in one run, with the machine's load. Prints markdown; ``--write`` puts it into BENCHMARKS.md
(section "ROS node", the other sections are kept).

    cvt-sim bench node [--seconds 5] [--repeat 3] [--case inprocess lockstep fast realtime]
                       [--scene conveyor] [--write FILE]

Cases (each ``cvt_node`` in its own process and ROS domain, discovery limited to this machine):

* ``inprocess``: lockstep with the controller a Python callable, no DDS (the Device as the
  controller kit's in-process back end drives it): a PI speed controller at 1 kHz commands the
  crank every period; simulated s per wall s, and the cost of each piece of a period.
* ``lockstep``: ``time_mode lockstep``, ``steps_per_command 1``, an rclpy PI controller in
  another process (subscribes ``state``, publishes ``crank_length_cmd``: docs/lockstep.md) at a
  1 ms and a 10 ms control period; simulated s per wall s of the round trips, CPU of both
  processes. Two controllers: the docs' example as written (rclpy.spin, a default Node), and the
  same law in a lean node (no parameter services, Fast DDS synchronous publication) whose thread
  waits on its state subscription itself (``cvt_ros.device.subscription_wait``, docs/lockstep.md)
  instead of an executor pass per sample, reads the samples' bytes
  (``interface.JointStateDecoder``) and publishes its commands' (``interface.float64_cdr``)
  instead of rclpy's message objects. Beside them the floor:
  the same round trips between two rclpy processes that only bounce a Float64 (no device, no
  controller law). Each controller runs twice: as the scheduler places the two processes, and
  with both on one CPU (``taskset -c N``; in lockstep one of them works at a time, and a hand-over
  within one CPU is a context switch where across two it is an interrupt that wakes the other —
  on a virtual machine the costlier of the two, docs/lockstep.md).
* ``fast``: ``time_mode fast`` at 1 kHz and 100 Hz publishing, a subscriber to joint_states and
  /clock in another process; simulated s per wall s and the node's CPU (share of one core).
* ``realtime``: 1 kHz, 10 s (``--seconds`` × 2): share of periods published on time (less than
  one period late: the node's own account, /diagnostics), share of samples a subscriber in
  another process received (distinct stamps); idle and with two busy processes beside it.
"""
import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from ..device import domains
from .report import cpu_model, replace_section, revision_and_date

SECTION = '## ROS node'
PI_TARGET, PI_KP, PI_KI = 60.0, 2e-4, 2e-3    # rad/s, m per rad/s, m per rad (docs/lockstep.md)
_LEASES = []


# ------------------------------------------------------------------ processes
def _domain():
    """A ROS domain of its own, held until this process ends (cvt_ros.device.domains)."""
    lease = domains.acquire()
    _LEASES.append(lease)
    return lease.domain


def _env(domain, **extra):
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1', **extra)
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    return env


def _cpu_s(pid):
    """CPU time [s] a process has used (user + system), from /proc."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _on_cpu(cpu):
    """A Popen preexec_fn that runs the child on one CPU (``taskset -c cpu``), or None."""
    return None if cpu is None else (lambda: os.sched_setaffinity(0, {cpu}))


def lockstep_cpu():
    """The CPU the pinned lockstep cases share: the last this process may run on."""
    return max(os.sched_getaffinity(0))


class Node:
    """``cvt_node`` with ``parameters`` in its own process and domain (on ``cpu`` alone if
    given)."""

    def __init__(self, parameters, scene='conveyor', cpu=None):
        self.domain = _domain()
        cmd = [sys.executable, '-m', 'cvt_ros.device', '--scene', scene, '--ros-args']
        for key, value in parameters.items():
            cmd += ['-p', f'{key}:={value}']
        self.proc = subprocess.Popen(cmd, env=_env(self.domain), stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, preexec_fn=_on_cpu(cpu))

    def cpu(self):
        return _cpu_s(self.proc.pid)

    def close(self):
        self.proc.send_signal(2)
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class Busy:
    """``n`` CPU-bound processes (a loaded machine), started and stopped by PID."""

    def __init__(self, n):
        self.procs = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
                      for _ in range(n)]

    def close(self):
        for p in self.procs:
            p.kill()
        for p in self.procs:
            p.wait()


# ------------------------------------------------------------------ in process
def inprocess(seconds, fidelity='full', method='rk4', paths=None, scene='conveyor'):
    """Lockstep with a Python PI controller, no DDS: Device.command_crank_length +
    Device.advance_row per period, as the controller kit's in-process back end does
    (``paths``: the scene's paths.count, if given)."""
    from ..device.core import Device
    from ..scene import load_scene
    from ..solver import advance_layout as AL
    from ..solver import hybrid
    from ..solver.output import COL

    values = load_scene(scene, {'solver.method': method, 'model.fidelity': fidelity,
                                **({'paths.count': paths} if paths else {})})
    dt = 1e-3
    w4 = COL['omega4']
    device = Device(values, dt)
    for _ in range(2000):           # past start-up, kernels loaded
        device.advance_row()
    device.reset()
    n = int(seconds / dt)
    row = device.present_state().row
    integral = 0.0
    t0 = time.perf_counter()
    for _ in range(n):
        error = PI_TARGET - row[w4]
        integral += error * dt
        device.command_crank_length(min(max(0.04 + PI_KP * error + PI_KI * integral, 0.0), 0.09))
        row = device.advance_row()
    wall = time.perf_counter() - t0
    # the pieces of a period, each timed on its own over the same kind of run
    sim, stepper = device.sim, device.stepper
    pieces = {}
    k = min(n, 5000)
    t0 = time.perf_counter()
    for i in range(k):
        device.command_crank_length(0.04 + 1e-7 * (i % 9 + 1))
    pieces['crank command (checked, profile planned, compiled)'] = (time.perf_counter() - t0) / k
    t0 = time.perf_counter()
    for _ in range(k):
        stepper.advance()
    pieces['period: one compiled advance-and-sample call'] = (time.perf_counter() - t0) / k
    if fidelity != 'averaged' and sim.n_paths == 1:
        args = (sim.y, sim.ms, sim.P, sim.ACT, sim.LIN, sim.S, sim.h_io, sim._empty_grid,
                sim._empty_out, sim._events_buf, sim.counters, sim.ledger, sim._scratch)
        steps0, rhs0 = int(sim.counters[AL.C_STEPS]), int(sim.counters[AL.C_RHS])
        t0 = time.perf_counter()
        for _ in range(k):
            sim.t = hybrid.advance(sim.t, sim.t + dt, *args)
            sim.counters[AL.C_EVENTS] = 0
        pieces['of which the core integration alone (hybrid.advance)'] = \
            (time.perf_counter() - t0) / k
        pieces['  (steps, right-hand sides per period)'] = (
            (int(sim.counters[AL.C_STEPS]) - steps0) / k, (int(sim.counters[AL.C_RHS]) - rhs0) / k)
    return {'periods': n, 'wall': wall, 'rtf': n * dt / wall, 'per_period': wall / n,
            'pieces': pieces}


# ------------------------------------------------------------------ lockstep over DDS
def controller_main(argv):
    """The controller process: an rclpy PI on ``state``, publishing ``crank_length_cmd``; prints
    one JSON line with the periods, wall and CPU time from its first sample."""
    periods, dt, lean = int(argv[0]), float(argv[1]), argv[2] == 'lean'
    import rclpy
    from rclpy.node import Node as RclNode
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from ..interface import float64_cdr

    class Controller(RclNode):
        def __init__(self):
            if lean:   # no parameter or type-description services: a smaller wait set
                super().__init__('bench_controller', start_parameter_services=False,
                                 parameter_overrides=[
                                     Parameter('start_type_description_service', value=False)])
            else:
                super().__init__('bench_controller')
            self.integral = 0.0
            self.count = 0
            self.start = None
            self.command_publisher = self.create_publisher(Float64, 'crank_length_cmd', 10)
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            if lean:   # the samples' bytes, read by one struct call (no rclpy message object)
                from ..interface import JointStateDecoder
                decode = JointStateDecoder().decode
                self.state_subscription = self.create_subscription(
                    JointState, 'state', lambda data: self.state_callback(decode(data)[2]),
                    latched, raw=True)
            else:
                self.state_subscription = self.create_subscription(
                    JointState, 'state', lambda msg: self.state_callback(msg.velocity), latched)

        def state_callback(self, velocity):
            if self.start is None:
                self.start = (time.perf_counter(), time.process_time())
                print('started', flush=True)   # the bench takes the node's CPU from here
            error = PI_TARGET - velocity[3]
            self.integral += error * dt
            crank = min(max(0.04 + PI_KP * error + PI_KI * self.integral, 0.0), 0.09)
            self.count += 1
            if self.count > periods:
                raise SystemExit
            # lean: the command's CDR bytes (Publisher.publish takes bytes; no message object)
            self.command_publisher.publish(float64_cdr(crank) if lean else Float64(data=crank))

    rclpy.init()
    node = Controller()
    try:
        if lean:   # its own wait on the one subscription: no executor pass per sample
            from ..device.subscription_wait import SubscriptionWait
            wait = SubscriptionWait(node.context, [node.state_subscription])
            while True:
                wait.wait(1.0)
        else:
            rclpy.spin(node)
    except SystemExit:
        pass
    wall, cpu = time.perf_counter() - node.start[0], time.process_time() - node.start[1]
    print(json.dumps({'periods': periods, 'wall': wall, 'cpu': cpu}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def lockstep(seconds, period, lean, cpu=None):
    """Round trips node ↔ controller process for ``seconds`` of simulation (``period`` [s]);
    ``cpu``: both processes on that one CPU."""
    node = Node({'time_mode': 'lockstep', 'steps_per_command': 1,
                 'publish_rate': 1.0 / period}, cpu=cpu)
    try:
        env = _env(node.domain, **({'RMW_FASTRTPS_PUBLICATION_MODE': 'SYNCHRONOUS'} if lean
                                   else {}))
        periods = int(round(seconds / period))
        cmd = [sys.executable, '-m', 'cvt_ros.bench.node', '--controller', str(periods),
               repr(period), 'lean' if lean else 'docs']
        controller = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True, preexec_fn=_on_cpu(cpu))
        cpu0 = math.nan
        for line in controller.stdout:   # the node's CPU from the first round trip on
            if line.strip() == 'started':
                cpu0 = node.cpu()
                break
        rest, err = controller.communicate(timeout=600)
        node_cpu = node.cpu() - cpu0
    finally:
        node.close()
    lines = [ln for ln in rest.splitlines() if ln.startswith('{')]
    if not lines:
        raise RuntimeError(f"the controller gave no result: {err[-500:]}")
    r = json.loads(lines[-1])
    r.update(rtf=r['periods'] * period / r['wall'], round_trip=r['wall'] / r['periods'],
             node_cpu=node_cpu / r['wall'], controller_cpu=r['cpu'] / r['wall'])
    return r


# ------------------------------------------------------------------ the floor: DDS alone
def pingpong_main(argv):
    """One side of a Float64 ping-pong between two rclpy processes, no work in between: the
    lean controller's way of waiting (its own wait set), synchronous publication. ``ping N``
    sends, waits for each answer and prints one JSON line (round trips, wall, CPU); ``pong``
    answers until a negative value comes."""
    role, rounds = argv[0], int(argv[1])
    import rclpy
    from rclpy.node import Node as RclNode
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64

    from ..device.subscription_wait import SubscriptionWait
    rclpy.init()
    node = RclNode(f'bench_{role}', start_parameter_services=False, parameter_overrides=[
        Parameter('start_type_description_service', value=False)])
    got = []
    publisher = node.create_publisher(Float64, 'ping' if role == 'ping' else 'pong', 10)
    subscription = node.create_subscription(Float64, 'pong' if role == 'ping' else 'ping',
                                            lambda msg: got.append(msg.data), 10)
    wait = SubscriptionWait(node.context, [subscription])

    def answer():
        while not got:
            wait.wait(1.0)
        return got.pop()
    if role == 'ping':
        while publisher.get_subscription_count() == 0 or subscription.get_publisher_count() == 0:
            wait.wait(0.01)
        for i in range(200):                 # past discovery's own traffic
            publisher.publish(Float64(data=float(i)))
            answer()
        t0, c0 = time.perf_counter(), time.process_time()
        for i in range(rounds):
            publisher.publish(Float64(data=float(i)))
            answer()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        publisher.publish(Float64(data=-1.0))
        print(json.dumps({'rounds': rounds, 'wall': wall, 'cpu': cpu}), flush=True)
    else:
        while (value := answer()) >= 0.0:
            publisher.publish(Float64(data=value))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def pingpong(rounds, cpu=None):
    """Round trips of the DDS floor (``pingpong_main``) in a domain of its own (``cpu``: both
    processes on that one CPU)."""
    env = _env(_domain(), RMW_FASTRTPS_PUBLICATION_MODE='SYNCHRONOUS')
    cmd = [sys.executable, '-m', 'cvt_ros.bench.node', '--pingpong']
    pong = subprocess.Popen(cmd + ['pong', '0'], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, preexec_fn=_on_cpu(cpu))
    try:
        ping = subprocess.run(cmd + ['ping', str(rounds)], env=env, capture_output=True,
                              text=True, timeout=600, preexec_fn=_on_cpu(cpu))
    finally:
        try:
            pong.wait(30)
        except subprocess.TimeoutExpired:
            pong.kill()
            pong.wait()
    lines = [ln for ln in ping.stdout.splitlines() if ln.startswith('{')]
    if not lines:
        raise RuntimeError(f"the ping-pong gave no result: {ping.stderr[-500:]}")
    r = json.loads(lines[-1])
    r.update(round_trip=r['wall'] / r['rounds'], rtf=1e-3 * r['rounds'] / r['wall'],
             ping_cpu=r['cpu'] / r['wall'])
    return r


# ------------------------------------------------------------------ free-running modes
class Watcher:
    """A subscriber in this process (another process than the node's): joint_states stamps,
    /clock, /diagnostics."""

    def __init__(self, domain):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState

        from ..device.background_node import BackgroundNode
        self.bg = BackgroundNode('cvt_bench_watcher', domain)
        self.stamps = []
        self.clock = None
        self.diagnostics = []
        self.recording = False
        node = self.bg.node
        node.create_subscription(JointState, 'joint_states', self._on_sample,
                                 QoSProfile(depth=1000))
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                 QoSProfile(depth=10))
        node.create_subscription(Clock, '/clock', self._on_clock,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.bg.start()

    def _on_sample(self, msg):
        if self.recording:
            self.stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)

    def _on_clock(self, msg):
        self.clock = (time.monotonic(), msg.clock.sec + msg.clock.nanosec * 1e-9)

    def _on_diagnostics(self, msg):
        self.diagnostics.append({kv.key: kv.value for kv in msg.status[0].values})

    def wait_diagnostics(self, timeout=120.0):
        """The next /diagnostics report's values."""
        n = len(self.diagnostics)
        end = time.monotonic() + timeout
        while len(self.diagnostics) <= n:
            if time.monotonic() > end:
                raise TimeoutError('no /diagnostics from the node')
            time.sleep(0.01)
        return self.diagnostics[-1]

    def close(self):
        self.bg.close()


def fast(seconds, rate):
    """Fast mode with ``rate`` Hz publishing: simulated s per wall s, node CPU."""
    node = Node({'time_mode': 'fast', 'publish_rate': float(rate)})
    watcher = Watcher(node.domain)
    try:
        watcher.wait_diagnostics()
        time.sleep(1.0)
        clock0, cpu0 = watcher.clock, node.cpu()
        watcher.recording = True
        time.sleep(seconds)
        watcher.recording = False
        clock1, cpu1 = watcher.clock, node.cpu()
    finally:
        watcher.close()
        node.close()
    wall = clock1[0] - clock0[0]
    return {'rtf': (clock1[1] - clock0[1]) / wall, 'node_cpu': (cpu1 - cpu0) / wall,
            'received': len(watcher.stamps) / wall}


def realtime(seconds, busy=0, scene='conveyor'):
    """Realtime 1 kHz: periods on time (node's account), samples a subscriber received."""
    load = Busy(busy) if busy else None
    node = Node({}, scene)
    watcher = Watcher(node.domain)
    try:
        watcher.wait_diagnostics()
        time.sleep(1.0)
        before = watcher.wait_diagnostics()
        watcher.recording = True
        time.sleep(seconds)
        after = watcher.wait_diagnostics()
        time.sleep(0.5)   # the last samples in flight
        watcher.recording = False
    finally:
        watcher.close()
        node.close()
        if load is not None:
            load.close()
    stamps = sorted(set(watcher.stamps))
    published = int(after['samples_published']) - int(before['samples_published'])
    missed = int(after['missed_deadlines']) - int(before['missed_deadlines'])
    # the subscriber's share over the stretch it listened: distinct stamps / periods spanned
    spanned = (stamps[-1] - stamps[0]) // 1_000_000 + 1 if stamps else 0
    return {'published': published, 'missed': missed,
            'on_time': 1.0 - missed / published if published else math.nan,
            'received': len(stamps) / spanned if spanned else 0.0,
            'resyncs': int(after['resyncs']) - int(before['resyncs']),
            'jitter_p99_us': float(after['jitter_p99_us'])}


# ------------------------------------------------------------------ report
def _best_median(runs, key, fmt):
    """'best× (median×)' of the ``key`` figures of ``runs`` (one run: just it). The best run is
    the one the machine's other jobs disturbed least; the median says how much they did."""
    values = sorted(r[key] for r in runs)
    best = f"{values[-1]:{fmt}}×"
    if len(values) == 1:
        return best
    middle = len(values) // 2
    median = values[middle] if len(values) % 2 else 0.5 * (values[middle - 1] + values[middle])
    return f"{best} ({median:{fmt}}×)"


def _pct(x):
    return '–' if x is None or not math.isfinite(x) else f"{100 * x:.2f} %"


def _machine():
    return f"{os.cpu_count()} CPUs ({cpu_model() or platform.machine()}), Python " \
           f"{platform.python_version()}"


def _load():
    return ' / '.join(f"{x:.2f}" for x in os.getloadavg())


def run(options, out):
    cases = options.case
    s = options.seconds
    revision, date = revision_and_date()
    out(f"Command: `{options.command}` (at revision {revision}, {date}). "
        f"Machine: {_machine()}; load average (1/5/15 min) "
        f"{_load()} at the start. Scene {options.scene}, control period 1 ms unless said; the "
        f"node's own solver: dopri5 in lockstep and fast, rk4 in realtime (docs/node.md).\n")
    if 'inprocess' in cases:
        out('### In-process lockstep (controller = Python callable, no DDS; target ≥ 200×)\n')
        out(f'| model.fidelity | solver.method | simulated s / wall s, best of {options.repeat} '
            f'(median) | µs per period (best) |')
        out('|---|---|---|---|')
        details = {}
        for fidelity, method in (('full', 'dopri5'), ('full', 'rk4'), ('rigid_shaft', 'dopri5'),
                                 ('averaged', 'rk4')):
            try:
                runs = [inprocess(max(s, 2.0), fidelity, method, scene=options.scene)
                        for _ in range(options.repeat)]
            except ValueError as exc:   # (SceneError: e.g. averaged with N ≥ 2 paths)
                out(f"| {fidelity} | {method} | not with this scene: {str(exc)[:120]} | – |")
                continue
            r = min(runs, key=lambda x: x['wall'])
            details[fidelity, method] = r['pieces']
            out(f"| {fidelity} | {method} | {_best_median(runs, 'rtf', '.0f')} | "
                f"{r['per_period'] * 1e6:.1f} |")
        out('\ndopri5 is the solver of lockstep, the node\'s and the controller kit\'s in-process '
            'back end\'s (the scenario\'s solver, dopri5 unless it says otherwise): error-'
            'controlled, the offline answer. rk4 is the node\'s solver when it starts in realtime '
            '(a fixed cost per period, for a deadline); the averaged model always steps with rk4.')
        methods = [m for m in ('dopri5', 'rk4') if ('full', m) in details]
        if methods:
            out('\nCost of the pieces of a period (full model, µs):\n')
            out('| piece | ' + ' | '.join(methods) + ' |')
            out('|---|' + '---|' * len(methods))
            for name in details['full', methods[0]]:
                cells = [(f"{v[0]:.2f} steps, {v[1]:.1f} evaluations" if isinstance(v, tuple)
                          else f"{v * 1e6:.2f}")
                         for v in (details['full', m][name] for m in methods)]
                out(f"| {name} | {' | '.join(cells)} |")
        out('')
    if 'lockstep' in cases:
        out('### Lockstep over DDS, controller in another process (target ≥ 3× at 1 ms, '
            '≥ 25× at 10 ms)\n')
        out(f'| control period | controller | simulated s / wall s, best of {options.repeat} '
            f'(median) | round trip [µs] (best) | node CPU | controller CPU |')
        out('|---|---|---|---|---|---|')
        cpu = lockstep_cpu()
        for period in (1e-3, 1e-2):
            for pinned in (None, cpu):
                for lean in (False, True):
                    runs = [lockstep(max(s, 2.0) * (1 if period < 5e-3 else 5), period, lean,
                                     pinned) for _ in range(options.repeat)]
                    r = min(runs, key=lambda x: x['round_trip'])
                    who = ('lean rclpy node: its own wait set, raw samples and commands, '
                           'synchronous publication' if lean
                           else 'docs/lockstep.md example (rclpy.spin)')
                    if pinned is not None:
                        who += f'; both processes on one CPU (`taskset -c {pinned}`)'
                    out(f"| {period * 1e3:g} ms | {who} | {_best_median(runs, 'rtf', '.2f')} | "
                        f"{r['round_trip'] * 1e6:.0f} | {_pct(r['node_cpu'])} | "
                        f"{_pct(r['controller_cpu'])} |")
        for pinned in (None, cpu):
            runs = [pingpong(int(max(s, 2.0) * 1000), pinned) for _ in range(options.repeat)]
            r = min(runs, key=lambda x: x['round_trip'])
            where = '' if pinned is None else f'; both on one CPU (`taskset -c {pinned}`)'
            out(f"| (1 ms) | the floor: no device — two rclpy processes bounce a Float64, "
                f"waiting as the lean controller does{where} | "
                f"{_best_median(runs, 'rtf', '.2f')} | {r['round_trip'] * 1e6:.0f} | – | "
                f"{_pct(r['ping_cpu'])} (one side) |")
        out('')
    if 'fast' in cases:
        out('### Fast mode (target ≥ 90 % of a core; ≥ 5× at 1 kHz publishing, ≥ 50× at '
            '100 Hz)\n')
        out('| publish_rate | simulated s / wall s | node CPU (one core = 100 %) | '
            'samples/s a subscriber received |')
        out('|---|---|---|---|')
        for rate in (1000, 100):
            r = fast(s, rate)
            out(f"| {rate} Hz | {r['rtf']:.1f}× | {_pct(r['node_cpu'])} | "
                f"{r['received']:.0f} |")
        out('')
    if 'realtime' in cases:
        out('### Realtime 1 kHz (targets idle: ≥ 99.9 % on time, ≥ 99 % received)\n')
        out('| machine | periods on time | samples received (another process) | missed / '
            'published | resyncs | node lateness p99 [µs] |')
        out('|---|---|---|---|---|---|')
        for busy in (0, 2):
            r = realtime(2 * s, busy, options.scene)
            who = 'as it is' if not busy else '+ two busy processes'
            out(f"| {who} (load {_load().split(' / ')[0]}) | {_pct(r['on_time'])} | "
                f"{_pct(r['received'])} | {r['missed']} / {r['published']} | {r['resyncs']} | "
                f"{r['jitter_p99_us']:.0f} |")
        out('')
    out(f"Load average at the end: {_load()}.\n")


def main(argv=None):
    parser = argparse.ArgumentParser(prog='cvt-sim bench node',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=5.0,
                        help='simulated seconds (in-process, lockstep) or wall seconds (fast, '
                             'realtime: twice this) per case (default 5)')
    parser.add_argument('--case', nargs='+', default=['inprocess', 'lockstep', 'fast',
                                                      'realtime'],
                        choices=('inprocess', 'lockstep', 'fast', 'realtime'))
    parser.add_argument('--repeat', type=int, default=3,
                        help='runs of each in-process and lockstep case: the best is reported, '
                             'the median beside it (default 3)')
    parser.add_argument('--scene', default='conveyor',
                        help='the scene of the in-process and realtime cases (default conveyor; '
                             'e.g. conveyor_4path)')
    parser.add_argument('--write', metavar='FILE', help='put the tables into FILE (section '
                        f'"{SECTION[3:]}"), e.g. BENCHMARKS.md')
    parser.add_argument('--controller', nargs=3, help=argparse.SUPPRESS)
    parser.add_argument('--pingpong', nargs=2, help=argparse.SUPPRESS)
    options = parser.parse_args(argv)
    if options.controller:
        return controller_main(options.controller)
    if options.pingpong:
        return pingpong_main(options.pingpong)
    options.command = './run.sh bench node ' + ' '.join(argv if argv is not None
                                                         else sys.argv[1:])
    lines = []

    def out(text):
        print(text, flush=True)
        lines.append(text)
    run(options, out)
    if options.write:
        replace_section(options.write, SECTION, f"{SECTION}\n\n" + '\n'.join(lines))
        print(f"written to {options.write} (section {SECTION[3:]!r})", file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
