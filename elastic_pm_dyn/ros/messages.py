"""Conversions between arrays and ROS messages, shared by the nodes.

Time stamps travel as integer nanoseconds so that simulated times k * period arrive
exactly (a float round trip could shift them by an ulp). Outgoing messages are built
once and refilled: numeric fields are set from ``array.array('d')``, which the generated
setters take without their per-element checks (this matters at 1-10 kHz).
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence

import numpy as np
from builtin_interfaces.msg import Time
from elastic_pm_dyn_msgs.msg import BranchForces
from geometry_msgs.msg import PoseStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from elastic_pm_dyn.ros.plant import Plant

NS = 1_000_000_000


def doubles(values: np.ndarray | Sequence[float]) -> array:
    return array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


def stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), NS)
    return Time(sec=sec, nanosec=nanosec)


def stamp_ns(msg_stamp: Time) -> int:
    return msg_stamp.sec * NS + msg_stamp.nanosec


class PlantMessages:
    """The plant's state messages, refilled from a :class:`Plant` for each publication."""

    def __init__(self, plant: Plant, base_frame: str):
        mech = plant.mech
        self.plant = plant
        self.joint_state = JointState()
        self.joint_state.name = list(mech.joint_names)
        self.branch_forces = BranchForces()
        self.branch_forces.name = [b.name for b in mech.model.branches]
        self.ee_pose = PoseStamped()
        self.ee_pose.header.frame_id = base_frame
        self.ee_pose.pose.orientation.w = 1.0  # a point end effector: orientation not modelled
        self._ee_components = [int(c) for c in mech.ee_components]
        self.clock = Clock()

    def fill(self, ns: int) -> None:
        p = self.plant
        sec, nanosec = divmod(ns, NS)
        for header in (self.joint_state.header, self.branch_forces.header, self.ee_pose.header):
            header.stamp.sec, header.stamp.nanosec = sec, nanosec
        self.clock.clock.sec, self.clock.clock.nanosec = sec, nanosec
        js = self.joint_state
        effort = p.efforts()
        js.position = doubles(p.q)
        js.velocity = doubles(p.qd)
        js.effort = doubles(effort)
        b = p.branches(effort)
        bf = self.branch_forces
        bf.force = doubles(b.force)
        bf.deflection = doubles(b.deflection)
        bf.deflection_rate = doubles(b.rate)
        pos = self.ee_pose.pose.position
        xyz = [0.0, 0.0, 0.0]
        for c, v in zip(self._ee_components, p.end_effector(), strict=True):
            xyz[c] = float(v)
        pos.x, pos.y, pos.z = xyz


def torque_command(kind: str, names: Sequence[str], tau: np.ndarray, ns: int) -> JointState | Float64MultiArray:
    """A torque command in the configured wire form; ``names`` give the order of ``tau``."""
    if kind == "joint_state":
        msg = JointState()
        msg.header.stamp = stamp(ns)
        msg.name = list(names)
        msg.effort = doubles(tau)
        return msg
    msg = Float64MultiArray()
    msg.data = doubles(tau)
    return msg


def joint_state(names: Sequence[str], ns: int, position: np.ndarray, velocity: np.ndarray,
                effort: np.ndarray) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp(ns)
    msg.name = list(names)
    msg.position = doubles(position)
    msg.velocity = doubles(velocity)
    msg.effort = doubles(effort)
    return msg
