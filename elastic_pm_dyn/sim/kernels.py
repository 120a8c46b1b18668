"""Compiled integration: fixed-step RK4 with constraint stabilisation.

The state is the tree state (q_t, qd_t) for every formulation:
- L-D'A is an ODE in q_ae (eq 26); its passive coordinates are recovered from the
  closure by Newton at every stage (coordinate partitioning, eqs 7-8 and 12), so its
  gap stays at round-off by construction;
- SCDD and the multiplier model integrate the whole tree, where |h| drifts (the paper's
  Fig. 4) unless stabilised: Baumgarte (inside the accelerations) and/or projection of
  q_t and qd_t back onto the constraint manifold after each step, in the mass metric
  (the smallest change of kinetic energy that restores h = 0 and A qd = 0).

Torque over one call is a polynomial tau(s) = c0 + c1 s + c2 s^2 of the time s since
the call's start: constant for a zero-order hold, linear for interpolated tables,
quadratic through the three RK4 stage times for an arbitrary function.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.evaluate import LDA, accelerations_into, workspace
from elastic_pm_dyn.dynamics.kernels import chain_size_max
from elastic_pm_dyn.kinematics.kernels import (
    TreeSweep,
    TreeTerms,
    all_closure_rows,
    point_buffers,
    tree_terms,
    tree_terms_into,
)
from elastic_pm_dyn.model.arrays import ModelArrays
from elastic_pm_dyn.model.layout import JF_COULOMB, JF_SLIP, STICK_SPEED
from elastic_pm_dyn.small_linalg import cholesky_recip, cholesky_solve_rows, lu_factor, lu_solve, matvec

STAB_BAUMGARTE = 1
STAB_PROJECTION = 2

# Newton on q_p left this much closure residual [m]: the passive coordinates are no
# longer determined by q_ae (a parallel singularity of the rigid machine is near).
NEWTON_FAILED = 1e-9

# A step that moves a joint by more than this [rad or m] (or a non-finite state or
# acceleration) has diverged: no configuration of the machine explains it, the step is too
# large for the motion or the torque too high. Told apart from a singular configuration,
# whose conditioning check a blown-up state also fails.
MAX_STEP_MOTION = 1.0
# A blow-up where the matrix the formulation inverts has lost two decades of conditioning
# (pivot ratio below this) comes from the singular configuration it approaches (L-D'A's
# passive rates W qd_ae grow as 1 / ratio there): it is reported as that.
NEAR_SINGULAR = 1e-2

# [m] a closure gap below which project_springs takes one correction without evaluating the
# closure again: with a Jacobian a step's motion away it leaves ~1e-3 of the gap (an ETD2 step
# leaves 1e-12 .. 1e-9), which the next step's projection removes
NEWTON_SURE = 1e-8

OK = 0
SINGULAR = 1
DIVERGED = 2


@njit(cache=True)
def transmit(transmission, u, out):
    """out = B u: the tree forces of motor inputs u (B: ``Mechanism.transmission``, n_t x n_a).
    B's zeros add nothing, so a motor on its own joint gives its input itself, bit for bit (and
    a non-finite input reaches only the joints its motor drives)."""
    for i in range(transmission.shape[0]):
        s = 0.0
        for j in range(transmission.shape[1]):
            if transmission[i, j] != 0.0:
                s += transmission[i, j] * u[j]
        out[i] = s


@njit(cache=True)
def _closure(ma, q, qd, M, h, J, a_pt, p_pt, A, gamma, res):
    tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    all_closure_rows(ma.closure_pairs, ma.closure_axes, ma.points, ma.couplings, q, J, a_pt, p_pt, A, gamma, res)
    return np.sqrt(np.sum(res * res))


@njit(cache=True)
def partition(ma, q, qd, tol, max_iter):
    """Coordinate partitioning: q_p from h(q_ae, q_p) = 0 by Newton, qd_p = W_p qd_ae.

    Returns (gap, pivot ratio of dh/dq_p).
    """
    n = q.shape[0]
    m = ma.p_index.shape[0]
    if m == 0:
        return 0.0, 1.0
    M, h = np.empty((0, 0)), np.empty(0)  # empty: the kinematics alone, no inertia terms
    J, a_pt, p_pt = point_buffers(ma.points, n)
    A, gamma, res = np.empty((m, n)), np.empty(m), np.empty(m)
    Ap = np.empty((m, m))
    piv = np.empty(m, dtype=np.int64)
    gap = 0.0
    ratio = 0.0
    for it in range(max_iter + 1):
        gap = _closure(ma, q, qd, M, h, J, a_pt, p_pt, A, gamma, res)
        for i in range(m):
            for j in range(m):
                Ap[i, j] = A[i, ma.p_index[j]]
        ratio = lu_factor(Ap, piv)
        if ratio == 0.0 or gap <= tol or it == max_iter:
            break
        lu_solve(Ap, piv, res)
        for j in range(m):
            q[ma.p_index[j]] -= res[j]
    if ratio == 0.0:
        return gap, ratio
    r = np.zeros(m)
    for i in range(m):
        for j in range(ma.ae_index.shape[0]):
            r[i] -= A[i, ma.ae_index[j]] * qd[ma.ae_index[j]]
    lu_solve(Ap, piv, r)
    for j in range(m):
        qd[ma.p_index[j]] = r[j]
    return gap, ratio


class ProjectionWorkspace(NamedTuple):
    """The work arrays of :func:`project_into` and :func:`project_springs` for one model, made
    once by :func:`projection_workspace` and reused every step."""

    M: np.ndarray  # (n, n) tree mass matrix at zero velocity
    h: np.ndarray  # (n,) tree bias forces (computed with M, not used)
    J: np.ndarray  # (n_points, 3 or 6, n) point Jacobians
    a_pt: np.ndarray  # (n_points, 3 or 6) point accelerations (not used)
    p_pt: np.ndarray  # (n_points, 3 or 12) point positions (and frames) in the world
    A: np.ndarray  # (m, n) closure Jacobian at the last evaluation
    gamma: np.ndarray  # (m,) closure right-hand side (not used)
    res: np.ndarray  # (m,) closure residual h(q), the Newton step's right-hand side
    wz: np.ndarray  # (n, 3) the tree sweep's joint axes in the world
    wo: np.ndarray  # (n, 3) the tree sweep's joint origins
    jv: np.ndarray  # (n, 3) the sweep's body-centre Jacobian columns: linear
    jw: np.ndarray  # (n, 3) and angular
    fr: np.ndarray  # (n, 18) the sweep's stored frames
    Y: np.ndarray  # (n, m) M^-1 A^T in each chain's closure rows
    zero: np.ndarray  # (n,) zeros: the velocity of the closure evaluations
    S: np.ndarray  # (m, m) A M^-1 A^T, LU-factored in place
    piv: np.ndarray  # (m,) int: S's pivots
    L: np.ndarray  # (nmax, nmax) one chain's mass-matrix Cholesky factor
    dinv: np.ndarray  # (nmax,) its reciprocal diagonal
    XY: np.ndarray  # (nmax, m) one chain's M_c^-1 A_c^T
    rows: np.ndarray  # (n_chains, m) int: the closure rows each chain takes part in
    n_rows: np.ndarray  # (n_chains,) int: how many
    v: np.ndarray  # (m,) A qd, the velocity correction's right-hand side


@njit(cache=True)
def projection_workspace(ma):
    """The :class:`ProjectionWorkspace` of the model ``ma`` (allocate once, reuse every step)."""
    n = ma.jf.shape[0]
    m = ma.p_index.shape[0]
    n_ch = ma.chain_start.shape[0] - 1
    nmax = chain_size_max(ma.chain_start)
    J, a_pt, p_pt = point_buffers(ma.points, n)
    return ProjectionWorkspace(
        np.empty((n, n)), np.empty(n), J, a_pt, p_pt, np.empty((m, n)), np.empty(m), np.empty(m),
        np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 18)),
        np.empty((n, m)), np.zeros(n), np.empty((m, m)), np.empty(m, dtype=np.int64), np.empty((nmax, nmax)),
        np.empty(nmax), np.empty((nmax, m)), np.empty((n_ch, m), dtype=np.int64), np.empty(n_ch, dtype=np.int64),
        np.empty(m))


@njit(cache=True)
def project(ma, q, qd, tol, max_iter):
    """Project (q, qd) onto h = 0, A qd = 0 in the mass metric; returns the gap before.

    dq = M^-1 A^T (A M^-1 A^T)^-1 h, iterated (Gauss-Newton); the velocity step is the
    same operator applied to A qd. M^-1 A^T and its Schur complement are exactly SCDD's
    per-chain responses, so this costs one tree evaluation per iteration.
    """
    return project_into(ma, q, qd, tol, max_iter, projection_workspace(ma))


@njit(cache=True, inline="always")
def chain_block(M, A, s, ne, c, rows, n_rows, L, dinv) -> int:
    """Chain c (tree columns s .. s + ne): the closure rows its columns of A touch (into
    ``rows[c]``, their count into ``n_rows[c]`` and returned) and its mass-matrix block's
    Cholesky factors in L, dinv; -1 if the block is not positive definite."""
    k = 0
    for r in range(A.shape[0]):
        for i in range(ne):
            if A[r, s + i] != 0.0:
                rows[c, k] = r
                k += 1
                break
    n_rows[c] = k
    for i in range(ne):
        for j in range(ne):
            L[i, j] = M[s + i, s + j]
    if not cholesky_recip(L, ne, dinv):
        return -1
    return k


@njit(cache=True, inline="always")
def add_chain_schur(A, XY, s, ne, c, k, rows, S) -> None:
    """S += A_c M_c^-1 A_c^T in chain c's k closure rows, XY's first k columns holding M_c^-1 A_c^T."""
    for a in range(k):
        for b in range(k):
            acc = 0.0
            for t in range(ne):
                acc += A[rows[c, a], s + t] * XY[t, b]
            S[rows[c, a], rows[c, b]] += acc


@njit(cache=True)
def _chain_responses_sparse(M, A, chain_start, Y, S, L, dinv, XY, rows, n_rows):
    """Y = M^-1 A^T and S = A M^-1 A^T chain by chain, each chain solved and summed only in
    the closure rows it takes part in (a hexapod leg in 3 of 18): the terms skipped are exact
    zeros, so Y (in those rows: the others are left as they were) and S equal
    :func:`chain_responses`' bit for bit. False if a chain mass matrix is not positive definite."""
    S[:, :] = 0.0
    for c in range(chain_start.shape[0] - 1):
        s = chain_start[c]
        ne = chain_start[c + 1] - s
        k = chain_block(M, A, s, ne, c, rows, n_rows, L, dinv)
        if k < 0:
            return False
        for i in range(ne):
            for j in range(k):
                XY[i, j] = A[rows[c, j], s + i]
        cholesky_solve_rows(L, dinv, ne, XY, 0, k)
        for i in range(ne):
            for j in range(k):
                Y[s + i, rows[c, j]] = XY[i, j]
        add_chain_schur(A, XY, s, ne, c, k, rows, S)
    return True


