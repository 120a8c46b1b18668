"""Nodes as child processes on a private, loopback-only ROS domain (no ``ros2 launch`` needed).

Each child runs ``python -m <module> --ros-args ...`` with its output in a log file and
in a session of its own, so that the parent decides the shutdown order (SIGINT, then
SIGTERM, then SIGKILL after deadlines).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from elastic_pm_dyn.errors import ElasticPmDynError

ENTRY = {"elastic_pm_dyn.ros.plant.node": "plant_node", "elastic_pm_dyn.ros.observer.node": "observer_node",
         "elastic_pm_dyn.ros.feedforward.node": "feedforward_node", "elastic_pm_dyn.ros.recorder.node": "recorder_node"}
STOP_SIGNALS = ((signal.SIGINT, 10.0), (signal.SIGTERM, 3.0), (signal.SIGKILL, 3.0))  # (signal, wait [s])


class NodeProcessError(ElasticPmDynError):
    """A node process failed or did not finish in time (the message quotes its log)."""


def private_domain_id() -> int:
    """A ROS domain id for this run: 1-100 (inside the range Fast DDS ports allow), by process id."""
    return 1 + os.getpid() % 100


def ros_env(domain_id: int) -> dict[str, str]:
    """The environment of the children: this domain, discovery on this machine only."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"  # logs in order, and complete when a child is killed
    return env


class NodeProcess:
    """One node in a child process; its stdout and stderr go to ``<log_dir>/<name>.log``."""

    def __init__(self, name: str, module: str, ros_args: list[str], env: dict[str, str], log_dir: Path):
        self.name = name
        self.log = log_dir / f"{name}.log"
        log_dir.mkdir(parents=True, exist_ok=True)
        # A node of ours starts through its console script's entry point: a SIGINT during its
        # start-up is then one line and status 130 in the log, not a traceback.
        target = ["-m", "elastic_pm_dyn.entry", ENTRY[module]] if module in ENTRY else ["-m", module]
        with self.log.open("w") as fh:
            self.proc = subprocess.Popen([sys.executable, *target, "--ros-args", *ros_args], env=env,
                                         stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)

    def check_running(self) -> None:
        """Raise if the process has ended (a node that fails at start-up ends at once)."""
        code = self.proc.poll()
        if code is not None:
            raise self.failure(code)

    def failure(self, code: int) -> NodeProcessError:
        return NodeProcessError(f"{self.name} exited with status {code}: {self.last_line()} (log: {self.log})")

    def wait(self, timeout: float) -> int:
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            raise NodeProcessError(f"{self.name} did not finish within {timeout:g} s: {self.last_line()} "
                                   f"(log: {self.log})") from None

    def stop(self) -> int:
        """End the process: SIGINT (clean shutdown), then SIGTERM, then SIGKILL."""
        for sig, wait in STOP_SIGNALS:
            if self.proc.poll() is not None:
                break
            self.proc.send_signal(sig)
            try:
                self.proc.wait(wait)
            except subprocess.TimeoutExpired:
                continue
        return self.proc.wait()

    def last_line(self) -> str:
        lines = [ln for ln in self.log.read_text(errors="replace").splitlines() if ln.strip()]
        return lines[-1].strip() if lines else "(no output)"


@contextlib.contextmanager
def _orchestrator(domain_id: int) -> Iterator[tuple[Any, Any]]:
    """(node, executor) of this process on the nodes' private domain, discovering on loopback
    as they do; everything shut down on the way out."""
    import rclpy  # the graph view of this process; nothing else here needs ROS
    from rclpy.executors import SingleThreadedExecutor

    old_range = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # read by rcl at init
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        node = rclpy.create_node("elastic_pm_dyn_orchestrator", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        yield node, executor
        executor.remove_node(node)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
        if old_range is None:
            os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
        else:
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = old_range


def wait_for_recording(topics: list[str], domain_id: int, timeout: float, watch: list[NodeProcess]) -> None:
    """Block until a recorder's /diagnostics say it has received a message on every topic.

    A subscriber in the ROS graph is not yet a reader the publisher serves: a CI run had the
    recorder shown on the plant's topics and given nothing (issue #29); the recorder subscribes
    a topic that stays silent anew, and this waits for that too. Raises if a watched process
    dies or time runs out."""
    from diagnostic_msgs.msg import DiagnosticArray

    from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS

    received: dict[str, int] = {}

    def take(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(": recorder"):
                for kv in status.values:
                    topic, _, key = kv.key.rpartition(" ")
                    if key == "received" and kv.value.isdigit():
                        received[topic] = max(received.get(topic, 0), int(kv.value))

    with _orchestrator(domain_id) as (node, executor):
        node.create_subscription(DiagnosticArray, "/diagnostics", take, DIAGNOSTICS_QOS)
        deadline = time.monotonic() + timeout
        while missing := [t for t in topics if not received.get(t)]:
            if time.monotonic() > deadline:
                raise NodeProcessError(f"the recorder received nothing on {', '.join(missing)} within {timeout:g} s")
            for p in watch:
                p.check_running()
            executor.spin_once(timeout_sec=0.1)


def wait_for_exit(target: NodeProcess, others: list[NodeProcess], timeout: float) -> int:
    """Wait until ``target`` ends; raise if it takes too long or one of ``others`` dies first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        code = target.proc.poll()
        if code is not None:
            return code
        for p in others:
            p.check_running()
        time.sleep(0.05)
    return target.wait(0.0)
