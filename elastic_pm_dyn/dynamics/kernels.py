"""Compiled formulations of the direct dynamics on the tree terms.

All share the tree equations (eq 19, chain by chain eq 33)

    M_t qdd_t + h_t = tau_t + A^T lambda,        A qdd_t = gamma,

with A = dh/dq_t (eq 9) and gamma = -Adot qd_t (the differentiated closure, eq 8), and
differ in how they eliminate the constraint:

- :func:`multipliers`: the (n_t + m) KKT system of the Lagrange equations of the first
  kind (eqs 3-5).
- :func:`lagrange_dalembert`: the compact model on q_ae (eqs 18-26): W = dq_t/dq_ae,
  M_c = W^T M_t W, an n_ae x n_ae solve.
- :func:`scdd`: SCDD (eqs 33-41) with the calculation loop solved exactly: each chain
  solves its own small system (eq 34) for its free accelerations and for the response to
  unit cut forces; the cut forces then follow from the m x m Schur complement
  (sum_i A_i M_i^-1 A_i^T) lambda = gamma - sum_i A_i M_i^-1 (tau_i - h_i).
- :func:`scdd_one_pass`: the paper's loop closed once per evaluation with the previous
  accelerations in eq 35 (virtual passive torques), mapped to cut forces by eq 39.

Each returns a scale-free conditioning indicator (pivot ratio) of the matrix it inverts.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from elastic_pm_dyn.small_linalg import (
    cholesky,
    cholesky_recip,
    cholesky_solve,
    cholesky_solve_rows,
    equilibrated_pivot_ratio,
    lu_factor,
    lu_solve,
    lu_solve_columns,
    lu_solve_transposed,
    matmul,
    matmul_tn,
    matvec,
    matvec_t,
)


@njit(cache=True)
def chain_responses(M, A, chain_start, tau_minus_h, x, Y):
    """Per-chain solves of eq 34: x_i = M_i^-1 (tau_i - h_i), Y_i = M_i^-1 A_i^T.

    Returns the Schur complement S = A M^-1 A^T (m x m), or an empty matrix with
    S[0,0] = nan if a chain mass matrix is not positive definite.
    """
    m = A.shape[0]
    nmax = chain_size_max(chain_start)
    S = np.empty((m, m))
    if not chain_responses_into(M, A, chain_start, tau_minus_h, x, Y, S, np.empty((nmax, nmax)), np.empty(nmax),
                                np.empty((nmax, 1 + m))):
        S[:, :] = np.nan
    return S


@njit(cache=True)
def chain_size_max(chain_start):
    nmax = 1
    for c in range(chain_start.shape[0] - 1):
        nmax = max(nmax, chain_start[c + 1] - chain_start[c])
    return nmax


@njit(cache=True)
def chain_responses_into(M, A, chain_start, tau_minus_h, x, Y, S, L, dinv, XY):
    """:func:`chain_responses` into S with work arrays L (nmax x nmax), dinv (nmax) and
    XY (nmax x (1 + m)), nmax the largest chain. False if a chain mass matrix is not
    positive definite."""
    m = A.shape[0]
    S[:, :] = 0.0
    for c in range(chain_start.shape[0] - 1):
        s = chain_start[c]
        e = chain_start[c + 1]
        ne = e - s
        for i in range(ne):
            for j in range(ne):
                L[i, j] = M[s + i, s + j]
        if not cholesky_recip(L, ne, dinv):
            return False
        for i in range(ne):  # [tau_i - h_i, A_i^T]: one sweep solves both
            XY[i, 0] = tau_minus_h[s + i]
            for j in range(m):
                XY[i, 1 + j] = A[j, s + i]
        cholesky_solve_rows(L, dinv, ne, XY, 0, 1 + m)
        for i in range(ne):
            x[s + i] = XY[i, 0]
            for j in range(m):
                Y[s + i, j] = XY[i, 1 + j]
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for k in range(ne):
                    acc += A[i, s + k] * XY[k, 1 + j]
                S[i, j] += acc
    return True


class ScddWork(NamedTuple):
    """The work arrays of :func:`scdd_into` (n tree coordinates, m closure rows, nmax joints
    in the largest chain), made by :func:`scdd_work`."""

    x: np.ndarray  # (n,) unconstrained tree accelerations M^-1 (tau - h)
    Y: np.ndarray  # (n, m) constraint responses M^-1 A^T
    S: np.ndarray  # (m, m) cut-force Schur complement A M^-1 A^T, LU-factored in place
    L: np.ndarray  # (nmax, nmax) one chain's mass-matrix Cholesky factor
    dinv: np.ndarray  # (nmax,) its reciprocal diagonal
    XY: np.ndarray  # (nmax, 1 + m) one chain's right-hand sides [tau - h, A^T], then solutions
    piv: np.ndarray  # (m,) int: S's pivots
    r: np.ndarray  # (m,) the closure's right-hand side gamma - A x, then the cut forces
    tmh: np.ndarray  # (n,) tau - h


@njit(cache=True)
def scdd_work(n, m, nmax):
    """The :class:`ScddWork` of a tree of n coordinates, m closure rows and chains of at most nmax joints."""
    return ScddWork(np.empty(n), np.empty((n, m)), np.empty((m, m)), np.empty((nmax, nmax)), np.empty(nmax),
                    np.empty((nmax, 1 + m)), np.empty(m, dtype=np.int64), np.empty(m), np.empty(n))


@njit(cache=True, inline="always")
def scdd(M, h, A, gamma, tau, chain_start, qdd, lam):
    """Exact SCDD (eqs 33-41, loop solved via the Schur complement). Returns pivot ratio."""
    return scdd_into(M, h, A, gamma, tau, chain_start, qdd, lam,
                     scdd_work(M.shape[0], A.shape[0], chain_size_max(chain_start)))


@njit(cache=True)
def scdd_into(M, h, A, gamma, tau, chain_start, qdd, lam, sw):
    """:func:`scdd` on the :class:`ScddWork` ``sw`` (no allocation)."""
    x, Y, S, L, dinv, XY, piv, r, tmh = sw
    n = M.shape[0]
    m = A.shape[0]
    for i in range(n):
        tmh[i] = tau[i] - h[i]
    ok = chain_responses_into(M, A, chain_start, tmh, x, Y, S, L, dinv, XY)
    if m == 0:
        qdd[:] = x
        return 1.0
    if not ok:
        return 0.0
    matvec(A, x, r)
    for i in range(m):
        r[i] = gamma[i] - r[i]
        lam[i] = S[i, i]  # lam and tmh (n >= m) are free until the solve: the ratio's scratch
    if lu_factor(S, piv) == 0.0:
        return 0.0
    # S's rows mix metres and radians and weigh bodies of any size: its own pivot ratio
    # would call a light part (a 6 mg ball spinning in a weld) a singularity
    ratio = equilibrated_pivot_ratio(S, piv, lam, tmh)
    lu_solve(S, piv, r)
    lam[:] = r
    for i in range(n):
        acc = x[i]
        for j in range(m):
            acc += Y[i, j] * r[j]
        qdd[i] = acc
    return ratio


@njit(cache=True)
def multipliers(M, h, A, gamma, tau, qdd, lam):
    """Lagrange equations of the first kind (eqs 3-5): one KKT solve on the tree."""
    n = M.shape[0]
    m = A.shape[0]
    K = np.zeros((n + m, n + m))
    K[:n, :n] = M
    K[:n, n:] = A.T
    K[n:, :n] = A
    rhs = np.empty(n + m)
    rhs[:n] = tau - h
    rhs[n:] = gamma
    piv = np.empty(n + m, dtype=np.int64)
    ratio = lu_factor(K, piv)
    if ratio == 0.0:
        return 0.0
    lu_solve(K, piv, rhs)
    qdd[:] = rhs[:n]
    lam[:] = -rhs[n:]
    return ratio


@njit(cache=True)
def passive_map(A, gamma, ae_index, p_index, Wp, cp):
    """W's passive rows and the Wdot qd term from the closure (eqs 9, 12, 18).

    qd_p = Wp qd_ae with Wp = -(dh/dq_p)^-1 dh/dq_ae, and qdd_p = Wp qdd_ae + cp with
    cp = (dh/dq_p)^-1 gamma. Returns the pivot ratio of dh/dq_p.
    """
    m = A.shape[0]
    nae = ae_index.shape[0]
    Ap = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            Ap[i, j] = A[i, p_index[j]]
        for j in range(nae):
            Wp[i, j] = -A[i, ae_index[j]]
        cp[i] = gamma[i]
    piv = np.empty(m, dtype=np.int64)
    ratio = lu_factor(Ap, piv)
    if ratio == 0.0:
        return 0.0
    lu_solve_columns(Ap, piv, Wp)
    lu_solve(Ap, piv, cp)
    return ratio


@njit(cache=True)
def lagrange_dalembert(M, h, A, gamma, tau, ae_index, p_index, qdd):
    """Compact Lagrange-D'Alembert direct dynamics (eq 26) with M_c = W^T M_t W (eq 21)."""
    n = M.shape[0]
    m = A.shape[0]
    nae = ae_index.shape[0]
    Wp = np.empty((m, nae))
    cp = np.empty(m)
    ratio = passive_map(A, gamma, ae_index, p_index, Wp, cp)
    if ratio == 0.0:
        return 0.0
    W = np.zeros((n, nae))
    c = np.zeros(n)
    for j in range(nae):
        W[ae_index[j], j] = 1.0
    for i in range(m):
        W[p_index[i], :] = Wp[i, :]
        c[p_index[i]] = cp[i]
    MW = matmul(M, W, np.empty((n, nae)))
    Mc = matmul_tn(W, MW, np.empty((nae, nae)))  # eq 21
    f = tau - h - matvec(M, c, np.empty(n))
    rhs = matvec_t(W, f, np.empty(nae))
    if not cholesky(Mc):
        return 0.0
    cholesky_solve(Mc, rhs)  # eq 26
    matvec(W, rhs, qdd)
    qdd += c
    return ratio


