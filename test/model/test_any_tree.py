"""Kinematic trees as CAD exports write them, against Pinocchio on the same files.

Three machines from test/robots/make_tree_robots.py, each a URDF + robot.yaml sidecar:
the Delta with parallelogram forearms (a branch inside every leg, the platform hung under
leg 1, the motors on a mount fixed to the base), two arms welded at their hands (a 6d
closure, a sprung tool branching off a forearm) and a crank-coupler-rocker pinned to the
base (a closure to the fixed base, its frame on an inner body). At random consistent
states our accelerations and closure forces equal Pinocchio's ``constraintDynamics``
(``RigidConstraintModel`` CONTACT_3D / CONTACT_6D between the sidecar's frames, LOCAL,
as Gepetto's loader builds them), and the formulations agree with each other.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from consistent_states import consistent_states
from pinocchio_urdf import PinocchioMachine

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
DELTA = ROBOTS / "delta_parallelogram" / "robot.urdf"
WELD = ROBOTS / "weld_arms" / "robot.urdf"
PINNED = ROBOTS / "base_pinned" / "robot.urdf"
REL_TOL = 1e-9  # against Pinocchio
ROUND_OFF = 1e-11  # between our formulations
N_STATES = 6


def _ours(mech: Mechanism, q, qd, tau, method: str) -> tuple[np.ndarray, np.ndarray]:
    d = Dynamics(mech, method)
    qdd = d.accelerations(q, qd, tau[mech.active])
    return qdd, d.cut_force.copy()


@pytest.mark.parametrize("urdf", [DELTA, WELD, PINNED], ids=["delta_parallelogram", "weld_arms", "base_pinned"])
def test_tree_machine_matches_pinocchio_constraint_dynamics(urdf):
    pytest.importorskip("pinocchio")
    model = load_model(urdf)
    mech = Mechanism(model)
    peer = PinocchioMachine(urdf, model)
    assert peer.gap(initial_state(mech)) < 1e-12
    worst_qdd = worst_lam = worst_forms = 0.0
    for q, qd, tau in consistent_states(mech, np.random.default_rng(3), N_STATES):
        a = peer.accelerations(q, qd, tau)
        f = peer.cut_forces_world(model.closure.components)
        ref, _ = _ours(mech, q, qd, tau, "multipliers")
        for method in ("scdd", "scdd_stacked", "lda", "multipliers"):
            qdd, lam = _ours(mech, q, qd, tau, method)
            worst_qdd = max(worst_qdd, float(np.abs(a - qdd).max() / np.abs(a).max()))
            worst_forms = max(worst_forms, float(np.abs(ref - qdd).max() / np.abs(ref).max()))
            if method != "lda":
                worst_lam = max(worst_lam, float(np.abs(f - lam).max() / np.abs(f).max()))
        # forward kinematics alone (Mechanism.points, the ROS publish path) places the points as the sweep does
        np.testing.assert_array_equal(mech.points(q)[2], mech.terms(q).p_tip[:, :3])
        assert mech.gap(q) < 1e-12
    print(f"{urdf.parent.name}: n_t {mech.n}, m {mech.m}; max rel. error qdd {worst_qdd:.2e}, "
          f"closure forces {worst_lam:.2e}; formulations among themselves {worst_forms:.2e}")
    assert worst_qdd <= REL_TOL and worst_lam <= REL_TOL and worst_forms <= ROUND_OFF


def test_parallelogram_delta_is_three_subtrees():
    """Each leg is one subtree: the two rods of a parallelogram hang on the same upper arm, so
    neither moves the other (no mass coupling, no Jacobian column of the sibling), while both
    couple with the motor that carries them; the platform is in leg 1's subtree."""
    model = load_model(DELTA)
    mech = Mechanism(model)
    assert [c.name for c in model.chains] == ["leg1_arm_inner", "leg2_arm_inner", "leg3_arm_inner"]
    names = mech.joint_names
    q = initial_state(mech)
    t = mech.terms(q, np.full(mech.n, 0.3))
    for leg in ("leg2", "leg3"):
        a, b, motor = (names.index(f"{leg}_{j}") for j in ("rod_a_1", "rod_b_1", "motor"))
        assert t.M[a, b] == 0.0 and t.M[b, a] == 0.0
        assert t.M[a, motor] != 0.0 and t.M[b, motor] != 0.0
        end_b = [label for _, _, label in model.point_list()].index(f"{leg}_arm_inner.{leg}_rod_b_end")
        assert not np.any(t.J[end_b][:, a]) and np.any(t.J[end_b][:, b])
    # every joint's parent comes before it within its leg
    for c in model.chains:
        assert all(p < k for k, p in enumerate(c.parent_indices()))
    assert "platform_ball_z" in [j.name for j in model.chains[0].joints]