@njit(cache=True, inline="always")
def _closure_at(ma, q, pws, inertia=True):
    """Closure residual (pws.res) and Jacobian (pws.A) at q, with the tree terms M, h at
    zero velocity or (inertia False) the kinematics alone; returns |h(q)|."""
    sweep = TreeSweep(pws.wz, pws.wo, pws.jv, pws.jw, pws.fr)
    if inertia:
        tree_terms_into(ma, q, pws.zero, TreeTerms(pws.M, pws.h, pws.J, pws.a_pt, pws.p_pt), sweep)
    else:
        tree_terms_into(ma, q, pws.zero, TreeTerms(pws.M[:0, :0], pws.h[:0], pws.J, pws.a_pt, pws.p_pt), sweep)
    all_closure_rows(ma.closure_pairs, ma.closure_axes, ma.points, ma.couplings, q, pws.J, pws.a_pt, pws.p_pt,
                     pws.A, pws.gamma, pws.res)
    return np.sqrt(np.sum(pws.res * pws.res))


@njit(cache=True, inline="always")
def _correct(chain_start, Y, S, piv, rows, n_rows, r, x):
    """x -= Y S^-1 r (r overwritten): the mass-metric step that removes the closure error r;
    Y's row i is zero outside its chain's closure rows."""
    lu_solve(S, piv, r)
    for c in range(chain_start.shape[0] - 1):
        for i in range(chain_start[c], chain_start[c + 1]):
            for a in range(n_rows[c]):
                x[i] -= Y[i, rows[c, a]] * r[rows[c, a]]


