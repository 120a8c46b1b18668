"""Dense linear algebra for the tiny matrices of one chain (compiled, no LAPACK call).

LAPACK's per-call overhead dominates for 2x2 to 12x12 systems; these loops do not.
"""

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _cholesky_rows(A, floor):
    """In-place lower Cholesky factor of the symmetric A, row by row (contiguous dot
    products); False as soon as a pivot is not above ``floor`` (a NaN is not). Inlined, so
    each caller's fastmath flags apply to it."""
    n = A.shape[0]
    for j in range(n):
        Aj = A[j]
        d = Aj[j]
        for k in range(j):
            d -= Aj[k] * Aj[k]
        if not d > floor:
            return False
        d = np.sqrt(d)
        Aj[j] = d
        for i in range(j + 1, n):
            Ai = A[i]
            s = Ai[j]
            for k in range(j):
                s -= Ai[k] * Aj[k]
            Ai[j] = s / d
    return True


@njit(cache=True)
def cholesky(A):
    """In-place lower Cholesky factor of a symmetric positive definite A; False if not PD."""
    return _cholesky_rows(A, 0.0)


# Reassociated sums let LLVM vectorise the dot products: 2.3x on a 66 x 66 matrix (the Hexa
# observer's covariance, checked three times a period). The factor only decides yes or no, so
# its last bits do not matter; no 'nnan'/'ninf' flags: the comparisons must see a NaN.
@njit(cache=True, fastmath={"reassoc", "contract"})
def positive_definite(A, floor):
    """True if the symmetric A (overwritten by its lower Cholesky factor) has every pivot above
    ``floor`` (a NaN fails)."""
    return _cholesky_rows(A, floor)


@njit(cache=True)
def cholesky_solve(L, b):
    """Solve (L L^T) x = b in place for a vector b."""
    n = L.shape[0]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * b[k]
        b[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, n):
            s -= L[k, i] * b[k]
        b[i] = s / L[i, i]