@njit(cache=True)
def scdd_one_pass(M, h, A, gamma, tau, ae_index, p_index, chain_start, qdd_prev, qdd, lam):
    """The paper's SCDD with the calculation loop closed once, by the previous accelerations.

    1. Passive accelerations consistent with the closure from the previous q_ae
       accelerations (eq 12 differentiated).
    2. Virtual passive torques (eq 35) of those accelerations; the condition tau_p = 0
       (eq 37) gives the cut forces through (dh/dq_p)^-T (eqs 38-39, 41).
    3. Each chain's direct dynamics with those cut forces (eq 34).
    Exact only when the previous accelerations are the current ones: the lag is what lets
    the closure gap drift (the paper's Fig. 4).
    """
    n = M.shape[0]
    m = A.shape[0]
    Ap = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            Ap[i, j] = A[i, p_index[j]]
    piv = np.empty(m, dtype=np.int64)
    ratio = lu_factor(Ap, piv)
    if ratio == 0.0:
        return 0.0
    qk = qdd_prev.copy()
    rp = gamma.copy()
    for i in range(m):
        for j in range(ae_index.shape[0]):
            rp[i] -= A[i, ae_index[j]] * qdd_prev[ae_index[j]]
    lu_solve(Ap, piv, rp)
    for j in range(m):
        qk[p_index[j]] = rp[j]
    tp = np.empty(m)
    for j in range(m):
        pj = p_index[j]
        acc = h[pj] - tau[pj]
        for k in range(n):
            acc += M[pj, k] * qk[k]
        tp[j] = acc
    lu_solve_transposed(Ap, piv, tp)
    lam[:] = tp
    rhs = tau - h + matvec_t(A, tp, np.empty(n))
    for c in range(chain_start.shape[0] - 1):
        s = chain_start[c]
        e = chain_start[c + 1]
        L = M[s:e, s:e].copy()
        if not cholesky(L):
            return 0.0
        xs = rhs[s:e].copy()
        cholesky_solve(L, xs)
        qdd[s:e] = xs
    return ratio


