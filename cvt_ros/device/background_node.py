"""An rclpy node in a private context, spun by a daemon thread: how the tools (demo, node
benchmark) watch and drive the simulator node from their own process without an executor of
their own in the main thread. rclpy is imported when one is made, never at module import."""
import threading


class BackgroundNode:
    """``node`` lives in its own context and ROS domain; call ``start()`` once its publishers and
    subscriptions are made, ``close()`` at the end."""

    def __init__(self, name, domain):
        import rclpy
        from rclpy.context import Context
        from rclpy.node import Node
        self.rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node(name, context=self.context)
        self.lock = threading.Lock()

    def start(self):
        from rclpy.executors import SingleThreadedExecutor
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:   # noqa: BLE001 — the context is shutting down
                return

    def close(self):
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
