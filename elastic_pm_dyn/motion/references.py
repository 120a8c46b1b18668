"""Rigid inverse dynamics of a desired motion, one control instant at a time (the feedforward node's).

A reference answers ``sample(t)`` with the rigid tree motion (q, qd, qdd; joint names of
the rigid model: active + passive) and the motor torques (active order) that produce it.
Times are relative to the reference's start; before the start and after the end the
reference holds its first/last pose at rest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from elastic_pm_dyn.dynamics.inverse import RigidFeedforward, motor_torques
from elastic_pm_dyn.errors import AssemblyError, InputError
from elastic_pm_dyn.kinematics.assembly import solve_acceleration, solve_pose, solve_velocity
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.elastic_inverse import PAD, solve, zoh_samples
from elastic_pm_dyn.motion.feedforward import INVERSE_GRID, elastic_line_motion
from elastic_pm_dyn.motion.trajectory import JointSpline, Line, QuinticLine


@dataclass
class ReferenceSample:
    q: np.ndarray  # rigid tree position (ff.mech.joint_names)
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray  # motor torques, active order [N m]


class LineReference:
    """The reference manoeuvre: a Cartesian straight line with quintic time law.

    The move is tabulated at t_k = k / rate when the reference is made (solves are slow
    next to a 1 kHz period), in the order of :func:`elastic_pm_dyn.motion.feedforward.line_torques`
    and from the same warm starts, so grid samples equal its torques exactly. After the
    move the line rests at its end: one sample serves the whole hold. Times off the grid
    are solved on demand.
    """

    def __init__(self, ff: RigidFeedforward, line: Line | QuinticLine, rate: float):
        self.ff = ff
        self.line = line
        self.rate = rate
        self.duration = line.duration
        n_move = int(np.ceil(line.move * rate - 1e-9))  # t_k >= move from k = n_move on: the end at rest
        self._table = [self._solve(k / rate) for k in range(n_move + 1)]

    def _solve(self, t: float) -> ReferenceSample:
        q, qd, qdd = self.ff.joint_motion(*self.line(t))
        return ReferenceSample(q, qd, qdd, motor_torques(self.ff.mech, q, qd, qdd))

    def sample(self, t: float) -> ReferenceSample:
        k = round(t * self.rate)
        if t >= self.line.move or k >= len(self._table):
            return self._table[-1]
        if k >= 0 and abs(t - k / self.rate) <= 1e-9:
            return self._table[k]
        return self._solve(t)


class ElasticLineReference:
    """A line through the elastic model's inverse (:mod:`elastic_inverse`), computed once when
    the reference is made: at the grid instants t_k = k / rate the torque is the mean over
    [t_k, t_k+1) (what a zero-order hold should hold), off the grid the continuous torque. The
    motion is the elastic tree's, reported under ``joint_names`` (the rigid model's: the motors
    at their deflection-compensated angles, the passive joints; the springs left out)."""

    def __init__(self, model: Model, line: Line | QuinticLine, rate: float, joint_names: Sequence[str]):
        mech = Mechanism(model)
        self.line = line
        self.rate = rate
        self.motion = elastic_line_motion(model, line, max(INVERSE_GRID, 1.0 / rate))
        # pre- and post-actuation (non-minimum phase): the reference starts pre before the move
        self.pre, self.post = self.motion.pre, self.motion.post
        self.duration = line.duration + self.pre + self.post
        self._index = [mech.joint_names.index(n) for n in joint_names]
        self._times, self._held = zoh_samples(self.motion, rate, line.move + 1.0 / rate)
        self._torque = self.motion.torque()
        m = self.motion
        # the motion between grid points: quintic splines (the PD's reference angles and rates)
        self._splines = [make_interp_spline(m.t, x[:, self._index], k=5, axis=0) for x in (m.q, m.qd, m.qdd)]

    def sample(self, t: float) -> ReferenceSample:
        t = min(max(t, 0.0), self.line.move + self.pre + self.post)  # t = pre: the move's start
        q, qd, qdd = (np.asarray(s(t - self.pre)) for s in self._splines)
        k = round(t * self.rate)
        on_grid = abs(t - k / self.rate) <= 1e-9 and k < len(self._held)
        tau = self._held[k].copy() if on_grid else self._torque(t - self.pre)
        return ReferenceSample(q, qd, qdd, tau)


class TaskReference:
    """Any path of the task coordinates (:class:`~elastic_pm_dyn.motion.task.Task`: a platform's
    pose, waypoints, a shaped path) through the rigid model's inverse, solved once on the grid
    t_k = k / rate: the table of :func:`~elastic_pm_dyn.motion.feedforward.rigid_task_torques`,
    bit for bit, at the grid instants; quintic splines between them; at rest at the path's
    start before it and at its end after it."""

    def __init__(self, ff: RigidFeedforward, path, rate: float):
        self.line = path
        self.rate = rate
        self.duration = path.duration
        self.motion = m = solve(ff.mech, path, path.move, 1.0 / rate, ff.q)
        self._splines = [make_interp_spline(m.t, x, k=5, axis=0) for x in (m.q, m.qd, m.qdd, m.tau)]

    def sample(self, t: float) -> ReferenceSample:
        m = self.motion
        k = round(t * self.rate)
        if abs(t - k / self.rate) <= 1e-9 or t <= 0.0 or t >= self.line.move:  # at rest outside the move
            i = int(np.clip(k + PAD, PAD, len(m.t) - 1))  # rigid_task_torques' row of t_k
            return ReferenceSample(m.q[i].copy(), m.qd[i].copy(), m.qdd[i].copy(), m.tau[i].copy())
        q, qd, qdd, tau = (np.asarray(s(t)) for s in self._splines)
        return ReferenceSample(q, qd, qdd, tau)


def joint_path(mech: Mechanism, joint_names: Sequence[str], times: Sequence[float],
               positions: Sequence[Sequence[float]], velocities: Sequence[Sequence[float]] | None = None,
               accelerations: Sequence[Sequence[float]] | None = None) -> JointSpline:
    """The motion of the active joints through waypoints (InputError, one line, for a bad one:
    names, sizes, times, NaN), before any waypoint is assembled."""
    names = list(joint_names)
    if sorted(names) != sorted(mech.active_names) or len(set(names)) != len(names):
        raise InputError(f"trajectory joints {names} must be the active joints "
                         f"{mech.active_names}, each once")
    order = [names.index(n) for n in mech.active_names]  # to active order
    return JointSpline(times, positions, order, velocities, accelerations)


class JointReference:
    """A smooth motion of the active joints through waypoints (:class:`JointSpline`), passive joints by assembly."""

    def __init__(self, ff: RigidFeedforward, joint_names: Sequence[str], times: Sequence[float],
                 positions: Sequence[Sequence[float]], velocities: Sequence[Sequence[float]] | None = None,
                 accelerations: Sequence[Sequence[float]] | None = None):
        self.path = joint_path(ff.mech, joint_names, times, positions, velocities, accelerations)

        self.ff = ff
        self.t0 = self.path.start
        self.duration = self.path.end
        self._q = ff.q.copy()  # warm start of the passive joints, follows the path
        for k, p in enumerate(self.path.positions):  # every waypoint must assemble
            try:
                self._assemble(p)
            except AssemblyError as err:
                raise InputError(f"trajectory point {k}: {err}") from None
        self._q = ff.q.copy()

    def _assemble(self, qa: np.ndarray) -> np.ndarray:
        mech = self.ff.mech
        q = self._q.copy()
        q[mech.active] = qa
        self._q = solve_pose(mech, q, mech.passive)
        return self._q

    def sample(self, t: float) -> ReferenceSample:
        mech = self.ff.mech
        qa, qda, qdda = self.path(t)
        q = self._assemble(qa)
        fixed = np.zeros(mech.n)
        fixed[mech.active] = qda
        qd = solve_velocity(mech, q, mech.passive, fixed)
        fixed[mech.active] = qdda
        qdd = solve_acceleration(mech, q, qd, mech.passive, fixed)
        return ReferenceSample(q.copy(), qd, qdd, motor_torques(mech, q, qd, qdd))


class HoldReference:
    """Hold the model's start pose for ``duration`` seconds: the rigid machine at rest there, and
    the motor torques that hold it against gravity (for machines whose end-effector point does
    not fix the pose, e.g. a hexapod, where a point line cannot be solved)."""

    def __init__(self, ff: RigidFeedforward, duration: float):
        if not (np.isfinite(duration) and duration > 0):
            raise InputError(f"hold duration must be > 0, got {duration}")
        mech = ff.mech
        q = ff.q.copy()
        zero = np.zeros(mech.n)
        self.ff = ff
        self.duration = float(duration)
        self._sample = ReferenceSample(q, zero, zero.copy(), motor_torques(mech, q, zero, zero))

    def sample(self, t: float) -> ReferenceSample:
        return self._sample
