"""Inverse dynamics (eqs 4-5, 17, 20) and the rigid feedforward of a desired motion."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.kinematics.assembly import solve_acceleration, solve_pose, solve_velocity
from elastic_pm_dyn.kinematics.mechanism import Mechanism


def tree_inverse_dynamics(mech: Mechanism, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """tau_c = W^T (M_t qdd_t + h_t): forces on q_ae for a consistent tree motion (eq 17).

    The tree forces M_t qdd_t + h_t are those of the real and virtual actuators of the
    tree (eq 11); W^T maps them onto the non-redundant coordinates. Entries for the
    elastic coordinates are the structure forces the motion would need (zero for a
    motion the free elastic machine can perform). Dry friction (Coulomb's law) is in h as
    F sign(qd) on a joint that moves, so the forces compensate it; a joint at rest (|qd| <=
    layout.STICK_SPEED) gets none: at rest its friction is any force within +-F, which a
    motion alone does not determine (docs/robot_files.md, "Dry friction").
    """
    t = mech.terms(q, qd)
    W, _ = mech.passive_map(t)
    return W.T @ (t.M @ qdd + t.h)


def motor_torques(mech: Mechanism, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """Motor inputs (active order) for a consistent tree motion of a model without elastic
    coordinates (the rigid one): B_a u = W^T (M_t qdd + h_t), B the motors' transmission."""
    return mech.motor_inputs(tree_inverse_dynamics(mech, q, qd, qdd))[0]


def multiplier_inverse_dynamics(mech: Mechanism, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
                                ) -> tuple[np.ndarray, np.ndarray]:
    """Eqs 4-5: multipliers from the passive rows, then the actuator forces.

    Returns (tau on q_ae, lambda). Equal to :func:`tree_inverse_dynamics` (a cross-check).
    """
    t = mech.terms(q, qd)
    f = t.M @ qdd + t.h  # tree forces before the constraint
    # Passive rows carry no actuator: f_p = A_p^T lambda (eq 4).
    lam = np.linalg.solve(t.A[:, mech.passive].T, f[mech.passive]) if mech.m else np.zeros(0)
    tau = f - t.A.T @ lam  # eq 5
    return tau[mech.ae], lam


class RigidFeedforward:
    """Rigid-model inverse dynamics of end-effector motions (elastic DOF locked).

    The rigid model is the elastic one with u = 0, c -> infinity (``Model.locked``); its
    tree coordinates are [q_a, q_p] only.
    """

    def __init__(self, rigid: Mechanism, q_guess: np.ndarray):
        if len(rigid.elastic):
            raise ValueError("RigidFeedforward needs a model with the elastic joints locked")
        self.mech = rigid
        self.q = np.array(q_guess, dtype=float)  # warm start, follows the path
        self.free = np.arange(rigid.n)

    def joint_motion(self, p: np.ndarray, pd: np.ndarray, pdd: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tree position, velocity, acceleration for an end-effector point motion."""
        mech = self.mech
        self.q = solve_pose(mech, self.q, self.free, np.asarray(p, dtype=float))
        qd = solve_velocity(mech, self.q, self.free, np.zeros(mech.n), np.asarray(pd, dtype=float))
        qdd = solve_acceleration(mech, self.q, qd, self.free, np.zeros(mech.n), np.asarray(pdd, dtype=float))
        return self.q.copy(), qd, qdd

    def torques(self, p: np.ndarray, pd: np.ndarray, pdd: np.ndarray) -> np.ndarray:
        """Motor torques that make the rigid machine follow p(t) (eq 20), through the motors'
        transmission (B's rows on the rigid joints)."""
        q, qd, qdd = self.joint_motion(p, pd, pdd)
        return self.mech.motor_inputs(tree_inverse_dynamics(self.mech, q, qd, qdd))[0]
