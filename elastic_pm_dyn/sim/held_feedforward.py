"""Feedforward tables for a zero-order hold: the elastic inverse of the held machine
(:mod:`~elastic_pm_dyn.sim.held_inverse`) beside the package's other methods.

``inverse`` picks how the elastic method treats the hold: ``held`` (the default) solves for
the samples the plant actually holds, so the machine follows the path at the samples and
between them and is at rest when the table ends; ``continuous`` is the continuous inverse's
mean over each period (:func:`~elastic_pm_dyn.motion.feedforward.elastic_line_torques`), a few
times faster to compute but with the hold's own error: micrometres off the path and a drift in
the hold. The default is what a user who asks for a table at a rate expects of it.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import make_interp_spline

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion import feedforward
from elastic_pm_dyn.motion.elastic_inverse import InverseMotion, zoh_samples
from elastic_pm_dyn.motion.feedforward import elastic_line_motion, inverse_step, path_shaper
from elastic_pm_dyn.motion.references import ElasticLineReference, ReferenceSample
from elastic_pm_dyn.motion.shaping import ShapedPath
from elastic_pm_dyn.motion.task import Task
from elastic_pm_dyn.sim.held_inverse import SETTLE, HeldInverse, rest_state, solve_held

INVERSES = ("held", "continuous")
DEFAULT_INVERSE = "held"


def held_solution(model: Model, path, rate: float, motion: InverseMotion | None = None) -> HeldInverse:
    """The held inverse of ``path`` at ``rate`` (the continuous inverse ``motion`` its first
    guess, computed if not given): samples over the path's duration (plus any pre- and
    post-actuation, and at least the settling periods after the move)."""
    mech = Mechanism(model)
    task = Task(mech)
    motion = elastic_line_motion(model, path, inverse_step(rate)) if motion is None else motion
    _, first = zoh_samples(motion, rate, path.duration)
    k0 = int(np.argmin(np.abs(motion.t + motion.pre)))  # the table's t = 0
    q0, _ = rest_state(mech, task, np.asarray(path(0.0)[0], dtype=float), motion.q[k0])
    q_rest, u_rest = rest_state(mech, task, np.asarray(path(path.duration)[0], dtype=float), motion.q[-1])
    horizon = motion.pre + path.move + motion.post + SETTLE / rate
    n_h = int(np.ceil(horizon * rate - 1e-9))
    if len(first) < n_h:  # a table without its settling periods: they are added
        first = np.vstack([first, np.tile(u_rest, (n_h - len(first), 1))])
    # the continuous inverse's state on the path: where a long horizon's windows end
    ae = mech.ae
    state = make_interp_spline(motion.t, np.hstack([motion.q[:, ae], motion.qd[:, ae]]), k=5, axis=0)
    held = solve_held(mech, path, rate, horizon, first, q0, u_rest, q_rest, offset=motion.pre, task=task,
                      through=lambda t: state(float(np.clip(t, motion.t[0], motion.t[-1]))))
    n = max(len(first), n_h + 1)
    values = np.tile(u_rest, (n, 1))
    values[:n_h] = held.torques[:n_h]
    held.times, held.torques = np.arange(n) / rate, values
    return held


def held_line_torques(model: Model, path, rate: float) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """As :func:`~elastic_pm_dyn.motion.feedforward.elastic_line_torques` (times, torques,
    motor names, the tree position the plant starts from at rest), by the held inverse."""
    held = held_solution(model, path, rate)
    return held.times, held.torques, Mechanism(model).active_names, held.q0


def feedforward_table(model: Model, path, rate: float, method: str, shaper: str = "zvd",
                      shaped_inverse: str = "rigid", inverse: str = DEFAULT_INVERSE
                      ) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """:func:`~elastic_pm_dyn.motion.feedforward.path_torques` with the elastic inverse's
    ``inverse`` (held or continuous), also after a shaper (``shaped_inverse`` elastic)."""
    if inverse not in INVERSES:
        raise InputError(f"the elastic inverse is held or continuous, got {inverse!r}")
    if inverse == "continuous" or method == "rigid" or (method == "shaped" and shaped_inverse == "rigid"):
        # through the module: the table of the other methods is that function's, wherever it is replaced
        return feedforward.path_torques(model, path, rate, method, shaper, shaped_inverse)
    if method == "shaped":
        if shaped_inverse != "elastic":
            raise InputError(f"the inverse after a shaper is rigid or elastic, got {shaped_inverse!r}")
        return held_line_torques(model, ShapedPath(path, path_shaper(model, path, shaper)), rate)
    if method != "elastic":
        raise InputError(f"unknown feedforward method {method!r} (expected rigid, elastic or shaped)")
    return held_line_torques(model, path, rate)


class HeldLineReference(ElasticLineReference):
    """:class:`~elastic_pm_dyn.motion.references.ElasticLineReference` whose samples at the grid
    instants are the held inverse's (its whole table: the settling periods and the rest torque
    after them); the motion between them stays the continuous inverse's (the PD's reference)."""

    def __init__(self, model: Model, line, rate: float, joint_names):
        super().__init__(model, line, rate, joint_names)
        held = held_solution(model, line, rate, self.motion)
        self._times, self._held = held.times, held.torques
        # the node holds the reference's end: the table's rest row, not a settling one
        self.duration = max(self.duration, (len(self._held) - 1) / rate)

    def sample(self, t: float) -> ReferenceSample:
        s = super().sample(t)
        k = round(t * self.rate)
        if abs(t - k / self.rate) <= 1e-9 and k >= 0:  # a grid instant: the table's row (its last after it)
            s.tau = self._held[min(k, len(self._held) - 1)].copy()
        return s
