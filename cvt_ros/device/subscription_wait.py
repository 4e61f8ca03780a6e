"""Waiting on a few subscriptions without an executor: one rcl wait set of their own.

rclpy's executor rebuilds its wait set from every entity of the node and dispatches through
Python on each pass (~0.2 ms on the 2-core reference machine); a lockstep round trip is a few
hundred µs in all, so the thread that lives on these messages waits for them itself: the
subscriptions (and a guard to interrupt the wait) in one rcl wait set, every ready message
taken and handed to its subscription's callback, in the order the subscriptions were given.
The device's run loop waits on its command topics this way, the scenario harness on the
device's samples. A subscription waited on here must not also be served by an executor at the
same time (the node puts its command subscriptions in a callback group the executor never runs).
"""
import contextlib

from rclpy.callback_groups import CallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription

RCLError = _rclpy.RCLError
TAKE_LIMIT = 1000   # messages taken per subscription and wait (a flood cannot starve the rest)


class WaitedApart(CallbackGroup):
    """The callback group of subscriptions a ``SubscriptionWait`` takes: an executor never runs
    them (its thread and the wait would take from the same reader)."""

    def can_execute(self, entity):
        return False

    def beginning_execution(self, entity):
        return True

    def ending_execution(self, entity):
        pass


class SubscriptionWait:
    """``wait(timeout_s)`` on ``subscriptions`` (rclpy Subscription objects of ``context``)."""

    def __init__(self, context, subscriptions, take_limit=TAKE_LIMIT):
        self._context = context
        self._subscriptions = tuple(subscriptions)
        self._pointers = [s.handle.pointer for s in self._subscriptions]
        # callback(msg) or callback(msg, info), as the executor would call it
        self._with_info = [s._callback_type is Subscription.CallbackType.WithMessageInfo
                           for s in self._subscriptions]
        self._take_limit = take_limit
        with context.handle:
            self._guard = _rclpy.GuardCondition(context.handle)
            self._wait_set = _rclpy.WaitSet(len(self._subscriptions), 1, 0, 0, 0, 0,
                                            context.handle)

    def wait(self, timeout_s):
        """Wait up to ``timeout_s`` (0: just look) for messages or ``wake()``; hand every message
        that arrived to its subscription's callback, subscription by subscription in the given
        order, at most ``take_limit`` each. True if any came; False on timeout, a wake-up or
        shutdown."""
        subs = self._subscriptions
        wait_set = self._wait_set
        try:
            with contextlib.ExitStack() as handles:
                handles.enter_context(self._context.handle)
                handles.enter_context(self._guard)
                for sub in subs:
                    handles.enter_context(sub.handle)
                wait_set.clear_entities()
                for sub in subs:
                    wait_set.add_subscription(sub.handle)
                wait_set.add_guard_condition(self._guard)
                wait_set.wait(int(timeout_s * 1e9))
                ready = wait_set.get_ready_entities('subscription')
        except (InvalidHandle, RCLError):   # shutting down
            return False
        if not ready:
            return False
        for sub, pointer, with_info in zip(subs, self._pointers, self._with_info, strict=True):
            if pointer not in ready:
                continue
            for _ in range(self._take_limit):
                try:
                    with sub.handle:
                        taken = sub.handle.take_message(sub.msg_type, sub.raw)
                except InvalidHandle:   # shutting down
                    return False
                if taken is None:
                    break
                if with_info:
                    sub.callback(*taken)
                else:
                    sub.callback(taken[0])
        return True

    def wake(self):
        """Interrupt a ``wait`` in another thread (a request, a setting, stop)."""
        try:
            with self._guard:
                self._guard.trigger_guard_condition()
        except InvalidHandle:
            pass
