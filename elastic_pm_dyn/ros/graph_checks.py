"""Checks of a starting node against the ROS graph and its own topic names.

- :func:`resolved_topics`: every topic parameter resolved as the node's publishers will resolve
  it (namespace, ``~``, remappings); a name that is no topic name is one ParameterError line at
  start-up instead of rclpy's traceback when the publisher is made.
- :func:`refuse_if_taken`: a node that stands for a machine (the plant) does not start where one
  already runs: the same node name in the same namespace, or another writer of its state topics
  (two plants in ``/r1`` interleave their states on ``/r1/joint_states`` and both serve
  ``/r1/plant/step``). Discovery takes a moment, so the check waits until the node has been in
  the graph for :data:`DISCOVERY_WAIT` (the model's loading usually covers it).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

from elastic_pm_dyn.ros.params import ParameterError

DISCOVERY_WAIT = 1.0  # [s] in the graph before a node is sure it is alone (local discovery: ~0.1-0.5 s)
POLL = 0.05  # [s]


def resolved_topics(node: Any, p: dict[str, Any], names: Iterable[str]) -> dict[str, str]:
    """Parameter name -> fully qualified topic, for the topic parameters ``names`` of ``p``."""
    out = {}
    for name in names:
        topic = p[name]
        try:
            if not isinstance(topic, str) or not topic.strip():
                raise RuntimeError("empty")
            out[name] = node.resolve_topic_name(topic)
        except RuntimeError as err:  # rclpy's RCLError: "failed to resolve name: <why>, at <source>"
            why = str(err).removeprefix("failed to resolve name: ").split(", at /")[0]
            raise ParameterError(f"parameter '{name}': {topic!r} is no topic name ({why})") from None
    return out


def refuse_if_taken(node: Any, topics: Iterable[str], since: float, wait: float = DISCOVERY_WAIT) -> None:
    """ParameterError (one line) if another node of this name and namespace, or another writer of
    one of ``topics`` (fully qualified), shows in the graph before ``since + wait`` (monotonic)."""
    me = (node.get_name(), node.get_namespace())
    topics = list(topics)
    while True:
        same = sum(1 for n in node.get_node_names_and_namespaces() if n == me)
        if same > 1:
            raise ParameterError(f"a node {node.get_fully_qualified_name()} already runs on this ROS domain: "
                                 "not starting a second one beside it (start it in another namespace, "
                                 "-r __ns:=/r2, or stop the first)")
        for topic in topics:
            infos = node.get_publishers_info_by_topic(topic)
            writers = [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos]
            if writers:
                raise ParameterError(f"{topic} is already published by {', '.join(sorted(set(writers)))}: not "
                                     "starting a second machine on it (another namespace: -r __ns:=/r2)")
        if time.monotonic() >= since + wait:
            return
        time.sleep(POLL)
