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

import numpy as np
from numba import njit

from elastic_pm_dyn.small_linalg import (
    cholesky,
    cholesky_solve,
    cholesky_solve_columns,
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
    S = np.zeros((m, m))
    for c in range(chain_start.shape[0] - 1):
        s = chain_start[c]
        e = chain_start[c + 1]
        L = M[s:e, s:e].copy()
        if not cholesky(L):
            S[:, :] = np.nan
            return S
        XY = np.empty((e - s, 1 + m))  # [tau_i - h_i, A_i^T]: one sweep solves both
        for i in range(e - s):
            XY[i, 0] = tau_minus_h[s + i]
            for j in range(m):
                XY[i, 1 + j] = A[j, s + i]
        cholesky_solve_columns(L, XY)
        for i in range(e - s):
            x[s + i] = XY[i, 0]
            for j in range(m):
                Y[s + i, j] = XY[i, 1 + j]
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for k in range(e - s):
                    acc += A[i, s + k] * XY[k, 1 + j]
                S[i, j] += acc
    return S


@njit(cache=True)
def scdd(M, h, A, gamma, tau, chain_start, qdd, lam):
    """Exact SCDD (eqs 33-41, loop solved via the Schur complement). Returns pivot ratio."""
    n = M.shape[0]
    m = A.shape[0]
    x = np.empty(n)
    Y = np.empty((n, m))
    S = chain_responses(M, A, chain_start, tau - h, x, Y)
    if m == 0:
        qdd[:] = x
        return 1.0
    if np.isnan(S[0, 0]):
        return 0.0
    r = gamma - matvec(A, x, np.empty(m))
    piv = np.empty(m, dtype=np.int64)
    ratio = lu_factor(S, piv)
    if ratio == 0.0:
        return 0.0
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
    (hub) chain H: A_i qdd_i - B_i xdd = gamma_k. Each leg alone (in parallel, eq 34):
    x_i = M_i^-1 (tau_i - h_i), Y_i = M_i^-1 A_i^T and its end-point inertia
    Lambda_i = (A_i Y_i)^-1, so that its cut force is lambda_i = Lambda_i (gamma_k + B_i xdd
    - A_i x_i). The platform then obeys
    (M_H + sum B_i^T Lambda_i B_i) xdd = tau_H - h_H - sum B_i^T Lambda_i (gamma_k - A_i x_i),
    one n_H x n_H solve (6 for a hexapod) instead of the stacked 3 n_legs cut forces.
    Returns a conditioning indicator (0 if a leg or the platform system is singular).
    """
    n = M.shape[0]
    c = n_comp
    n_pairs = closure_pairs.shape[0]
    hs = chain_start[hub]
    he = chain_start[hub + 1]
    nh = he - hs
    N = M[hs:he, hs:he].copy()
    r = tau[hs:he] - h[hs:he]
    Lam = np.empty((n_pairs, c, c))
    B = np.empty((n_pairs, c, nh))
    g = np.empty((n_pairs, c))
    Y = np.zeros((n, c))
    cond = 1.0
    in_pair = np.zeros(chain_start.shape[0] - 1, dtype=np.bool_)
    in_pair[hub] = True
    for k in range(n_pairs):
        leg = point_chain[closure_pairs[k, 0]]
        in_pair[leg] = True
        s = chain_start[leg]
        e = chain_start[leg + 1]
        L = M[s:e, s:e].copy()
        if not cholesky(L):
            return 0.0
        Ai = A[k * c:(k + 1) * c, s:e]
        XY = np.empty((e - s, 1 + c))  # [tau_i - h_i, A_i^T]: one sweep solves both
        for i in range(e - s):
            XY[i, 0] = tau[s + i] - h[s + i]
            for j in range(c):
                XY[i, 1 + j] = Ai[j, i]
        cholesky_solve_columns(L, XY)
        xs = XY[:, 0].copy()
        Ys = XY[:, 1:]
        qdd[s:e] = xs
        Y[s:e, :] = Ys
        Li = matmul(Ai, Ys, np.empty((c, c)))  # Lambda_i^-1, symmetric positive definite
        if not cholesky(Li):
            return 0.0
        cond = min(cond, _chol_conditioning(Li))
        eye = np.eye(c)
        cholesky_solve_columns(Li, eye)
        Lam[k] = eye
        for i in range(c):
            for j in range(nh):
                B[k, i, j] = -A[k * c + i, hs + j]
            acc = gamma[k * c + i]
            for j in range(e - s):
                acc -= Ai[i, j] * xs[j]
            g[k, i] = acc
        LB = matmul(Lam[k], B[k], np.empty((c, nh)))
        Lg = matvec(Lam[k], g[k], np.empty(c))
        for i in range(nh):
            for j in range(nh):
                acc = 0.0
                for t in range(c):
                    acc += B[k, t, i] * LB[t, j]
                N[i, j] += acc
            acc = 0.0
            for t in range(c):
                acc += B[k, t, i] * Lg[t]
            r[i] -= acc
    if not cholesky(N):
        return 0.0
    cond = min(cond, _chol_conditioning(N))
    cholesky_solve(N, r)
    qdd[hs:he] = r
    for k in range(n_pairs):
        leg = point_chain[closure_pairs[k, 0]]
        s = chain_start[leg]
        e = chain_start[leg + 1]
        rhs = g[k] + matvec(B[k], r, np.empty(c))
        lk = matvec(Lam[k], rhs, np.empty(c))
        lam[k * c:(k + 1) * c] = lk
        for i in range(s, e):
            for j in range(c):
                qdd[i] += Y[i, j] * lk[j]
    for ch in range(chain_start.shape[0] - 1):  # chains outside the closure move freely
        if in_pair[ch]:
            continue
        s = chain_start[ch]
        e = chain_start[ch + 1]
        L = M[s:e, s:e].copy()
        if not cholesky(L):
            return 0.0
        xs = tau[s:e] - h[s:e]
        cholesky_solve(L, xs)
        qdd[s:e] = xs
    return cond
