"""Drive this package's nodes from a plain Python script: start them, talk to them, stop them.

A script that tries a controller against ``plant_node`` (or records, or watches two robots)
repeats the same plumbing: the shell's ROS domain, discovery kept on this machine, the nodes
as child processes with their logs, rclpy in the script on the same domain, a spin loop that
gives up when a node dies or time runs out, and a clean stop however the script ends.
:class:`LocalNodes` is that plumbing once::

    with LocalNodes(Path("my_run")) as ros:
        ros.start("plant", ["-p", "sync_mode:=lockstep"])
        node = rclpy.create_node("my_controller")
        ...  # publishers, subscriptions
        ros.spin_until(node, lambda: len(states) > 100, timeout=60.0)
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.demos.processes import NodeProcess, NodeProcessError, private_domain_id, ros_env

MAX_DOMAIN_ID = 232  # the highest ROS_DOMAIN_ID whose DDS ports fit on Linux (ROS 2 docs, "The ROS_DOMAIN_ID")


def domain_from_env() -> int:
    """The ROS domain every ROS 2 tool in this shell uses: ``ROS_DOMAIN_ID``, 0 when unset."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > MAX_DOMAIN_ID:
        raise InputError(f"ROS_DOMAIN_ID must be a whole number 0-{MAX_DOMAIN_ID}, got {text!r}")
    return int(text)


def run_domain_id(given: int | None = None) -> int:
    """The domain of a run that starts its own nodes (``ros-demo``): ``given`` (``--domain-id``),
    else ``ROS_DOMAIN_ID`` when it is set (the shell's ROS 2 tools then see the run), else a
    private one (:func:`~elastic_pm_dyn.ros.demos.processes.private_domain_id`: no other run hears it)."""
    if given is not None:
        if not 0 <= given <= MAX_DOMAIN_ID:
            raise InputError(f"domain id must be a whole number 0-{MAX_DOMAIN_ID}, got {given}")
        return given
    if os.environ.get("ROS_DOMAIN_ID", "").strip():
        return domain_from_env()
    return private_domain_id()


class LocalNodes:
    """Node processes and this script's rclpy on the shell's domain (``ROS_DOMAIN_ID``), with
    discovery on this machine only unless ``ROS_AUTOMATIC_DISCOVERY_RANGE`` says otherwise.

    A context manager: on the way out, also after an error, a timeout or Ctrl+C, every
    started process is stopped (SIGINT first: a clean shutdown), every node given to
    :meth:`spin_until` destroyed and rclpy shut down. Node logs go to ``<log_dir>/<name>.log``.
    """

    def __init__(self, log_dir: Path):
        self.log_dir = Path(log_dir)
        self.domain_id = domain_from_env()
        self.processes: list[NodeProcess] = []
        self._nodes: list[Any] = []

    def __enter__(self) -> LocalNodes:
        import rclpy  # only a script that drives nodes needs ROS

        # Read by rcl at init and inherited by the children: a run does not reach (or hear)
        # other machines on the same domain.
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        rclpy.init(domain_id=self.domain_id)
        return self

    def start(self, name: str, ros_args: list[str], module: str = "elastic_pm_dyn.ros.plant.node") -> NodeProcess:
        """Start ``module`` (default: the plant) with ``ros_args`` (``-p``, ``-r`` ...); ``name`` names its log."""
        env = ros_env(self.domain_id)
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]
        process = NodeProcess(name, module, ros_args, env, self.log_dir)
        self.processes.append(process)
        return process

    def spin_until(self, node: Any, done: Callable[[], bool], timeout: float) -> None:
        """Spin ``node`` until ``done()`` holds. Raises :class:`NodeProcessError` if a started
        process ends first or ``timeout`` [s] passes (so a script never hangs on a dead plant)."""
        import rclpy

        if node not in self._nodes:
            self._nodes.append(node)
        deadline = time.monotonic() + timeout
        while not done():
            for process in self.processes:
                process.check_running()
            if time.monotonic() > deadline:
                raise NodeProcessError(f"{node.get_name()}: not done within {timeout:g} s "
                                       f"(logs: {self.log_dir})")
            rclpy.spin_once(node, timeout_sec=0.05)

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        import rclpy

        try:
            for process in reversed(self.processes):
                process.stop()
        finally:
            for node in self._nodes:
                node.destroy_node()
            rclpy.try_shutdown()