@njit(cache=True)
def project_into(ma, q, qd, tol, max_iter, pws):
    """:func:`project` on the :class:`ProjectionWorkspace` ``pws``: allocates nothing, and
    solves each chain only in its own closure rows (bit-identical)."""
    m = ma.p_index.shape[0]
    if m == 0:
        return 0.0
    gap0 = -1.0
    for it in range(max_iter + 1):
        gap = _closure_at(ma, q, pws)
        if gap0 < 0.0:
            gap0 = gap
        if not _chain_responses_sparse(pws.M, pws.A, ma.chain_start, pws.Y, pws.S, pws.L, pws.dinv, pws.XY,
                                       pws.rows, pws.n_rows):
            pws.S[:, :] = np.nan
        if lu_factor(pws.S, pws.piv) == 0.0:
            return gap0
        if gap <= tol or it == max_iter:
            break
        _correct(ma.chain_start, pws.Y, pws.S, pws.piv, pws.rows, pws.n_rows, pws.res, q)
    matvec(pws.A, qd, pws.v)
    _correct(ma.chain_start, pws.Y, pws.S, pws.piv, pws.rows, pws.n_rows, pws.v, qd)
    return gap0


@njit(cache=True)
def project_springs(ma, q, qd, tol, max_iter, pws, fast, sk, G, Y0, S0, piv0, rows0, n_rows0, sw):
    """Project (q, qd) onto h = 0, A qd = 0 after an exponential step (returns the gap before),
    with the factors of the step's start (the gains' Y0 = M^-1 A^T, LU-factored
    S0 = A M^-1 A^T with their chain rows, and G = P M^-1 E): no factorisation of its own.

    Positions: Gauss-Newton in the metric W = M + H^2 K, K the springs' stiffness on the
    elastic joints ``fast`` (sk = H sqrt(k) per joint, H the step): the least action over a
    step of inertia and springs, so the correction goes into the soft motions. In the mass
    metric alone it moved the stiff elastic joints too, where omega H >> 1 makes a 1e-11 rad
    shift a systematic change of the springs' energy: the Hexa at n_ek = 2, undamped, lost
    8.4 % of its modes' energy over 10 s at 1 ms steps (0.37 % in W), 0.8 % at 0.5 ms (0.46 %).
    The W step is the mass-metric one, dq_M = -Y0 S0^-1 h, plus the constrained response
    G f to the spring forces f = -H^2 K E^T dq it meets: (I + s B s) g = -s E^T dq_M,
    f = s g (s = H K^1/2, B = E^T G, symmetric: an n_f x n_f Cholesky). The Jacobian is a
    step's motion away, so a correction leaves ~1e-3 of the gap (1e-14 after a step's
    1e-11): from below NEWTON_SURE one is taken without evaluating the closure again, and
    what is left goes with the next step's. Velocities: the mass metric (the kinetic energy's
    own) twice, with the closure rows of the last evaluation.
    """
    A, res, v = pws.A, pws.res, pws.v
    Z, zinv, g, dq = sw
    n = q.shape[0]
    nf = fast.shape[0]
    if ma.p_index.shape[0] == 0:
        return 0.0
    gap0 = -1.0
    spd = False
    for it in range(max_iter + 1):
        gap = _closure_at(ma, q, pws, False)  # the factors are the step's: no inertia needed
        if gap0 < 0.0:
            gap0 = gap
        if gap <= tol or it == max_iter:
            break
        if it == 0:  # I + s B s, factored once, when a correction is due
            for i in range(nf):
                for j in range(nf):
                    Z[i, j] = sk[i] * G[fast[i], j] * sk[j] + (1.0 if i == j else 0.0)
            spd = cholesky_recip(Z, nf, zinv)
        dq[:] = 0.0
        _correct(ma.chain_start, Y0, S0, piv0, rows0, n_rows0, res, dq)
        if spd:
            for i in range(nf):
                g[i] = -sk[i] * dq[fast[i]]
            cholesky_solve_rows(Z, zinv, nf, g.reshape((nf, 1)), 0, 1)
            for i in range(nf):
                g[i] *= sk[i]
            for i in range(n):
                acc = 0.0
                for j in range(nf):
                    acc += G[i, j] * g[j]
                dq[i] += acc
        for i in range(n):
            q[i] += dq[i]
        if gap <= NEWTON_SURE:
            break
    for _ in range(2):
        matvec(A, qd, v)
        _correct(ma.chain_start, Y0, S0, piv0, rows0, n_rows0, v, qd)
    return gap0


