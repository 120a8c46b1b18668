"""Cartesian goals: a ``trajectory_msgs/MultiDOFJointTrajectory`` as a path of the task coordinates.

Why that message: it is ROS's trajectory of poses (one ``geometry_msgs/Transform`` per
multi-DOF joint and point, optional twists and accelerations, ``time_from_start``), the
Cartesian sibling of the JointTrajectory the node already takes, and what MoveIt and
joint_trajectory_controller users hand over for a floating or planar joint.

Rules (each broken rule: one :class:`InputError` line, nothing else happens):

- ``joint_names``: exactly one, naming the end effector: ``end_effector``, or the platform
  chain's name where the machine has one (``platform`` on the Triglide and the Hexa);
- ``header.frame_id``: empty or the base frame (``frames.base``, ``world``);
- the transform is the platform frame's pose (Triglide: x, y, z; Hexa: x, y, z and the
  orientation, given as a quaternion, read as R = Rz(yaw) Ry(pitch) Rx(roll)) or the end-effector
  point's position (five-bar: x, y; z must be the machine's plane). A goal that fixes more
  than the task coordinates can hold (a rotation of a point or a level platform, a point out
  of the plane) is refused;
- at least two points, ``time_from_start`` >= 0 and strictly increasing, finite numbers,
  unit quaternions (to 1e-3; then normalised);
- twists and accelerations left out or zero: the path passes every waypoint at rest (each
  segment a rest-to-rest move with the time law, a rotation on its SO(3) geodesic:
  :class:`~elastic_pm_dyn.motion.waypoints.WaypointPath`, the CLI's ``--waypoints``);
- given (in the base frame, like the transforms; the angular ones the platform's angular
  velocity and acceleration): the path passes the waypoints with them, per coordinate the
  Hermite polynomial of the time law's continuity C^r (r = 2, quintic, for rigid as
  joint_trajectory_controller; r = 4 for elastic;
  :class:`~elastic_pm_dyn.motion.waypoints.MovingWaypointPath`, angles as coordinates). The
  first and the last point must be at rest; a twist the task cannot hold (a turn of a point)
  is refused like such a pose.

The path starts at the first point (the plant must stand there, as for a JointTrajectory)
and rests there until its ``time_from_start``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.feedforward import path_shaper, rigid_feedforward
from elastic_pm_dyn.motion.poses import _rates_matrix, _rates_matrix_dot
from elastic_pm_dyn.motion.references import ElasticLineReference, TaskReference
from elastic_pm_dyn.motion.shaping import ShapedPath
from elastic_pm_dyn.motion.task import Task
from elastic_pm_dyn.motion.waypoints import MovingWaypointPath, WaypointPath
from elastic_pm_dyn.sim.held_feedforward import DEFAULT_INVERSE, HeldLineReference

END_EFFECTOR = "end_effector"
POSITION_TOLERANCE = 1e-6  # [m] a coordinate the machine cannot move must match to this
ANGLE_TOLERANCE = 1e-6  # [rad] likewise a rotation the machine cannot make
UNIT_TOLERANCE = 1e-3  # |q| - 1 of a quaternion accepted (and normalised)
REST_TOLERANCE = 1e-9  # twist and acceleration components taken as zero
NS = 1_000_000_000
MIN_PERIODS = 10  # a goal shorter than this many control periods would not be in its torques (the CLI's rule)
# The goal is computed in a child process beside the command stream (ros.goal_worker): 1e5
# control instants (100 s at 1 kHz) take some 10-60 s on one core, and its table that much memory
MAX_SAMPLES = 100_000
_AXES = ([1, 0, 0], [0, 1, 0], [0, 0, 1])


def goal_names(model: Model) -> list[str]:
    """The names a goal's single joint may have."""
    closure = model.closure
    names = [END_EFFECTOR]
    if closure is not None and closure.hub >= 0:
        names.append(model.chains[closure.hub].name)
    return names


