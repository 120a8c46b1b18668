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

URDF = Path(__file__).resolve().parents[1] / "robots" / "split_rod" / "robot.urdf"


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


def test_cardan_is_two_revolutes_about_x_then_y(tmp_path):
    """joint_type CARDAN, as Gepetto's loader builds it (RX then RY at the joint's frame,
    <joint>_X and _Y): on the crank's ball it stops the rod's spin, so no joint is free, and
    the machine's accelerations are Pinocchio's at random consistent states."""
    pytest.importorskip("pinocchio")
    from consistent_states import consistent_states
    from pinocchio_urdf import PinocchioMachine

    from elastic_pm_dyn.dynamics.direct import Dynamics
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(URDF.read_text())
    (tmp_path / "robot.yaml").write_text(
        "closed_loop: [['closedloop1_A', 'closedloop1_B']]\ntype: ['6d']\nname_mot: ['motor_crank']\n"
        "joint_name: ['spherical_crank', 'spherical_rocker']\njoint_type: ['CARDAN', 'SPHERICAL']\n")
    model = load_model(urdf)
    mech = Mechanism(model)
    joints = {j.name: j for j in model.joints}
    np.testing.assert_array_equal(joints["spherical_crank_X"].axis, [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(joints["spherical_crank_Y"].axis, [0.0, 1.0, 0.0])
    assert len(mech.elastic) == 0 and len(mech.passive) == 6
    peer = PinocchioMachine(urdf, model)
    for q, qd, tau in consistent_states(mech, np.random.default_rng(5), 4):
        a = peer.accelerations(q, qd, tau)
        qdd = Dynamics(mech, "scdd").accelerations(q, qd, tau[mech.active])
        assert np.abs(a - qdd).max() <= 1e-9 * np.abs(a).max()


def test_check_prints_a_passed_over_joint_as_one_warning_line() -> None:
    """As a user sees it (a process of its own: pytest would capture the warning)."""
    import subprocess
    import sys
    urdf = Path(__file__).resolve().parents[1] / "robots" / "split_rod" / "robot.urdf"
    out = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "check", str(urdf)], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    err = [line for line in out.stderr.splitlines() if line.strip()]
    # each warning one line (the file's joint limits and effort limits have theirs too)
    assert all(line.startswith("elastic-pm-dyn: warning: ") for line in err), err
    assert len([line for line in err if "spherical_old" in line]) == 1, err
