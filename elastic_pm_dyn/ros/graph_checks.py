"""Checks of a starting node against the ROS graph and its own topic names.

- :func:`resolved_topics`: every topic parameter resolved as the node's publishers will resolve
  it (namespace, ``~``, remappings); a name that is no topic name is one ParameterError line at
  start-up instead of rclpy's traceback when the publisher is made.
- :func:`refuse_if_taken`: a node that stands for a machine (the plant, an observer) does not
  start where one already runs: the same node name in the same namespace, or another writer of
  its state topic (two plants in ``/r1`` interleave their states on ``/r1/joint_states`` and both
  serve ``/r1/plant/step``). On one host that is certain at once: each such node holds an
  exclusive lock (``flock``) on a file named by its ROS domain and state topic
  (:func:`claim_on_host`), which the kernel releases when the process ends however it ends.
  Across hosts only the graph can tell, and discovery takes a moment, so the check looks until the node has been
  in the graph for :data:`DISCOVERY_WAIT` (the model's loading usually covers it). The graph also
  shows, for a while, a node that has just stopped (one killed without a goodbye: up to the DDS
  lease, ~20 s), so a node seen there counts only if it is alive: it publishes its status on
  ``/diagnostics`` (every node of ours does, named by its full name) within :data:`ALIVE_WAIT`.
"""

from __future__ import annotations

import fcntl
import os
import re
import tempfile
import time
from collections.abc import Iterable
from typing import Any, ClassVar

from elastic_pm_dyn.ros.params import ParameterError

DISCOVERY_WAIT = 2.0  # [s] in the graph before a node is sure it is alone (local discovery: ~0.1-0.5 s)
MIN_LOOK = 0.5  # [s] of looking at the graph in any case
ALIVE_WAIT = 5.0  # [s] for a status of a node seen in the graph (our nodes report at 1 Hz by default)
POLL = 0.05  # [s]


def resolve_topic(node: Any, parameter: str, topic: Any) -> str:
    """The fully qualified name of ``topic`` (the value of ``parameter``); ParameterError (one line)
    when it is no topic name."""
    try:
        if not isinstance(topic, str) or not topic.strip():
            raise RuntimeError("empty")
        return node.resolve_topic_name(topic)
    except RuntimeError as err:  # rclpy's RCLError: "failed to resolve name: <why>, at <source>"
        why = str(err).removeprefix("failed to resolve name: ").split(", at /")[0]
        raise ParameterError(f"parameter '{parameter}': {topic!r} is no topic name ({why})") from None


def resolved_topics(node: Any, p: dict[str, Any], names: Iterable[str]) -> dict[str, str]:
    """Parameter name -> fully qualified topic, for the topic parameters ``names`` of ``p``."""
    return {name: resolve_topic(node, name, p[name]) for name in names}


def _others(node: Any, topics: list[str]) -> set[str]:
    """Full names of other nodes of this name, and of the writers of ``topics`` (graph view)."""
    me = (node.get_name(), node.get_namespace())
    found = set()
    if sum(1 for n in node.get_node_names_and_namespaces() if n == me) > 1:
        found.add(node.get_fully_qualified_name())
    for topic in topics:
        for info in node.get_publishers_info_by_topic(topic):
            found.add(f"{info.node_namespace.rstrip('/')}/{info.node_name}")
    return found


def _alive(node: Any, names: set[str], wait: float) -> set[str]:
    """Those of ``names`` whose status comes on /diagnostics within ``wait`` seconds."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS

    heard: set[str] = set()

    def take(msg: DiagnosticArray) -> None:
        heard.update(s.name.split(": ")[0] for s in msg.status)

    sub = node.create_subscription(DiagnosticArray, "/diagnostics", take, DIAGNOSTICS_QOS)
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline and not names & heard:
            executor.spin_once(timeout_sec=POLL)
    finally:
        executor.remove_node(node)
        executor.shutdown()
        node.destroy_subscription(sub)
    return names & heard


def lock_dir() -> str:
    """Where the host's claims live: the user's runtime directory, else the temporary one."""
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return os.path.join(base, f"elastic_pm_dyn-{os.getuid()}")


class HostClaim:
    """One claimed lock file, shared by the nodes of this process that claimed it (see
    :func:`claim_on_host`); the lock goes when the last of them releases it."""

    held: ClassVar[dict[str, HostClaim]] = {}  # path -> the claim of this process

    def __init__(self, path: str, file: Any):
        self.path, self.file, self.users = path, file, 1

    def release(self) -> None:
        self.users -= 1
        if self.users == 0:
            self.file.close()
            HostClaim.held.pop(self.path, None)


def claim_on_host(node: Any, topics: Iterable[str]) -> list[HostClaim]:
    """Exclusive locks on ``topics`` (fully qualified) in this node's ROS domain, held until each
    returned claim is released (the node does so when destroyed; the kernel when the process
    ends); ParameterError (one line, naming the holder) if another process of this host holds
    one. Nodes of one process (a test harness, a component container) share the process's
    claim: among them only the graph check tells."""
    domain = node.context.get_domain_id()
    folder = os.path.join(lock_dir(), f"domain-{domain}")
    os.makedirs(folder, mode=0o700, exist_ok=True)
    claims: list[HostClaim] = []
    for topic in topics:
        path = os.path.join(folder, re.sub(r"[^\w.-]", "_", topic.strip("/")) + ".lock")
        if path in HostClaim.held:
            claim = HostClaim.held[path]
            claim.users += 1
            claims.append(claim)
            continue
        f = open(path, "a+", encoding="utf-8")  # noqa: SIM115 (kept open: the lock lives with it)
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "another process"
            f.close()
            for c in claims:
                c.release()
            raise ParameterError(f"{holder} already runs on this host in ROS domain {domain} and publishes "
                                 f"{topic}: not starting a second one beside it (another namespace: "
                                 "-r __ns:=/r2, or stop the first)") from None
        f.seek(0)
        f.truncate()
        f.write(f"{node.get_fully_qualified_name()} (pid {os.getpid()})")
        f.flush()
        HostClaim.held[path] = claim = HostClaim(path, f)
        claims.append(claim)
    return claims


def refuse_if_taken(node: Any, topics: Iterable[str], since: float, wait: float = DISCOVERY_WAIT) -> None:
    """ParameterError (one line) if a process of this host holds ``topics`` (:func:`claim_on_host`;
    the node then holds them, in ``node.host_claims``), or if another node of this name and
    namespace, or another writer of one of ``topics`` (fully qualified), shows in the graph before
    ``since + wait`` (monotonic) and is alive (see the module doc); a silent one is one warning."""
    topics = list(topics)
    node.host_claims = [*getattr(node, "host_claims", []), *claim_on_host(node, topics)]
    # at least MIN_LOOK of looking now: a loaded machine's discovery may lag the node's own start-up
    deadline = max(since + wait, time.monotonic() + MIN_LOOK)
    while not (others := _others(node, topics)) and time.monotonic() < deadline:
        time.sleep(POLL)
    if not others:
        return
    named = {n for n in others if "_UNKNOWN_" not in n} or {node.get_fully_qualified_name()}
    alive = _alive(node, named | {node.get_fully_qualified_name()}, ALIVE_WAIT)
    if alive:
        raise ParameterError(f"{', '.join(sorted(alive))} already runs on this ROS domain and publishes "
                             f"{', '.join(topics)}: not starting a second one beside it (another namespace: "
                             "-r __ns:=/r2, or stop the first)")
    node.get_logger().warning(f"{', '.join(sorted(named))} shows in the ROS graph but is silent (stopped a moment "
                              "ago?): starting")
