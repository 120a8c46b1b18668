"""One compiled entry point: state -> tree accelerations, for any formulation.

The formulation is an integer so that integrators can be compiled once for all of them.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.kernels import lagrange_dalembert, multipliers, scdd, scdd_one_pass
from elastic_pm_dyn.kinematics.kernels import closure_rows, tree_terms
from elastic_pm_dyn.small_linalg import matvec

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
    Returns (conditioning, gap): the pivot ratio of the matrix the formulation inverts
    (dh/dq_p for L-D'A and one-pass SCDD, the paper's assumption behind eq 12; the cut-force
    Schur complement for SCDD; the KKT matrix for multipliers; 0 if a mass matrix is not
    positive definite) and the closure residual norm |h(q)|. The elastic machine passes the
    rigid machine's parallel singularities, which only the formulations inverting dh/dq_p
    cannot.
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
    if m > 0:
        closure_rows(ma.closure_chains, ma.closure_components, J, a_tip, p_tip, A, gamma, res)
        gap = np.sqrt(np.sum(res * res))
        if baumgarte_alpha > 0.0 or baumgarte_beta > 0.0:
            gamma -= 2.0 * baumgarte_alpha * matvec(A, qd, np.empty(m)) + baumgarte_beta * baumgarte_beta * res
    if form == SCDD:
        cond = scdd(M, h, A, gamma, tau, ma.chain_start, qdd, lam)
    elif form == LDA:
        cond = lagrange_dalembert(M, h, A, gamma, tau, ma.ae_index, ma.p_index, qdd)
        lam[:] = 0.0
    elif form == MULTIPLIERS:
        cond = multipliers(M, h, A, gamma, tau, qdd, lam)
    else:
        cond = scdd_one_pass(M, h, A, gamma, tau, ma.ae_index, ma.p_index, ma.chain_start,
                          qdd_prev, qdd, lam)
    return cond, gap