def _check_platform_chain(model: Model, size: int) -> None:
    """The platform's coordinates must be the transform's: prismatic x, y, z (then revolute z,
    y, x) from the base, no offsets."""
    chain = model.chains[model.closure.hub]
    for k, joint in enumerate(chain.joints[:size]):
        kind = "prismatic" if k < 3 else "revolute"
        axis = _AXES[k] if k < 3 else _AXES[5 - k]
        if (joint.type != kind or not np.allclose(joint.axis, axis) or np.any(joint.origin_xyz)
                or np.any(joint.origin_rpy)):
            raise InputError(f"{model.name}: the platform chain '{chain.name}' is not x, y, z[, yaw, pitch, roll] "
                             "from the base: Cartesian goals need its coordinates to be the platform frame's pose")


def _seconds(duration: Any) -> float:
    return duration.sec + duration.nanosec / NS


def _vector(v: Any) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=float)


def goal_waypoints(msg: Any, model: Model, frame: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(times, task coordinates, their rates, their accelerations per point) of a
    MultiDOFJointTrajectory (see module doc)."""
    ff = rigid_feedforward(model)
    mech = ff.mech
    task = Task(mech)
    names = list(msg.joint_names)
    if len(names) != 1 or names[0] not in goal_names(model):
        raise InputError(f"joint_names {names}: give one, the end effector: {' or '.join(goal_names(model))}")
    if msg.header.frame_id not in ("", frame):
        raise InputError(f"frame '{msg.header.frame_id}': goals are poses in the base frame '{frame}' (or empty)")
    points = list(msg.points)
    if len(points) < 2:
        raise InputError(f"{len(points)} point(s): a goal needs at least two (the first is where the machine "
                         "stands when it starts)")
    times = np.array([_seconds(p.time_from_start) for p in points])
    if times[0] < 0 or np.any(np.diff(times) <= 0):
        raise InputError("time_from_start must be >= 0 and strictly increasing")
    rows, rates, accs = [], [], []
    angles_before = ff.q[task.joints[3:]] if task.kind == "platform" and task.size == 6 else None
    for k, p in enumerate(points):
        if len(p.transforms) != 1:
            raise InputError(f"point {k}: {len(p.transforms)} transforms for 1 joint")
        twist = []
        for what in ("velocities", "accelerations"):
            twists = getattr(p, what)
            if len(twists) not in (0, 1):
                raise InputError(f"point {k}: {len(twists)} {what} for 1 joint")
            values = (np.concatenate([_vector(twists[0].linear), _vector(twists[0].angular)]) if len(twists)
                      else np.zeros(6))
            if not np.all(np.isfinite(values)):
                raise InputError(f"point {k}: {what} contain NaN or Inf")
            twist.append(np.where(np.abs(values) > REST_TOLERANCE, values, 0.0))
        tr = p.transforms[0]
        xyz = _vector(tr.translation)
        quat = np.array([tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w], dtype=float)
        if not np.all(np.isfinite(np.concatenate([xyz, quat]))):
            raise InputError(f"point {k}: NaN or Inf in the transform")
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > UNIT_TOLERANCE:
            raise InputError(f"point {k}: rotation quaternion of norm {norm:.6g}, not a unit quaternion")
        rotation = Rotation.from_quat(quat / norm)
        rows.append(_task_row(k, xyz, rotation, model, mech, task, ff.q, angles_before))
        r, a = _task_rates(k, twist[0], twist[1], rotation, rows[-1], mech, task, model)
        rates.append(r)
        accs.append(a)
        if angles_before is not None:
            angles_before = rows[-1][3:]
    return times, np.array(rows), np.array(rates), np.array(accs)


def _task_rates(k: int, velocity: np.ndarray, acceleration: np.ndarray, rotation: Rotation, y: np.ndarray,
                mech: Mechanism, task: Task, model: Model) -> tuple[np.ndarray, np.ndarray]:
    """The task coordinates' rates and accelerations of a twist and its rate (base frame)."""
    if not (np.any(velocity) or np.any(acceleration)):
        return np.zeros(len(y)), np.zeros(len(y))
    if task.kind == "platform" and task.size == 6:
        # Euler rates: w_body = R^T w = E [yawd, pitchd, rolld]; the body acceleration is R^T alpha
        E = _rates_matrix(y[4], y[5])
        rates = np.linalg.solve(E, rotation.inv().apply(velocity[3:]))
        E_dot = _rates_matrix_dot(y[4], y[5], rates[1], rates[2])
        angles_dd = np.linalg.solve(E, rotation.inv().apply(acceleration[3:]) - E_dot @ rates)
        return np.concatenate([velocity[:3], rates]), np.concatenate([acceleration[:3], angles_dd])
    if np.any(velocity[3:]) or np.any(acceleration[3:]):
        raise InputError(f"point {k}: an angular twist, but {model.name} holds only {', '.join(task.names)} (its "
                         "end effector cannot turn)")
    if task.kind == "platform":
        return velocity[:3].copy(), acceleration[:3].copy()
    if len(mech.ee_components) == 2:
        normal = model.plane_basis[2]
        if abs(normal @ velocity[:3]) > REST_TOLERANCE or abs(normal @ acceleration[:3]) > REST_TOLERANCE:
            raise InputError(f"point {k}: a twist out of the plane of {model.name}")
    return mech.ee_of(velocity[:3]), mech.ee_of(acceleration[:3])


def _task_row(k: int, xyz: np.ndarray, rotation: Rotation, model: Model, mech: Mechanism, task: Task,
              q_start: np.ndarray, angles_before: np.ndarray | None) -> np.ndarray:
    """Task coordinates of one transform; refused where the goal fixes more than they can hold."""
    angle = float(np.linalg.norm(rotation.as_rotvec()))
    if task.kind == "platform":
        _check_platform_chain(model, task.size)
        if task.size == 6:
            near = np.asarray(angles_before, dtype=float)  # whole turns: joint angles are continuous
            angles = near + (rotation.as_euler("ZYX") - near + np.pi) % (2 * np.pi) - np.pi
            return np.concatenate([xyz, angles])
        if task.size != 3:
            raise InputError(f"{model.name}: a platform with {task.size} coordinates takes no Cartesian goals")
    else:
        plane = model.plane_basis
        if len(mech.ee_components) == 2:  # a planar machine: the goal must lie in its plane
            tip = mech.points(q_start)[2][model.end_effector_chain]
            off = float(plane[2] @ (xyz - tip))
            if abs(off) > POSITION_TOLERANCE:
                raise InputError(f"point {k}: {off:.3g} m out of the plane of {model.name} (task coordinates "
                                 f"{', '.join(task.names)})")
        xyz = mech.ee_of(xyz)
    if angle > ANGLE_TOLERANCE:
        raise InputError(f"point {k}: a rotation of {np.degrees(angle):.3g} deg, but {model.name} holds only "
                         f"{', '.join(task.names)} (its end effector cannot turn): send the identity rotation")
    return np.asarray(xyz, dtype=float)


def goal_path(msg: Any, model: Model, frame: str, order: int, rate: float) -> WaypointPath | MovingWaypointPath:
    """The goal as rest-to-rest segments through its poses with the time law of ``order``;
    its span between MIN_PERIODS and MAX_SAMPLES control periods at ``rate``."""
    times, points, rates, accelerations = goal_waypoints(msg, model, frame)
    span = float(times[-1] - times[0])
    if span * rate < MIN_PERIODS:
        raise InputError(f"the goal spans {span:g} s, shorter than {MIN_PERIODS} control periods "
                         f"({MIN_PERIODS / rate:g} s)")
    if times[-1] * rate > MAX_SAMPLES:
        raise InputError(f"the goal lasts {times[-1]:g} s: more than {MAX_SAMPLES} control periods to compute at once; "
                         "send it in parts")
    if np.any(rates) or np.any(accelerations):
        return MovingWaypointPath(times, points, rates, accelerations, 0.0, order)
    return WaypointPath(times, points, 0.0, order)


def goal_reference(model: Model, path: WaypointPath | MovingWaypointPath, method: str, rate: float, shaper: str,
                   joint_names: Sequence[str], inverse: str = DEFAULT_INVERSE) -> TaskReference | ElasticLineReference:
    """The reference of a goal's path by ``method`` (rigid, elastic, shaped: as ``feedforward
    --waypoints``'s table at the control instants; elastic by the ``inverse``, held or
    continuous). Unreachable or singular poses raise."""
    if method == "elastic":
        if inverse == "held":
            return HeldLineReference(model, path, rate, joint_names)
        return ElasticLineReference(model, path, rate, joint_names)
    if method == "shaped":
        path = ShapedPath(path, path_shaper(model, path, shaper))
    return TaskReference(rigid_feedforward(model), path, rate)

