"""Helpers for the node tests: the node in a subprocess, a probe node in the test process.

Every test module gets its own ROS domain (``domain_id``: allocated machine-wide, held until this
process and the nodes started in it have ended), discovery is limited to this machine, and nothing
waits by sleeping: ``wait_for`` polls a condition until a timeout.

Run as a script, ``python test/node_harness.py flood TOPIC RATE SECONDS VALUE...`` publishes
std_msgs/Float64 commands at RATE per second from its own process (a flood must not share the
probe's interpreter lock).
"""
import bisect
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time

import rclpy
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.exceptions import InvalidHandle
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from cvt_ros.device import domains
from cvt_ros.device.subscription_wait import SubscriptionWait, WaitedApart

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
SCENES = os.path.join(REPO, 'config', 'scenes')
_leases = {}   # domain id -> DomainLease held by this process

RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# every message kept until taken: a lockstep burst (thousands of samples in milliseconds) must not
# overrun a probe whose executor takes ~100 µs per message
KEEP_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
BEST_EFFORT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)


def domain_id():
    """A ROS domain no other process on this machine holds (21..101), held by this process until
    it ends; nodes started with ``NodeProcess`` hold it too (an orphaned node keeps it taken)."""
    lease = domains.acquire()
    _leases[lease.domain] = lease
    return lease.domain


def _lock_fds(domain):
    """The lock descriptor to hand to a child on ``domain`` (none for a domain not from here)."""
    lease = _leases.get(domain)
    return (lease.fd,) if lease is not None and lease.fd is not None else ()


def ros_env(domain):
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    env.pop('ROS_STATIC_PEERS', None)
    return env


def wait_for(predicate, timeout, interval=0.005):
    """Poll ``predicate`` until it is truthy (returns its value) or ``timeout`` [s] passes."""
    end = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > end:
            return value
        time.sleep(interval)


def reset_sample(joints, requested_ns, timeout=30.0):
    """The index in ``joints`` of the t = 0 sample a ~/reset requested at system time
    ``requested_ns`` published: the first one sent after the request. (Not the first t = 0 after
    the request's index: a probe behind on a busy machine may still hold an earlier reset's.)"""
    index = wait_for(lambda: (i := joints.first_sent_since(
        requested_ns, lambda m: stamp_ns(m) == 0)) is not None and i + 1, timeout)
    assert index, 'no t = 0 sample after ~/reset'
    return index - 1


def stamp_s(msg):
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class NodeProcess:
    """``python -m cvt_ros.device ARGS --ros-args ROS_ARGS`` in its own process and domain."""

    def __init__(self, domain, ros_args=(), args=(), command=None):
        self.log = tempfile.TemporaryFile(mode='w+')
        self._final_output = None   # the log's text once the log is closed
        cmd = list(command or [sys.executable, '-m', 'cvt_ros.device'])
        cmd += list(args) + ['--ros-args'] + list(ros_args)
        self.proc = subprocess.Popen(cmd, env=ros_env(domain), stdout=self.log,
                                     stderr=subprocess.STDOUT, cwd=REPO,
                                     pass_fds=_lock_fds(domain))

    def output(self):
        if self._final_output is not None:   # after the with block (an assert's message)
            return self._final_output
        self.log.flush()
        self.log.seek(0)
        return self.log.read()

    def alive(self):
        return self.proc.poll() is None

    def stop(self, sig=signal.SIGINT, timeout=10.0):
        """Send ``sig``; returns (exit code, seconds until the process ended)."""
        if not self.alive():
            return self.proc.returncode, 0.0
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        return code, time.monotonic() - t0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.alive():
            self.stop(signal.SIGINT, 5.0)
        self._final_output = self.output()
        self.log.close()


