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
    comps = mech.model.closure.components
    cols = []
    for ci in _branch_chains(mech):
        lo, hi = mech.arrays.chain_start[ci], mech.arrays.chain_start[ci + 1]
        passive = [j for j in mech.passive if lo <= j < hi]
        Jp = t.J[ci][np.ix_(comps, passive)]
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
    """G^{+T} = W^T J_t^T U S^{-1} (eq 31): end-effector force -> forces on q_ae (eq 32).

    S = [s_1 ... s_na] maps branch forces to the end-effector force (eq 27); U stacks the
    s_i block-diagonally (eq 29) so that U S^-1 f distributes f over the chain ends
    (eq 40); J_t (eq 30) and W (eq 18) carry them to the joints.
    """
    t = mech.terms(q)
    W, _ = mech.passive_map(t)
    comps = list(mech.model.closure.components)
    chains = _branch_chains(mech)
    S = branch_directions(mech, q)
    if S.shape[0] != S.shape[1]:
        raise SingularConfigurationError(f"the static matrix S is {S.shape[0]}x{S.shape[1]}, not square")
    if np.linalg.cond(S) > 1e12:
        raise SingularConfigurationError("the static matrix S is singular (branch forces parallel)")
    k = len(comps)
    U = np.zeros((k * len(chains), len(chains)))
    Jt = np.zeros((k * len(chains), mech.n))
    for b, ci in enumerate(chains):
        U[b * k:(b + 1) * k, b] = S[:, b]
        Jt[b * k:(b + 1) * k] = t.J[ci][comps]
    return W.T @ Jt.T @ U @ np.linalg.inv(S)


def _branch_chains(mech: Mechanism) -> tuple[int, ...]:
    """Chains whose ends carry a branch force: all closure chains, or the legs of a platform."""
    closure = mech.model.closure
    return closure.chains[1:] if closure.hub >= 0 else closure.chains
