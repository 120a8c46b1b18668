"""What every console script of a node does: init, build the node, spin, shut down cleanly.

A node that cannot start (bad parameter, model file, ROS arguments) prints one line
``<program>: error: <reason>`` on stderr and the process exits with status 2. Ctrl-C while
it starts (imports, model, numba's first compile) interrupts the start-up at once: one
line, status 130 (:mod:`elastic_pm_dyn.entry`). Once it spins, SIGINT and SIGTERM only ask
the spin loop to stop (rclpy's own handlers would invalidate the context first), so the
node's ``close()`` still runs with ROS up: the recorder closes its bag and its last log
lines still reach /rosout; the status is then 0.
"""

from __future__ import annotations

import signal
import sys
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from elastic_pm_dyn import interrupts
from elastic_pm_dyn.errors import ElasticPmDynError

EXIT_START_FAILED = 2
SPIN_TIMEOUT = 0.1  # [s] longest time until a stop request or node.done is seen
_stop: list[int] = []  # the signals that asked the running node to stop


def stopping() -> bool:
    """Has SIGINT or SIGTERM asked the node to stop? A long service call or computation in a
    callback asks this between its steps and ends early (the spin loop only sees the request
    once the callback returns)."""
    return bool(_stop)


class ManagedNode(Node):
    """A node run by :func:`run_node`: set ``done`` to end the process, override ``close``."""

    done = False
    exit_status = 0  # what the process ends with once done (EXIT_START_FAILED: a start-up that failed late)

    def __init__(self, *args: Any, **kwargs: Any):
        self.created = time.monotonic()  # when it joined the graph (graph_checks waits for discovery from here)
        super().__init__(*args, **kwargs)

    def close(self) -> None:
        """Release resources before the node is destroyed (called once, also on signals)."""

    def destroy_node(self) -> None:
        for claim in getattr(self, "host_claims", []):  # graph_checks.claim_on_host: another may start now
            claim.release()
        self.host_claims = []
        super().destroy_node()


def run_node(program: str, factory: Callable[[], ManagedNode], args: list[str] | None = None) -> int:
    """Run one node in its own process; returns the exit status."""
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except rclpy_implementation.RCLError as err:  # e.g. a malformed --params-file
        reason = str(err).split(", at ")[0]  # drop rcl's source locations
        print(f"{program}: error: ROS arguments rejected: {reason}", file=sys.stderr)
        return EXIT_START_FAILED
    stop = _stop
    stop.clear()

    def request_stop(signum: int, _frame: object) -> None:
        if stop:  # a second signal: the loop did not get to it, stop the hard way
            raise KeyboardInterrupt
        stop.append(signum)

    previous: dict[int, object] = {}
    try:
        try:
            node = factory()  # Ctrl-C here is a KeyboardInterrupt: start-up ends at once
        except ElasticPmDynError as err:
            print(f"{program}: error: {err}", file=sys.stderr)
            return EXIT_START_FAILED
        if interrupts.requested():  # a Ctrl-C during start-up that a finalizer swallowed
            node.destroy_node()
            raise KeyboardInterrupt
        previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            while rclpy.ok() and not node.done and not stop:
                executor.spin_once(timeout_sec=SPIN_TIMEOUT)
        finally:
            node.close()
            executor.remove_node(node)
            node.destroy_node()
        return node.exit_status
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        rclpy.try_shutdown()
