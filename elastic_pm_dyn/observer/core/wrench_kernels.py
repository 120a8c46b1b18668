"""The compiled joint forces of the end-effector wrench states (``process.wrench``).

:func:`wrench_columns` is G = W^T (J_p^T f + J_w^T m) per wrench component at a pose (seed eq 31's
G^{+T}, by another route: the end-effector point's Jacobian and its body's angular Jacobian on
the tree, projected on q_ae), :func:`refresh_wrench` writes it into the disturbance map Lz
(:class:`~elastic_pm_dyn.observer.core.kernels.Process`: its last n_ae rows and n_w columns).
``period.advance`` refreshes it at every linearisation, before the prediction, so the live filter
and ``observe`` take the same numbers.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.observer.core.kernels import (
    PR_LZ,
    PR_WRENCH_AXES,
    PR_WRENCH_POINTS,
    _kinematics,
    _passive_rows_from,
    _work,
)


@njit(cache=True)
def wrench_columns(ma, q, wpoints, waxes, G):
    """G (n_ae x n_w): the generalised forces on q_ae of a unit wrench component at q,
    W^T (J_p^T f + J_w^T m) (f, m: the component's force and couple axes; seed eq 31's G^{+T},
    the same numbers by another route). J_w, the end-effector body's angular Jacobian, from its
    other points b: [r_b]x J_w = J_p - J_b (r_b = p_b - p), in the least-squares sense. Returns
    the pivot ratio of the closure's dh/dq_p."""
    n = q.shape[0]
    nae = ma.ae_index.shape[0]
    nw = waxes.shape[0]
    J, a_pt, p_pt, A, gamma, res = _work(ma, n)
    _kinematics(ma, q, J, a_pt, p_pt, A, gamma, res)
    W = np.empty((n, nae))
    ratio = _passive_rows_from(ma, A, gamma, W)
    e = wpoints[0]
    couples = False
    for c in range(nw):
        for r in range(3, 6):
            couples = couples or waxes[c, r] != 0.0
    Jw = np.zeros((3, n))
    if couples:  # normal equations sum X^T X J_w = sum X^T (J_p - J_b), X = [r_b]x (a 3x3 solve)
        N = np.zeros((3, 3))
        R = np.zeros((3, n))
        X = np.zeros((3, 3))
        for k in range(1, wpoints.shape[0]):
            b = wpoints[k]
            r0, r1, r2 = p_pt[b, 0] - p_pt[e, 0], p_pt[b, 1] - p_pt[e, 1], p_pt[b, 2] - p_pt[e, 2]
            X[0, 0], X[0, 1], X[0, 2] = 0.0, -r2, r1
            X[1, 0], X[1, 1], X[1, 2] = r2, 0.0, -r0
            X[2, 0], X[2, 1], X[2, 2] = -r1, r0, 0.0
            for i in range(3):
                for j in range(3):
                    for m in range(3):
                        N[i, j] += X[m, i] * X[m, j]
                for j in range(n):
                    for m in range(3):
                        R[i, j] += X[m, i] * (J[e, m, j] - J[b, m, j])
        # the inverse of the symmetric 3x3 N by cofactors (no LAPACK in cached kernels)
        c00 = N[1, 1] * N[2, 2] - N[1, 2] * N[2, 1]
        c01 = N[0, 2] * N[2, 1] - N[0, 1] * N[2, 2]
        c02 = N[0, 1] * N[1, 2] - N[0, 2] * N[1, 1]
        c11 = N[0, 0] * N[2, 2] - N[0, 2] * N[2, 0]
        c12 = N[0, 2] * N[1, 0] - N[0, 0] * N[1, 2]
        c22 = N[0, 0] * N[1, 1] - N[0, 1] * N[1, 0]
        det = N[0, 0] * c00 + N[0, 1] * (N[1, 2] * N[2, 0] - N[1, 0] * N[2, 2]) + N[0, 2] * (
            N[1, 0] * N[2, 1] - N[1, 1] * N[2, 0])
        Ni = np.empty((3, 3))
        Ni[0, 0], Ni[0, 1], Ni[0, 2] = c00 / det, c01 / det, c02 / det
        Ni[1, 0], Ni[1, 1], Ni[1, 2] = c01 / det, c11 / det, c12 / det
        Ni[2, 0], Ni[2, 1], Ni[2, 2] = c02 / det, c12 / det, c22 / det
        for i in range(3):
            for j in range(n):
                Jw[i, j] = Ni[i, 0] * R[0, j] + Ni[i, 1] * R[1, j] + Ni[i, 2] * R[2, j]
    tau = np.empty(n)
    for c in range(nw):
        for j in range(n):
            s = 0.0
            for r in range(3):
                s += waxes[c, r] * J[e, r, j] + waxes[c, 3 + r] * Jw[r, j]
            tau[j] = s
        for i in range(nae):
            s = 0.0
            for j in range(n):
                s += W[j, i] * tau[j]
            G[i, c] = s
    return ratio


@njit(cache=True)
def refresh_wrench(ma, proc, q):
    """Lz's wrench block (the last n_ae rows, the last n_w columns) from :func:`wrench_columns`
    at q; nothing without wrench states."""
    waxes = proc[PR_WRENCH_AXES]
    nw = waxes.shape[0]
    if nw == 0:
        return
    Lz = proc[PR_LZ]
    nae = ma.ae_index.shape[0]
    G = np.empty((nae, nw))
    wrench_columns(ma, q, proc[PR_WRENCH_POINTS], waxes, G)
    r0 = Lz.shape[0] - nae
    c0 = Lz.shape[1] - nw
    for i in range(nae):
        for c in range(nw):
            Lz[r0 + i, c0 + c] = G[i, c]
