"""Joint splines pass through their waypoints."""

from __future__ import annotations

import numpy as np
import pytest

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.motion.trajectory import JointSpline


def test_joint_spline_meets_waypoints_in_output_order_and_rests_outside() -> None:
    times = [0.5, 1.0, 2.0]
    pos = [[0.0, 1.0], [0.2, 1.5], [0.1, 2.0]]  # columns: joint b, joint a
    vel = [[0.0, 0.0], [0.3, -1.0], [0.0, 0.0]]
    path = JointSpline(times, pos, [1, 0], vel)  # output: a, b
    for t, p, v in zip(times, pos, vel, strict=True):
        q, qd, _ = path(t)
        np.testing.assert_allclose(q, p[::-1], atol=1e-12)
        if t not in (path.start, path.end):
            np.testing.assert_allclose(qd, v[::-1], atol=1e-12)
    for t in (0.0, 3.0):
        q, qd, qdd = path(t)
        np.testing.assert_array_equal(q, path.positions[0 if t < 1 else -1])
        assert not qd.any() and not qdd.any()
    with pytest.raises(InputError, match="accelerations need velocities"):
        JointSpline(times, pos, [0, 1], accelerations=vel)