@njit(cache=True)
def _chol_conditioning(L):
    """(min L_ii / max L_ii)^2 of a Cholesky factor: a cheap conditioning indicator."""
    lo = np.inf
    hi = 0.0
    for i in range(L.shape[0]):
        lo = min(lo, L[i, i])
        hi = max(hi, L[i, i])
    return (lo / hi) ** 2 if hi > 0.0 else 0.0


@njit(cache=True)
def scdd_platform(M, h, A, gamma, tau, chain_start, point_chain, closure_pairs, n_comp, hub, qdd, lam):
    """SCDD reduced onto a moving platform's coordinates (DESIGN.md §3).

    Every closure pair k joins the end of one leg chain i to a point of the platform
    (hub) chain H: A_i qdd_i - B_i xdd = gamma_k with B_i = -A[rows k, H]. Each leg alone
    (in parallel, eq 34): [x_i, Y_i] = M_i^-1 [tau_i - h_i, A_i^T] in one sweep, its
    end-point inertia Lambda_i = (A_i Y_i)^-1, so that its cut force is
    lambda_i = Lambda_i (gamma_k + B_i xdd - A_i x_i). The platform then obeys
    (M_H + sum B_i^T Lambda_i B_i) xdd = tau_H - h_H - sum B_i^T Lambda_i (gamma_k - A_i x_i),
    one n_H x n_H solve (6 for a hexapod) instead of the stacked 3 n_legs cut forces.
    Scratch is allocated once and factors keep 1 / diag(L), so the solves multiply.
    Returns a conditioning indicator (0 if a leg or the platform system is singular).
    """
    return scdd_platform_into(M, h, A, gamma, tau, chain_start, point_chain, closure_pairs, n_comp, hub, qdd, lam,
                              platform_workspace(chain_start, closure_pairs, n_comp, hub, M.shape[0]))