@njit(cache=True)
def _step_motion(qd, qdd, dt):
    """Largest joint motion dt |qd| + dt^2 |qdd| / 2 of one step (inf or nan if not finite)."""
    vmax = 0.0
    amax = 0.0
    for i in range(qd.shape[0]):
        if not (np.isfinite(qd[i]) and np.isfinite(qdd[i])):
            return np.inf, np.inf
        vmax = max(vmax, abs(qd[i]))
        amax = max(amax, abs(qdd[i]))
    return dt * vmax + 0.5 * dt * dt * amax, amax


@njit(cache=True)
def _sane(q, qd, limit):
    """q finite, qd finite and within +-limit (a sum: one branch, no allocation)."""
    total = 0.0
    vmax = 0.0
    for i in range(q.shape[0]):
        total += q[i] + qd[i]
        vmax = max(vmax, abs(qd[i]))
    return np.isfinite(total) and vmax <= limit


@njit(cache=True)
def rk4_steps(form, ma, q, qd, tau_coef, dt, n_steps, stab, alpha, beta, tol, singular_tol,
              qdd_prev, lam, info):
    """Advance (q, qd) in place by n_steps RK4 steps of dt.

    tau_coef (3, n_t): tree torque polynomial in the time since this call's start.
    info receives [steps done, worst conditioning, last gap]. Returns OK, SINGULAR (the
    conditioning fell below singular_tol; L-D'A: below sqrt(singular_tol), see below) or
    DIVERGED (a step would move a joint by more than MAX_STEP_MOTION, or the state or the
    acceleration is not finite, with a pivot ratio above NEAR_SINGULAR; info[1] is then
    max |qdd|); in both cases (q, qd) is the
    state after the last good step. Divergence is checked before singularity: a blown-up
    state ruins the conditioning too, and must not be reported as a singular configuration.

    L-D'A solves q_p from h(q_ae, q_p) = 0 by Newton: near a fold of the closure (a parallel
    singularity) a residual r leaves q_p uncertain by ~sqrt(r), so its threshold on the
    pivot ratio of dh/dq_p is the square root of the linear solves' singular_tol.
    """
    n = q.shape[0]
    a = alpha if stab & STAB_BAUMGARTE else 0.0
    b = beta if stab & STAB_BAUMGARTE else 0.0
    a1, a2, a3, a4 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    q2, q3, q4 = np.empty(n), np.empty(n), np.empty(n)
    v2, v3, v4 = np.empty(n), np.empty(n), np.empty(n)
    tau = np.empty(n)
    ws = workspace(ma)
    worst = 1.0
    gap = 0.0
    info[0] = 0.0
    lda_tol = np.sqrt(singular_tol)
    limit = MAX_STEP_MOTION / dt  # [rad/s or m/s] a faster joint moves more than that in one step
    for step in range(n_steps):
        s0 = step * dt
        for stage in range(4):
            s = s0 + (0.0 if stage == 0 else (dt if stage == 3 else 0.5 * dt))
            for i in range(n):
                tau[i] = tau_coef[0, i] + s * (tau_coef[1, i] + s * tau_coef[2, i])
            if stage == 0:
                qs, vs, acc = q, qd, a1
            elif stage == 1:
                for i in range(n):
                    q2[i] = q[i] + 0.5 * dt * qd[i]
                    v2[i] = qd[i] + 0.5 * dt * a1[i]
                qs, vs, acc = q2, v2, a2
            elif stage == 2:
                for i in range(n):
                    q3[i] = q[i] + 0.5 * dt * v2[i]
                    v3[i] = qd[i] + 0.5 * dt * a2[i]
                qs, vs, acc = q3, v3, a3
            else:
                for i in range(n):
                    q4[i] = q[i] + dt * v3[i]
                    v4[i] = qd[i] + dt * a3[i]
                qs, vs, acc = q4, v4, a4
            if form == LDA:
                g, cond = partition(ma, qs, vs, tol, np.int64(4))
                if cond < lda_tol or not g <= NEWTON_FAILED:
                    if not _sane(qs, vs, limit):
                        return _diverged(ma, qs, vs, tau, a, b, qdd_prev, acc, lam, ws, form, info)
                    info[1] = cond
                    info[2] = g
                    return SINGULAR
            cond, g = accelerations_into(form, ma, qs, vs, tau, a, b, qdd_prev, acc, lam, ws)
            qdd_prev[:] = acc
            if stage == 0:
                gap = g
                motion, amax = _step_motion(vs, acc, dt)
                if not motion <= MAX_STEP_MOTION:
                    info[1] = cond if cond < NEAR_SINGULAR else amax
                    info[2] = g
                    return SINGULAR if cond < NEAR_SINGULAR else DIVERGED
            worst = min(worst, cond)
            if cond < singular_tol:
                motion, amax = _step_motion(vs, acc, dt)
                if not (_sane(qs, vs, limit) and motion <= MAX_STEP_MOTION):
                    info[1] = amax
                    info[2] = g
                    return DIVERGED
                info[1] = cond
                info[2] = g
                return SINGULAR
        stop = stops_within(ma.jf, qd, v2, v3, v4)  # a sliding joint with Coulomb friction stops at a stage
        # the new state goes to q4, v4 first: a step that diverges leaves (q, qd) as they were
        for i in range(n):
            q4[i] = q[i] + dt / 6.0 * (qd[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i])
            v4[i] = qd[i] + dt / 6.0 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i])
        if stop or stops_within(ma.jf, qd, v4, v4, v4):  # ... or at the step's end
            stop_within_step(form, ma, q, qd, tau_coef, s0, dt, a, b, tol, qdd_prev, lam, ws, q4, v4)
        if not _sane(q4, v4, limit):
            return unsound_step(worst, a1, a4, gap, info)
        q[:] = q4
        qd[:] = v4
        settle_at_rest(ma.jf, qd)
        if form == LDA:
            gap, cond = partition(ma, q, qd, tol, np.int64(4))
            if cond < lda_tol or not gap <= NEWTON_FAILED:
                info[1] = cond
                info[2] = gap
                return SINGULAR
        elif stab & STAB_PROJECTION:
            project(ma, q, qd, tol, np.int64(3))
        info[0] = step + 1
    info[1] = worst
    info[2] = gap
    return OK


