"""How well a feedforward torque table drives the elastic plant along its path (simulate and measure).

The scores of the feedforward bench and tests: the plant (any formulation and integrator of
:mod:`elastic_pm_dyn.sim`) is started at rest in the state the path starts from and driven
open loop by the table (zero-order hold); then

- ``path_deviation``: the largest distance of the task coordinates from the path during the move;
- ``residual_vibration``: the largest deviation of the branch forces from their static value
  at the path's end over the hold (what rings after the move);
- ``hold_drift``: the largest distance from the end point over the hold (torques that do not
  balance the machine let its free motors drift).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.motion.task import Task
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable

Path = Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass
class Score:
    path_deviation: float  # [m or m and rad mixed: the task coordinates' Euclidean norm]
    residual_vibration: float  # [N or N m]
    hold_drift: float
    run_seconds: float

    def as_dict(self) -> dict:
        return {"path_deviation": self.path_deviation, "residual_vibration": self.residual_vibration,
                "hold_drift": self.hold_drift, "run_seconds": self.run_seconds}


def score(plant: Mechanism, times: np.ndarray, torques: np.ndarray, q0: np.ndarray, path: Path, move: float,
          duration: float, static_forces: np.ndarray, options: SimulationOptions) -> Score:
    """Simulate ``duration`` seconds of the table on ``plant`` from rest at ``q0`` and score it."""
    start = time.perf_counter()
    result = Simulator(plant, options).run(TorqueTable(times, torques), duration, q0=q0)
    seconds = time.perf_counter() - start
    task = Task(plant)
    y = np.array([task.coordinates(q) for q in result.q])
    y_ref = np.array([path(float(t))[0] for t in result.t])
    dev = np.linalg.norm(y - y_ref, axis=1)
    moving = result.t <= move + 1e-12
    hold = ~moving
    forces = result.branch_forces
    return Score(float(dev[moving].max()),
                 float(np.abs(forces[hold] - static_forces).max()) if hold.any() else 0.0,
                 float(dev[hold].max()) if hold.any() else 0.0, seconds)


@dataclass
class Exactness:
    """How exactly a table moves the plant (issue #42's figures)."""

    contour: float  # largest distance from the path's curve during the move and ``after`` it [task units]
    tracking: float  # largest distance from the path's point at the same time, same window
    ringing: float  # largest deviation of the branch forces from their static value after the move [N or N m]
    drift: float  # largest distance from the end point over the hold [task units]

    def as_dict(self) -> dict:
        return {"contour": self.contour, "tracking": self.tracking, "ringing": self.ringing, "drift": self.drift}


def exactness(plant: Mechanism, times: np.ndarray, torques: np.ndarray, q0: np.ndarray, path: Path, move: float,
              duration: float, static_forces: np.ndarray, options: SimulationOptions, after: float = 0.1,
              start: float = 0.0) -> Exactness:
    """Simulate the table on ``plant`` from rest at ``q0`` for ``duration`` and measure it; the
    path's t = 0 is the table's ``start`` (a table with pre-actuation starts earlier)."""
    result = Simulator(plant, options).run(TorqueTable(times, torques), duration, q0=q0)
    task = Task(plant)
    t = result.t - start
    y = np.array([task.coordinates(q) for q in result.q])
    y_ref = np.array([path(float(tk))[0] for tk in t])
    window = t <= move + after + 1e-12
    hold = t > move + 1e-12
    curve = np.array([path(float(s))[0] for s in np.linspace(0.0, move, 4001)])
    end = np.asarray(path(move)[0], dtype=float)
    return Exactness(float(_curve_distance(y[window], curve).max()),
                     float(np.linalg.norm(y - y_ref, axis=1)[window].max()),
                     float(np.abs(result.branch_forces[hold] - static_forces).max()) if hold.any() else 0.0,
                     float(np.linalg.norm(y[hold] - end, axis=1).max()) if hold.any() else 0.0)


def _curve_distance(points: np.ndarray, curve: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Distance of each point from a polyline (its segments), in chunks of points."""
    a, d = curve[:-1], np.diff(curve, axis=0)
    length2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    out = np.empty(len(points))
    for lo in range(0, len(points), chunk):
        p = points[lo:lo + chunk, None, :] - a[None]  # (c, segments, dims)
        s = np.clip(np.einsum("csd,sd->cs", p, d) / length2, 0.0, 1.0)
        out[lo:lo + chunk] = np.sqrt(np.min(np.sum((p - s[..., None] * d) ** 2, axis=2), axis=1))
    return out
