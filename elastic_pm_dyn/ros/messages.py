"""Conversions between arrays and ROS messages, shared by the nodes.

Time stamps travel as integer nanoseconds so that simulated times k * period arrive
exactly (a float round trip could shift them by an ulp). Outgoing messages are built
once and refilled: numeric fields are set from ``array.array('d')``, which the generated
setters take without their per-element checks (this matters at 1-10 kHz).
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from builtin_interfaces.msg import Time
from elastic_pm_dyn_msgs.msg import BranchForces
from geometry_msgs.msg import PoseStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from elastic_pm_dyn.bags.msgtypes import NS
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.sim.plant import Plant

if TYPE_CHECKING:
    from elastic_pm_dyn.observer.ekf import Estimate


def doubles(values: np.ndarray | Sequence[float]) -> array:
    return array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())


def stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), NS)
    return Time(sec=sec, nanosec=nanosec)


class StateMessages:
    """joint_states, branch_forces and ee_pose of a mechanism, built once and refilled per publication."""

    def __init__(self, mech: Mechanism, base_frame: str):
        self.joint_state = JointState()
        self.joint_state.name = list(mech.joint_names)
        self.branch_forces = BranchForces()
        self.branch_forces.name = [b.name for b in mech.model.branches]
        self.ee_pose = PoseStamped()
        self.ee_pose.header.frame_id = base_frame
        self.ee_pose.pose.orientation.w = 1.0  # a point end effector: orientation not modelled
        self._ee_components = [int(c) for c in mech.ee_components]

    def _set_stamp(self, ns: int, headers: Sequence) -> None:
        sec, nanosec = divmod(ns, NS)
        for header in headers:
            header.stamp.sec, header.stamp.nanosec = sec, nanosec

    def _set(self, ns: int, q: np.ndarray, qd: np.ndarray, effort: np.ndarray, force: np.ndarray,
             deflection: np.ndarray, rate: np.ndarray, ee: np.ndarray) -> None:
        self._set_stamp(ns, (self.joint_state.header, self.branch_forces.header, self.ee_pose.header))
        js = self.joint_state
        js.position = doubles(q)
        js.velocity = doubles(qd)
        js.effort = doubles(effort)
        bf = self.branch_forces
        bf.force = doubles(force)
        bf.deflection = doubles(deflection)
        bf.deflection_rate = doubles(rate)
        pos = self.ee_pose.pose.position
        xyz = [0.0, 0.0, 0.0]
        for c, v in zip(self._ee_components, ee, strict=True):
            xyz[c] = float(v)
        pos.x, pos.y, pos.z = xyz


class PlantMessages(StateMessages):
    """The plant's state messages (and /clock), refilled from a :class:`Plant` for each publication."""

    def __init__(self, plant: Plant, base_frame: str):
        super().__init__(plant.mech, base_frame)
        self.plant = plant
        self.clock = Clock()

    def fill(self, ns: int) -> None:
        p = self.plant
        effort = p.efforts()
        b = p.branches(effort)
        self._set(ns, p.q, p.qd, effort, b.force, b.deflection, b.rate, p.end_effector())
        sec, nanosec = divmod(ns, NS)
        self.clock.clock.sec, self.clock.clock.nanosec = sec, nanosec


class EstimateMessages(StateMessages):
    """An observer :class:`~elastic_pm_dyn.observer.ekf.Estimate` as the plant's state messages
    (``branch_forces`` with ``force_stddev``) plus ``stddev``: a JointState whose position and
    velocity hold the 1-sigma standard deviations of every tree joint (effort empty)."""

    def __init__(self, mech: Mechanism, base_frame: str):
        super().__init__(mech, base_frame)
        self.stddev = JointState()
        self.stddev.name = list(mech.joint_names)

    def fill(self, ns: int, e: Estimate) -> None:
        self._set(ns, e.q, e.qd, e.effort, e.branch_force, e.deflection, e.deflection_rate, e.ee)
        self.branch_forces.force_stddev = doubles(e.branch_force_std)
        self._set_stamp(ns, (self.stddev.header,))
        self.stddev.position = doubles(e.q_std)
        self.stddev.velocity = doubles(e.qd_std)


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
