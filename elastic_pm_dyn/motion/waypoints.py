"""Waypoint files: poses (task coordinates) or motor positions with times, as a path.

A CSV file with a header ``t,<names>`` and one row per waypoint, times strictly increasing:

- ``<names>`` the task coordinates (:class:`~elastic_pm_dyn.motion.task.Task`: ``x,y`` for the
  five-bar, ``platform_x,...,platform_roll`` for a platform; m and rad): a path through the
  poses, each segment a rest-to-rest move with the time law (a platform's orientation on the
  SO(3) geodesic), at rest at every waypoint; for both methods;
- ``<names>`` the active joints (optionally ``<joint>_vel`` and ``<joint>_acc`` columns):
  a joint-space motion with joint_trajectory_controller's rules
  (:class:`~elastic_pm_dyn.motion.trajectory.JointSpline`); rigid method only (the elastic
  inverse prescribes the output, not the motors).
Before the first time the path rests at its first waypoint.

The file is read like every user file (:func:`~elastic_pm_dyn.text_file.read_text`: regular
files only, at most :data:`MAX_WAYPOINT_BYTES`) and holds at most :data:`MAX_WAYPOINTS` rows,
both checked before a number is converted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.interpolate import BPoly

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.feedforward import rigid_feedforward
from elastic_pm_dyn.motion.poses import PoseLine
from elastic_pm_dyn.motion.references import JointReference
from elastic_pm_dyn.motion.trajectory import make_line
from elastic_pm_dyn.text_file import TextFileError, read_text

MAX_WAYPOINTS = 10_000  # rows of a waypoint file, points of a goal message: a path, not a sampled table
MAX_WAYPOINT_BYTES = 4 * 2**20  # 10 000 rows of a 6-DOF pose take some 1.3 MB


def read_waypoints(path: str | Path) -> tuple[list[str], np.ndarray]:
    """(column names after ``t``, rows [t, values...]) of a waypoint CSV; one clear line on error."""
    p = Path(path)
    try:
        text = read_text(p, MAX_WAYPOINT_BYTES, "waypoint file")
    except TextFileError as err:
        where = "" if err.line is None else f" line {err.line}:"
        raise InputError(f"waypoint file {p}:{where} {err.reason}") from None
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(lines) < 2:
        raise InputError(f"waypoint file {p}: needs a header t,<names> and at least one row")
    if len(lines) - 1 > MAX_WAYPOINTS:
        raise InputError(f"waypoint file {p}: {len(lines) - 1} rows, more than the {MAX_WAYPOINTS} a path may have "
                         "(a waypoint file holds poses to pass, not a sampled motion)")
    header = [h.strip() for h in lines[0].split(",")]
    if header[0] != "t" or len(header) < 2:
        raise InputError(f"waypoint file {p}: the header must start with t and name the columns, got {lines[0][:60]!r}")
    rows = []
    for k, ln in enumerate(lines[1:], start=2):
        cells = ln.split(",")
        if len(cells) != len(header):
            raise InputError(f"waypoint file {p} row {k}: {len(cells)} values for {len(header)} columns")
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise InputError(f"waypoint file {p} row {k}: not a number in {ln[:60]!r}") from None
    table = np.array(rows)
    if not np.all(np.isfinite(table)):
        raise InputError(f"waypoint file {p}: NaN or Inf")
    if table[0, 0] < 0 or np.any(np.diff(table[:, 0]) <= 0):
        raise InputError(f"waypoint file {p}: times must be >= 0 and strictly increasing")
    return header[1:], table


class WaypointPath:
    """Rest-to-rest segments through poses of the task coordinates (see module doc)."""

    def __init__(self, times: np.ndarray, points: np.ndarray, hold: float, order: int):
        times = np.asarray(times, dtype=float)
        points = np.atleast_2d(np.asarray(points, dtype=float))
        if len(times) < 2:
            raise InputError("a waypoint path needs at least two waypoints")
        pose = points.shape[1] == 6
        self.times = times
        self.segments = [(PoseLine if pose else make_line)(points[k], points[k + 1], times[k + 1] - times[k], 0.0,
                                                            order) for k in range(len(times) - 1)]
        self.move = float(times[-1])
        self.hold = float(hold)
        self.start = points[0]

    @property
    def duration(self) -> float:
        return self.move + self.hold

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        k = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.segments) - 1))
        return self.segments[k](t - self.times[k])


class MovingWaypointPath:
    """Segments through poses of the task coordinates passed with given rates (and
    accelerations): per coordinate the Hermite polynomial of degree 2 r + 1 that matches
    position and derivatives 1 .. r at both ends of its segment, the rates and accelerations
    given (zero where not given) and the higher ones zero, so the path is C^r like the time
    law of order r (r = 2: joint_trajectory_controller's quintic; r = 4: what the elastic
    inverse needs). With zero rates it is :class:`WaypointPath` of a point task. A platform's
    angles are interpolated as coordinates (not on the SO(3) geodesic). It starts and ends at
    rest: before the first and after the last time it rests at the first and last pose."""

    def __init__(self, times: np.ndarray, points: np.ndarray, rates: np.ndarray, accelerations: np.ndarray,
                 hold: float, order: int):
        times = np.asarray(times, dtype=float)
        points, rates, accelerations = (np.atleast_2d(np.asarray(a, dtype=float))
                                        for a in (points, rates, accelerations))
        if len(times) < 2:
            raise InputError("a waypoint path needs at least two waypoints")
        if np.any(rates[[0, -1]]) or np.any(accelerations[[0, -1]]):
            raise InputError("the first and the last waypoint need zero rates and accelerations (the path starts "
                             "and ends at rest)")
        n, dims = points.shape
        derivs = np.zeros((n, order + 1, dims))
        derivs[:, 0], derivs[:, 1] = points, rates
        if order >= 2:
            derivs[:, 2] = accelerations
        elif np.any(accelerations):
            raise InputError("accelerations need a time law of order 2 or more")
        self._polys = [BPoly.from_derivatives(times, derivs[:, :, j]) for j in range(dims)]
        self._rates = [[p.derivative(m) for p in self._polys] for m in (1, 2)]
        self.times = times
        self.move = float(times[-1])
        self.hold = float(hold)
        self.start = points[0]
        self._first, self._last = points[0], points[-1]

    @property
    def duration(self) -> float:
        return self.move + self.hold

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rest = np.zeros(len(self._polys))
        if t <= self.times[0]:
            return self._first.copy(), rest, rest.copy()
        if t >= self.times[-1]:
            return self._last.copy(), rest, rest.copy()
        y = np.array([float(p(t)) for p in self._polys])
        yd, ydd = (np.array([float(p(t)) for p in ps]) for ps in self._rates)
        return y, yd, ydd


def joint_waypoint_torques(model: Model, names: list[str], table: np.ndarray, rate: float, hold: float
                           ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Rigid torques at t_k of a motor-space waypoint table (columns ``names``: the active joints,
    optionally ``<joint>_vel`` and ``<joint>_acc``), by joint_trajectory_controller's rules
    (:class:`~elastic_pm_dyn.motion.trajectory.JointSpline`)."""
    ff = rigid_feedforward(model)
    active = ff.mech.active_names

    def columns(suffix: str) -> np.ndarray | None:
        wanted = [f"{n}{suffix}" for n in active]
        if not all(w in names for w in wanted):
            return None
        return table[:, [1 + names.index(w) for w in wanted]]

    ref = JointReference(ff, active, table[:, 0], columns(""), columns("_vel"), columns("_acc"))
    n = round((ref.duration + hold) * rate)
    times = np.arange(n + 1) / rate
    return times, np.array([ref.sample(t).tau for t in times]), active
