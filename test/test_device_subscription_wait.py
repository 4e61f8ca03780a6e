"""SubscriptionWait: the executor-free wait that the node's loop and the lockstep controllers use.
Every message is handed over once, in order, also when a callback raises (the rest come at the
next wait, before it waits again). Synchronised on the messages themselves, not on time."""
import rclpy
from node_harness import domain_id, wait_for
from rclpy.context import Context
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from cvt_ros.device.subscription_wait import SubscriptionWait

EVERY = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


class Boom(Exception):
    pass


def test_each_message_once_in_order_also_past_a_callback_that_raises():
    context = Context()
    rclpy.init(context=context, domain_id=domain_id())
    node = rclpy.create_node('cvt_test_wait', context=context)
    try:
        seen = []

        def on_value(msg):
            seen.append(msg.data)
            if msg.data == 2.0:
                raise Boom

        first = node.create_subscription(Float64, 'first', on_value, EVERY)
        second = node.create_subscription(Float64, 'second', lambda m: seen.append(-m.data),
                                          EVERY)
        wait = SubscriptionWait(node.context, [first, second])
        to_first = node.create_publisher(Float64, 'first', EVERY)
        to_second = node.create_publisher(Float64, 'second', EVERY)
        assert wait_for(lambda: to_first.get_subscription_count() == 1
                        and to_second.get_subscription_count() == 1, 30.0)
        for value in (1.0, 2.0, 3.0):
            to_first.publish(Float64(data=value))
        to_second.publish(Float64(data=9.0))
        raised = 0
        for _ in range(100):   # until all four were handed over (a failure within 20 s)
            if len(seen) == 4:
                break
            try:
                wait.wait(0.2)
            except Boom:
                raised += 1
        assert raised == 1
        assert [v for v in seen if v > 0] == [1.0, 2.0, 3.0] and -9.0 in seen, seen
        assert not wait.wait(0.0)              # nothing handed over twice
    finally:
        node.destroy_node()
        context.try_shutdown()