@njit(cache=True)
def cholesky_recip(L, n, dinv):
    """In-place Cholesky of L[:n, :n] that also keeps dinv = 1 / diag(L): one division per
    row, and :func:`cholesky_solve_rows` multiplies. False if not positive definite."""
    for j in range(n):
        d = L[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        L[j, j] = d
        r = 1.0 / d
        dinv[j] = r
        for i in range(j + 1, n):
            s = L[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s * r
    return True


@njit(cache=True)
def cholesky_solve_rows(L, dinv, n, B, off, nc):
    """(L L^T) X = B[off:off+n, :nc] in place with the factors of :func:`cholesky_recip`.

    All nc columns in one row-oriented (axpy) sweep: independent columns overlap instead of
    waiting on each other, and rows multiply by 1/L_ii. Works inside a larger array. (One
    function for all column counts: numba's on-disk cache crashes on recursive functions
    specialised for several argument types.)
    """
    for i in range(n):
        for k in range(i):
            lik = L[i, k]
            for t in range(nc):
                B[off + i, t] -= lik * B[off + k, t]
        r = dinv[i]
        for t in range(nc):
            B[off + i, t] *= r
    for i in range(n - 1, -1, -1):
        for k in range(i + 1, n):
            lki = L[k, i]
            for t in range(nc):
                B[off + i, t] -= lki * B[off + k, t]
        r = dinv[i]
        for t in range(nc):
            B[off + i, t] *= r


@njit(cache=True)
def lu_factor(A, piv):
    """In-place LU with partial pivoting. Returns min|pivot| / max|pivot| (0 = singular).

    The pivot ratio is a cheap, scale-free singularity indicator.
    """
    n = A.shape[0]
    pmin = np.inf
    pmax = 0.0
    for k in range(n):
        p = k
        best = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > best:
                best = abs(A[i, k])
                p = i
        piv[k] = p
        if p != k:
            for j in range(n):
                t = A[k, j]
                A[k, j] = A[p, j]
                A[p, j] = t
        pmin = min(pmin, best)
        pmax = max(pmax, best)
        if best == 0.0:
            continue
        for i in range(k + 1, n):
            A[i, k] /= A[k, k]
            f = A[i, k]
            for j in range(k + 1, n):
                A[i, j] -= f * A[k, j]
    if n == 0:
        return 1.0
    if pmax == 0.0:
        return 0.0
    return pmin / pmax


@njit(cache=True)
def equilibrated_pivot_ratio(LU, piv, diag, work):
    """The pivot ratio of D A D (D = diag(A)^-1/2, ``diag`` A's diagonal before
    :func:`lu_factor`) from A's factors in their pivot order: pivot k of P D A D is
    d[row at k] U_kk d[k]. For a positive definite A (a Schur complement A M^-1 A^T) this
    is free of the rows' units and of the bodies' scale: a 6 mg ball's spin beside 10 g
    links makes A's own ratio 1e-10 where D A D's is 0.4 and the pose far from singular.
    ``work``: scratch of A's size (at least). Returns 0 if a diagonal entry is not positive."""
    n = LU.shape[0]
    if n == 0:
        return 1.0
    for k in range(n):
        work[k] = diag[k]
    pmin = np.inf
    pmax = 0.0
    for k in range(n):
        p = piv[k]
        if p != k:  # later swaps touch rows after k only: work[k] is now row k's original diagonal
            t = work[k]
            work[k] = work[p]
            work[p] = t
        s = work[k] * diag[k]
        if not s > 0.0:
            return 0.0
        v = abs(LU[k, k]) / np.sqrt(s)
        pmin = min(pmin, v)
        pmax = max(pmax, v)
    return pmin / pmax if pmax > 0.0 else 0.0


@njit(cache=True)
def lu_solve(LU, piv, b):
    """Solve A x = b in place for a vector b, with the factors of :func:`lu_factor`."""
    n = LU.shape[0]
    for k in range(n):
        p = piv[k]
        if p != k:
            t = b[k]
            b[k] = b[p]
            b[p] = t
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= LU[i, k] * b[k]
        b[i] = s
    for i in range(n - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, n):
            s -= LU[i, k] * b[k]
        b[i] = s / LU[i, i]


@njit(cache=True)
def lu_solve_rows(LU, piv, B):
    """Solve A X = B in place for all columns of B at once, row by row (the columns' sweeps
    overlap instead of waiting on each other); each column sees exactly the operations of
    :func:`lu_solve`, so the result is the same to the bit."""
    n = LU.shape[0]
    nc = B.shape[1]
    for k in range(n):
        p = piv[k]
        if p != k:
            for j in range(nc):
                t = B[k, j]
                B[k, j] = B[p, j]
                B[p, j] = t
    for i in range(n):
        for k in range(i):
            lik = LU[i, k]
            for j in range(nc):
                B[i, j] -= lik * B[k, j]
    for i in range(n - 1, -1, -1):
        for k in range(i + 1, n):
            lik = LU[i, k]
            for j in range(nc):
                B[i, j] -= lik * B[k, j]
        d = LU[i, i]
        for j in range(nc):
            B[i, j] = B[i, j] / d


@njit(cache=True)
def lu_solve_columns(LU, piv, B):
    """Solve A X = B in place, column by column."""
    for c in range(B.shape[1]):
        lu_solve(LU, piv, B[:, c])


@njit(cache=True)
def lu_solve_transposed(LU, piv, b):
    """Solve A^T x = b in place with the factors of A."""
    n = LU.shape[0]
    for i in range(n):  # U^T y = b
        s = b[i]
        for k in range(i):
            s -= LU[k, i] * b[k]
        b[i] = s / LU[i, i]
    for i in range(n - 1, -1, -1):  # L^T z = y
        s = b[i]
        for k in range(i + 1, n):
            s -= LU[k, i] * b[k]
        b[i] = s
    for k in range(n - 1, -1, -1):  # undo the row swaps
        p = piv[k]
        if p != k:
            t = b[k]
            b[k] = b[p]
            b[p] = t


@njit(cache=True)
def matvec(A, x, out):
    """out = A x (no BLAS: its call overhead dominates at these sizes)."""
    for i in range(A.shape[0]):
        s = 0.0
        for k in range(A.shape[1]):
            s += A[i, k] * x[k]
        out[i] = s
    return out


@njit(cache=True)
def matvec_t(A, x, out):
    """out = A^T x."""
    for j in range(A.shape[1]):
        out[j] = 0.0
    for i in range(A.shape[0]):
        xi = x[i]
        for j in range(A.shape[1]):
            out[j] += A[i, j] * xi
    return out


@njit(cache=True)
def matmul(A, B, out):
    """out = A B."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            s = 0.0
            for k in range(A.shape[1]):
                s += A[i, k] * B[k, j]
            out[i, j] = s
    return out


@njit(cache=True)
def matmul_tn(A, B, out):
    """out = A^T B."""
    for i in range(A.shape[1]):
        for j in range(B.shape[1]):
            s = 0.0
            for k in range(A.shape[0]):
                s += A[k, i] * B[k, j]
            out[i, j] = s
    return out
