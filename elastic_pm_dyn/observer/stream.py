"""Decoded messages -> observer calls: the one path shared by the offline pass and the live node.

The plant node in ``mode: observer`` converts its rclpy messages to these plain
arguments (stamps as integer nanoseconds, names, float arrays) and calls the same
methods as the offline command does with messages read from a bag, so both give the same
estimates for the same message sequence. Stamps are header stamps (the time the value
refers to), converted once as ns * 1e-9.

A torque command is a ``sensor_msgs/JointState`` with names and efforts (any order;
extra names ignored, every active joint required) or, with ``names`` empty, efforts in
the model's active-joint order (``std_msgs/Float64MultiArray``, the ros2_control form).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer.ekf import Observer, UpdateResult


def seconds(stamp_ns: int) -> float:
    return int(stamp_ns) * 1e-9


class ObserverStream:
    """Routes time-stamped samples to an :class:`Observer` and counts what it could not use."""

    def __init__(self, observer: Observer, command_joints: Sequence[str] | None = None):
        self.obs = observer
        active = observer.mech.active_names
        self.command_joints = list(command_joints) if command_joints else list(active)
        missing = [n for n in active if n not in self.command_joints]
        if missing:
            raise InputError(f"command joint order lacks active joint(s) {', '.join(missing)}")
        self._order = np.array([self.command_joints.index(n) for n in active], dtype=np.int64)
        self.bad_commands = 0
        self.last_error = ""
        self.results: list[UpdateResult] = []  # of the last call
        self._name_orders: dict[tuple, np.ndarray] = {}  # command names -> active joint order

    def command_tau(self, names: Sequence[str], effort) -> np.ndarray:
        """The efforts of a torque command in active-joint order (InputError if it lacks some)."""
        effort = np.asarray(effort, dtype=float)
        if len(names):
            key = tuple(names)
            order = self._name_orders.get(key)
            if order is None:
                lookup = {n: k for k, n in enumerate(names)}
                missing = [n for n in self.obs.mech.active_names if n not in lookup]
                if missing:
                    raise InputError(f"torque command without effort for {', '.join(missing)}")
                if len(self._name_orders) > 64:
                    self._name_orders.clear()
                order = self._name_orders[key] = np.array([lookup[n] for n in self.obs.mech.active_names],
                                                          dtype=np.int64)
            if len(effort) != len(names):
                raise InputError("torque command without effort for every name")
            return effort[order]
        if len(effort) != len(self.command_joints):
            raise InputError(f"torque command with {len(effort)} values, expected {len(self.command_joints)}")
        return effort[self._order]

    def on_torque_command(self, stamp_ns: int, names: Sequence[str], effort: Sequence[float]) -> bool:
        try:
            return self.obs.command(seconds(stamp_ns), self.command_tau(names, effort))
        except InputError as err:
            self.bad_commands += 1
            self.last_error = str(err)
            return False

    def on_joint_state(self, stamp_ns: int, names: Sequence[str], position: Sequence[float] = (),
                       velocity: Sequence[float] = (), effort: Sequence[float] = ()) -> list[UpdateResult]:
        self.results = self.obs.update_joint_states(seconds(stamp_ns), list(names), np.asarray(position, dtype=float),
                                                    np.asarray(velocity, dtype=float),
                                                    np.asarray(effort, dtype=float))
        return self.results

    def on_imu(self, stamp_ns: int, linear_acceleration: Sequence[float], frame_id: str = "") -> list[UpdateResult]:
        r = self.obs.update_imu(seconds(stamp_ns), np.asarray(linear_acceleration, dtype=float), frame_id)
        self.results = [] if r is None else [r]
        return self.results

    def on_branch_forces(self, stamp_ns: int, names: Sequence[str], force: Sequence[float]) -> list[UpdateResult]:
        r = self.obs.update_branch_forces(seconds(stamp_ns), list(names), np.asarray(force, dtype=float))
        self.results = [] if r is None else [r]
        return self.results
