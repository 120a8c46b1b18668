"""Feedback on the motor encoders: the PD law and the encoder samples it reads (no ROS).

tau = tau_ff + kp (q_ref - q_meas) + kd (qd_ref - qd_meas), per active joint: the rigid
feedforward plus a PD on the measured motor angles. ``qd_meas`` is the sample's own velocity
when the encoder gives one, else the angle differenced from the previous sample over the
difference of their stamps (:class:`EncoderRates`). The feedforward node applies it with
``feedback.kp`` / ``feedback.kd``; with both zero it is the pure feedforward.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from elastic_pm_dyn.errors import InputError


def pd_torque(tau_ff: np.ndarray, q_ref: np.ndarray, qd_ref: np.ndarray, q_meas: np.ndarray,
              qd_meas: np.ndarray, kp: np.ndarray | float, kd: np.ndarray | float) -> np.ndarray:
    """The PD law on top of the feedforward (every argument per active joint, or a scalar gain)."""
    return (np.asarray(tau_ff, dtype=float) + np.multiply(kp, np.subtract(q_ref, q_meas))
            + np.multiply(kd, np.subtract(qd_ref, qd_meas)))


def gains(values: float | Sequence[float], n: int, name: str) -> np.ndarray:
    """One gain for every joint, or one per joint (n values); finite and >= 0."""
    g = np.atleast_1d(np.asarray(values, dtype=float))
    if g.ndim != 1 or len(g) not in (1, n):
        raise InputError(f"{name} takes one value or {n} (one per active joint), got {len(g)}")
    if not np.all(np.isfinite(g) & (g >= 0)):
        raise InputError(f"{name} must be finite and >= 0, got {g.tolist()}")
    return np.broadcast_to(g, (n,)).copy()


class EncoderError(InputError):
    """An encoder sample that cannot be used; ``kind`` names why (warnings are throttled per kind)."""

    def __init__(self, kind: str, message: str):
        self.kind = kind
        super().__init__(message)


class EncoderRates:
    """Motor angles and rates of encoder samples (JointState fields: names, position, velocity).

    Names of other joints are ignored (a full joint state works as well as the motors
    alone); every active joint must be there once, with finite values. The rate is the
    sample's velocity when it gives one for every active joint, else the difference to the
    previous sample over their stamps (zero for the first sample).
    """

    def __init__(self, active_names: Sequence[str]):
        self.active_names = list(active_names)
        self.last: tuple[int, np.ndarray] | None = None  # (stamp [ns], angles) of the newest sample
        self._orders: dict[tuple, np.ndarray] = {}

    def _order(self, names: Sequence[str]) -> np.ndarray:
        key = tuple(names)
        order = self._orders.get(key)
        if order is None:
            if len(set(key)) != len(key):
                raise EncoderError("duplicate name", "encoder sample names a joint twice")
            missing = [n for n in self.active_names if n not in key]
            if missing:
                raise EncoderError("missing joint", f"encoder sample lacks active joint(s) {', '.join(missing)}")
            order = np.array([key.index(n) for n in self.active_names], dtype=np.int64)
            if len(self._orders) > 64:
                self._orders.clear()
            self._orders[key] = order
        return order

    def sample(self, stamp_ns: int, names: Sequence[str], position: Sequence[float],
               velocity: Sequence[float] = ()) -> tuple[np.ndarray, np.ndarray]:
        """(angles, rates) of the active joints; :class:`EncoderError` if the sample cannot be used."""
        order = self._order(names)
        if len(position) != len(names):
            raise EncoderError("length", f"encoder sample has {len(names)} names but {len(position)} positions")
        q = np.asarray(position, dtype=float)[order]
        if not np.all(np.isfinite(q)):
            raise EncoderError("not finite", "encoder sample contains NaN or Inf")
        if self.last is not None and stamp_ns <= self.last[0]:
            raise EncoderError("old stamp", f"encoder sample stamped {stamp_ns * 1e-9:.6f} s, not after the "
                               f"previous one ({self.last[0] * 1e-9:.6f} s): ignored")
        if len(velocity) == len(names):
            qd = np.asarray(velocity, dtype=float)[order]
            if not np.all(np.isfinite(qd)):
                raise EncoderError("not finite", "encoder sample velocity contains NaN or Inf")
        elif self.last is None:
            qd = np.zeros(len(q))
        else:
            qd = (q - self.last[1]) / ((stamp_ns - self.last[0]) * 1e-9)
        self.last = (int(stamp_ns), q)
        return q, qd