class PlatformWork(NamedTuple):
    """The work arrays of :func:`scdd_platform_into` (c rows per closure pair, n_H platform
    coordinates, nmax joints in the largest chain), made by :func:`platform_workspace`."""

    L: np.ndarray  # (nmax, nmax) one leg's mass-matrix Cholesky factor
    N: np.ndarray  # (n_H, n_H) the platform's reduced mass matrix M_H + sum B_i^T Lambda_i B_i, factored
    R: np.ndarray  # (n_H, 1) its right-hand side, then the platform accelerations xdd
    XY: np.ndarray  # (n, 1 + c) each leg's [x_i, Y_i] = M_i^-1 [tau_i - h_i, A_i^T] in its rows
    Lam: np.ndarray  # (n_pairs, c, c) each pair's end-point inertia Lambda_i = (A_i Y_i)^-1
    g: np.ndarray  # (n_pairs, c) gamma_k - A_i x_i
    Li: np.ndarray  # (c, c) A_i Y_i, Cholesky-factored
    LB: np.ndarray  # (c, n_H) Lambda_i B_i
    Lg: np.ndarray  # (c,) Lambda_i g_i, then g_i + B_i xdd
    lk: np.ndarray  # (c,) the pair's cut force lambda_i
    dinv: np.ndarray  # (max(nmax, n_H),) reciprocal diagonal of L or N
    dinv_c: np.ndarray  # (c,) reciprocal diagonal of Li
    in_pair: np.ndarray  # (n_chains,) bool: the chain is the hub or a leg of a closure pair


@njit(cache=True)
def platform_workspace(chain_start, closure_pairs, n_comp, hub, n):
    """The :class:`PlatformWork` of :func:`scdd_platform_into` (allocate once, reuse every evaluation)."""
    c = n_comp
    n_ch = chain_start.shape[0] - 1
    n_pairs = closure_pairs.shape[0]
    nh = chain_start[hub + 1] - chain_start[hub] if hub >= 0 else 0
    nmax = 0
    for ch in range(n_ch):
        nmax = max(nmax, chain_start[ch + 1] - chain_start[ch])
    return PlatformWork(np.empty((nmax, nmax)), np.empty((nh, nh)), np.empty((nh, 1)), np.empty((n, 1 + c)),
                        np.empty((n_pairs, c, c)), np.empty((n_pairs, c)), np.empty((c, c)), np.empty((c, nh)),
                        np.empty(c), np.empty(c), np.empty(max(nmax, nh)), np.empty(c), np.empty(n_ch, dtype=np.bool_))


