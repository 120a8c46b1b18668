"""The plant node's external wrench on the end effector (parameters ``wrench.*``): its scenario,
its input topic and its truth topic. The physics is :mod:`elastic_pm_dyn.sim.wrench`'s; this
module only declares, validates, subscribes and publishes.

- ``wrench.scenario``: none | step | ramp (``wrench.value`` [fx, fy, fz, mx, my, mz] in the base
  frame, from ``wrench.start`` s on, a ramp over ``wrench.ramp`` s) | wall (a plane through
  ``wrench.wall_point`` with its normal ``wrench.wall_normal`` into free space, stiffness and
  damping ``wrench.wall_stiffness``, ``wrench.wall_damping``);
- ``wrench.input``: subscribe ``topics.wrench_input`` (geometry_msgs/WrenchStamped, base frame or
  an empty frame_id), each message held until the next, added to the scenario;
- the true wrench at t_k on ``topics.wrench`` (WrenchStamped, at the end-effector point, base
  frame), beside the states and with their stamp, whenever a wrench is configured.

Nothing of it exists unless configured: the plant then steps exactly as it did without it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.messages import stamp
from elastic_pm_dyn.ros.params import Param, ParameterError
from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_OUT_QOS
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.wrench import ExternalWrench, StepWrench, Wall, WrenchSource

SCENARIOS = ("none", "step", "ramp", "wall")
WRENCH_PARAMS = [
    Param("wrench.scenario", "none", "external wrench on the end effector: none | step | ramp | wall",
          choices=SCENARIOS),
    Param("wrench.value", [0.0, 0.0, 0.0, 0.0, 0.0, 0.0], "step / ramp: [fx, fy, fz, mx, my, mz] in the base frame "
          "[N, N m] (a couple only on a platform that turns)"),
    Param("wrench.start", 0.0, "[s] step / ramp: when it starts (the plant's time)"),
    Param("wrench.ramp", 0.0, "[s] ramp: how long it takes to reach wrench.value"),
    Param("wrench.wall_point", [0.0, 0.0, 0.0], "wall: a point of its plane [m], base frame"),
    Param("wrench.wall_normal", [0.0, 1.0, 0.0], "wall: its normal, pointing into free space"),
    Param("wrench.wall_stiffness", 1.0e4, "wall: [N/m]", positive=True),
    Param("wrench.wall_damping", 0.0, "wall: [N s/m] (pushes only, never pulls)"),
    Param("wrench.input", False, "subscribe topics.wrench_input: a wrench held until the next message"),
    Param("topics.wrench_input", "wrench_input", "input: geometry_msgs/WrenchStamped on the end effector, base frame"),
    Param("topics.wrench", "wrench", "truth: geometry_msgs/WrenchStamped, the external wrench at t_k"),
]


def external_wrench(p: dict[str, Any]) -> ExternalWrench | None:
    """The ``wrench.*`` parameters as an ExternalWrench (None: no wrench at all); ParameterError
    (one line) when out of range."""
    kind = p["wrench.scenario"]
    if kind == "none" and not p["wrench.input"]:
        return None
    try:
        sources: list[WrenchSource] = []
        if kind in ("step", "ramp"):
            ramp = p["wrench.ramp"] if kind == "ramp" else 0.0
            sources.append(StepWrench(p["wrench.start"], p["wrench.value"], ramp))
        elif kind == "wall":
            sources.append(Wall(p["wrench.wall_point"], p["wrench.wall_normal"], p["wrench.wall_stiffness"],
                                p["wrench.wall_damping"]))
    except InputError as err:
        raise ParameterError(f"parameter wrench.*: {err}") from None
    return ExternalWrench(sources)


class WrenchIO:
    """The input subscription (``wrench.input``) and the truth publisher of a plant with a wrench."""

    def __init__(self, node: Node, plant: Plant, p: dict[str, Any], frame: str):
        self.node, self.plant, self.frame = node, plant, frame
        self.pub = node.create_publisher(WrenchStamped, p["topics.wrench"], STATE_OUT_QOS)
        self.rejected = 0
        if p["wrench.input"]:
            node.create_subscription(WrenchStamped, p["topics.wrench_input"], self._on_wrench, COMMAND_QOS)

    def _on_wrench(self, msg: WrenchStamped) -> None:
        """Hold a received wrench; a bad one (not finite, another frame) is one warning line and the last holds."""
        f, m = msg.wrench.force, msg.wrench.torque
        w = np.array([f.x, f.y, f.z, m.x, m.y, m.z])
        frame = msg.header.frame_id
        try:
            if frame and frame != self.frame:
                raise InputError(f"frame {frame!r}, expected {self.frame!r} (or empty)")
            if np.any(w[3:] != 0) and not self.plant.wrench_map.turns:
                raise InputError("a couple on an end effector that cannot turn")
            self.plant.wrench.hold(w)
        except InputError as err:
            self.rejected += 1
            self.node.get_logger().warning(f"external wrench rejected: {err}; the last valid one holds",
                                           throttle_duration_sec=1.0)

    def publish(self, ns: int) -> None:
        """The true wrench at the plant's current state, stamped ``ns``."""
        msg = WrenchStamped()
        msg.header.stamp = stamp(ns)
        msg.header.frame_id = self.frame
        w = self.plant.true_wrench
        f, m = msg.wrench.force, msg.wrench.torque
        f.x, f.y, f.z, m.x, m.y, m.z = (float(v) for v in w)
        self.pub.publish(msg)
