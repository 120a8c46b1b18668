"""Bring your own robot: URDF + closure sidecar and MJCF, checked against engines we did not write.

(a) the reference five-bar as URDF + robot.yaml gives config/five_bar.yaml's Model and run;
(b) URDF machines against Pinocchio's constraintDynamics on the same URDF + closures, built
    as Gepetto's loader builds them (RigidConstraintModel CONTACT_3D between the frames);
(c) the MJCF five-bar against MuJoCo within its soft-constraint error (docs/peers.md);
bad files: test_robot_file_errors.py.
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from consistent_states import consistent_states
from pinocchio_urdf import PinocchioMachine

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

REPO = Path(__file__).resolve().parents[1].parent
ROBOTS = REPO / "test" / "robots"
FIVE_BAR_URDF = ROBOTS / "five_bar_urdf" / "robot.urdf"
FOUR_BAR_URDF = ROBOTS / "four_bar_onshape" / "robot.urdf"
FIVE_BAR_MJCF = ROBOTS / "five_bar.xml"
REL_TOL = 1e-9


def _ours(mech: Mechanism, q, qd, tau, method: str = "scdd"):
    qdd, lam = np.empty(mech.n), np.zeros(mech.m)
    cond, gap = accelerations(FORMULATION_CODES[method], mech.arrays, q, qd, tau, 0.0, 0.0, np.zeros(mech.n), qdd, lam)
    assert cond > 1e-9 and gap < 1e-11
    return qdd, lam


# ------------------------------------------------------------------ (a) the same Model
def _assert_same_model(a, b):
    assert a.joint_names == b.joint_names
    for ja, jb in zip(a.joints, b.joints, strict=True):
        for f in fields(ja):
            va, vb = getattr(ja, f.name), getattr(jb, f.name)
            if f.name == "body":
                assert va.mass == pytest.approx(vb.mass, rel=1e-15)
                np.testing.assert_allclose(va.com, vb.com, rtol=0, atol=1e-16)
                np.testing.assert_allclose(va.inertia, vb.inertia, rtol=0, atol=1e-18)
            elif isinstance(va, np.ndarray):
                np.testing.assert_allclose(va, vb, rtol=0, atol=1e-16, err_msg=f"{ja.name}.{f.name}")
            else:
                assert va == vb, f"{ja.name}.{f.name}: {va!r} != {vb!r}"
    for ca, cb in zip(a.chains, b.chains, strict=True):
        np.testing.assert_array_equal(ca.end_xyz, cb.end_xyz)
        assert ca.points == cb.points
    assert a.closure == b.closure and a.planar == b.planar
    np.testing.assert_array_equal(a.gravity, b.gravity)
    assert a.end_effector_mass == b.end_effector_mass and a.branches == b.branches
    ia, ib = a.initial, b.initial
    np.testing.assert_array_equal(ia.end_effector, ib.end_effector)
    assert (ia.active, ia.guess, ia.signs) == (ib.active, ib.guess, ib.signs)


def test_five_bar_urdf_is_the_reference_model_and_run():
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    urdf, ref = load_model(FIVE_BAR_URDF), load_model(REPO / "config" / "five_bar.yaml")
    _assert_same_model(urdf, ref)
    runs = [Simulator(Mechanism(m), SimulationOptions(formulation="scdd")).run(ConstantTorque([0.4, -0.3]), 0.02)
            for m in (urdf, ref)]
    assert runs[0].q.shape == runs[1].q.shape and len(runs[0].t) >= 20
    scale = np.abs(runs[1].q).max()
    assert np.abs(runs[0].q - runs[1].q).max() <= 1e-14 * scale
    assert np.abs(runs[0].qd - runs[1].qd).max() <= 1e-12 * np.abs(runs[1].qd).max()


def test_closures_named_explicitly_and_by_content(tmp_path):
    """closures= names the sidecar; a URDF under another suffix is found by its <robot> root."""
    (tmp_path / "machine.xml").write_text(FIVE_BAR_URDF.read_text())
    (tmp_path / "loops.yaml").write_text((FIVE_BAR_URDF.parent / "robot.yaml").read_text())
    model = load_model(tmp_path / "machine.xml", closures=tmp_path / "loops.yaml")
    _assert_same_model(model, load_model(FIVE_BAR_URDF))


def test_mjcf_five_bar_is_the_reference_machine():
    """MuJoCo's compiled numbers: the end effector folded into the forearms, moments floored at 1e-10."""
    pytest.importorskip("mujoco")
    mj, ref = load_model(FIVE_BAR_MJCF), load_model(REPO / "config" / "five_bar.yaml")
    assert mj.joint_names == ref.joint_names and mj.closure == ref.closure and mj.planar
    assert [j.role for j in mj.joints] == [j.role for j in ref.joints]
    for a, b in zip(mj.joints, ref.joints, strict=True):
        assert a.body.mass == pytest.approx(b.body.mass, rel=1e-15)
        np.testing.assert_allclose(a.body.com, b.body.com, atol=1e-15)
        np.testing.assert_allclose(a.body.inertia, b.body.inertia, atol=1.1e-10)  # MuJoCo's floor
        assert (a.stiffness, a.damping, a.rotor_inertia) == (b.stiffness, b.damping, b.rotor_inertia)
    q = initial_state(Mechanism(mj))  # from the keyframe's guess, passive joints assembled
    assert Mechanism(mj).gap(q) < 1e-13 and np.sin(q[2]) < 0 < np.sin(q[5])


