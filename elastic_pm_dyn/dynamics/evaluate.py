"""One compiled entry point: state -> tree accelerations, for any formulation.

The formulation is an integer so that integrators can be compiled once for all of them.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.kernels import (
    chain_size_max,
    lagrange_dalembert,
    multipliers,
    platform_workspace,
    scdd,
    scdd_into,
    scdd_one_pass,
    scdd_platform,
    scdd_platform_into,
)
from elastic_pm_dyn.kinematics.kernels import all_closure_rows, point_buffers, tree_terms, tree_terms_into
from elastic_pm_dyn.model.arrays import ModelArrays
from elastic_pm_dyn.model.layout import JI_CHAIN
from elastic_pm_dyn.small_linalg import matvec

SCDD = 0
LDA = 1
MULTIPLIERS = 2
SCDD_ONE_PASS = 3
SCDD_STACKED = 4  # SCDD without the platform reduction (all cut forces stacked), for comparison
FORMULATION_CODES = {"scdd": SCDD, "lda": LDA, "multipliers": MULTIPLIERS, "scdd_one_pass": SCDD_ONE_PASS,
                     "scdd_stacked": SCDD_STACKED}


@njit(cache=True)
def workspace(ma):
    """Work arrays of :func:`accelerations_into` for the model ``ma`` (allocate once, reuse)."""
    n = ma.jf.shape[0]
    m = ma.p_index.shape[0]
    nmax = chain_size_max(ma.chain_start)
    J, a_pt, p_pt = point_buffers(ma.points, n)
    return (np.empty((n, n)), np.empty(n), J, a_pt, p_pt,
            np.empty((m, n)), np.empty(m), np.empty(m),
            np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 18)),
            np.empty(n), np.empty((n, m)), np.empty((m, m)), np.empty((nmax, nmax)), np.empty(nmax),
            np.empty((nmax, 1 + m)), np.empty(m, dtype=np.int64), np.empty(m), np.empty(n), np.empty(m),
            _point_chains(ma.ji, ma.point_body),
            platform_workspace(ma.chain_start, ma.closure_pairs, ma.closure_axes.shape[0], ma.hub, n))


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
    # One-off calls allocate only what they use: cheaper than a whole workspace (~0.6 us).
    n = q.shape[0]
    m = ma.p_index.shape[0]
    M, h = np.empty((n, n)), np.empty(n)
    J, a_pt, p_pt = point_buffers(ma.points, n)
    tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    A, gamma, res = np.empty((m, n)), np.empty(m), np.empty(m)
    gap = _closure_terms(ma, q, qd, J, a_pt, p_pt, A, gamma, res, baumgarte_alpha, baumgarte_beta, np.empty(m))
    if form in (SCDD, SCDD_STACKED) and not (form == SCDD and ma.hub >= 0):
        return scdd(M, h, A, gamma, tau, ma.chain_start, qdd, lam), gap
    return _other_formulations(form, ma, M, h, A, gamma, tau, qdd_prev, qdd, lam), gap


@njit(cache=True)
def accelerations_into(form, ma, q, qd, tau, baumgarte_alpha, baumgarte_beta, qdd_prev, qdd, lam, ws):
    """:func:`accelerations` on the work arrays ``ws`` of :func:`workspace`: SCDD on a
    serial-chain closure or on a platform allocates nothing (allocation was a third of an
    evaluation on the five-bar, 17 arrays of the platform SCDD's per call). The tree terms
    (M, h, J, a_pt, p_pt = ws[:5]) and the closure rows (A, gamma, res = ws[5:8]) of (q, qd)
    stay in ``ws`` for the caller."""
    M, h, J, a_pt, p_pt, A, gamma, res, wz, wo, jv, jw, fr, x, Y, S, L, dinv, XY, piv, r, tmh, bm, pc, pw = ws
    tree_terms_into(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt,
                    p_pt, wz, wo, jv, jw, fr)
    gap = _closure_terms(ma, q, qd, J, a_pt, p_pt, A, gamma, res, baumgarte_alpha, baumgarte_beta, bm)
    if form in (SCDD, SCDD_STACKED) and not (form == SCDD and ma.hub >= 0):
        cond = scdd_into(M, h, A, gamma, tau, ma.chain_start, qdd, lam, x, Y, S, L, dinv, XY, piv, r, tmh)
        return cond, gap
    if form == SCDD:  # with a platform hub
        return scdd_platform_into(M, h, A, gamma, tau, ma.chain_start, pc, ma.closure_pairs,
                                  ma.closure_axes.shape[0], ma.hub, qdd, lam, pw), gap
    return _other_formulations(form, ma, M, h, A, gamma, tau, qdd_prev, qdd, lam), gap


@njit(cache=True, inline="always")
def _closure_terms(ma, q, qd, J, a_pt, p_pt, A, gamma, res, baumgarte_alpha, baumgarte_beta, work):
    """Closure rows (A, gamma, residual) with Baumgarte's terms in gamma; returns |h(q)|."""
    if ma.p_index.shape[0] == 0:
        return 0.0
    all_closure_rows(ma.closure_pairs, ma.closure_axes, ma.points, ma.couplings, q, J, a_pt, p_pt, A, gamma, res)
    if baumgarte_alpha > 0.0 or baumgarte_beta > 0.0:
        gamma -= 2.0 * baumgarte_alpha * matvec(A, qd, work) + baumgarte_beta * baumgarte_beta * res
    return np.sqrt(np.sum(res * res))


@njit(cache=True)
def _point_chains(ji, point_body):
    """The chain of each point's body (-1: the base)."""
    out = np.full(point_body.shape[0], -1, dtype=np.int64)
    for i in range(point_body.shape[0]):
        if point_body[i] >= 0:
            out[i] = ji[point_body[i], JI_CHAIN]
    return out


@njit(cache=True)
def _other_formulations(form, ma, M, h, A, gamma, tau, qdd_prev, qdd, lam):
    """Every formulation but the serial-chain SCDD: the platform SCDD, L-D'A, multipliers, one pass."""
    if form == SCDD:  # with a platform hub
        return scdd_platform(M, h, A, gamma, tau, ma.chain_start, _point_chains(ma.ji, ma.point_body), ma.closure_pairs,
                             ma.closure_axes.shape[0], ma.hub, qdd, lam)
    if form == LDA:
        lam[:] = 0.0
        return lagrange_dalembert(M, h, A, gamma, tau, ma.ae_index, ma.p_index, qdd)
    if form == MULTIPLIERS:
        return multipliers(M, h, A, gamma, tau, qdd, lam)
    return scdd_one_pass(M, h, A, gamma, tau, ma.ae_index, ma.p_index, ma.chain_start, qdd_prev, qdd, lam)


@njit(cache=True)
def accelerations_flat(form, jf, ji, chain_start, points, point_body, gravity, closure_pairs,
                       closure_axes, hub, ae_index, p_index, couplings, q, qd, tau, baumgarte_alpha,
                       baumgarte_beta, qdd_prev, qdd, lam):
    """:func:`accelerations` with the model as separate arrays (``*mech.arrays``).

    The entry point for calls from Python: numba types plain arrays on a fast path, a
    namedtuple argument on a slow one (about 1.7 us per call, a third of an evaluation).
    """
    ma = ModelArrays(jf, ji, chain_start, points, point_body, gravity, closure_pairs, closure_axes,
                     hub, ae_index, p_index, couplings)
    return accelerations(form, ma, q, qd, tau, baumgarte_alpha, baumgarte_beta, qdd_prev, qdd, lam)
