"""The reference manoeuvre: the one set of numbers every reference run is made from.

The seed paper's five-bar test: the end effector moves on a straight line with a quintic
time law, then holds the end point; the rigid model's torques are sampled at the control
rate and held (ZOH). The offline demo, the paper figures, the observer's recordings and the
feedforward node's parameter defaults all take their numbers from :data:`REFERENCE_MANOEUVRE`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.motion.trajectory import QuinticLine


@dataclass(frozen=True)
class Manoeuvre:
    """A quintic rest-to-rest line p_A -> p_E, its hold, and how it is sampled."""

    start: tuple[float, ...]  # p_A [m] (2 numbers planar, 3 spatial)
    end: tuple[float, ...]  # p_E [m]
    move: float  # T [s]
    hold: float  # time at p_E that belongs to the manoeuvre [s]
    control_rate: float  # [Hz] torque samples, zero-order hold
    sample: float  # [s] output interval of the simulations

    def __post_init__(self) -> None:
        if not (np.isfinite(self.control_rate) and self.control_rate > 0
                and np.isfinite(self.sample) and self.sample > 0):
            raise InputError(f"control rate and output sample must be > 0 (got {self.control_rate}, {self.sample})")
        self.line  # noqa: B018  (the line checks start, end, move and hold)

    @property
    def line(self) -> QuinticLine:
        """The desired end-effector motion (fresh arrays: callers may not share them)."""
        return QuinticLine(np.array(self.start, dtype=float), np.array(self.end, dtype=float), self.move, self.hold)


REFERENCE_MANOEUVRE = Manoeuvre(
    start=(-0.05, 0.35),
    end=(0.05, 0.45),
    move=0.2,
    hold=0.3,
    control_rate=1000.0,
    sample=1e-4,  # 10 kHz resolves the ~550 Hz spring mode
)
