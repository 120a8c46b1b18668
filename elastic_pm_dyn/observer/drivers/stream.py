"""Decoded messages -> observer calls: the one path shared by the offline pass and the live node.

The plant node in ``mode: observer`` converts its rclpy messages to these plain
arguments (stamps as integer nanoseconds, names, float arrays) and calls the same
methods as the offline command does with messages read from a bag, so both give the same
estimates for the same message sequence. Stamps are header stamps (the time the value
refers to).

Time origin: the filter runs on float seconds since an integer-ns origin
(:attr:`ObserverStream.origin_ns`, by default the first stamp the stream sees), so that epoch
stamps (~1.7e9 s, where a double's spacing is 0.24 us) keep their nanoseconds: a stamp
becomes ``(stamp_ns - origin_ns) * 1e-9``, the integer difference exact. The estimates
keep the exact stamps (integer ns); their ``t`` is relative to the origin.

A torque command is a ``sensor_msgs/JointState`` with names and efforts (any order;
extra names ignored, every active joint required) or, with ``names`` empty, efforts in
the model's active-joint order (``std_msgs/Float64MultiArray``, the ros2_control form).

A measured joint state must name every configured encoder joint once: one that names a
joint twice (``duplicate``), lacks a configured one (``missing``) or names no joint of the
model at all (``unknown``: another machine's, or prefixed names) is not used and counted
per reason (:attr:`ObserverStream.joint_state_rejections`); names of joints the observer
does not measure are ignored. Each distinct name list is checked once.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.observer.schedule.sensor_stats import UpdateResult

NAME_PROBLEMS = ("duplicate", "missing", "unknown")  # why a joint state's names are not used


class ObserverStream:
    """Routes time-stamped samples to an :class:`Observer` and counts what it could not use."""

    def __init__(self, observer: Observer, command_joints: Sequence[str] | None = None,
                 origin_ns: int | None = None):
        self.obs = observer
        # None: set by the first stamp, which then maps to the observer's time (0 for an
        # observer made at t0 = 0, the usual case)
        self.origin_ns = None if origin_ns is None else int(origin_ns)
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
        self.joint_state_rejections: Counter[str] = Counter()  # reason -> joint states not used
        self.last_joint_state_problem = ""
        self._name_checks: dict[tuple, tuple[str, str]] = {}  # joint-state names -> (reason, detail)
        enc = observer.encoders
        self._measured = ([] if enc is None else
                          list(dict.fromkeys(observer.mech.joint_names[j] for j in enc.pos + enc.vel)))
        self._joint_names = set(observer.mech.joint_names)

    def seconds(self, stamp_ns: int) -> float:
        """The filter time of a stamp: seconds since :attr:`origin_ns` (the integer difference exact)."""
        ns = int(stamp_ns)
        if self.origin_ns is None:
            self.origin_ns = ns - round(self.obs.t * 1e9)
        return (ns - self.origin_ns) * 1e-9

    def name_problem(self, names: Sequence[str]) -> tuple[str, str]:
        """("", "") if a joint state with these names can be used, else (reason, detail): reason
        one of :data:`NAME_PROBLEMS`. Checked once per distinct name list."""
        key = tuple(names)
        hit = self._name_checks.get(key)
        if hit is None:
            hit = ("", "")
            counts = Counter(key)
            twice = [n for n, c in counts.items() if c > 1]
            if twice:
                hit = ("duplicate", f"names {', '.join(map(repr, twice))} more than once")
            elif key and not self._joint_names.intersection(key):
                hit = ("unknown", f"no joint of the model among {', '.join(map(repr, key[:4]))}"
                                  + (" ..." if len(key) > 4 else ""))
            else:
                missing = [n for n in self._measured if n not in counts]
                if missing:
                    hit = ("missing", f"without the measured joint(s) {', '.join(map(repr, missing))}")
            if len(self._name_checks) > 64:
                self._name_checks.clear()
            self._name_checks[key] = hit
        return hit

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
            return self.obs.command(self.seconds(stamp_ns), self.command_tau(names, effort))
        except InputError as err:
            self.bad_commands += 1
            self.last_error = str(err)
            return False

    def on_joint_state(self, stamp_ns: int, names: Sequence[str], position: Sequence[float] = (),
                       velocity: Sequence[float] = (), effort: Sequence[float] = ()) -> list[UpdateResult]:
        t = self.seconds(stamp_ns)
        reason, detail = self.name_problem(names)
        if reason:
            self.joint_state_rejections[reason] += 1
            self.last_joint_state_problem = f"joint state at t = {t:.6f} s not used ({reason} names): {detail}"
            self.results = [UpdateResult("encoders", t, False, reason=reason)]
            return self.results
        self.results = self.obs.update_joint_states(t, list(names), np.asarray(position, dtype=float),
                                                    np.asarray(velocity, dtype=float),
                                                    np.asarray(effort, dtype=float))
        return self.results

    def on_imu(self, stamp_ns: int, linear_acceleration: Sequence[float], frame_id: str = "") -> list[UpdateResult]:
        r = self.obs.update_imu(self.seconds(stamp_ns), np.asarray(linear_acceleration, dtype=float), frame_id)
        self.results = [] if r is None else [r]
        return self.results

    def on_branch_forces(self, stamp_ns: int, names: Sequence[str], force: Sequence[float]) -> list[UpdateResult]:
        r = self.obs.update_branch_forces(self.seconds(stamp_ns), list(names), np.asarray(force, dtype=float))
        self.results = [] if r is None else [r]
        return self.results
