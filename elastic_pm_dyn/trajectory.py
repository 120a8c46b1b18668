"""Desired end-effector motions: the quintic rest-to-rest straight line."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.errors import InputError


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
