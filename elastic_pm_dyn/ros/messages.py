"""Conversions between arrays and ROS messages, shared by the nodes.

Time stamps travel as integer nanoseconds so that simulated times k * period arrive
exactly (a float round trip could shift them by an ulp). Outgoing messages are built
once and refilled: numeric fields are set from ``array.array('d')``, which the generated
setters take without their per-element checks (this matters at 1-10 kHz). The plant's
four 1 kHz topics go further (:class:`PlantMessages`): each message is serialized once
and its stamp and numbers are then written into the bytes in place, which rclpy publishes
as they are (``Publisher.publish(bytes)``: no conversion of a Python message, no CDR
serialization in the middleware; bench/benchmarks/README_plant.md has the times).
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from builtin_interfaces.msg import Time
from elastic_pm_dyn_msgs.msg import BranchForces
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from elastic_pm_dyn.bags import cdr
from elastic_pm_dyn.bags.msgtypes import NS
from elastic_pm_dyn.kinematics.kernels import chain_points
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.sim.plant import Plant

if TYPE_CHECKING:
    from elastic_pm_dyn.observer.core.estimate import Estimate


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
        self._ee_unit, self._ee_axes = mech.ee_unit, mech.ee_axes

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
        pos.x, pos.y, pos.z = ee_in_base(ee, self._ee_unit, self._ee_axes)


def ee_in_base(ee: np.ndarray, unit: list[int] | None, axes: np.ndarray) -> tuple[float, float, float]:
    """The end effector's components (``axes``' directions) as a point of the base frame: the
    coordinates themselves where they are base axes (0 for the others), else sum ee_k axes_k,
    the point's projection on the machine's plane through the origin (a tilted planar machine)."""
    if unit is not None:
        xyz = [0.0, 0.0, 0.0]
        for c, v in zip(unit, ee, strict=True):
            xyz[c] = float(v)
        return xyz[0], xyz[1], xyz[2]
    x, y, z = (float(c) for c in np.asarray(ee, dtype=float) @ axes)
    return x, y, z


_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time right after the 4-byte CDR encapsulation
_CLOCK_SIZE = 12  # encapsulation + rosgraph_msgs/Clock (one Time)


class SerializedMessage:
    """One message kept as its CDR bytes: a template serialized once by :mod:`elastic_pm_dyn.bags.cdr`,
    whose header stamp and float64 arrays are then overwritten in place (``arrays[k]`` is a
    writable float64 view of the k-th array's bytes). Lengths and names never change after
    construction, so neither does anything but the numbers."""

    def __init__(self, encode, lengths: Sequence[int]):
        # Distinct sentinels locate each array in the template: the layout is the CDR writer's.
        sentinels = [np.full(n, -(k + 1.5) * 2.0**-40) for k, n in enumerate(lengths)]
        template = bytes(encode(sentinels))
        self.buffer = bytearray(template)
        self.arrays: list[np.ndarray] = []
        for values in sentinels:
            if not len(values):
                self.arrays.append(np.zeros(0))
                continue
            offset = template.find(values.tobytes())
            if offset < 0 or template.find(values.tobytes(), offset + 1) >= 0:
                raise ValueError("float64 array not found exactly once in its serialized template")
            view = np.frombuffer(self.buffer, dtype="<f8", count=len(values), offset=offset)
            view[:] = 0.0
            self.arrays.append(view)

    def set_stamp(self, sec: int, nanosec: int) -> None:
        _STAMP.pack_into(self.buffer, 4, sec, nanosec)

    def raw(self) -> bytes:
        """What :meth:`rclpy.publisher.Publisher.publish` takes (it wants ``bytes``, not a bytearray)."""
        return bytes(self.buffer)


class SerializedStates:
    """``joint_states``, ``branch_forces`` and ``ee_pose`` of ``mech`` kept as CDR bytes
    (:class:`SerializedMessage` ``_js``, ``_bf`` (with ``force_stddev`` if ``with_stddev``, else
    empty), ``_pose``): the bytes to publish, and the same decoded as rclpy messages (for
    inspection, not for the 1 kHz path)."""

    def __init__(self, mech: Mechanism, base_frame: str, with_stddev: bool):
        n, names = mech.n, list(mech.joint_names)
        branches = [b.name for b in mech.model.branches]
        nb = len(branches)
        self._js = SerializedMessage(lambda a: cdr.encode_joint_state(0, names, *a), (n, n, n))
        if with_stddev:
            self._bf = SerializedMessage(lambda a: cdr.encode_branch_forces(0, branches, *a), (nb,) * 4)
        else:
            self._bf = SerializedMessage(lambda a: cdr.encode_branch_forces(0, branches, *a, np.zeros(0)), (nb,) * 3)
        # PoseStamped: position xyz, then the orientation (0, 0, 0, 1): a point end effector has none.
        self._pose = SerializedMessage(lambda a: cdr.encode_pose_stamped_batch([0], a[0][:3], base_frame)[0],
                                       (3,))

    @property
    def joint_state_raw(self) -> bytes:
        return self._js.raw()

    @property
    def branch_forces_raw(self) -> bytes:
        return self._bf.raw()

    @property
    def ee_pose_raw(self) -> bytes:
        return self._pose.raw()

    @property
    def joint_state(self) -> JointState:
        return deserialize_message(self.joint_state_raw, JointState)

    @property
    def branch_forces(self) -> BranchForces:
        return deserialize_message(self.branch_forces_raw, BranchForces)

    @property
    def ee_pose(self) -> PoseStamped:
        return deserialize_message(self.ee_pose_raw, PoseStamped)


class PlantMessages(SerializedStates):
    """The plant's ``joint_states``, ``branch_forces``, ``ee_pose`` and ``/clock``, serialized once and
    refilled from a :class:`Plant` in place for each publication (:meth:`fill`, then the ``*_raw``
    bytes to publish). Field by field they are what :class:`StateMessages` would build from the
    same state: every number comes from the same arithmetic as :meth:`Plant.efforts`,
    :meth:`Plant.branches` and :meth:`Plant.end_effector`, into arrays allocated once."""

    def __init__(self, plant: Plant, base_frame: str):
        self.plant = plant
        mech = plant.mech
        super().__init__(mech, base_frame, with_stddev=False)
        n = mech.n
        self._clock = bytearray(cdr.ENCAPSULATION + bytes(_CLOCK_SIZE - len(cdr.ENCAPSULATION)))
        self.position, self.velocity, self.effort = self._js.arrays
        self.force, self.deflection, self.rate = self._bf.arrays
        self.ee_xyz = self._pose.arrays[0]
        # Scratch of the per-period arithmetic (Plant.efforts in place; branches as Plant.branches).
        self._spring = np.empty(n)
        self._damper = np.empty(n)
        self._origins, self._coms = np.empty((n, 3)), np.empty((n, 3))
        self._tips = np.empty((mech.n_points, 3))
        self._ee_chain = mech.model.end_effector_chain
        self._ee_unit = np.asarray(mech.ee_unit if mech.ee_unit is not None else [], dtype=np.int64)
        # world point -> its in-plane components -> back in the base frame (a tilted plane's)
        self._ee_projector = np.ascontiguousarray(mech.ee_axes.T @ mech.ee_axes)
        self.stamp_ns = 0

    def fill(self, ns: int) -> None:
        p, mech = self.plant, self.plant.mech
        self.stamp_ns = ns
        sec, nanosec = divmod(ns, NS)
        for m in (self._js, self._bf, self._pose):
            m.set_stamp(sec, nanosec)
        _STAMP.pack_into(self._clock, 4, sec, nanosec)
        q, qd = p.q, p.qd
        self.position[:] = q
        self.velocity[:] = qd
        effort = p.efforts(self.effort, self._spring, self._damper)
        j = mech.branch_joints
        self.force[:] = effort[j]
        np.subtract(q[j], mech.rest[j], out=self.deflection)
        self.rate[:] = qd[j]
        ma = mech.arrays
        chain_points(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, q, self._origins, self._coms,
                     self._tips)
        if len(self._ee_unit):
            self.ee_xyz[self._ee_unit] = self._tips[self._ee_chain, self._ee_unit]
        else:
            np.dot(self._ee_projector, self._tips[self._ee_chain], out=self.ee_xyz)

    @property
    def clock_raw(self) -> bytes:
        return bytes(self._clock)

    @property
    def clock(self) -> Clock:
        return deserialize_message(self.clock_raw, Clock)


class EstimateMessages(SerializedStates):
    """An observer :class:`~elastic_pm_dyn.observer.core.estimate.Estimate` as the plant's state messages
    (``branch_forces`` with ``force_stddev``) plus ``stddev``: a JointState whose position and
    velocity hold the 1-sigma standard deviations of every tree joint (effort empty). Serialized
    once and refilled in place as :class:`PlantMessages` (:meth:`fill`, then the ``*_raw`` bytes);
    field by field what :class:`StateMessages` builds from the same estimate."""

    def __init__(self, mech: Mechanism, base_frame: str):
        super().__init__(mech, base_frame, with_stddev=True)
        names = list(mech.joint_names)
        self._std = SerializedMessage(lambda a: cdr.encode_joint_state(0, names, *a, np.zeros(0)), (mech.n,) * 2)
        self._ee_unit, self._ee_axes = mech.ee_unit, mech.ee_axes

    def fill(self, ns: int, e: Estimate) -> None:
        sec, nanosec = divmod(ns, NS)
        for m in (self._js, self._bf, self._pose, self._std):
            m.set_stamp(sec, nanosec)
        for view, values in zip((*self._js.arrays, *self._bf.arrays, *self._std.arrays),
                                (e.q, e.qd, e.effort, e.branch_force, e.deflection, e.deflection_rate,
                                 e.branch_force_std, e.q_std, e.qd_std), strict=True):
            view[:] = values
        self._pose.arrays[0][:] = ee_in_base(e.ee, self._ee_unit, self._ee_axes)

    @property
    def stddev_raw(self) -> bytes:
        return self._std.raw()

    @property
    def stddev(self) -> JointState:
        return deserialize_message(self.stddev_raw, JointState)


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
