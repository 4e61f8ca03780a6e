"""Benchmark of the ROS node (not a test): publish-rate accuracy, loop jitter and missed deadlines
at 1 kHz, and the top speed of fast mode. Prints a markdown table.

    cvt-sim bench node [--seconds 10] [--scene conveyor]

Each case starts ``cvt_node`` in its own process and ROS domain (discovery limited to this
machine) and watches it from a subscriber in this process:

* the node's own figures come from /diagnostics: lateness of each sample against its deadline on
  the monotonic clock (p50 / p99 over the last 4096 samples, worst window; max over the run),
  missed deadlines (samples published a whole period or more late) and step time;
* the subscriber's figures: samples received per wall second, simulation time per wall second,
  and the arrival jitter of the samples (arrival − scheduled time, minus the smallest such delay:
  what a controller in another process sees, including DDS and its own executor).
"""
import argparse
import os
import platform
import subprocess
import sys
import time

import numpy as np

from ..device import domains
from ..device.background_node import BackgroundNode

FLOOD_RATE = 10_000
_LEASES = []


def _domain():
    """A ROS domain of its own, held until this process ends (cvt_ros.device.domains)."""
    lease = domains.acquire()
    _LEASES.append(lease)
    return lease.domain


def _env(domain):
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    return env


class _Watcher(BackgroundNode):
    """Subscriber side: joint_states arrival times and stamps, diagnostics, /clock."""

    def __init__(self, domain):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState

        super().__init__('cvt_bench_watcher', domain)
        self.arrivals = []      # (monotonic ns, stamp ns)
        self.diagnostics = []   # (monotonic ns, {key: value})
        self.clock = None
        self.recording = False
        self.node.create_subscription(JointState, 'joint_states', self._on_joint_states,
                                      QoSProfile(depth=1000))
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                      QoSProfile(depth=10))
        self.node.create_subscription(
            Clock, '/clock', self._on_clock,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.start()

    def _on_joint_states(self, msg):
        now = time.monotonic_ns()
        if self.recording:
            with self.lock:
                self.arrivals.append(
                    (now, msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec))
        self.seen = True

    def _on_diagnostics(self, msg):
        values = {kv.key: kv.value for kv in msg.status[0].values}
        with self.lock:
            self.diagnostics.append((time.monotonic_ns(), values))

    def _on_clock(self, msg):
        self.clock = (time.monotonic_ns(), msg.clock.sec + msg.clock.nanosec * 1e-9)

    def wait_diagnostics(self, count, timeout):
        end = time.monotonic() + timeout
        n0 = len(self.diagnostics)
        while len(self.diagnostics) < n0 + count:
            if time.monotonic() > end:
                raise TimeoutError('no diagnostics from the node')
            time.sleep(0.01)
        return self.diagnostics[-1][1]


def _agg(fn, values):
    """``fn`` over the finite values (nan when there are none, e.g. jitter in fast mode)."""
    finite = [v for v in values if np.isfinite(v)]
    return float(fn(finite)) if finite else float('nan')


def _float(values, key):
    try:
        return float(values[key])
    except (KeyError, ValueError):
        return float('nan')


def run_case(name, parameters, seconds, scene, flood=False, warmup=2.0):
    """One node run; returns a dict of figures."""
    domain = _domain()
    cmd = [sys.executable, '-m', 'cvt_ros.device', '--scene', scene, '--ros-args']
    for key, value in parameters.items():
        cmd += ['-p', f'{key}:={value}']
    node = subprocess.Popen(cmd, env=_env(domain), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    watcher = _Watcher(domain)
    flooder = None
    try:
        watcher.wait_diagnostics(1, 60.0)
        time.sleep(warmup)   # past start-up (discovery, first allocations)
        if flood:
            flooder = subprocess.Popen(
                [sys.executable, '-m', 'cvt_ros.bench.node', '--flood', str(seconds + 2)],
                env=_env(domain), stdout=subprocess.DEVNULL)
            time.sleep(1.0)
        start = watcher.wait_diagnostics(1, 5.0)
        n_diag = len(watcher.diagnostics)
        clock0 = watcher.clock
        watcher.recording = True
        time.sleep(seconds)
        watcher.recording = False
        clock1 = watcher.clock
        end = watcher.wait_diagnostics(1, 5.0)
        windows = [v for _, v in watcher.diagnostics[n_diag:]]
    finally:
        if flooder is not None:
            flooder.wait(seconds + 30)
        watcher.close()
        node.send_signal(2)
        try:
            node.wait(10)
        except subprocess.TimeoutExpired:
            node.kill()
    arrivals = np.array(watcher.arrivals, dtype=np.int64)
    out = {'case': name, 'seconds': seconds}
    missed = int(_float(end, 'missed_deadlines') - _float(start, 'missed_deadlines'))
    samples = int(_float(end, 'samples_published') - _float(start, 'samples_published'))
    out['missed'] = missed
    out['samples'] = samples
    out['node_p50'] = _agg(np.median, [_float(w, 'jitter_p50_us') for w in windows])
    out['node_p99'] = _agg(np.max, [_float(w, 'jitter_p99_us') for w in windows])
    out['node_max'] = _agg(np.max, [_float(w, 'jitter_max_us') for w in windows])
    out['step_p50'] = _agg(np.median, [_float(w, 'step_time_p50_us') for w in windows])
    out['step_p99'] = _agg(np.max, [_float(w, 'step_time_p99_us') for w in windows])
    out['refused'] = int(_float(end, 'commands_refused') - _float(start, 'commands_refused'))
    out['received'] = int(_float(end, 'commands_received') - _float(start, 'commands_received'))
    if clock0 and clock1 and clock1[0] > clock0[0]:
        out['rtf'] = (clock1[1] - clock0[1]) / ((clock1[0] - clock0[0]) * 1e-9)
    else:
        out['rtf'] = float('nan')
    if len(arrivals) > 2:
        wall = (arrivals[-1, 0] - arrivals[0, 0]) * 1e-9
        out['rate'] = (len(arrivals) - 1) / wall
        rtf = parameters.get('real_time_factor', 1.0)
        delay = arrivals[:, 0] - arrivals[:, 1] / rtf   # arrival − scheduled, up to a constant
        delay = (delay - delay.min()) / 1e3
        out['sub_p50'], out['sub_p99'] = np.percentile(delay, [50, 99])
        out['sub_max'] = float(delay.max())
        out['gaps'] = int(np.sum(np.diff(arrivals[:, 1]) != np.median(np.diff(arrivals[:, 1]))))
    return out


def _flood_main(seconds):
    """A command flood from its own process: FLOOD_RATE crank-length commands per second,
    every third one invalid (NaN)."""
    import rclpy
    from rclpy.node import Node
    from std_msgs.msg import Float64
    rclpy.init()
    node = Node('cvt_bench_flood')
    pub = node.create_publisher(Float64, 'crank_length_cmd', 10)
    end = time.monotonic() + 10
    while pub.get_subscription_count() == 0 and time.monotonic() < end:
        time.sleep(0.01)
    cycle = [Float64(data=0.04), Float64(data=0.041), Float64(data=float('nan'))]
    period = 1e9 / FLOOD_RATE
    t0 = time.monotonic_ns()
    for i in range(int(FLOOD_RATE * seconds)):
        ahead = t0 + i * period - time.monotonic_ns()
        if ahead > 500_000:
            time.sleep(ahead * 1e-9)
        pub.publish(cycle[i % 3])
    node.destroy_node()
    rclpy.try_shutdown()


def _machine():
    model = ''
    try:
        with open('/proc/cpuinfo') as f:
            model = next((line.split(':', 1)[1].strip() for line in f
                          if line.startswith('model name')), '')
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else float('nan')
    return (f"{os.cpu_count()} CPUs ({model or platform.machine()}), Python "
            f"{platform.python_version()}, load average {load:.2f} at the start")


def _fmt(value, digits=0):
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return '–'
    return f"{value:.{digits}f}"


def main(argv=None):
    parser = argparse.ArgumentParser(prog='cvt-sim bench node',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=10.0, help='measured window per case')
    parser.add_argument('--scene', default='conveyor')
    parser.add_argument('--case', action='append', choices=('fifo', 'normal', 'flood', 'fast'),
                        help='run only these cases (repeatable; default: all)')
    parser.add_argument('--flood', type=float, default=None, help=argparse.SUPPRESS)
    options = parser.parse_args(argv)
    if options.flood is not None:
        _flood_main(options.flood)
        return 0
    s = options.seconds
    print(f"Machine: {_machine()}. Scene: {options.scene}. Measured window: {s:g} s per case.\n")
    cases = set(options.case or ('fifo', 'normal', 'flood', 'fast'))
    realtime = [
        ('fifo', 'realtime 1 kHz, SCHED_FIFO 50 (default)', {}, False),
        ('normal', 'realtime 1 kHz, normal scheduling', {'realtime_priority': 0}, False),
        ('flood', f'realtime 1 kHz + {FLOOD_RATE} cmd/s flood', {}, True),
    ]
    print('| case | samples/s received (target 1000) | sim s / wall s | node lateness '
          'p50 / p99 / max [µs] | missed deadlines | step time p50 / p99 [µs] | subscriber '
          'arrival jitter p50 / p99 / max [µs] | commands taken / refused |')
    print('|---|---|---|---|---|---|---|---|')
    for key, name, params, flood in realtime:
        if key not in cases:
            continue
        r = run_case(name, params, s, options.scene, flood=flood)
        cmds = f"{r['received']} / {r['refused']}" if flood else '–'
        print(f"| {name} | {_fmt(r.get('rate'), 1)} | {_fmt(r['rtf'], 4)} | "
              f"{_fmt(r['node_p50'], 1)} / {_fmt(r['node_p99'], 1)} / {_fmt(r['node_max'])} | "
              f"{r['missed']} of {r['samples']} | {_fmt(r['step_p50'], 1)} / "
              f"{_fmt(r['step_p99'], 1)} | {_fmt(r.get('sub_p50'))} / {_fmt(r.get('sub_p99'))} "
              f"/ {_fmt(r.get('sub_max'))} | {cmds} |", flush=True)
    if 'fast' not in cases:
        return 0
    print('\n| fast mode, publish_rate | s of simulation per wall s | samples/s published | '
          'step time p50 / p99 [µs] |')
    print('|---|---|---|---|')
    for rate in (1000, 100):
        r = run_case('fast', {'time_mode': 'fast', 'publish_rate': float(rate)}, s,
                     options.scene)
        wall = r['samples'] / r['rtf'] / rate if r['rtf'] > 0 else float('nan')
        print(f"| {rate} Hz (joint_states and /clock every {1000 / rate:g} ms of simulation) | "
              f"{_fmt(r['rtf'], 1)} | {_fmt(r['samples'] / wall if wall > 0 else None)} | "
              f"{_fmt(r['step_p50'], 1)} / {_fmt(r['step_p99'], 1)} |", flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
