"""In-process ROS test harness: own context, own domain, every wait with a deadline.

Nodes run in the test's thread: :meth:`RosHarness.wait_until` spins the executor until a
condition holds or its deadline passes, so no test can hang and no thread races the test.
Like test_ros_msgs.py: skip when rclpy is missing, fail instead when
ELASTIC_PM_DYN_REQUIRE_ROS=1.
"""

from __future__ import annotations

import importlib
import os
import time
from collections.abc import Callable
from types import ModuleType
from typing import Any

import pytest


def require(module: str) -> ModuleType:
    """Import `module`, or skip (fail when ELASTIC_PM_DYN_REQUIRE_ROS=1) if it is missing."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        if os.environ.get("ELASTIC_PM_DYN_REQUIRE_ROS") == "1":
            pytest.fail(f"{module} not importable ({exc}); run scripts/setup_ros.sh VENV")
        pytest.skip(f"{module} not importable ({exc}); run scripts/setup_ros.sh VENV")


def domain_id(offset: int) -> int:
    """A domain id in 1-100 per test module (``offset``) and pytest process. No two modules
    share an offset (test_domains.py): a node one module killed leaves nothing (a dead
    participant's ports, its shared memory) in another module's domain."""
    return 1 + (os.getpid() + offset) % 100


class RosHarness:
    """A ROS context on a private domain, an executor, and deadline-bounded spinning."""

    def __init__(self, domain: int, args: list[str] | None = None):
        rclpy = require("rclpy")
        from rclpy.executors import SingleThreadedExecutor

        self._old_range = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # read by rcl at init
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain, args=args)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes: list[Any] = []

    def add(self, node: Any) -> Any:
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def node(self, name: str) -> Any:
        return self.add(self.rclpy.create_node(name, context=self.context))

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.005)

    def wait_until(self, condition: Callable[[], bool], timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.005)

    def call(self, client: Any, request: Any, timeout: float = 10.0) -> Any:
        self.wait_until(client.service_is_ready, timeout, f"service {client.srv_name}")
        future = client.call_async(request)
        self.wait_until(future.done, timeout, f"response of {client.srv_name}")
        return future.result()

    def close(self) -> None:
        for node in reversed(self.nodes):
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown(timeout_sec=2.0)
        self.rclpy.try_shutdown(context=self.context)
        if self._old_range is None:
            os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
        else:
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = self._old_range
