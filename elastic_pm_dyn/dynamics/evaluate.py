"""One compiled entry point: state -> tree accelerations, for any formulation.

The formulation is an integer so that integrators can be compiled once for all of them.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.kernels import lagrange_dalembert, multipliers, scdd, scdd_one_pass
from elastic_pm_dyn.kinematics.kernels import closure_rows, tree_terms
from elastic_pm_dyn.small_linalg import lu_factor, matvec

SCDD = 0
LDA = 1
MULTIPLIERS = 2
SCDD_ONE_PASS = 3
FORMULATION_CODES = {"scdd": SCDD, "lda": LDA, "multipliers": MULTIPLIERS, "scdd_one_pass": SCDD_ONE_PASS}


@njit(cache=True)
def accelerations(form, ma, q, qd, tau, baumgarte_alpha, baumgarte_beta, qdd_prev, qdd, lam):
    """Tree accelerations qdd (n_t) and cut-force multipliers lam (m) at (q, qd, tau).

    tau is the tree generalised force vector (motor torques on active joints, external
    loads elsewhere). Baumgarte stabilisation replaces A qdd = gamma by
    hdd + 2 alpha hd + beta^2 h = 0 when alpha or beta > 0.
    Returns (conditioning, gap): the smaller of the pivot ratios of dh/dq_p (the
    paper's invertibility assumption behind eq 12) and of the formulation's own matrix,
    and the closure residual norm |h(q)|.
    """
    n = q.shape[0]
    nc = ma.chain_start.shape[0] - 1
    m = ma.p_index.shape[0]
    M = np.empty((n, n))
    h = np.empty(n)
    J = np.empty((nc, 3, n))
    a_tip = np.empty((nc, 3))
    p_tip = np.empty((nc, 3))
    tree_terms(ma.jf, ma.ji, ma.chain_start, ma.chain_end, ma.gravity, q, qd, M, h, J, a_tip, p_tip)
    A = np.empty((m, n))
    gamma = np.empty(m)
    res = np.empty(m)
    gap = 0.0
    cond = 1.0
    if m > 0:
        closure_rows(ma.closure_chains, ma.closure_components, J, a_tip, p_tip, A, gamma, res)
        gap = np.sqrt(np.sum(res * res))
        if baumgarte_alpha > 0.0 or baumgarte_beta > 0.0:
            gamma -= 2.0 * baumgarte_alpha * matvec(A, qd, np.empty(m)) + baumgarte_beta * baumgarte_beta * res
        Ap = np.empty((m, m))
        for i in range(m):
            for j in range(m):
                Ap[i, j] = A[i, ma.p_index[j]]
        cond = lu_factor(Ap, np.empty(m, dtype=np.int64))
    if form == SCDD:
        r = scdd(M, h, A, gamma, tau, ma.chain_start, qdd, lam)
    elif form == LDA:
        r = lagrange_dalembert(M, h, A, gamma, tau, ma.ae_index, ma.p_index, qdd)
        lam[:] = 0.0
    elif form == MULTIPLIERS:
        r = multipliers(M, h, A, gamma, tau, qdd, lam)
    else:
        r = scdd_one_pass(M, h, A, gamma, tau, ma.ae_index, ma.p_index, ma.chain_start,
                          qdd_prev, qdd, lam)
    return min(cond, r), gap
