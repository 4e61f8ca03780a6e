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
import collections

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
        self._take_limit = take_limit
        with context.handle:
            self._guard = _rclpy.GuardCondition(context.handle)
            self._wait_set = _rclpy.WaitSet(len(self._subscriptions), 1, 0, 0, 0, 0,
                                            context.handle)
        # what one wait holds: the context, the guard, then the subscriptions in order
        self._handles = (context.handle, self._guard) + tuple(s.handle for s in
                                                               self._subscriptions)
        # taken, not yet handed over: a callback that raised leaves the rest for the next wait
        self._taken = collections.deque()

    def wait(self, timeout_s):
        """Wait up to ``timeout_s`` (0: just look) for messages or ``wake()``; hand every message
        that arrived to its subscription's callback, subscription by subscription in the given
        order, at most ``take_limit`` each. True if any came; False on timeout, a wake-up or
        shutdown."""
        if self._taken:   # a callback raised in the last wait: the messages after it first
            self._hand_over()
            return True
        # The handles are held (entered) for the wait and the takes, so that a node destroyed
        # meanwhile defers its destruction; entered one by one, not by an ExitStack: this runs
        # once per lockstep period and an ExitStack of four handles costs ~5 µs in itself
        handles = self._handles
        entered = 0
        taken = self._taken
        try:
            for handle in handles:
                handle.__enter__()
                entered += 1
            wait_set = self._wait_set
            wait_set.clear_entities()
            for handle in handles[2:]:
                wait_set.add_subscription(handle)
            wait_set.add_guard_condition(self._guard)
            wait_set.wait(int(timeout_s * 1e9))
            ready = wait_set.get_ready_entities('subscription')
            if not ready:
                return False
            for sub, pointer in zip(self._subscriptions, self._pointers, strict=True):
                if pointer in ready:
                    handle, msg_type, raw = sub.handle, sub.msg_type, sub.raw
                    for _ in range(self._take_limit):
                        message = handle.take_message(msg_type, raw)
                        if message is None:
                            break
                        taken.append((sub, message))
        except (InvalidHandle, RCLError):   # shutting down
            return False
        finally:
            for handle in reversed(handles[:entered]):
                handle.__exit__(None, None, None)
        self._hand_over()   # with no handle held: a callback may destroy the node
        return True

    def _hand_over(self):
        """Each taken message to its subscription's callback, in order."""
        taken = self._taken
        while taken:
            sub, message = taken.popleft()
            if sub._callback_type is Subscription.CallbackType.WithMessageInfo:
                sub.callback(*message)
            else:
                sub.callback(message[0])

    def wake(self):
        """Interrupt a ``wait`` in another thread (a request, a setting, stop)."""
        try:
            with self._guard:
                self._guard.trigger_guard_condition()
        except InvalidHandle:
            pass
