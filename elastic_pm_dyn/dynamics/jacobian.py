"""The parallel manipulator's Jacobian from the serial chains' Jacobians (section 4)."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.errors import SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism


def branch_directions(mech: Mechanism, q: np.ndarray) -> np.ndarray:
    """Unit branch force directions s_i (eq 28), one column per closure chain.

    A chain end can only pass a force that does no work on the chain's passive joints
    (they carry no actuator): f_i must be orthogonal to the passive columns of J_i. For
    the five-bar this is the forearm direction. Requires that space to be 1-D.
    """
    t = mech.terms(q)
    axes = mech.model.closure.axes  # the closure's directions: x, y[, z] or in a planar machine's plane
    cols = []
    for ci in _branch_chains(mech):
        lo, hi = mech.arrays.chain_start[ci], mech.arrays.chain_start[ci + 1]
        passive = [j for j in mech.passive if lo <= j < hi]
        Jp = (axes @ t.J[ci][:3])[:, passive]
        _, s, vt = np.linalg.svd(Jp.T)
        rank = int(np.sum(s > 1e-12 * max(s.max(initial=0.0), 1e-300)))
        null = vt[rank:]
        if null.shape[0] != 1:
            raise SingularConfigurationError(
                f"chain {mech.model.chains[ci].name}: branch force direction is not unique "
                f"({null.shape[0]}-dimensional)")
        cols.append(null[0])
    return np.array(cols).T


def parallel_jacobian_transpose(mech: Mechanism, q: np.ndarray) -> np.ndarray:
    """G^{+T} = W^T J_t^T U S^{-1} (eq 31): end-effector force/wrench -> forces on q_ae (eq 32).

    S maps the branch forces to the end-effector load (eq 27): its column i is the
    branch direction s_i (eq 28), or for a platform that can turn the wrench of a unit
    force along s_i through the leg's platform point, [s_i; (a_i - c) x s_i]. U stacks
    the s_i block-diagonally (eq 29), so that U S^-1 w distributes the load over the
    chain ends (eq 40); J_t (eq 30) and W (eq 18) carry it to the joints. The load is a
    force (planar/translational machines) or a wrench [force; moment about the end
    effector] (platforms with orientation DOF). Returns n_ae x (size of the load).
    """
    t = mech.terms(q)
    W, _ = mech.passive_map(t)
    closure = mech.model.closure
    axes = closure.axes
    chains = _branch_chains(mech)
    S = branch_directions(mech, q)
    k = len(axes)
    if closure.hub >= 0 and _platform_turns(mech):
        _, _, points = mech.points(q)
        centre = points[mech.model.end_effector_chain]
        arms = [points[b] - centre for _, b in closure.pairs]
        S = np.vstack([S, np.array([np.cross(a, s) for a, s in zip(arms, S.T, strict=True)]).T])
    if S.shape[0] != S.shape[1]:
        raise SingularConfigurationError(f"the static matrix S is {S.shape[0]}x{S.shape[1]}, not square")
    if np.linalg.cond(S) > 1e12:
        raise SingularConfigurationError("the static matrix S is singular (branch forces cannot carry the load)")
    U = np.zeros((k * len(chains), len(chains)))
    Jt = np.zeros((k * len(chains), mech.n))
    for b, ci in enumerate(chains):
        U[b * k:(b + 1) * k, b] = S[:k, b]
        Jt[b * k:(b + 1) * k] = axes @ t.J[ci][:3]
    return W.T @ Jt.T @ U @ np.linalg.inv(S)


def _platform_turns(mech: Mechanism) -> bool:
    """A platform chain with revolute joints has orientation DOF: loads are wrenches."""
    chain = mech.model.chains[mech.model.closure.hub]
    return any(j.type == "revolute" for j in chain.joints)


def _branch_chains(mech: Mechanism) -> tuple[int, ...]:
    """Chains whose ends carry a branch force: all closure chains, or the legs of a platform."""
    closure = mech.model.closure
    return closure.chains[1:] if closure.hub >= 0 else closure.chains