class Collector:
    """Messages of one subscription as (monotonic receive time, message), with the time each was
    published (the publisher's source timestamp: system clock, ns). Taken as CDR bytes by a
    thread of its own (``Probe.subscribe``) and turned into messages when read."""

    def __init__(self, msg_type):
        self.items = []     # (receive time, message, or its CDR bytes until read)
        self.sent_ns = []
        self.lock = threading.Lock()
        self._msg_type = msg_type

    def __call__(self, msg, info):
        with self.lock:
            self.items.append((time.monotonic(), msg))
            self.sent_ns.append(info['source_timestamp'])

    def __len__(self):
        return len(self.items)

    def _message(self, i):
        """Item i's message (the caller holds the lock)."""
        received, msg = self.items[i]
        if isinstance(msg, bytes):
            msg = deserialize_message(msg, self._msg_type)
            self.items[i] = (received, msg)
        return msg

    def _indices(self, since):
        return range(*slice(since, None).indices(len(self.items)))

    def messages(self, since=0):
        with self.lock:
            return [self._message(i) for i in self._indices(since)]

    def timed(self, since=0):
        with self.lock:
            return [(self.items[i][0], self._message(i)) for i in self._indices(since)]

    def last(self):
        with self.lock:
            return self._message(len(self.items) - 1) if self.items else None

    def first_sent_since(self, wall_ns, predicate):
        """Index of the first message published at or after system time ``wall_ns``
        (``time.time_ns()``) for which ``predicate(msg)`` holds, or None. A probe behind the
        node on a busy machine may still be taking messages published long before."""
        with self.lock:
            # one publisher's messages arrive in the order sent: their timestamps are sorted
            for i in range(bisect.bisect_left(self.sent_ns, wall_ns), len(self.items)):
                if predicate(self._message(i)):
                    return i
        return None


class _Taker:
    """One subscription's messages taken as CDR bytes by a thread of its own, in batches from one
    rcl wait set (cvt_ros.device.subscription_wait). rclpy's executor costs ~100 µs a message in
    Python: on a busy 2-core machine a probe served by it took 350–600 JointState samples per
    second of a 1 kHz node, fell seconds behind and then lost samples in DDS (the node's writer
    keeps 10); taken apart it keeps up."""

    def __init__(self, context, subscription):
        self._stop = threading.Event()
        self._wait = SubscriptionWait(context, [subscription])
        self._thread = threading.Thread(target=self._take, daemon=True)
        self._thread.start()

    def _take(self):
        while not self._stop.is_set():
            self._wait.wait(0.05)

    def stop(self):
        self._stop.set()
        self._wait.wake()
        self._thread.join(5.0)


class Probe:
    """A test node in its own rclpy context (domain), spun by a background thread."""

    def __init__(self, domain, name='cvt_test_probe', parameter_overrides=None):
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node(name, context=self.context, parameter_overrides=parameter_overrides)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._waited_apart = WaitedApart()
        self._takers = []
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except InvalidHandle:
                # the test thread destroyed a subscription or node while this thread gathered
                # the wait set (rclpy takes the entity list before it holds the handles); the
                # executor gathers anew on the next spin_once
                continue
            except Exception:   # noqa: BLE001 — shutting down
                if not self.context.ok():
                    return
                raise

    def close(self):
        for taker in self._takers:
            taker.stop()
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(2.0)

    def subscribe(self, msg_type, topic, qos=RELIABLE):
        collector = Collector(msg_type)
        collector.subscription = self.node.create_subscription(
            msg_type, topic, collector, qos, callback_group=self._waited_apart, raw=True)
        collector.taker = _Taker(self.context, collector.subscription)
        self._takers.append(collector.taker)
        return collector

    def unsubscribe(self, collector):
        collector.taker.stop()
        self._takers.remove(collector.taker)
        self.node.destroy_subscription(collector.subscription)

    def publisher(self, msg_type, topic, qos=RELIABLE):
        return self.node.create_publisher(msg_type, topic, qos)

    def call(self, srv_type, name, request=None, timeout=10.0):
        """Call a service; returns the response (raises TimeoutError)."""
        client = self.node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=timeout):
                raise TimeoutError(f"service {name} not available")
            done = threading.Event()
            future = client.call_async(request if request is not None else srv_type.Request())
            future.add_done_callback(lambda _: done.set())
            if not done.wait(timeout):
                raise TimeoutError(f"service {name} did not answer")
            return future.result()
        finally:
            self.node.destroy_client(client)

    # parameters of another node, through its parameter services
    def set_parameters(self, node, **values):
        """``set_parameters('/ns/cvt_sim', name=value)`` (dotted names: pass a dict with **)."""
        request = SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        return self.call(SetParameters, f"{node}/set_parameters", request).results

    def set_raw_parameter(self, node, msg):
        """Set one rcl_interfaces/Parameter message as is (to send a wrong type)."""
        request = SetParameters.Request(parameters=[msg])
        return self.call(SetParameters, f"{node}/set_parameters", request).results[0]

    def get_parameters(self, node, names):
        request = GetParameters.Request(names=list(names))
        values = self.call(GetParameters, f"{node}/get_parameters", request).values
        return {n: Parameter.from_parameter_msg(ParameterMsg(name=n, value=v)).value
                for n, v in zip(names, values, strict=True)}

    def describe_parameters(self, node, names):
        request = DescribeParameters.Request(names=list(names))
        return self.call(DescribeParameters, f"{node}/describe_parameters", request).descriptors

    def list_parameters(self, node):
        return self.call(ListParameters, f"{node}/list_parameters",
                         ListParameters.Request()).result.names

    def publishers(self, topic):
        return self.node.get_publishers_info_by_topic(topic)

    def subscriptions(self, topic):
        return self.node.get_subscriptions_info_by_topic(topic)