@njit(cache=True, inline="always")
def unsound_step(worst, acc_first, acc_last, gap, info):
    """The status of a step whose new state is not sane (:func:`_sane`): SINGULAR if the
    conditioning fell below NEAR_SINGULAR on the way (info[1] = it), else DIVERGED (info[1] =
    the largest |qdd| of the step's first and last stage); info[2] = the gap."""
    info[1] = worst if worst < NEAR_SINGULAR else max(np.max(np.abs(acc_first)), np.max(np.abs(acc_last)))
    info[2] = gap
    return SINGULAR if worst < NEAR_SINGULAR else DIVERGED


@njit(cache=True)
def _diverged(ma, qs, vs, tau, a, b, qdd_prev, acc, lam, ws, form, info):
    """DIVERGED with info[1] = max |qdd| at the stage state (as far as it can be evaluated)."""
    for i in range(qs.shape[0]):
        if not (np.isfinite(qs[i]) and np.isfinite(vs[i])):
            info[1] = np.inf
            info[2] = np.nan
            return DIVERGED
    _, g = accelerations_into(form, ma, qs, vs, tau, a, b, qdd_prev, acc, lam, ws)
    info[1] = np.max(np.abs(acc))
    info[2] = g
    return DIVERGED


# A sliding joint with Coulomb friction that stops within an RK4 step (its velocity at a stage or
# at the step's end reaches STICK_SPEED or beyond): the step is taken again in pieces, each under
# the law of its start frozen, every sliding joint's friction a constant -F sign(qd) (smooth, so
# RK4 keeps its order and the velocity's zero is found by the Illinois method to STICK_SPEED in
# at most STOP_ITERATIONS pieces); the first joint to stop gets a velocity of exactly 0 there, and
# the rest of the step is taken from that state, where Coulomb's law at rest decides whether it
# sticks (at most STOPS_PER_STEP stops a step). Without it the friction's sign would flip within
# the step's stages and the joint chatter about zero speed instead of sticking.
STOP_ITERATIONS = 40
STOPS_PER_STEP = 8


