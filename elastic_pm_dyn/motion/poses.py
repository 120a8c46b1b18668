"""A platform's pose along a straight line: position on the segment, orientation on the SO(3)
geodesic, both with one rest-to-rest time law, in the platform's own coordinates
[x, y, z, yaw, pitch, roll] (R = Rz(yaw) Ry(pitch) Rx(roll), the URDF rpy convention the
platform chains of ``config/hexa.yaml`` use: prismatic x, y, z, then revolute z, y, x).

R(t) = R_A exp(s(t) [w]), w = log(R_A^T R_B): a rotation about one body-fixed axis, so the
body angular velocity is sd w and its acceleration sdd w; the Euler rates follow from
w_b = E(pitch, roll) [yawd, pitchd, rolld] and their rates from its time derivative.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.motion.time_laws import time_law


def _rates_matrix(pitch: float, roll: float) -> np.ndarray:
    """E with w_body = E [yawd, pitchd, rolld] for R = Rz(yaw) Ry(pitch) Rx(roll)."""
    sp, cp, sr, cr = np.sin(pitch), np.cos(pitch), np.sin(roll), np.cos(roll)
    return np.array([[-sp, 0.0, 1.0], [sr * cp, cr, 0.0], [cr * cp, -sr, 0.0]])


def _rates_matrix_dot(pitch: float, roll: float, pitch_d: float, roll_d: float) -> np.ndarray:
    sp, cp, sr, cr = np.sin(pitch), np.cos(pitch), np.sin(roll), np.cos(roll)
    d_pitch = np.array([[-cp, 0.0, 0.0], [-sr * sp, 0.0, 0.0], [-cr * sp, 0.0, 0.0]])
    d_roll = np.array([[0.0, 0.0, 0.0], [cr * cp, -sr, 0.0], [-sr * cp, -cr, 0.0]])
    return d_pitch * pitch_d + d_roll * roll_d


@dataclass(frozen=True)
class PoseLine:
    """Rest-to-rest move of a platform between two poses (position [m], rpy [rad] each)."""

    start: np.ndarray  # [x, y, z, yaw, pitch, roll] at the start (the platform's coordinates)
    end: np.ndarray
    move: float
    hold: float = 0.0
    order: int = 4

    def __post_init__(self) -> None:
        if np.shape(self.start) != (6,) or np.shape(self.end) != (6,):
            raise InputError("a pose line needs 6 coordinates at each end: x y z yaw pitch roll")
        if not (self.move > 0 and self.hold >= 0 and np.isfinite(self.move + self.hold)):
            raise InputError(f"move time must be > 0 and hold >= 0 (got {self.move}, {self.hold})")
        if not np.all(np.isfinite(np.concatenate([self.start, self.end]))):
            raise InputError("pose line start and end must be finite")
        for pose in (self.start, self.end):
            if abs(np.cos(pose[4])) < 1e-3:
                raise InputError("pitch of +-90 degrees: yaw and roll are not determined there (gimbal lock)")

    @property
    def duration(self) -> float:
        return self.move + self.hold

    @property
    def _rotations(self) -> tuple[Rotation, np.ndarray]:
        ra = Rotation.from_euler("ZYX", self.start[3:6])
        rb = Rotation.from_euler("ZYX", self.end[3:6])
        return ra, (ra.inv() * rb).as_rotvec()

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Platform coordinates, their rates and accelerations at time t."""
        s, sd, sdd = time_law(self.order, self.move, t, 2)
        ra, w = self._rotations
        d = self.end[:3] - self.start[:3]
        yaw, pitch, roll = (ra * Rotation.from_rotvec(s * w)).as_euler("ZYX")
        if t >= self.move:  # the end pose exactly (as_euler may pick the other branch of an equal rotation)
            yaw, pitch, roll = self.end[3:6]
        E = _rates_matrix(pitch, roll)
        angles_d = np.linalg.solve(E, sd * w)
        E_dot = _rates_matrix_dot(pitch, roll, angles_d[1], angles_d[2])
        angles_dd = np.linalg.solve(E, sdd * w - E_dot @ angles_d)
        y = np.concatenate([self.start[:3] + s * d, _unwrap(np.array([yaw, pitch, roll]), self.start[3:6])])
        return y, np.concatenate([sd * d, angles_d]), np.concatenate([sdd * d, angles_dd])


def _unwrap(angles: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Angles shifted by whole turns to lie within half a turn of ``near`` (joint angles are continuous)."""
    return near + (angles - near + np.pi) % (2 * np.pi) - np.pi
