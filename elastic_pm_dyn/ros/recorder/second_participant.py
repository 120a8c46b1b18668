"""A second DDS participant in this process, for readers that the first one's peers never serve.

Fast DDS (2.14, under rmw_fastrtps) can leave a reader matched on its own side while the
writer never sends to it. We saw it with recorders started where one had just been SIGKILLed
(the new one takes the dead participant's id and ports), and once with a reader created while
the publishing process was still starting. More readers in the same participant stayed
unserved. Readers in other processes, beside the stuck one, were served. A participant of its
own gives this process what those other processes have: a new rclpy Context, so a new
participant id, new ports and a new GUID prefix. Its node spins in a thread of its own, so the
callbacks made here run on that thread (the recorder's take and matched callbacks only count
and queue).
"""

from __future__ import annotations

import threading

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

SPIN_TIMEOUT = 0.1  # [s] longest time until close() is seen by the spinning thread


class SecondParticipant:
    """A node on ``domain_id`` in a context of its own, spun by a daemon thread until :meth:`close`."""

    def __init__(self, domain_id: int, node_name: str):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(node_name, context=self.context, start_parameter_services=False)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name=f"{node_name} spin", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self._executor.spin_once(timeout_sec=SPIN_TIMEOUT)

    def close(self) -> None:
        """Stop the thread, destroy the node and shut the context down (once; later calls do nothing)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join()
        self._executor.remove_node(self.node)
        self.node.destroy_node()
        self._executor.shutdown()
        self.context.try_shutdown()
