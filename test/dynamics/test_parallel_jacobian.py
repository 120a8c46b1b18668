"""G^{+T} = W^T J_t^T U S^{-1} (eq 31) against finite differences of the forward kinematics."""

import numpy as np
from conftest import random_state

from elastic_pm_dyn.dynamics.jacobian import branch_directions, parallel_jacobian_transpose
from elastic_pm_dyn.kinematics.assembly import solve_pose


def _ee_of_q_ae(mech, q_ref: np.ndarray, q_ae: np.ndarray) -> np.ndarray:
    q = q_ref.copy()
    q[mech.ae] = q_ae
    return mech.end_effector(solve_pose(mech, q, mech.passive))


def test_eq31_equals_transpose_of_forward_kinematics_jacobian(five_bar) -> None:
    mech = five_bar
    rng = np.random.default_rng(20)
    for _ in range(10):
        q, _, _ = random_state(mech, rng)
        G_T = parallel_jacobian_transpose(mech, q)  # n_ae x 2
        q_ae = q[mech.ae]
        fd = np.zeros((2, len(q_ae)))
        for j in range(len(q_ae)):
            step = 1e-6 if j < len(mech.active) else 1e-8
            e = np.zeros(len(q_ae))
            e[j] = step
            fd[:, j] = (_ee_of_q_ae(mech, q, q_ae + e) - _ee_of_q_ae(mech, q, q_ae - e)) / (2 * step)
        assert np.allclose(G_T, fd.T, rtol=1e-6, atol=1e-8)


def test_branch_directions_are_the_forearms(five_bar) -> None:
    """A force through the passive elbow passes along the forearm (two-force member)."""
    rng = np.random.default_rng(21)
    q, _, _ = random_state(five_bar, rng)
    S = branch_directions(five_bar, q)
    origins, _, tips = five_bar.points(q)
    for col, (elbow, tip) in enumerate(((2, 0), (5, 1))):
        forearm = (tips[tip] - origins[elbow])[:2]
        assert abs(abs(S[:, col] @ forearm) - np.linalg.norm(forearm)) < 1e-12


def test_virtual_work_an_end_effector_force_as_joint_forces(five_bar) -> None:
    """tau_ae = G^{+T} f is the static equivalent: W^T J_0^T f for the force on one chain end."""
    rng = np.random.default_rng(22)
    q, _, _ = random_state(five_bar, rng)
    f = np.array([3.0, -2.0])
    W, _ = five_bar.passive_map(five_bar.terms(q))
    J_ee, _ = five_bar.end_effector_jacobian(five_bar.terms(q))
    assert np.allclose(parallel_jacobian_transpose(five_bar, q) @ f, W.T @ J_ee.T @ f, rtol=1e-10, atol=1e-12)