def test_four_bar_starts_from_the_files_zero_configuration():
    """No initial_state: the passive joints are assembled from the URDF's zero pose; the
    1e-9 kg closure frames stay (as Pinocchio keeps them), the 2500 kg base never moves."""
    model = load_model(FOUR_BAR_URDF)
    mech = Mechanism(model)
    assert model.planar and model.closure.components == (0, 1)
    assert [j.role for j in model.joints] == ["active", "passive", "elastic", "passive"]
    assert model.joints[2].damping == 2.0  # the URDF's <dynamics damping> on the spring
    assert model.joints[3].body.mass == pytest.approx(0.2 + 1e-9, rel=1e-15)
    q = initial_state(mech)
    assert q[0] == 0.0 and q[2] == 0.0 and mech.gap(q) < 1e-13 and abs(q[3]) > 0.05


# -------------------------------------------------------------------- (b) Pinocchio
@pytest.mark.parametrize("urdf", [FIVE_BAR_URDF, FOUR_BAR_URDF], ids=["five_bar", "four_bar_onshape"])
def test_urdf_matches_pinocchio_constraint_dynamics(urdf):
    pytest.importorskip("pinocchio")
    model = load_model(urdf)
    mech = Mechanism(model)
    peer = PinocchioMachine(urdf, model)
    worst_qdd = worst_lam = 0.0
    for q, qd, tau in consistent_states(mech, np.random.default_rng(7), 12):
        for method in ("scdd", "lda", "multipliers"):
            qdd, lam = _ours(mech, q, qd, tau, method)
            a = peer.accelerations(q, qd, tau)
            worst_qdd = max(worst_qdd, float(np.abs(a - qdd).max() / np.abs(qdd).max()))
            if method != "lda":
                f = peer.cut_force_world()[list(model.closure.components)]
                worst_lam = max(worst_lam, float(np.abs(f - lam).max() / np.abs(lam).max()))
    print(f"{urdf.parent.name}: max rel. error qdd {worst_qdd:.2e}, cut force {worst_lam:.2e}")
    assert worst_qdd <= REL_TOL and worst_lam <= REL_TOL


# ----------------------------------------------------------------------- (c) MuJoCo
def test_mjcf_matches_mujoco_within_its_soft_constraint():
    mujoco = pytest.importorskip("mujoco")
    model = load_model(FIVE_BAR_MJCF)
    mech = Mechanism(model)
    m = mujoco.MjModel.from_xml_path(str(FIVE_BAR_MJCF))
    d = mujoco.MjData(m)
    adr = [m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in model.joint_names]
    worst = 0.0
    for q, qd, tau in consistent_states(mech, np.random.default_rng(11), 8):
        qdd, _ = _ours(mech, q, qd, tau)
        mujoco.mj_resetData(m, d)
        d.qpos[adr], d.qvel[adr], d.qfrc_applied[adr] = q, qd, tau
        mujoco.mj_forward(m, d)
        worst = max(worst, float(np.abs(d.qacc[adr] - qdd).max() / np.abs(qdd).max()))
    print(f"MuJoCo five-bar: max rel. difference qdd {worst:.2e}")
    assert worst < 1e-3  # MuJoCo's loops are soft: ~2e-5 with the nearly hard connect of docs/peers.md