@njit(cache=True)
def _sliding(jf, k, v):
    """Joint k has Coulomb friction (no slip speed) and slides at v (|v| > STICK_SPEED)."""
    return jf[k, JF_COULOMB] > 0.0 and jf[k, JF_SLIP] == 0.0 and abs(v) > STICK_SPEED


@njit(cache=True)
def stops_within(jf, qd0, v2, v3, v4):
    """A joint sliding at qd0 whose velocity at a later stage (v2, v3, v4) or at the step's end
    has reached STICK_SPEED or crossed zero."""
    for k in range(jf.shape[0]):
        if _sliding(jf, k, qd0[k]):
            s = 1.0 if qd0[k] > 0.0 else -1.0
            if s * v2[k] <= STICK_SPEED or s * v3[k] <= STICK_SPEED or s * v4[k] <= STICK_SPEED:
                return True
    return False


@njit(cache=True)
def settle_at_rest(jf, qd):
    """A joint with Coulomb friction whose velocity a step ends within +-STICK_SPEED (its stop
    fell on the step's end) is at rest: its velocity set to exactly 0."""
    for k in range(jf.shape[0]):
        if jf[k, JF_COULOMB] > 0.0 and jf[k, JF_SLIP] == 0.0 and abs(qd[k]) <= STICK_SPEED:
            qd[k] = 0.0


