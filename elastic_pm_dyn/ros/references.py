"""Desired motions for the feedforward node and their rigid inverse dynamics (no rclpy here).

A reference answers ``sample(t)`` with the rigid tree motion (q, qd, qdd; joint names of
the rigid model: active + passive) and the motor torques (active order) that produce it.
Times are relative to the reference's start; before the start and after the end the
reference holds its first/last pose at rest.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BPoly, CubicSpline

from elastic_pm_dyn.dynamics.inverse import RigidFeedforward, tree_inverse_dynamics
from elastic_pm_dyn.errors import AssemblyError, InputError
from elastic_pm_dyn.kinematics.assembly import solve_acceleration, solve_pose, solve_velocity
from elastic_pm_dyn.trajectory import QuinticLine


@dataclass
class ReferenceSample:
    q: np.ndarray  # rigid tree position (ff.mech.joint_names)
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray  # motor torques, active order [N m]


class LineReference:
    """The reference manoeuvre: a Cartesian straight line with quintic time law.

    The move is tabulated at t_k = k / rate when the reference is made (solves are slow
    next to a 1 kHz period), in the order of :func:`elastic_pm_dyn.feedforward.line_torques`
    and from the same warm starts, so grid samples equal its torques exactly. After the
    move the line rests at its end: one sample serves the whole hold. Times off the grid
    are solved on demand.
    """

    def __init__(self, ff: RigidFeedforward, line: QuinticLine, rate: float):
        self.ff = ff
        self.line = line
        self.rate = rate
        self.duration = line.duration
        n_move = int(np.ceil(line.move * rate - 1e-9))  # t_k >= move from k = n_move on: the end at rest
        self._table = [self._solve(k / rate) for k in range(n_move + 1)]

    def _solve(self, t: float) -> ReferenceSample:
        q, qd, qdd = self.ff.joint_motion(*self.line(t))
        return ReferenceSample(q, qd, qdd, tree_inverse_dynamics(self.ff.mech, q, qd, qdd))

    def sample(self, t: float) -> ReferenceSample:
        k = round(t * self.rate)
        if t >= self.line.move or k >= len(self._table):
            return self._table[-1]
        if k >= 0 and abs(t - k / self.rate) <= 1e-9:
            return self._table[k]
        return self._solve(t)


class JointReference:
    """A smooth motion of the active joints through waypoints, passive joints by assembly.

    Interpolation per joint: with velocities at every point, a piecewise polynomial that
    matches positions, velocities and (when given at every point) accelerations (cubic or
    quintic Hermite); with positions only, a C2 cubic spline starting and ending at rest.
    """

    def __init__(self, ff: RigidFeedforward, joint_names: Sequence[str], times: Sequence[float],
                 positions: Sequence[Sequence[float]], velocities: Sequence[Sequence[float]] | None = None,
                 accelerations: Sequence[Sequence[float]] | None = None):
        mech = ff.mech
        names = list(joint_names)
        if sorted(names) != sorted(mech.active_names) or len(set(names)) != len(names):
            raise InputError(f"trajectory joints {names} must be the active joints "
                             f"{mech.active_names}, each once")
        order = [names.index(n) for n in mech.active_names]  # to active order
        times = np.asarray(times, dtype=float)
        if times.ndim != 1 or len(times) == 0:
            raise InputError("trajectory has no points")
        if times[0] < 0 or np.any(np.diff(times) <= 0):
            raise InputError("trajectory time_from_start must be >= 0 and strictly increasing")
        pos = _table(positions, len(times), len(names), "positions")[:, order]
        vel = None if velocities is None else _table(velocities, len(times), len(names), "velocities")[:, order]
        acc = None if accelerations is None else _table(accelerations, len(times), len(names),
                                                        "accelerations")[:, order]
        if acc is not None and vel is None:
            raise InputError("trajectory accelerations need velocities at every point too")

        self.ff = ff
        self.t0 = float(times[0])
        self.duration = float(times[-1])
        self._pos0, self._pos1 = pos[0], pos[-1]
        self._q = ff.q.copy()  # warm start of the passive joints, follows the path
        for k, p in enumerate(pos):  # every waypoint must assemble
            try:
                self._assemble(p)
            except AssemblyError as err:
                raise InputError(f"trajectory point {k}: {err}") from None
        self._q = ff.q.copy()
        self._splines = None
        if len(times) > 1:
            if vel is None:
                spline = CubicSpline(times, pos, bc_type="clamped", axis=0)
                self._splines = [spline, spline.derivative(1), spline.derivative(2)]
            else:
                derivs = [vel] if acc is None else [vel, acc]
                polys = [BPoly.from_derivatives(times, np.stack([pos[:, j], *[d[:, j] for d in derivs]], axis=1))
                         for j in range(pos.shape[1])]
                self._splines = [_Stack(polys, 0), _Stack(polys, 1), _Stack(polys, 2)]

    def _assemble(self, qa: np.ndarray) -> np.ndarray:
        mech = self.ff.mech
        q = self._q.copy()
        q[mech.active] = qa
        self._q = solve_pose(mech, q, mech.passive)
        return self._q

    def sample(self, t: float) -> ReferenceSample:
        mech = self.ff.mech
        n_a = len(mech.active)
        if self._splines is None or t <= self.t0:
            qa, qda, qdda = self._pos0, np.zeros(n_a), np.zeros(n_a)
        elif t >= self.duration:
            qa, qda, qdda = self._pos1, np.zeros(n_a), np.zeros(n_a)
        else:
            qa, qda, qdda = (np.asarray(s(t), dtype=float) for s in self._splines)
        q = self._assemble(qa)
        fixed = np.zeros(mech.n)
        fixed[mech.active] = qda
        qd = solve_velocity(mech, q, mech.passive, fixed)
        fixed[mech.active] = qdda
        qdd = solve_acceleration(mech, q, qd, mech.passive, fixed)
        return ReferenceSample(q.copy(), qd, qdd, tree_inverse_dynamics(mech, q, qd, qdd))


class _Stack:
    """Evaluate one derivative of per-joint polynomials as a vector."""

    def __init__(self, polys: list[BPoly], order: int):
        self.polys = [p.derivative(order) if order else p for p in polys]

    def __call__(self, t: float) -> np.ndarray:
        return np.array([float(p(t)) for p in self.polys])


def _table(rows: Sequence[Sequence[float]], n_points: int, n_joints: int, what: str) -> np.ndarray:
    if len(rows) != n_points or any(len(r) != n_joints for r in rows):
        raise InputError(f"trajectory {what}: every point needs {n_joints} values")
    out = np.array([list(r) for r in rows], dtype=float).reshape(n_points, n_joints)
    if not np.all(np.isfinite(out)):
        raise InputError(f"trajectory {what} contain NaN or Inf")
    return out