@njit(cache=True)
def scdd_platform_into(M, h, A, gamma, tau, chain_start, point_chain, closure_pairs, n_comp, hub, qdd, lam, pw):
    """:func:`scdd_platform` on the :class:`PlatformWork` ``pw``."""
    L, N, R, XY, Lam, g, Li, LB, Lg, lk, dinv, dinv_c, in_pair = pw
    c = n_comp
    n_ch = chain_start.shape[0] - 1
    n_pairs = closure_pairs.shape[0]
    hs = chain_start[hub]
    he = chain_start[hub + 1]
    nh = he - hs
    in_pair[:] = False
    in_pair[hub] = True
    for i in range(nh):
        R[i, 0] = tau[hs + i] - h[hs + i]
        for j in range(nh):
            N[i, j] = M[hs + i, hs + j]
    cond = 1.0
    for k in range(n_pairs):
        leg = point_chain[closure_pairs[k, 0]]
        in_pair[leg] = True
        s = chain_start[leg]
        ne = chain_start[leg + 1] - s
        r0 = k * c
        for i in range(ne):
            for j in range(ne):
                L[i, j] = M[s + i, s + j]
            XY[s + i, 0] = tau[s + i] - h[s + i]
            for t in range(c):
                XY[s + i, 1 + t] = A[r0 + t, s + i]
        if not cholesky_recip(L, ne, dinv):
            return 0.0
        cholesky_solve_rows(L, dinv, ne, XY, s, 1 + c)
        for i in range(c):  # Lambda_i^-1 = A_i Y_i, g_i = gamma_i - A_i x_i
            acc = gamma[r0 + i]
            for t in range(ne):
                acc -= A[r0 + i, s + t] * XY[s + t, 0]
            g[k, i] = acc
            for j in range(c):
                acc = 0.0
                for t in range(ne):
                    acc += A[r0 + i, s + t] * XY[s + t, 1 + j]
                Li[i, j] = acc
        if not cholesky_recip(Li, c, dinv_c):
            return 0.0
        cond = min(cond, _chol_conditioning(Li))
        Lk = Lam[k]
        for i in range(c):
            for j in range(c):
                Lk[i, j] = 1.0 if i == j else 0.0
        cholesky_solve_rows(Li, dinv_c, c, Lk, 0, c)
        for i in range(c):  # LB = Lambda B with B = -A[rows, platform], Lg = Lambda g
            for j in range(nh):
                LB[i, j] = 0.0
            acc = 0.0
            for t in range(c):
                lit = Lk[i, t]
                for j in range(nh):
                    LB[i, j] -= lit * A[r0 + t, hs + j]
                acc += lit * g[k, t]
            Lg[i] = acc
        for t in range(c):  # N += B^T LB, r -= B^T Lg
            for i in range(nh):
                ati = A[r0 + t, hs + i]
                for j in range(nh):
                    N[i, j] -= ati * LB[t, j]
                R[i, 0] += ati * Lg[t]
    if not cholesky_recip(N, nh, dinv):
        return 0.0
    cond = min(cond, _chol_conditioning(N))
    cholesky_solve_rows(N, dinv, nh, R, 0, 1)
    for i in range(nh):
        qdd[hs + i] = R[i, 0]
    for k in range(n_pairs):
        leg = point_chain[closure_pairs[k, 0]]
        s = chain_start[leg]
        e = chain_start[leg + 1]
        r0 = k * c
        for t in range(c):  # lambda_i = Lambda_i (g_i + B_i xdd)
            acc = g[k, t]
            for j in range(nh):
                acc -= A[r0 + t, hs + j] * R[j, 0]
            Lg[t] = acc
        for i in range(c):
            acc = 0.0
            for t in range(c):
                acc += Lam[k, i, t] * Lg[t]
            lk[i] = acc
            lam[r0 + i] = acc
        for i in range(s, e):
            acc = XY[i, 0]
            for j in range(c):
                acc += XY[i, 1 + j] * lk[j]
            qdd[i] = acc
    for ch in range(n_ch):  # chains outside the closure move freely
        if in_pair[ch]:
            continue
        s = chain_start[ch]
        ne = chain_start[ch + 1] - s
        for i in range(ne):
            for j in range(ne):
                L[i, j] = M[s + i, s + j]
            XY[s + i, 0] = tau[s + i] - h[s + i]
        if not cholesky_recip(L, ne, dinv):
            return 0.0
        cholesky_solve_rows(L, dinv, ne, XY, s, 1)
        for i in range(s, chain_start[ch + 1]):
            qdd[i] = XY[i, 0]
    return cond
