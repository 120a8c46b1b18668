"""Rigid inverse-dynamics feedforward of a quintic line (model -> torque table at a control rate)."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.inverse import RigidFeedforward
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.trajectory import QuinticLine


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