@njit(cache=True)
def _first_zero(jf, qd0, qd1):
    """The joint sliding at qd0 whose velocity qd1 has crossed zero, the first by linear
    interpolation; -1: none."""
    first = -1
    when = 2.0
    for k in range(jf.shape[0]):
        if _sliding(jf, k, qd0[k]) and (qd0[k] > 0.0) != (qd1[k] > 0.0):
            theta = qd0[k] / (qd0[k] - qd1[k])
            if theta < when:
                first, when = k, theta
    return first


@njit(cache=True)
def frozen_slip(ma, qd, tau_coef):
    """The model and torque polynomial with every joint sliding at qd under a constant friction:
    its Coulomb friction moved out of the model into the torque, -F sign(qd)."""
    jf = ma.jf.copy()
    coef = tau_coef.copy()
    for k in range(jf.shape[0]):
        if _sliding(ma.jf, k, qd[k]):
            coef[0, k] -= jf[k, JF_COULOMB] if qd[k] > 0.0 else -jf[k, JF_COULOMB]
            jf[k, JF_COULOMB] = 0.0
    return ModelArrays(jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, ma.closure_pairs,
                       ma.closure_axes, ma.hub, ma.ae_index, ma.p_index, ma.couplings), coef


@njit(cache=True)
def stop_within_step(form, ma, q, qd, tau_coef, s0, dt, a, b, tol, qdd_prev, lam, ws, q_out, qd_out):
    """The RK4 step of dt from (q, qd) at s0 into (q_out, qd_out) through the stops of its
    sliding joints with Coulomb friction (see STOP_ITERATIONS)."""
    qa, va = q.copy(), qd.copy()  # the state after the part of the step done
    done = 0.0
    for _ in range(STOPS_PER_STEP):
        rest = dt - done
        mf, coef = frozen_slip(ma, va, tau_coef)
        rk4_piece(form, mf, qa, va, coef, s0 + done, rest, a, b, tol, qdd_prev, lam, ws, q_out, qd_out)
        j = _first_zero(ma.jf, va, qd_out)
        if j < 0:
            return
        lo, hi, vlo, vhi, side = 0.0, rest, va[j], qd_out[j], 0
        t = rest
        for _ in range(STOP_ITERATIONS):
            t = (lo * vhi - hi * vlo) / (vhi - vlo)
            rk4_piece(form, mf, qa, va, coef, s0 + done, t, a, b, tol, qdd_prev, lam, ws, q_out, qd_out)
            v = qd_out[j]
            if abs(v) <= STICK_SPEED or hi - lo <= 1e-15 * dt:
                break
            if (v > 0.0) == (vlo > 0.0):
                lo, vlo = t, v
                if side < 0:
                    vhi *= 0.5
                side = -1
            else:
                hi, vhi = t, v
                if side > 0:
                    vlo *= 0.5
                side = 1
        qd_out[j] = 0.0
        qa[:] = q_out
        va[:] = qd_out
        done += t
    # more stops than that in one step: the rest of it as the plain step takes it
    rk4_piece(form, ma, qa, va, tau_coef, s0 + done, dt - done, a, b, tol, qdd_prev, lam, ws, q_out, qd_out)
