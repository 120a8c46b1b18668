"""Inverse then direct dynamics is the identity; both inverse methods agree (eqs 4-5, 17)."""

import numpy as np
from conftest import random_state

from elastic_pm_dyn.dynamics.direct import FORMULATIONS
from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.dynamics.inverse import multiplier_inverse_dynamics, tree_inverse_dynamics
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism


def _direct(mech: Mechanism, formulation: str, q, qd, tau_tree) -> np.ndarray:
    qdd, lam = np.empty(mech.n), np.zeros(mech.m)
    accelerations(FORMULATION_CODES[formulation], mech.arrays, q, qd, tau_tree, 0.0, 0.0,
                  np.zeros(mech.n), qdd, lam)
    return qdd


def test_inverse_then_direct_round_trip_elastic(five_bar_vertical) -> None:
    """Pick qdd_ae, get tau_c = [tau_a, tau_e] (tau_e: structure forces on the elastic DOF),
    apply them, get qdd back, for every exact formulation."""
    mech = five_bar_vertical
    rng = np.random.default_rng(10)
    for _ in range(30):
        q, qd, _ = random_state(mech, rng)
        t = mech.terms(q, qd)
        W, c = mech.passive_map(t)
        qdd_ae = rng.uniform(-50, 50, len(mech.ae))
        qdd = W @ qdd_ae + c
        tau_c = tree_inverse_dynamics(mech, q, qd, qdd)
        tau_tree = np.zeros(mech.n)
        tau_tree[mech.ae] = tau_c
        for f in ("scdd", "lda", "multipliers"):
            back = _direct(mech, f, q, qd, tau_tree)
            assert np.max(np.abs(back - qdd)) <= 1e-9 * np.max(np.abs(qdd)), f


def test_two_inverse_methods_agree(five_bar_vertical) -> None:
    mech = five_bar_vertical
    rng = np.random.default_rng(11)
    for _ in range(20):
        q, qd, _ = random_state(mech, rng)
        W, c = mech.passive_map(mech.terms(q, qd))
        qdd = W @ rng.uniform(-50, 50, len(mech.ae)) + c
        a = tree_inverse_dynamics(mech, q, qd, qdd)
        b, _ = multiplier_inverse_dynamics(mech, q, qd, qdd)
        assert np.allclose(a, b, rtol=1e-10, atol=1e-12)


def test_rigid_round_trip_with_motor_torques_only(five_bar_vertical) -> None:
    """On the rigid model (elastic DOF locked) the motor torques alone reproduce the motion."""
    rigid = Mechanism(five_bar_vertical.model.locked())
    assert len(rigid.elastic) == 0 and rigid.n == 4
    rng = np.random.default_rng(12)
    q0 = initial_state(rigid)
    for _ in range(20):
        q = q0.copy()
        q[rigid.active] += rng.uniform(-0.2, 0.2, 2)
        q = solve_pose(rigid, q, rigid.passive)
        qd = rigid.tree_velocity(q, rng.uniform(-2, 2, 2))
        W, c = rigid.passive_map(rigid.terms(q, qd))
        qdd = W @ rng.uniform(-30, 30, 2) + c
        tau = tree_inverse_dynamics(rigid, q, qd, qdd)
        for f in FORMULATIONS[:3]:
            back = _direct(rigid, f, q, qd, rigid.split_tau(tau))
            assert np.max(np.abs(back - qdd)) <= 1e-9 * np.max(np.abs(qdd)), f


def test_locked_model_equals_elastic_model_with_springs_at_rest(five_bar_vertical) -> None:
    """Locking merges bodies and offsets: M and h of the rigid tree are the elastic ones at u = 0."""
    elastic = five_bar_vertical
    rigid = Mechanism(elastic.model.locked())
    rng = np.random.default_rng(13)
    keep = np.array([i for i in range(elastic.n) if i not in elastic.elastic])
    for _ in range(10):
        q = rng.uniform(-3, 3, elastic.n)
        qd = rng.uniform(-2, 2, elastic.n)
        q[elastic.elastic] = 0.0
        qd[elastic.elastic] = 0.0
        te, tr = elastic.terms(q, qd), rigid.terms(q[keep], qd[keep])
        assert np.allclose(tr.M, te.M[np.ix_(keep, keep)], rtol=1e-12, atol=1e-15)
        assert np.allclose(tr.h, te.h[keep], rtol=1e-12, atol=1e-13)
        assert np.allclose(tr.residual, te.residual, rtol=0, atol=1e-15)


def test_round_trip_on_machines_whose_legs_branch() -> None:
    """The tree robots (a parallelogram Delta, arms welded at their hands, a rocker pinned to
    the base): inverse then direct dynamics is the identity, the two inverse methods agree."""
    from pathlib import Path

    from consistent_states import consistent_states

    from elastic_pm_dyn.errors import AssemblyError
    from elastic_pm_dyn.model.loader import load_model
    robots = Path(__file__).resolve().parents[1] / "robots"
    for name in ("delta_parallelogram", "weld_arms", "base_pinned"):
        mech = Mechanism(load_model(robots / name / "robot.urdf"))
        rng = np.random.default_rng(14)
        done = 0
        for _ in range(30):
            try:
                q, qd, _ = next(consistent_states(mech, rng, 1))
            except AssemblyError:  # a draw the machine cannot reach: draw again
                continue
            done += 1
            W, c = mech.passive_map(mech.terms(q, qd))
            qdd = W @ rng.uniform(-30, 30, len(mech.ae)) + c
            tau_c = tree_inverse_dynamics(mech, q, qd, qdd)
            b, _ = multiplier_inverse_dynamics(mech, q, qd, qdd)
            assert np.allclose(tau_c, b, rtol=1e-9, atol=1e-10), name
            tau_tree = np.zeros(mech.n)
            tau_tree[mech.ae] = tau_c
            for f in ("scdd", "lda", "multipliers"):
                back = _direct(mech, f, q, qd, tau_tree)
                assert np.max(np.abs(back - qdd)) <= 1e-8 * np.max(np.abs(qdd)), (name, f)
            if done == 5:
                break
        assert done == 5, name
