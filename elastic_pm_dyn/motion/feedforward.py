"""Feedforward torque tables of a line (model -> torques at a control rate): the rigid model's
inverse dynamics (``rigid``) or the elastic model's (``elastic``, :mod:`elastic_inverse`)."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.inverse import RigidFeedforward
from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.elastic_inverse import PAD, InverseMotion, solve, zoh_samples
from elastic_pm_dyn.motion.poses import PoseLine
from elastic_pm_dyn.motion.shaping import ShapedPath, Shaper, for_modes
from elastic_pm_dyn.motion.task import Task
from elastic_pm_dyn.motion.trajectory import Line, QuinticLine

METHODS = ("rigid", "elastic", "shaped")
# [s] grid of the elastic inverse: its torques are smooth within the move (a quintic spline
# between grid points reproduces the 1 kHz ZOH means to ~1e-6 of the springs' share, measured
# on the five-bar: the same path deviation and residual vibration as a 1 ms grid), and the
# solve has half the grid points of a 1 ms grid to find
INVERSE_GRID = 2e-3


def inverse_step(rate: float) -> float:
    """The continuous elastic inverse's grid for a table at ``rate``: INVERSE_GRID, or the
    control period where that is longer."""
    return max(INVERSE_GRID, 1.0 / rate)


def rigid_feedforward(model: Model) -> RigidFeedforward:
    """Feedforward on the rigid model (elastic DOF locked), warm-started at the start pose."""
    elastic = Mechanism(model)
    q0 = initial_state(elastic)
    rigid = Mechanism(model.locked())
    guess = np.array([q0[elastic.joint_names.index(n)] for n in rigid.joint_names])
    return RigidFeedforward(rigid, guess)


def line_torques(model: Model, line: QuinticLine, rate: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Torques sampled at t_k = k / rate over the line's duration (both ends included).

    Returns (times, torques (N x n_a), active joint names).
    """
    ff = rigid_feedforward(model)
    n = round(line.duration * rate)
    times = np.arange(n + 1) / rate
    torques = np.array([ff.torques(*line(t)) for t in times])
    return times, torques, ff.mech.active_names


def elastic_line_motion(model: Model, line: Line | QuinticLine | PoseLine, step: float) -> InverseMotion:
    """The elastic machine's motion and torques along the path of its task coordinates
    (:class:`~elastic_pm_dyn.motion.task.Task`; grid ``step`` over the move)."""
    mech = Mechanism(model)
    return solve(mech, line, line.move, step, initial_state(mech))


def rigid_task_torques(model: Model, path: Line | QuinticLine | PoseLine, rate: float
                       ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The rigid model's torques sampled at t_k = k / rate along a path of the task coordinates
    (a platform's pose where the end-effector point does not fix the machine: the Hexa)."""
    ff = rigid_feedforward(model)
    motion = solve(ff.mech, path, path.move, 1.0 / rate, ff.q)
    n = round(path.duration * rate)
    k = np.minimum(np.arange(n + 1) + PAD, len(motion.t) - 1)  # the grid holds t_k; at rest after it
    return np.arange(n + 1) / rate, motion.tau[k], ff.mech.active_names


def path_shaper(model: Model, path, kind: str, step: float = INVERSE_GRID) -> Shaper:
    """The ``kind`` shaper (zv, zvd, ei) of the machine's elastic modes at the path's start and
    end poses: the plant at rest there, linearised with its motors free (a feedforward drives
    torques, so those modes ring); of its n_a + n_e modes the n_e highest are the elastic ones."""
    mech = Mechanism(model)
    n_e = len(mech.elastic)
    if not n_e:
        raise InputError(f"{model.name} has no elastic joint: nothing to shape for")
    freqs, damping = [], []
    for when in (0.0, path.duration):
        modes = elastic_modes(mech, _static_at(mech, path, when, step), clamp_motors=False)
        order = np.argsort(modes.natural_hz)[-n_e:]
        freqs.extend(modes.natural_hz[order])
        damping.extend(modes.damping_ratio[order])
    return for_modes(kind, np.array(freqs), np.array(damping))


def path_torques(model: Model, path: Line | QuinticLine | PoseLine, rate: float, method: str,
                 shaper: str = "zvd", shaped_inverse: str = "rigid"
                 ) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Feedforward table of any path of the task coordinates by ``method`` (rigid: samples at
    t_k, as :func:`line_torques`; elastic: :func:`elastic_line_torques`; shaped: the
    ``shaped_inverse`` torques (rigid or elastic) of the path through the ``shaper`` of
    :func:`path_shaper`), and the elastic tree position the plant starts from (at rest) for
    the torques to fit."""
    if method == "shaped":
        if shaped_inverse not in ("rigid", "elastic"):
            raise InputError(f"the inverse after a shaper is rigid or elastic, got {shaped_inverse!r}")
        shaped = ShapedPath(path, path_shaper(model, path, shaper))
        return path_torques(model, shaped, rate, shaped_inverse)
    if method == "elastic":
        return elastic_line_torques(model, path, rate)
    mech = Mechanism(model)
    start = static_start(mech, path, 1.0 / rate) if len(mech.elastic) else None
    if isinstance(path, Line | QuinticLine) and Task(mech).kind == "point":
        times, values, names = line_torques(model, path, rate)
    else:
        times, values, names = rigid_task_torques(model, path, rate)
    return times, values, names, initial_state(mech) if start is None else start


def static_start(mech: Mechanism, path: Line | QuinticLine | PoseLine, step: float) -> np.ndarray:
    """The elastic machine at rest (springs loaded by gravity) with the task coordinates of the
    path's start: the elastic inverse of standing still there."""
    return _static_at(mech, path, 0.0, step)


def _static_at(mech: Mechanism, path, t: float, step: float) -> np.ndarray:
    y0 = np.array(path(t)[0])
    zero = np.zeros_like(y0)
    still = solve(mech, lambda _: (y0, zero, zero), 10 * step, step, initial_state(mech))
    return still.q[PAD].copy()


def elastic_line_torques(model: Model, line: Line | QuinticLine | PoseLine, rate: float
                         ) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Torques of the elastic inverse for a zero-order hold at ``rate`` over the line's duration.

    Returns (times, torques (N x n_a), active joint names, the elastic tree position at t = 0:
    where the plant must start, at rest, for the torques to fit: with gravity its springs are
    loaded and its motors offset so that the end effector sits on the line's start). A machine
    with slow unstable zero dynamics (:func:`~elastic_pm_dyn.motion.elastic_inverse.zero_dynamics`)
    needs pre-actuation: the table then starts ``motion.pre`` before the move, which begins at
    t = pre, and runs ``motion.post`` longer.
    """
    motion = elastic_line_motion(model, line, inverse_step(rate))
    times, values = zoh_samples(motion, rate, line.duration)
    k0 = int(np.argmin(np.abs(motion.t + motion.pre)))  # the table's t = 0 (before any pre-actuation)
    return times, values, Mechanism(model).active_names, motion.q[k0].copy()