@njit(cache=True)
def rk4_piece(form, ma, q, qd, tau_coef, s, h, a, b, tol, qdd_prev, lam, ws, q_out, qd_out):
    """One classical RK4 step of h from (q, qd) at the time s of the call's torque polynomial
    into (q_out, qd_out), as :func:`rk4_steps` takes them, without its checks."""
    n = q.shape[0]
    k = np.empty((4, n))
    qs, vs, tau = q.copy(), qd.copy(), np.empty(n)
    acc = np.empty(n)
    for stage in range(4):
        c = 0.0 if stage == 0 else (1.0 if stage == 3 else 0.5)
        if stage > 0:
            for i in range(n):
                qs[i] = q[i] + c * h * vs[i]
                vs[i] = qd[i] + c * h * k[stage - 1, i]
        st = s + c * h
        for i in range(n):
            tau[i] = tau_coef[0, i] + st * (tau_coef[1, i] + st * tau_coef[2, i])
        if form == LDA:
            partition(ma, qs, vs, tol, np.int64(4))
        accelerations_into(form, ma, qs, vs, tau, a, b, qdd_prev, acc, lam, ws)
        qdd_prev[:] = acc
        k[stage] = acc
        if stage == 0:
            for i in range(n):
                q_out[i] = qd[i]  # the stage velocities' weighted sum, for q
        else:
            w = 1.0 if stage == 3 else 2.0
            for i in range(n):
                q_out[i] += w * vs[i]
    for i in range(n):
        q_out[i] = q[i] + h / 6.0 * q_out[i]
        qd_out[i] = qd[i] + h / 6.0 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])
