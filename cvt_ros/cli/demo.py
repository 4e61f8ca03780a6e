"""``cvt-sim demo``: the paper's scene offline, then the ROS node driven by a scripted controller.

    cvt-sim demo [--scene conveyor] [--real-time-factor 2]

Starts ``cvt_node`` on the scene in a subprocess (its own ROS domain, discovery limited to this
machine), then, as a controller in another process would: a crank-length step (0.04 → 0.06 m) at
3 s, a NaN command (refused, the last valid command stays) at 6 s, a load step (8 → 14 N·m) at
8 s. Prints what happened per phase, beside the offline core's prediction for the same commands.
"""
import math
import os
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from ..device import domains
from ..device.background_node import BackgroundNode

CRANK_STEP = (3.0, 0.06)      # (simulation time [s], crank length [m])
BAD_COMMAND = 6.0             # a NaN crank length, to show the refusal
LOAD_STEP = (8.0, 14.0)       # (simulation time [s], load torque [N·m])
END = 12.0
DT = 1e-3
PHASES = (('before the steps', 1.5, 3.0), ('after the crank step', 6.0, 8.0),
          ('after the load step', 10.0, 12.0))


class _Controller(BackgroundNode):
    """The demo's controller node: watches the device and sends the scripted commands."""

    def __init__(self, domain):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64

        self.Float64 = Float64
        super().__init__('cvt_demo_controller', domain)
        self.samples = []        # (t, ω1, ω4, shaft torque)
        self.switch_times = []   # simulation time at which each clutch_engaged message arrived
        self.diagnostics = {}
        self.now = -1.0
        self.node.create_subscription(JointState, 'joint_states', self._on_joint_states,
                                      QoSProfile(depth=1000))
        self.node.create_subscription(
            Bool, 'clutch_engaged', self._on_clutch,
            QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.node.create_subscription(
            Clock, '/clock', self._on_clock,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.crank = self.node.create_publisher(Float64, 'crank_length_cmd', 10)
        self.load = self.node.create_publisher(Float64, 'load_torque_cmd', 10)
        self.start()

    def _on_joint_states(self, msg):
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        with self.lock:
            self.samples.append((t, msg.velocity[0], msg.velocity[3], msg.effort[2]))

    def _on_clutch(self, msg):
        with self.lock:
            self.switch_times.append(self.now)

    def _on_diagnostics(self, msg):
        self.diagnostics = {kv.key: kv.value for kv in msg.status[0].values}

    def _on_clock(self, msg):
        self.now = msg.clock.sec + msg.clock.nanosec * 1e-9

    def wait_until(self, t, timeout):
        end = time.monotonic() + timeout
        while self.now < t:
            if time.monotonic() > end:
                raise TimeoutError(f"simulation time did not reach {t} s")
            time.sleep(0.001)
        return self.now

    def send(self, publisher, value):
        publisher.publish(self.Float64(data=value))


def _offline(scene, crank_at, load_at, end):
    """The same scene and commands through the core alone: (t, ω4) per control period."""
    from ..scene import load_scene
    from ..solver.output import COL
    from ..solver.simulator import Simulator
    sim = Simulator(load_scene(scene, {'solver.method': 'rk4'}))
    k_crank, k_load = round(crank_at / DT) + 1, round(load_at / DT) + 1
    out = []
    for k in range(round(end / DT)):
        if k == k_crank:
            sim.command_crank_length(CRANK_STEP[1])
        if k == k_load:
            sim.set_load_torque(LOAD_STEP[1])
        sim.advance(DT)
        row = sim.sample()
        out.append((row[COL['t']], row[COL['omega4']]))
    return np.array(out)


def _mean(rows, column, lo, hi):
    sel = (rows[:, 0] > lo) & (rows[:, 0] <= hi)
    return float(rows[sel, column].mean()) if sel.any() else math.nan


def run_demo(scene='conveyor', real_time_factor=2.0, out=None):
    """Run the demo; prints the summary to ``out`` (stdout). Returns 0, or 1 if it failed."""
    out = out or sys.stdout
    lease = domains.acquire()   # a ROS domain no other run on this machine uses
    domain = lease.domain
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    log = tempfile.TemporaryFile(mode='w+')
    cmd = [sys.executable, '-m', 'cvt_ros.device', '--scene', scene, '--ros-args',
           '-p', f'real_time_factor:={real_time_factor}']
    print(f"$ cvt_node --scene {scene} --ros-args -p real_time_factor:={real_time_factor}",
          file=out)
    node = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                            pass_fds=[lease.fd])
    controller = _Controller(domain)
    try:
        controller.wait_until(0.0, 60.0)
        # the run starts from the scene's initial state, whenever the controller came up
        from std_srvs.srv import Trigger
        client = controller.node.create_client(Trigger, '/cvt_sim/reset')
        client.wait_for_service(timeout_sec=10.0)
        done = threading.Event()
        client.call_async(Trigger.Request()).add_done_callback(lambda _: done.set())
        done.wait(10.0)
        time.sleep(0.1)
        with controller.lock:
            controller.samples.clear()
            controller.switch_times.clear()
        timeout = 10.0 + 2 * END / real_time_factor
        crank_at = controller.wait_until(CRANK_STEP[0], timeout)
        controller.send(controller.crank, CRANK_STEP[1])
        print(f"t = {crank_at:6.3f} s  controller: crank_length_cmd {CRANK_STEP[1]} m", file=out)
        bad_at = controller.wait_until(BAD_COMMAND, timeout)
        controller.send(controller.crank, math.nan)
        print(f"t = {bad_at:6.3f} s  controller: crank_length_cmd nan (must be refused)",
              file=out)
        load_at = controller.wait_until(LOAD_STEP[0], timeout)
        controller.send(controller.load, LOAD_STEP[1])
        print(f"t = {load_at:6.3f} s  controller: load_torque_cmd {LOAD_STEP[1]} N*m", file=out)
        controller.wait_until(END, timeout)
        time.sleep(1.2)   # one more diagnostics message
        with controller.lock:
            rows = np.array(controller.samples)
            switches = np.array(controller.switch_times)
        diagnostics = dict(controller.diagnostics)
    except TimeoutError as exc:
        print(f"demo failed: {exc}", file=out)
        return 1
    finally:
        controller.close()
        node.send_signal(2)
        try:
            node.wait(10)
        except subprocess.TimeoutExpired:
            node.kill()
    offline = _offline(scene, crank_at, load_at, END)

    print(f"\ncvt_sim on the {scene} scene, realtime mode at {real_time_factor:g}x: what the "
          f"controller saw\n", file=out)
    print('| phase | simulation time [s] | crank length [m] | load torque [N·m] | ω1 [rad/s] | '
          'ω4 [rad/s] | ω4 offline core [rad/s] | ratio ω4/ω1 | shaft torque [N·m] | '
          'clutch switches/s |', file=out)
    print('|---|---|---|---|---|---|---|---|---|---|', file=out)
    for i, (name, lo, hi) in enumerate(PHASES):
        w1, w4 = _mean(rows, 1, lo, hi), _mean(rows, 2, lo, hi)
        crank = CRANK_STEP[1] if i >= 1 else 0.04
        load = LOAD_STEP[1] if i >= 2 else 8.0
        n_switch = np.sum((switches > lo) & (switches <= hi))
        print(f"| {name} | {lo:g}–{hi:g} | {crank:.3f} | {load:.1f} | {w1:.2f} | {w4:.2f} | "
              f"{_mean(offline, 1, lo, hi):.2f} | {w4 / w1:.4f} | {_mean(rows, 3, lo, hi):.2f} | "
              f"{n_switch / (hi - lo):.1f} |", file=out)
    refusals = [line for line in _read(log).splitlines() if 'refused' in line]
    d = diagnostics
    print(f"\nnode diagnostics: real-time factor {d.get('real_time_factor', '?')}, "
          f"{d.get('samples_published', '?')} samples, {d.get('missed_deadlines', '?')} missed "
          f"deadlines, step time p50 / p99 {d.get('step_time_p50_us', '?')} / "
          f"{d.get('step_time_p99_us', '?')} µs, energy balance relative residual "
          f"{d.get('energy_relative_residual', '?')}, commands refused "
          f"{d.get('commands_refused', '?')}", file=out)
    for line in refusals[:1]:
        print(f"node log: {line.strip()}", file=out)
    log.close()
    return 0


def _read(log):
    log.flush()
    log.seek(0)
    return log.read()


def add_parser(sub):
    demo = sub.add_parser(
        'demo', help='the demo: the paper scene offline, then the node driven by a scripted '
                     'controller',
        description='The end-to-end demo (./run.sh demo): the paper\'s Fig. 2/3 scene offline '
                    '(its summary), then cvt_node on a scene in realtime mode, driven from '
                    'another process by a scripted controller (a crank-length step, a refused '
                    'NaN command, a load step); prints what the controller saw beside what the '
                    'offline core predicts for the same commands. Exit code 0, or 1 if the '
                    'node did not answer.')
    demo.add_argument('--scene', default='conveyor', help='scene of the node part (default '
                                                         'conveyor)')
    demo.add_argument('--real-time-factor', type=float, default=2.0, metavar='R',
                      help='node part: simulated seconds per wall second (default 2)')
    demo.set_defaults(func=demo_command)


def demo_command(args):
    from ..solver.offline import run_scene, summarize
    from .run import format_summary
    print("cvt-sim demo 1/2: the paper's Fig. 2/3 scene offline (i ≈ 0.25), 10 s from "
          "start-up\n")
    _, result = run_scene('paper', 10.0)
    print(format_summary(summarize(result, 10.0), 'paper'))
    print(f"\ncvt-sim demo 2/2: the ROS 2 node on the {args.scene} scene, driven by a scripted "
          f"controller\n")
    return run_demo(args.scene, args.real_time_factor)
