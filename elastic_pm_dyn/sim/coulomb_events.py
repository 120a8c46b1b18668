"""Coulomb friction's events for scipy's adaptive DOP853: where a sliding joint stops, where one at
rest breaks away.

The accelerations (dynamics/evaluate.py) hold a joint at rest by Coulomb's law while the force it
needs is within its friction F and slide it against -F sign(qd) otherwise; what an ODE solver
cannot see is a sliding joint's velocity reaching zero within a step, where its friction
changes sign. The adaptive run is therefore integrated in segments, each under the law of its
start frozen (:func:`frozen_slip`: a joint sliding there keeps the constant friction -F sign(qd),
a smooth law the solver integrates to its order), and each ends at the first event of its joints
with Coulomb friction (scipy's terminal events, located on the dense output): a stop (the velocity
of a joint sliding at the segment's start reaches 0: it is set to exactly 0, and Coulomb's law at
rest decides whether it sticks) or a breakaway (a joint at rest at the segment's start leaves
STICK_SPEED: from then on it slides, with a stop event of its own).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from elastic_pm_dyn.model.arrays import ModelArrays
from elastic_pm_dyn.model.layout import JF_COULOMB, JF_SLIP, STICK_SPEED

Event = Callable[[float, np.ndarray], float]


def frozen_slip(arrays: ModelArrays, joints: np.ndarray, qd: np.ndarray) -> tuple[ModelArrays, np.ndarray]:
    """The model arrays without the Coulomb friction of the ``joints`` sliding at qd, and that
    friction as a constant tree force (-F sign(qd) on each), to add to the torques."""
    jf = arrays.jf.copy()
    force = np.zeros(len(qd))
    for k in joints:
        if abs(qd[k]) > STICK_SPEED:
            force[k] = -jf[k, JF_COULOMB] * np.sign(qd[k])
            jf[k, JF_COULOMB] = 0.0
    return arrays._replace(jf=jf), force


def coulomb_joints(jf: np.ndarray) -> np.ndarray:
    """The tree joints with Coulomb friction (F > 0, no slip speed: JF_SLIP 0)."""
    return np.flatnonzero((jf[:, JF_COULOMB] > 0) & (jf[:, JF_SLIP] == 0))


def segment_events(joints: np.ndarray, n: int, y: np.ndarray) -> list[Event]:
    """The terminal events of a segment starting at state y = (q, qd) (n coordinates each): for
    each joint sliding there, its stop (qd crossing 0 from its side); for each at rest, its breakaway."""
    events: list[Event] = []
    for k in joints:
        v = float(y[n + k])
        if abs(v) > STICK_SPEED:
            side = 1.0 if v > 0 else -1.0
            events.append(_event(lambda t, yy, i=n + k, s=side: s * yy[i], -1.0))
        else:
            events.append(_event(lambda t, yy, i=n + k: abs(yy[i]) - 2.0 * STICK_SPEED, 1.0))
    return events


def _event(fun: Event, direction: float) -> Event:
    fun.terminal = True  # type: ignore[attr-defined]
    fun.direction = direction  # type: ignore[attr-defined]
    return fun


def settle_stops(joints: np.ndarray, n: int, y_start: np.ndarray, fired: list[bool], y: np.ndarray) -> None:
    """At the end y (in place) of a segment that started at y_start and ended on the events
    ``fired`` (one flag per event of :func:`segment_events`, in its order): the velocity of each
    joint whose stop it was set to exactly 0 (the root is found to the solver's rounding, not to 0)."""
    for k, hit in zip(joints, fired, strict=True):
        if hit and abs(y_start[n + k]) > STICK_SPEED:
            y[n + k] = 0.0


def settle_at_rest(joints: np.ndarray, qd: np.ndarray) -> None:
    """Each of the ``joints`` whose velocity a segment ends within +-STICK_SPEED (its stop fell on
    the segment's end, where no event is seen) is at rest: its velocity set to exactly 0 (in place)."""
    for k in joints:
        if abs(qd[k]) <= STICK_SPEED:
            qd[k] = 0.0