def diagnostics_values(msg):
    """The key/value pairs of the first status of a DiagnosticArray."""
    return {kv.key: kv.value for kv in msg.status[0].values}


def flood(domain, topic, rate, seconds, values, keep_all=False):
    """Run the flooder in its own process: ``rate`` Float64 messages per second (``keep_all``:
    its publisher keeps every message until delivered, so none is lost on its side)."""
    cmd = [sys.executable, os.path.abspath(__file__), 'flood' + ('_all' if keep_all else ''),
           topic, str(rate), str(seconds)]
    cmd += [repr(float(v)) for v in values]
    return subprocess.Popen(cmd, env=ros_env(domain), stdout=subprocess.PIPE, text=True,
                            pass_fds=_lock_fds(domain))


def _flood_main(keep_all, topic, rate, seconds, *values):
    from std_msgs.msg import Float64
    rclpy.init()
    node = Node('cvt_test_flood')
    pub = node.create_publisher(Float64, topic, KEEP_ALL if keep_all else RELIABLE)
    wait_for(lambda: pub.get_subscription_count() > 0, 10.0)
    rate, seconds = float(rate), float(seconds)
    cycle = [Float64(data=float(v)) for v in values]
    period = int(1e9 / rate)
    n = int(rate * seconds)
    t0 = time.monotonic_ns()
    for i in range(n):   # a monotonic schedule; sleeps in ~1 ms slices, then a burst
        ahead = t0 + i * period - time.monotonic_ns()
        if ahead > 500_000:
            time.sleep(ahead * 1e-9)
        pub.publish(cycle[i % len(cycle)])
    elapsed = (time.monotonic_ns() - t0) * 1e-9
    # a reliable writer's history dies with its process: deliver it before leaving
    pub.wait_for_all_acked(Duration(seconds=30))
    print(f"{n} {elapsed:.3f}", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == '__main__':
    if len(sys.argv) > 1 and sys.argv[1] in ('flood', 'flood_all'):
        _flood_main(sys.argv[1] == 'flood_all', *sys.argv[2:])
    else:
        sys.exit(f"usage: {sys.argv[0]} flood TOPIC RATE SECONDS VALUE...")


__all__ = ['NodeProcess', 'Probe', 'Collector', 'domain_id', 'wait_for', 'flood', 'stamp_s',
           'stamp_ns', 'diagnostics_values', 'RELIABLE', 'LATCHED', 'BEST_EFFORT', 'KEEP_ALL',
           'SCENES',
           'signal']
