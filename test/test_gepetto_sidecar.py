"""A sidecar as Gepetto's example-parallel-robots writes them, on test/robots/split_rod (a
crank-rod-rocker whose rod is two halves on balls, welded where they meet; written by
make_tree_robots.py): the motor named by part of its name, a re-typed joint the file no
longer has, a 6D weld in upper case, a zero pose with one half folded back a half turn,
and the rod's spin about its own axis, which no closure fixes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

URDF = Path(__file__).resolve().parent / "robots" / "split_rod" / "robot.urdf"


def _mech() -> Mechanism:
    with pytest.warns(UserWarning, match="no joint 'spherical_old'.*passed over"):
        return Mechanism(load_model(URDF))


def test_gepetto_keys_read_as_its_loader_reads_them():
    mech = _mech()
    assert mech.active_names == ["motor_crank"]  # name_mot 'motor': the joints whose names contain it
    assert mech.model.closure.welds and mech.m == 6  # '6D' is a weld
    free = [mech.joint_names[i] for i in mech.elastic]
    assert len(free) == 1 and mech.model.joints[mech.elastic[0]].stiffness == 0.0


def test_half_turn_zero_pose_assembles():
    """The weld frames are half a turn apart at the file's zero pose: Newton on sin(angle)
    stalled there (residual 0.14 m); the assembled pose closes for Pinocchio too."""
    mech = _mech()
    q0 = initial_state(mech)
    assert mech.gap(q0) < 1e-12
    pin = pytest.importorskip("pinocchio")
    from pinocchio_urdf import PinocchioMachine
    assert pin is not None and PinocchioMachine(URDF, mech.model).gap(q0) < 1e-12


def test_free_joint_is_the_rod_spinning_on_its_axis():
    """Turn the free joint and close the loops again: the motor, the rocker and the rod's two
    ends stay where they were (a spin moves nothing but the rod about its own axis)."""
    mech = _mech()
    q0 = initial_state(mech)
    free = mech.elastic[0]
    q = q0.copy()
    q[free] += 0.7
    q1 = solve_pose(mech, q, mech.passive)
    assert mech.gap(q1) < 1e-12
    rocker = mech.joint_names.index("free_rocker")
    assert abs(q1[rocker] - q0[rocker]) < 1e-10 and q1[mech.active[0]] == q0[mech.active[0]]
    origins0, _, tips0 = mech.points(q0)
    origins1, _, tips1 = mech.points(q1)
    np.testing.assert_allclose(origins1, origins0, rtol=0, atol=1e-10)  # the balls at both rod ends
    np.testing.assert_allclose(tips1, tips0, rtol=0, atol=1e-10)  # the weld point, the rod's middle
    assert np.abs(q1 - q0).max() > 0.5  # something did turn
