"""Prototypes of kernel changes, to measure what they would gain (bench/benchmarks/bench_cost.py).

Not part of the package: the same mathematics as the core kernels, written to avoid
what the cost analysis (bench/benchmarks/README_cost.md) found to dominate. Each must reproduce the
core's accelerations to round-off (checked by the bench before timing).

Two of them proved out and are now the core's own (imported here under their prototype
names so the bench's columns stay comparable): ``closure_rows_noalloc`` is
``kinematics.kernels.closure_rows`` and ``scdd_platform_fast`` is
``dynamics.kernels.scdd_platform``.

- :func:`closure_rows_noalloc`: the closure rows without a temporary array per row
  (``A[r, :] = J[a] - J[b]`` allocates in numba).
- :func:`scdd_platform_ws`: platform-reduced SCDD with one workspace per call instead of
  about 12 small allocations per leg (copies, ``np.eye``, temporaries of matmul/matvec).
- :func:`lda_blocks`: compact L-D'A that respects the structure the dense version
  ignores: M_t is block diagonal (products per chain block), and W's q_ae rows are unit
  rows (only the passive rows are dense). The same passive map (LU of dh/dq_p) and the
  same n_ae x n_ae Cholesky as the core: only the products change.
  With ``recip=True`` the Cholesky factors also keep 1 / L_ii, so that the many short
  triangular solves multiply instead of divide (divisions are latency-bound).
- :func:`scdd_platform_fast`: the same with multi-column triangular solves in axpy form
  (x_i and the c columns of Y_i in one sweep; Lambda_i's c columns likewise), so that
  independent columns overlap instead of each solve waiting on its own chain.
- :func:`accelerations_proto`: ``evaluate.accelerations`` with the above.

What each found: bench/prototypes/README.md.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.kernels import _chol_conditioning, passive_map
from elastic_pm_dyn.dynamics.kernels import scdd_platform as scdd_platform_fast
from elastic_pm_dyn.kinematics.kernels import closure_rows as closure_rows_noalloc
from elastic_pm_dyn.kinematics.kernels import tree_terms
from elastic_pm_dyn.small_linalg import cholesky, cholesky_solve
from elastic_pm_dyn.small_linalg import cholesky_recip as _chol_recip

SCDD, LDA, SCDD_RECIP, SCDD_FAST = 0, 1, 2, 3


@njit(cache=True)
def _chol_solve_block(L, ne, B2, off, col):
    """Solve (L L^T) x = b in place, b = B2[off:off+ne, col] (L: the leading ne x ne of a workspace)."""
    for i in range(ne):
        s = B2[off + i, col]
        for k in range(i):
            s -= L[i, k] * B2[off + k, col]
        B2[off + i, col] = s / L[i, i]
    for i in range(ne - 1, -1, -1):
        s = B2[off + i, col]
        for k in range(i + 1, ne):
            s -= L[k, i] * B2[off + k, col]
        B2[off + i, col] = s / L[i, i]


@njit(cache=True)
def _chol_inplace(L, ne):
    """Cholesky of the leading ne x ne block of the workspace L; False if not PD."""
    for j in range(ne):
        d = L[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, ne):
            s = L[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    return True


@njit(cache=True)
def _chol_solve_recip(L, dinv, ne, B2, off, col):
    """_chol_solve_block with multiplications by the stored reciprocals (no division)."""
    for i in range(ne):
        s = B2[off + i, col]
        for k in range(i):
            s -= L[i, k] * B2[off + k, col]
        B2[off + i, col] = s * dinv[i]
    for i in range(ne - 1, -1, -1):
        s = B2[off + i, col]
        for k in range(i + 1, ne):
            s -= L[k, i] * B2[off + k, col]
        B2[off + i, col] = s * dinv[i]


@njit(cache=True)
def _factor(L, ne, dinv, recip):
    return _chol_recip(L, ne, dinv) if recip else _chol_inplace(L, ne)


@njit(cache=True)
def _solve(L, dinv, ne, B2, off, col, recip):
    if recip:
        _chol_solve_recip(L, dinv, ne, B2, off, col)
    else:
        _chol_solve_block(L, ne, B2, off, col)


@njit(cache=True)
def scdd_platform_ws(M, h, A, gamma, tau, chain_start, point_chain, closure_pairs, c, hub, qdd, lam, recip=False):
    """dynamics.kernels.scdd_platform with one workspace per call (same operations).

    recip: Cholesky factors keep 1 / L_ii, so that the triangular solves multiply instead
    of divide (about 460 -> 54 divisions on Hexa, n_ek = 2; round-off changes slightly).
    """
    n = M.shape[0]
    n_ch = chain_start.shape[0] - 1
    n_pairs = closure_pairs.shape[0]
    hs = chain_start[hub]
    he = chain_start[hub + 1]
    nh = he - hs
    nmax = 0
    for ch in range(n_ch):
        nmax = max(nmax, chain_start[ch + 1] - chain_start[ch])
    L = np.empty((nmax, nmax))
    N = np.empty((nh, nh))
    r = np.empty(nh)
    Y = np.empty((n, c))
    X = np.empty((n, 1))  # free accelerations, a column for the shared solver
    Lam = np.empty((n_pairs, c, c))
    g = np.empty((n_pairs, c))
    Li = np.empty((c, c))
    LB = np.empty((c, nh))
    Lg = np.empty(c)
    lk = np.empty(c)
    dinv = np.empty(max(nmax, nh))
    dinv_c = np.empty(c)
    R = np.empty((nh, 1))
    in_pair = np.zeros(n_ch, dtype=np.bool_)
    in_pair[hub] = True
    for i in range(nh):
        r[i] = tau[hs + i] - h[hs + i]
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
            X[s + i, 0] = tau[s + i] - h[s + i]
            for t in range(c):
                Y[s + i, t] = A[r0 + t, s + i]
        if not _factor(L, ne, dinv, recip):
            return 0.0
        _solve(L, dinv, ne, X, s, 0, recip)
        for t in range(c):
            _solve(L, dinv, ne, Y, s, t, recip)
        for i in range(c):  # Lambda_i^-1 = A_i Y_i
            for j in range(c):
                acc = 0.0
                for t in range(ne):
                    acc += A[r0 + i, s + t] * Y[s + t, j]
                Li[i, j] = acc
            acc = gamma[r0 + i]
            for t in range(ne):
                acc -= A[r0 + i, s + t] * X[s + t, 0]
            g[k, i] = acc
        if not _factor(Li, c, dinv_c, recip):
            return 0.0
        cond = min(cond, _chol_conditioning(Li))
        for i in range(c):
            for j in range(c):
                Lam[k, i, j] = 1.0 if i == j else 0.0
        for t in range(c):
            _solve(Li, dinv_c, c, Lam[k], 0, t, recip)
        for i in range(c):  # LB = Lambda B with B = -A[rows, platform], Lg = Lambda g
            for j in range(nh):
                acc = 0.0
                for t in range(c):
                    acc -= Lam[k, i, t] * A[r0 + t, hs + j]
                LB[i, j] = acc
            acc = 0.0
            for t in range(c):
                acc += Lam[k, i, t] * g[k, t]
            Lg[i] = acc
        for i in range(nh):
            for j in range(nh):
                acc = 0.0
                for t in range(c):
                    acc -= A[r0 + t, hs + i] * LB[t, j]
                N[i, j] += acc
            acc = 0.0
            for t in range(c):
                acc -= A[r0 + t, hs + i] * Lg[t]
            r[i] -= acc
    if not _factor(N, nh, dinv, recip):
        return 0.0
    cond = min(cond, _chol_conditioning(N))
    for i in range(nh):
        R[i, 0] = r[i]
    _solve(N, dinv, nh, R, 0, 0, recip)
    for i in range(nh):
        r[i] = R[i, 0]
        qdd[hs + i] = r[i]
    for k in range(n_pairs):
        leg = point_chain[closure_pairs[k, 0]]
        s = chain_start[leg]
        e = chain_start[leg + 1]
        r0 = k * c
        for t in range(c):  # lambda_i = Lambda_i (g_i + B_i xdd)
            acc = g[k, t]
            for j in range(nh):
                acc -= A[r0 + t, hs + j] * r[j]
            Lg[t] = acc
        for i in range(c):
            acc = 0.0
            for t in range(c):
                acc += Lam[k, i, t] * Lg[t]
            lk[i] = acc
            lam[r0 + i] = acc
        for i in range(s, e):
            acc = X[i, 0]
            for j in range(c):
                acc += Y[i, j] * lk[j]
            qdd[i] = acc
    for ch in range(n_ch):  # chains outside the closure move freely
        if in_pair[ch]:
            continue
        s = chain_start[ch]
        ne = chain_start[ch + 1] - s
        for i in range(ne):
            for j in range(ne):
                L[i, j] = M[s + i, s + j]
            X[s + i, 0] = tau[s + i] - h[s + i]
        if not _factor(L, ne, dinv, recip):
            return 0.0
        _solve(L, dinv, ne, X, s, 0, recip)
        for i in range(s, chain_start[ch + 1]):
            qdd[i] = X[i, 0]
    return cond


@njit(cache=True)
def lda_blocks(M, h, A, gamma, tau, ae_index, p_index, chain_start, qdd):
    """dynamics.kernels.lagrange_dalembert with block-diagonal M_t and unit q_ae rows of W exploited."""
    n = M.shape[0]
    m = A.shape[0]
    nae = ae_index.shape[0]
    Wp = np.empty((m, nae))
    cp = np.empty(m)
    ratio = passive_map(A, gamma, ae_index, p_index, Wp, cp)
    if ratio == 0.0:
        return 0.0
    col = np.full(n, -1, dtype=np.int64)  # tree row -> q_ae column (unit row of W), or -1
    prow = np.full(n, -1, dtype=np.int64)  # tree row -> passive row of Wp, or -1
    for j in range(nae):
        col[ae_index[j]] = j
    for i in range(m):
        prow[p_index[i]] = i
    MW = np.empty((n, nae))
    f = np.empty(n)
    for ch in range(chain_start.shape[0] - 1):  # MW = M W and f = tau - h - M c, per chain block
        s = chain_start[ch]
        e = chain_start[ch + 1]
        for i in range(s, e):
            for a in range(nae):
                MW[i, a] = 0.0
            acc = tau[i] - h[i]
            for j in range(s, e):
                mij = M[i, j]
                if col[j] >= 0:
                    MW[i, col[j]] += mij
                else:
                    pr = prow[j]
                    for a in range(nae):
                        MW[i, a] += mij * Wp[pr, a]
                    acc -= mij * cp[pr]
            f[i] = acc
    Mc = np.zeros((nae, nae))
    rhs = np.zeros(nae)
    for i in range(n):  # lower triangle of M_c = W^T (M W) (all cholesky reads), rhs = W^T f
        if col[i] >= 0:  # a unit row of W adds a row
            a0 = col[i]
            for b in range(a0 + 1):
                Mc[a0, b] += MW[i, b]
            rhs[a0] += f[i]
        else:  # a passive row an outer product
            pr = prow[i]
            for a in range(nae):
                w = Wp[pr, a]
                for b in range(a + 1):
                    Mc[a, b] += w * MW[i, b]
                rhs[a] += w * f[i]
    if not cholesky(Mc):
        return 0.0
    cholesky_solve(Mc, rhs)
    for i in range(n):
        if col[i] >= 0:
            qdd[i] = rhs[col[i]]
        else:
            pr = prow[i]
            acc = cp[pr]
            for a in range(nae):
                acc += Wp[pr, a] * rhs[a]
            qdd[i] = acc
    return ratio


@njit(cache=True)
def accelerations_proto(form, ma, q, qd, tau, qdd, lam):
    """evaluate.accelerations (no Baumgarte) with the prototypes.

    form: SCDD (0: platform SCDD, workspace), LDA (1: block L-D'A), SCDD_RECIP (2: SCDD,
    workspace and reciprocal diagonals), SCDD_FAST (3: and multi-column solves).
    """
    n = q.shape[0]
    npt = ma.points.shape[0]
    m = ma.p_index.shape[0]
    M = np.empty((n, n))
    h = np.empty(n)
    J = np.empty((npt, 3, n))
    a_pt = np.empty((npt, 3))
    p_pt = np.empty((npt, 3))
    tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    A = np.empty((m, n))
    gamma = np.empty(m)
    res = np.empty(m)
    closure_rows_noalloc(ma.closure_pairs, ma.closure_axes, J, a_pt, p_pt, A, gamma, res)
    acc = 0.0
    for i in range(m):
        acc += res[i] * res[i]
    gap = np.sqrt(acc)
    if form in (SCDD, SCDD_RECIP):
        cond = scdd_platform_ws(M, h, A, gamma, tau, ma.chain_start, ma.point_chain, ma.closure_pairs,
                                ma.closure_axes.shape[0], ma.hub, qdd, lam, form == SCDD_RECIP)
    elif form == SCDD_FAST:
        cond = scdd_platform_fast(M, h, A, gamma, tau, ma.chain_start, ma.point_chain, ma.closure_pairs,
                                  ma.closure_axes.shape[0], ma.hub, qdd, lam)
    else:
        cond = lda_blocks(M, h, A, gamma, tau, ma.ae_index, ma.p_index, ma.chain_start, qdd)
        lam[:] = 0.0
    return cond, gap
