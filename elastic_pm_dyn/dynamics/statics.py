"""Static equilibrium of the elastic machine under motor torques and an end-effector load."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.inverse import tree_inverse_dynamics
from elastic_pm_dyn.errors import SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism


def elastic_residual(mech: Mechanism, q: np.ndarray, ee_force: np.ndarray | None = None,
                     tau_active: np.ndarray | None = None) -> np.ndarray:
    """Generalised force on q_ae at rest, W^T (h_t(q, 0) - tau_t): zero where balanced.

    tau_t holds the motor torques and J_ee^T f of an end-effector force f.
    """
    t = mech.terms(q)
    W, _ = mech.passive_map(t)
    tau = mech.split_tau(np.zeros(len(mech.active)) if tau_active is None else tau_active)
    if ee_force is not None:
        J_ee, _ = mech.end_effector_jacobian(t)
        tau = tau + J_ee.T @ np.asarray(ee_force, dtype=float)
    return W.T @ (t.h - tau)


def static_deflection(mech: Mechanism, q0: np.ndarray, ee_force: np.ndarray, tol: float = 1e-12,
                      max_iter: int = 30) -> np.ndarray:
    """Equilibrium with the motors clamped at q0's positions under an end-effector force (and gravity).

    Newton on the elastic coordinates (passive ones from the closure) until the elastic
    generalised forces vanish relative to the load. Returns the tree coordinates.
    """
    q = solve_pose(mech, np.array(q0, dtype=float), mech.passive)
    n_a = len(mech.active)
    e = np.arange(n_a, len(mech.ae))  # elastic rows of q_ae
    # Converged relative to the load: the end-effector force or the start's imbalance (gravity).
    scale = max(float(np.linalg.norm(ee_force)), float(np.linalg.norm(elastic_residual(mech, q, ee_force)[e])),
                1e-12)

    def residual(q_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        qq = q.copy()
        qq[mech.elastic] = q_e
        qq = solve_pose(mech, qq, mech.passive)
        return elastic_residual(mech, qq, ee_force)[e], qq

    q_e = q[mech.elastic].copy()
    r, q = residual(q_e)
    for _ in range(max_iter):
        if np.linalg.norm(r) <= tol * scale:
            return q
        K = np.empty((len(e), len(e)))
        for j in range(len(e)):
            step = 1e-9 * max(1.0, abs(q_e[j]))
            dq = np.zeros(len(e))
            dq[j] = step
            K[:, j] = (residual(q_e + dq)[0] - residual(q_e - dq)[0]) / (2 * step)
        q_e = q_e - np.linalg.solve(K, r)
        r, q = residual(q_e)
    if np.linalg.norm(r) <= 1e3 * tol * scale:
        return q
    raise SingularConfigurationError(f"static equilibrium not found: residual {np.linalg.norm(r):.3g}")


def rest_state(mech: Mechanism) -> np.ndarray:
    """The model's initial pose at rest: the springs in static equilibrium under gravity with
    the motors held where the file puts them (a machine standing still)."""
    return static_deflection(mech, initial_state(mech), np.zeros(len(mech.ee_components)))


def holding_torques(mech: Mechanism, q: np.ndarray) -> np.ndarray:
    """Motor torques (active joint order) that hold the consistent pose q at rest against
    gravity: the motors' rows of the inverse dynamics at zero rates and accelerations, solved
    through their transmission (a tendon motor's input is its force)."""
    zero = np.zeros(mech.n)
    return mech.motor_inputs(tree_inverse_dynamics(mech, q, zero, zero))[0]
