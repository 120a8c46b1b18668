"""The machine as URDF on ``robot_description``, for robot_state_publisher and RViz.

A URDF machine publishes its own file (meshes and all); a model YAML or an MJCF the URDF
that :func:`~elastic_pm_dyn.model.urdf_writer.model_to_urdf` writes (one link per joint,
joint names the model's). robot_state_publisher places the links from ``joint_states``.
A URDF is a tree, so it cannot hold a loop closure: the loops are drawn closed because
every tree joint is published (the two sides of a cut meet where the closure holds them).
The node lists those closures once at start-up; a joint of ``joint_states`` that the URDF
lacks (a joint a closure sidecar re-typed as a ball, published as ``<joint>_x/_y/_z``) is
one that robot_state_publisher ignores, and the node names it in a warning.

Published once at start-up, reliable, keep last 1, transient local (as robot_state_publisher
does), so RViz or a tool that starts later still gets it. The ``model`` parameter is
read-only: the machine never changes while the node runs, so there is nothing to publish again.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.model.urdf_writer import model_to_urdf

DESCRIPTION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)


def robot_description(model: Model) -> str:
    """The URDF text of ``model``: a URDF machine's own file, else the written one."""
    return model_to_urdf(model)


def robot_description_of_file(path: str | Path) -> str:
    """The URDF text of a model file (what a plant node with ``model: path`` publishes); for launch files."""
    return robot_description(load_model(path))


def urdf_joint_names(text: str) -> list[str]:
    """Names of the ``<joint>`` elements of a URDF, in file order."""
    return [j.get("name", "") for j in ET.fromstring(text).iter("joint")]


def urdf_root_link(text: str) -> str:
    """The link of a URDF that no joint has as child: the frame the machine stands in (RViz's fixed frame)."""
    root = ET.fromstring(text)
    children = {c.get("link") for j in root.iter("joint") for c in j.iter("child")}
    roots = [link.get("name", "") for link in root.iter("link") if link.get("name") not in children]
    return roots[0] if roots else ""


def missing_joints(text: str, joint_names: Sequence[str]) -> list[str]:
    """The names in ``joint_names`` that are not joints of the URDF ``text`` (robot_state_publisher ignores them)."""
    known = set(urdf_joint_names(text))
    return [n for n in joint_names if n not in known]


def loop_closures(model: Model) -> list[str]:
    """The closure pairs that the URDF tree leaves open, as ``a = b`` of the model's point labels."""
    if model.closure is None:
        return []
    labels = [label for _, _, label in model.point_list()]
    return [f"{labels[a]} = {labels[b]}" for a, b in model.closure.pairs]


def publish_robot_description(node: Node, mech: Mechanism, p: dict[str, Any]) -> Publisher | None:
    """Publish ``mech``'s URDF once on ``p["topics.robot_description"]`` (transient local) unless
    ``p["publish_robot_description"]`` is false; log what RViz will and will not draw."""
    if not p["publish_robot_description"]:
        return None
    text = robot_description(mech.model)
    pub = node.create_publisher(String, p["topics.robot_description"], DESCRIPTION_QOS)
    pub.publish(String(data=text))
    log = node.get_logger()
    loops = loop_closures(mech.model)
    log.info(f"robot_description on '{pub.topic_name}': {len(urdf_joint_names(text))} joints"
             + (f"; loops closed by joint_states, not by the URDF: {', '.join(loops)}" if loops else ""))
    missing = missing_joints(text, mech.joint_names)
    if missing:
        log.warning(f"robot_description: joints of joint_states that the URDF does not have "
                    f"(robot_state_publisher ignores them): {', '.join(missing)}")
    return pub
