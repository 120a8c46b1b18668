"""Feedforward torque tables of a line (model -> torques at a control rate): the rigid model's
inverse dynamics (``rigid``) or the elastic model's (``elastic``, :mod:`elastic_inverse`)."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.inverse import RigidFeedforward
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.elastic_inverse import InverseMotion, solve, zoh_samples
from elastic_pm_dyn.motion.trajectory import Line, QuinticLine

METHODS = ("rigid", "elastic")


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


def elastic_line_motion(model: Model, line: Line | QuinticLine, step: float) -> InverseMotion:
    """The elastic machine's motion and torques along the line (grid ``step`` over the move)."""
    mech = Mechanism(model)
    return solve(mech, line, line.move, step, initial_state(mech))


def elastic_line_torques(model: Model, line: Line | QuinticLine, rate: float
                         ) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Torques of the elastic inverse for a zero-order hold at ``rate`` over the line's duration.

    Returns (times, torques (N x n_a), active joint names, the elastic tree position at t = 0:
    where the plant must start, at rest, for the torques to fit: with gravity its springs are
    loaded and its motors offset so that the end effector sits on the line's start).
    """
    motion = elastic_line_motion(model, line, 1.0 / rate)
    times, values = zoh_samples(motion, rate, line.duration)
    k0 = int(np.argmin(np.abs(motion.t)))
    return times, values, Mechanism(model).active_names, motion.q[k0].copy()
