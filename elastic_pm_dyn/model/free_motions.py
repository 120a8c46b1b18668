"""Passive motions the closures leave free: a rod between two ball joints spins about its
own axis, whatever the motors do (Gepetto's legged robots close every rod this way, a 6d
weld between two half rods each hung on a ball). The closures then give fewer equations
than there are passive joints, and no choice of dependent joints fixes them all.

Such a motion is a degree of freedom of its own, unactuated and unsprung: it becomes an
independent coordinate, an elastic joint of zero stiffness (its damping the file's joint
damping), as Pinocchio integrates it. Which joints stay dependent is chosen from the
closure Jacobian at the file's zero configuration by QR with column pivoting (the
best-conditioned set); the others of a ball are the free ones.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.linalg

from elastic_pm_dyn.model.description import ELASTIC, PASSIVE, Model

RANK_TOL = 1e-9  # relative to the largest pivot: below it a column adds nothing new


def _zero_pose_frames(model: Model) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """World rotation and origin of each joint's frame at q = 0, tree order."""
    Rs: list[np.ndarray] = []
    ps: list[np.ndarray] = []
    for j, par in zip(model.joints, model.parents(), strict=True):
        R0, p0 = (Rs[par], ps[par]) if par >= 0 else (np.eye(3), np.zeros(3))
        Rs.append(R0 @ j.origin_rotation())
        ps.append(p0 + R0 @ np.asarray(j.origin_xyz, dtype=float))
    return Rs, ps


def closure_jacobian_at_zero(model: Model) -> np.ndarray:
    """d(closure residual)/dq at q = 0, all tree joints: point rows (eq 8's S (p_a - p_b)),
    then each weld's orientation rows, in the order of :attr:`Closure.size`."""
    c = model.closure
    n = len(model.joints)
    if c is None:
        return np.zeros((0, n))
    Rs, ps = _zero_pose_frames(model)
    parents = model.parents()
    joints = model.joints
    axes = [Rs[k] @ np.asarray(j.axis, dtype=float) for k, j in enumerate(joints)]
    points = model.point_list()
    bodies = model.point_bodies()

    def ancestors(b: int) -> list[int]:
        out = []
        while b >= 0:
            out.append(b)
            b = parents[b]
        return out

    def position_rows(i: int) -> np.ndarray:
        _, xyz, _ = points[i]
        b = bodies[i]
        J = np.zeros((3, n))
        if b < 0:
            return J  # a point on the base
        x = ps[b] + Rs[b] @ np.asarray(xyz, dtype=float)
        for k in ancestors(b):
            J[:, k] = np.cross(axes[k], x - ps[k]) if joints[k].type == "revolute" else axes[k]
        return J

    def angular_rows(i: int) -> np.ndarray:
        J = np.zeros((3, n))
        for k in ancestors(bodies[i]):
            if joints[k].type == "revolute":
                J[:, k] = axes[k]
        return J

    rows = [(position_rows(a) - position_rows(b))[list(c.components)] for a, b in c.pairs]
    rows += [(angular_rows(a) - angular_rows(b))[list(c.weld_components)] for a, b in c.welds]
    return np.vstack(rows)


def free_passive_motions(model: Model) -> Model:
    """``model`` with the passive joints the closures cannot fix made independent
    (elastic, zero stiffness); the same model when there are none or the closures are
    redundant (the counts then name the problem)."""
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    J = closure_jacobian_at_zero(model)
    m = J.shape[0]
    if len(passive) <= m or m == 0:
        return model
    Jp = J[:, passive]
    _, r, piv = scipy.linalg.qr(Jp, pivoting=True, mode="economic")
    diag = np.abs(np.diag(r))
    rank = int(np.sum(diag > RANK_TOL * max(diag[0], 1e-300)))
    if rank < m:
        return model  # redundant closures: not a free motion, _check_counts says so
    free = {passive[k] for k in piv[m:]}
    chains = []
    start = 0
    for ch in model.chains:
        joints = tuple(replace(j, role=ELASTIC, stiffness=0.0, damping=j.friction, rest=0.0, friction=0.0)
                       if start + k in free else j for k, j in enumerate(ch.joints))
        chains.append(replace(ch, joints=joints))
        start += len(ch.joints)
    return replace(model, chains=tuple(chains))
