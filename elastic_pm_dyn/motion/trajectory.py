"""Desired motions, time -> position, velocity, acceleration: the quintic rest-to-rest straight
line of the end effector and smooth motions of the active joints through waypoints."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BPoly

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.motion.time_laws import time_law


@dataclass(frozen=True)
class QuinticLine:
    """p(t) = p_A + (p_E - p_A) s(t/T), s = 10 x^3 - 15 x^4 + 6 x^5, then hold p_E.

    Rest to rest: velocity and acceleration vanish at both ends.
    """

    start: np.ndarray
    end: np.ndarray
    move: float  # T [s]
    hold: float = 0.0  # time held at the end [s]

    def __post_init__(self) -> None:
        if self.move <= 0 or self.hold < 0 or not np.isfinite(self.move + self.hold):
            raise InputError(f"move time must be > 0 and hold >= 0 (got {self.move}, {self.hold})")
        if np.shape(self.start) != np.shape(self.end):
            raise InputError("line start and end need the same number of coordinates")

    @property
    def duration(self) -> float:
        return self.move + self.hold

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration at time t (clamped to [0, duration])."""
        x = min(max(t / self.move, 0.0), 1.0)
        s = x**3 * (10 - 15 * x + 6 * x**2)
        sd = 30 * x**2 * (1 - x) ** 2 / self.move
        sdd = 60 * x * (1 - x) * (1 - 2 * x) / self.move**2
        d = np.asarray(self.end, dtype=float) - np.asarray(self.start, dtype=float)
        return self.start + s * d, sd * d, sdd * d


@dataclass(frozen=True)
class Line:
    """p(t) = p_A + (p_E - p_A) s(t/T) with the C^r rest-to-rest law of :mod:`time_laws`
    (r = 2: :class:`QuinticLine`'s; r = 4, the default: the 9th-order law the elastic
    feedforward wants), then hold p_E. Any number of coordinates (a point, or a platform's)."""

    start: np.ndarray
    end: np.ndarray
    move: float  # T [s]
    hold: float = 0.0  # time held at the end [s]
    order: int = 4  # r: derivatives 1..r vanish at both ends

    def __post_init__(self) -> None:
        if not (self.move > 0 and self.hold >= 0 and np.isfinite(self.move + self.hold)):
            raise InputError(f"move time must be > 0 and hold >= 0 (got {self.move}, {self.hold})")
        if np.shape(self.start) != np.shape(self.end):
            raise InputError("line start and end need the same number of coordinates")
        if not np.all(np.isfinite(np.concatenate([np.ravel(self.start), np.ravel(self.end)]))):
            raise InputError("line start and end must be finite")

    @property
    def duration(self) -> float:
        return self.move + self.hold

    def derivatives(self, t: float, n: int) -> np.ndarray:
        """Rows: position and its first n time derivatives at t."""
        s = time_law(self.order, self.move, t, n)
        d = np.asarray(self.end, dtype=float) - np.asarray(self.start, dtype=float)
        out = s[:, None] * d[None, :]
        out[0] += np.asarray(self.start, dtype=float)
        return out

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration at time t (clamped to [0, duration])."""
        p, pd, pdd = self.derivatives(t, 2)
        return p, pd, pdd


def make_line(start: np.ndarray, end: np.ndarray, move: float, hold: float = 0.0, order: int = 2
              ) -> QuinticLine | Line:
    """The line of a time law: :class:`QuinticLine` for r = 2 (its closed form, so the rigid
    feedforward's tables stay what they were, bit for bit), else :class:`Line`."""
    if order == 2:
        return QuinticLine(np.asarray(start, dtype=float), np.asarray(end, dtype=float), move, hold)
    return Line(np.asarray(start, dtype=float), np.asarray(end, dtype=float), move, hold, order)


class JointSpline:
    """A smooth motion of joints through waypoints; before the first and after the last at rest there.

    Interpolation per joint, joint_trajectory_controller's rules where they give a torque:
    with velocities at every point a cubic that matches positions and velocities, with
    accelerations too a quintic that matches all three. Positions alone, which that
    controller joins by straight lines (an infinite acceleration, so a torque impulse, at
    every waypoint), get :data:`AT_REST_LAW` instead: each segment a rest-to-rest move with
    the 9th-order (C^4) law, stopping at every waypoint (the elastic machine's torques stay
    continuous; a clamped cubic spline, used before, started with a torque step).
    ``order`` picks the joints of the output from the columns of the waypoints (each row
    has ``len(order)`` values).
    """

    def __init__(self, times: Sequence[float], positions: Sequence[Sequence[float]], order: Sequence[int],
                 velocities: Sequence[Sequence[float]] | None = None,
                 accelerations: Sequence[Sequence[float]] | None = None):
        order = list(order)
        times = np.asarray(times, dtype=float)
        if times.ndim != 1 or len(times) == 0:
            raise InputError("trajectory has no points")
        if times[0] < 0 or np.any(np.diff(times) <= 0):
            raise InputError("trajectory time_from_start must be >= 0 and strictly increasing")
        n = len(order)
        pos = _table(positions, len(times), n, "positions")[:, order]
        vel = None if velocities is None else _table(velocities, len(times), n, "velocities")[:, order]
        acc = None if accelerations is None else _table(accelerations, len(times), n, "accelerations")[:, order]
        if acc is not None and vel is None:
            raise InputError("trajectory accelerations need velocities at every point too")

        self.positions = pos  # the waypoints, output order
        self.start = float(times[0])
        self.end = float(times[-1])
        self._splines = None
        self.rule = "quintic" if acc is not None else "cubic" if vel is not None else "at rest"
        if len(times) > 1:
            if vel is None:
                self._splines = [_AtRest(times, pos, m) for m in range(3)]
            else:
                derivs = [vel] if acc is None else [vel, acc]
                polys = [BPoly.from_derivatives(times, np.stack([pos[:, j], *[d[:, j] for d in derivs]], axis=1))
                         for j in range(pos.shape[1])]
                self._splines = [_Stack(polys, 0), _Stack(polys, 1), _Stack(polys, 2)]

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, accelerations at time t (at rest outside [start, end])."""
        rest = np.zeros(self.positions.shape[1])
        if self._splines is None or t <= self.start:
            return self.positions[0], rest, rest.copy()
        if t >= self.end:
            return self.positions[-1], rest, rest.copy()
        return tuple(np.asarray(s(t), dtype=float) for s in self._splines)


AT_REST_LAW = 4  # r of the rest-to-rest law of a positions-only trajectory's segments (C^4)


class _AtRest:
    """Derivative ``order`` of the segment-wise rest-to-rest motion through waypoints."""

    def __init__(self, times: np.ndarray, positions: np.ndarray, order: int):
        self.times, self.positions, self.order = times, positions, order

    def __call__(self, t: float) -> np.ndarray:
        k = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2))
        t0, t1 = self.times[k], self.times[k + 1]
        s = time_law(AT_REST_LAW, t1 - t0, t - t0, self.order)[self.order]
        d = self.positions[k + 1] - self.positions[k]
        return self.positions[k] + s * d if self.order == 0 else s * d


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