def test_base_closure_is_a_fixed_point_and_weld_rows_hold_orientation():
    """The pinned rocker's partner point is the base's own (fixed: no Jacobian, no motion);
    the welded hands keep their relative orientation along a simulated motion."""
    pinned = Mechanism(load_model(PINNED))
    assert [label for _, _, label in pinned.model.point_list()][-1] == "base.base_pin"
    t = pinned.terms(initial_state(pinned), np.ones(pinned.n))
    assert not np.any(t.J[-1]) and not np.any(t.a_tip[-1])
    np.testing.assert_array_equal(t.p_tip[-1], [0.05, 0.3, 0.22])

    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    weld = Mechanism(load_model(WELD))
    assert weld.m == 6 and weld.model.closure.welds == weld.model.closure.pairs
    run = Simulator(weld, SimulationOptions(formulation="scdd", integrator="rk4", dt=1e-4, sample=1e-2)).run(
        ConstantTorque([0.3, -0.2]), 0.1)
    moved = float(np.abs(run.q - run.q[0]).max())
    worst = 0.0
    for q in run.q:
        pa, pb = weld.terms(q).p_tip[list(weld.model.closure.pairs[0])]
        Ra, Rb = pa[3:].reshape(3, 3), pb[3:].reshape(3, 3)
        worst = max(worst, float(np.abs(Ra.T @ Rb - np.eye(3)).max()), float(np.abs(pa[:3] - pb[:3]).max()))
    print(f"welded hands: joints moved {moved:.3g} rad, largest relative rotation/offset {worst:.1e}")
    assert moved > 0.05 and worst < 1e-12


@pytest.mark.parametrize("urdf", [DELTA, WELD, PINNED], ids=["delta_parallelogram", "weld_arms", "base_pinned"])
def test_locked_subtree_is_the_machine_with_springs_at_rest(urdf):
    """The rigid model of a tree (elastic joints locked at rest) has, at any state of the kept
    joints, the mass matrix, bias and closure of the elastic model with its springs held at
    rest: locking re-hangs the children and points of a locked joint on its kept ancestor."""
    full = Mechanism(load_model(urdf))
    rigid = Mechanism(full.model.locked())
    kept = np.array([i for i in range(full.n) if i not in set(full.elastic)])
    assert rigid.joint_names == [full.joint_names[i] for i in kept]
    rng = np.random.default_rng(5)
    q = initial_state(full) + rng.uniform(-0.3, 0.3, full.n)
    qd = rng.uniform(-1.0, 1.0, full.n)
    q[full.elastic], qd[full.elastic] = full.rest[full.elastic], 0.0
    a, b = full.terms(q, qd), rigid.terms(q[kept], qd[kept])
    np.testing.assert_allclose(b.M, a.M[np.ix_(kept, kept)], rtol=0, atol=1e-13 * np.abs(a.M).max())
    np.testing.assert_allclose(b.h, a.h[kept], rtol=0, atol=1e-13 * np.abs(a.h).max())
    np.testing.assert_allclose(b.residual, a.residual, rtol=0, atol=1e-15)
    np.testing.assert_allclose(b.A, a.A[:, kept], rtol=0, atol=1e-14)


def test_planar_weld_matches_pinocchio(tmp_path):
    """A weld on a planar machine constrains x, y and the turn about z: the five-bar whose right
    forearm carries a hand on a pin, welded to the left forearm's end, against Pinocchio's
    CONTACT_6D (whose z, roll and pitch rows are zero here, as a 3D contact's z row is)."""
    pytest.importorskip("pinocchio")
    src = ROBOTS / "five_bar_urdf"
    urdf = (src / "robot.urdf").read_text().replace(
        '<joint name="right_closure_joint" type="fixed">', '<joint name="right_hand" type="continuous">').replace(
        '<origin xyz="0.35 0 0" rpy="0 0 0"/>\n  </joint>\n  <link name="closure_right"/>',
        '<origin xyz="0.35 0 0" rpy="0 0 0"/>\n    <axis xyz="0 0 1"/>\n  </joint>\n  <link name="closure_right">'
        '<inertial><origin xyz="0.02 0 0"/><mass value="0.05"/>'
        '<inertia ixx="0" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link>')
    assert 'name="right_hand"' in urdf and '<mass value="0.05"/>' in urdf
    (tmp_path / "robot.urdf").write_text(urdf)
    (tmp_path / "robot.yaml").write_text((src / "robot.yaml").read_text().replace("type: ['3d']", "type: ['6d']"))
    model = load_model(tmp_path / "robot.urdf")
    mech = Mechanism(model)
    assert model.planar and mech.m == 3 and len(model.closure.welds) == 1
    peer = PinocchioMachine(tmp_path / "robot.urdf", model)
    worst_qdd = worst_lam = 0.0
    for q, qd, tau in consistent_states(mech, np.random.default_rng(9), N_STATES):
        a = peer.accelerations(q, qd, tau)
        f = peer.cut_forces_world(model.closure.components)
        for method in ("scdd", "lda", "multipliers"):
            qdd, lam = _ours(mech, q, qd, tau, method)
            worst_qdd = max(worst_qdd, float(np.abs(a - qdd).max() / np.abs(a).max()))
            if method != "lda":
                worst_lam = max(worst_lam, float(np.abs(f - lam).max() / np.abs(f).max()))
    print(f"planar weld: max rel. error qdd {worst_qdd:.2e}, closure forces {worst_lam:.2e}")
    assert worst_qdd <= REL_TOL and worst_lam <= REL_TOL
