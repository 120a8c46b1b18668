"""One compiled entry point: state -> tree accelerations, for any formulation.

The formulation is an integer so that integrators can be compiled once for all of them.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.dry_friction import coulomb_at_rest, count_at_rest, joints_at_rest
from elastic_pm_dyn.dynamics.kernels import (
    PlatformWork,
    ScddWork,
    chain_size_max,
    lagrange_dalembert,
    multipliers,
    platform_workspace,
    scdd,
    scdd_into,
    scdd_one_pass,
    scdd_platform,
    scdd_platform_into,
    scdd_work,
)
from elastic_pm_dyn.kinematics.kernels import (
    TreeSweep,
    TreeTerms,
    all_closure_rows,
    point_buffers,
    tree_terms,
    tree_terms_into,
)
from elastic_pm_dyn.model.layout import (
    JF_COULOMB,
    JF_FORCE_HI,
    JF_FORCE_LO,
    JF_SERVO_C,
    JF_SERVO_G,
    JF_SERVO_K,
    JF_SERVO_REST,
    JI_CHAIN,
)
from elastic_pm_dyn.small_linalg import matvec

SCDD = 0
LDA = 1
MULTIPLIERS = 2
SCDD_ONE_PASS = 3
SCDD_STACKED = 4  # SCDD without the platform reduction (all cut forces stacked), for comparison
FORMULATION_CODES = {"scdd": SCDD, "lda": LDA, "multipliers": MULTIPLIERS, "scdd_one_pass": SCDD_ONE_PASS,
                     "scdd_stacked": SCDD_STACKED}

# The conditioning (:func:`accelerations`' pivot ratio, smallest over largest pivot, about the
# inverse of the condition number) below which an evaluation counts as singular: for the direct
# dynamics, the simulator and the observer alike. A ratio r costs a solve about eps / r of
# relative accuracy (eps = 2.2e-16): at 1e-8 the accelerations still keep about 8 digits, far
# below it they are round-off, and since the ratio falls about in proportion to the distance to
# a singular configuration, the stop comes close to it, not on the way. L-D'A's Newton on q_p
# stops at its square root (sim/kernels.py rk4_steps).
SINGULAR_TOL = 1e-8


class Workspace(NamedTuple):
    """The work arrays of :func:`accelerations_into` for one model, made once by
    :func:`workspace` and reused by every evaluation (as Pinocchio's ``model.createData()``).

    The order is part of the interface: compiled callers that predate the names read
    ``ws[0]`` (M), ``ws[2]`` (J), ``ws[3]`` (a_pt) and ``ws[5]`` (A).
    """

    M: np.ndarray  # (n, n) tree mass matrix at the last evaluation
    h: np.ndarray  # (n,) tree bias forces (Coriolis, gravity, springs, dampers)
    J: np.ndarray  # (n_points, 3 or 6, n) point Jacobians (6 rows with point frames)
    a_pt: np.ndarray  # (n_points, 3 or 6) point accelerations at qdd = 0
    p_pt: np.ndarray  # (n_points, 3 or 12) point positions (and frame orientations) in the world
    A: np.ndarray  # (m, n) closure Jacobian dh/dq at the last evaluation
    gamma: np.ndarray  # (m,) closure right-hand side A qdd = gamma (with Baumgarte's terms)
    res: np.ndarray  # (m,) closure residual h(q)
    wz: np.ndarray  # (n, 3) the tree sweep's joint axes in the world
    wo: np.ndarray  # (n, 3) the tree sweep's joint origins in the world
    jv: np.ndarray  # (n, 3) the sweep's Jacobian columns of a body's centre: linear velocity
    jw: np.ndarray  # (n, 3) and angular velocity
    fr: np.ndarray  # (n, 18) the sweep's stored frames (subtrees and kept bodies)
    sw: ScddWork  # the serial-chain SCDD's work arrays (dynamics.kernels.ScddWork)
    bm: np.ndarray  # (m,) A qd for Baumgarte's terms
    pc: np.ndarray  # (n_points,) int: each point's chain (-1: the base), for the platform SCDD
    pw: PlatformWork  # the platform SCDD's work arrays (dynamics.kernels.PlatformWork)


@njit(cache=True)
def workspace(ma):
    """The :class:`Workspace` of :func:`accelerations_into` for the model ``ma`` (allocate once, reuse)."""
    n = ma.jf.shape[0]
    m = ma.p_index.shape[0]
    J, a_pt, p_pt = point_buffers(ma.points, n)
    return Workspace(np.empty((n, n)), np.empty(n), J, a_pt, p_pt,
                     np.empty((m, n)), np.empty(m), np.empty(m),
                     np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 18)),
                     scdd_work(n, m, chain_size_max(ma.chain_start)), np.empty(m),
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
    # One-off calls allocate only what they use: cheaper than a whole workspace (~0.6 us,
    # measured 2026-11-22 on the 2-core dev machine).
    n = q.shape[0]
    m = ma.p_index.shape[0]
    M, h = np.empty((n, n)), np.empty(n)
    J, a_pt, p_pt = point_buffers(ma.points, n)
    tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    servo_force_ranges(ma.jf, q, qd, tau, h)
    A, gamma, res = np.empty((m, n)), np.empty(m), np.empty(m)
    gap = _closure_terms(ma, q, qd, J, a_pt, p_pt, A, gamma, res, baumgarte_alpha, baumgarte_beta, np.empty(m))
    cond = _formulate(form, ma, M, h, A, gamma, tau, qdd_prev, qdd, lam)
    at_rest = count_at_rest(ma.jf, qd)
    if at_rest > 0:
        _coulomb_at_rest(form, ma, M, h, A, gamma, tau, qd, at_rest, qdd_prev, qdd, lam)
    return cond, gap


@njit(cache=True)
def _formulate(form, ma, M, h, A, gamma, tau, qdd_prev, qdd, lam):
    """The formulation ``form`` on the tree terms (allocating its work arrays): qdd, lam; its conditioning."""
    if form in (SCDD, SCDD_STACKED) and not (form == SCDD and ma.hub >= 0):
        return scdd(M, h, A, gamma, tau, ma.chain_start, qdd, lam)
    return _other_formulations(form, ma, M, h, A, gamma, tau, qdd_prev, qdd, lam)


@njit(cache=True)
def _coulomb_at_rest(form, ma, M, h, A, gamma, tau, qd, at_rest, qdd_prev, qdd, lam):
    """qdd and lam, the accelerations without friction on the ``at_rest`` joints at rest with
    Coulomb friction, made those with it (dynamics/dry_friction.py): each joint's response to its
    friction F is the formulation's own (qdd at tau + F e_j less qdd), the forces Coulomb's law at
    rest, and a joint that sticks gets an acceleration of exactly 0."""
    idx = joints_at_rest(ma.jf, qd, at_rest)
    c = at_rest
    n = qd.shape[0]
    F, a0, f = np.empty(c), np.empty(c), np.empty(c)
    G = np.empty((c, c))
    stick = np.empty(c, dtype=np.bool_)
    for j in range(c):
        F[j] = ma.jf[idx[j], JF_COULOMB]
        a0[j] = qdd[idx[j]]
    pushed, spare = tau.copy(), np.empty(n)
    for j in range(c):
        pushed[idx[j]] += F[j]
        _formulate(form, ma, M, h, A, gamma, pushed, qdd_prev, spare, lam.copy())
        pushed[idx[j]] = tau[idx[j]]
        for i in range(c):
            G[i, j] = (spare[idx[i]] - a0[i]) / F[j]
    for i in range(c):  # symmetric in exact arithmetic
        for j in range(i):
            G[i, j] = G[j, i] = 0.5 * (G[i, j] + G[j, i])
    coulomb_at_rest(a0, G, F, f, stick)
    for j in range(c):
        pushed[idx[j]] = tau[idx[j]] + f[j]
    _formulate(form, ma, M, h, A, gamma, pushed, qdd_prev, qdd, lam)
    for j in range(c):
        if stick[j]:
            qdd[idx[j]] = 0.0


@njit(cache=True)
def accelerations_into(form, ma, q, qd, tau, baumgarte_alpha, baumgarte_beta, qdd_prev, qdd, lam, ws):
    """:func:`accelerations` on the :class:`Workspace` ``ws``: SCDD on a serial-chain closure
    or on a platform allocates nothing (allocation was a third of an evaluation on the
    five-bar, 17 arrays of the platform SCDD's per call). The tree terms (ws.M, h, J, a_pt,
    p_pt) and the closure rows (ws.A, gamma, res) of (q, qd) stay in ``ws`` for the caller."""
    tree_terms_into(ma, q, qd, TreeTerms(ws.M, ws.h, ws.J, ws.a_pt, ws.p_pt),
                    TreeSweep(ws.wz, ws.wo, ws.jv, ws.jw, ws.fr))
    servo_force_ranges(ma.jf, q, qd, tau, ws.h)
    gap = _closure_terms(ma, q, qd, ws.J, ws.a_pt, ws.p_pt, ws.A, ws.gamma, ws.res, baumgarte_alpha, baumgarte_beta,
                         ws.bm)
    if form in (SCDD, SCDD_STACKED) and not (form == SCDD and ma.hub >= 0):
        cond = scdd_into(ws.M, ws.h, ws.A, ws.gamma, tau, ma.chain_start, qdd, lam, ws.sw)
    elif form == SCDD:  # with a platform hub
        cond = scdd_platform_into(ws.M, ws.h, ws.A, ws.gamma, tau, ma.chain_start, ws.pc, ma.closure_pairs,
                                  ma.closure_axes.shape[0], ma.hub, qdd, lam, ws.pw)
    else:
        cond = _other_formulations(form, ma, ws.M, ws.h, ws.A, ws.gamma, tau, qdd_prev, qdd, lam)
    at_rest = count_at_rest(ma.jf, qd)
    if at_rest > 0:  # (allocates: a machine at rest on its friction)
        _coulomb_at_rest(form, ma, ws.M, ws.h, ws.A, ws.gamma, tau, qd, at_rest, qdd_prev, qdd, lam)
    return cond, gap


@njit(cache=True, inline="always")
def servo_force_ranges(jf, q, qd, tau, h):
    """A servo's force clamped to its range, as MuJoCo clamps it: its force f along its length
    (the input's share tau over G, less its own spring and damper) beyond [low, high] gives back
    the excess through h (tau - h drives the joint)."""
    for k in range(jf.shape[0]):
        g = jf[k, JF_SERVO_G]
        if g != 0.0:
            f = (tau[k] - jf[k, JF_SERVO_K] * (q[k] - jf[k, JF_SERVO_REST]) - jf[k, JF_SERVO_C] * qd[k]) / g
            clamped = min(max(f, jf[k, JF_FORCE_LO]), jf[k, JF_FORCE_HI])
            h[k] -= g * (clamped - f)


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
