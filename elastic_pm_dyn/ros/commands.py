"""Torque commands -> motor torques in the mechanism's active order (no rclpy here).

Two wire forms, as ros2_control users know them:
- sensor_msgs/JointState: matched by ``name``, torques in ``effort``; every active joint
  must be named once, other names are an error (a typo must not pass as zero torque).
- std_msgs/Float64MultiArray: ``data`` in a configured joint order (the forward command
  controller convention).
Every rejection raises :class:`CommandError` (an :class:`InputError`) with a one-line
reason and its ``kind``, so that warnings can be throttled per kind.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from elastic_pm_dyn.errors import InputError


class CommandError(InputError):
    """A rejected command; ``kind`` names the reason (``length``, ``unknown name``, ``duplicate name``,
    ``missing joint``, ``not finite``)."""

    def __init__(self, kind: str, message: str):
        self.kind = kind
        super().__init__(message)


class CommandDecoder:
    """Checks a command and returns the torques (n_a,) in ``active_names`` order."""

    def __init__(self, active_names: Sequence[str], array_order: Sequence[str] | None = None):
        self.active_names = list(active_names)
        order = list(array_order) if array_order else self.active_names
        if sorted(order) != sorted(self.active_names):
            raise InputError(f"command joint order {order} must list each active joint once "
                             f"({', '.join(self.active_names)})")
        self.array_order = order
        # data[k] belongs to active joint _array_index[k]
        self._array_index = np.array([self.active_names.index(n) for n in order])

    def from_joint_state(self, names: Sequence[str], efforts: Sequence[float]) -> np.ndarray:
        names = list(names)
        if len(names) != len(efforts):
            raise CommandError("length", f"JointState command has {len(names)} names but {len(efforts)} efforts")
        unknown = [n for n in names if n not in self.active_names]
        if unknown:
            raise CommandError("unknown name", f"JointState command names unknown joint(s) {', '.join(unknown)} "
                             f"(active joints: {', '.join(self.active_names)})")
        if len(set(names)) != len(names):
            raise CommandError("duplicate name", "JointState command names a joint twice")
        missing = [n for n in self.active_names if n not in names]
        if missing:
            raise CommandError("missing joint", f"JointState command lacks active joint(s) {', '.join(missing)}")
        values = _finite(efforts, "JointState command")
        tau = np.empty(len(self.active_names))
        tau[[self.active_names.index(n) for n in names]] = values
        return tau

    def from_array(self, data: Sequence[float]) -> np.ndarray:
        if len(data) != len(self.array_order):
            raise CommandError("length", f"Float64MultiArray command has {len(data)} values, expected "
                             f"{len(self.array_order)} ({', '.join(self.array_order)})")
        tau = np.empty(len(self.active_names))
        tau[self._array_index] = _finite(data, "Float64MultiArray command")
        return tau


def _finite(values: Sequence[float], what: str) -> np.ndarray:
    try:
        out = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise CommandError("not finite", f"{what} holds values that are not numbers") from None
    if not np.all(np.isfinite(out)):
        raise CommandError("not finite", f"{what} contains NaN or Inf")
    return out
