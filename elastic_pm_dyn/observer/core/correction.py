"""Compiled measurement updates of the observer: the Kalman correction (plain and with the
log-determinant the likelihood needs), the closure-consistent correction of the tree state,
and the encoder and accelerometer updates over the filter's
:class:`~elastic_pm_dyn.observer.core.kernels.State` (the prediction, linearisation and bundles:
:mod:`~elastic_pm_dyn.observer.core.kernels`)."""

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.evaluate import SINGULAR_TOL
from elastic_pm_dyn.observer.core.kernels import (
    CLOSURE_TOL,
    FX_POINT,
    IM_R,
    PR_DIST_IDX,
    PR_LZ,
    ST_HPT,
    ST_P,
    ST_Q,
    ST_QD,
    ST_Z,
    covariance_ok,
    point_acceleration,
)
from elastic_pm_dyn.sim.kernels import partition
from elastic_pm_dyn.small_linalg import cholesky, cholesky_solve


@njit(cache=True)
def kalman_update(P, H, R, r, gate, dx):
    """EKF correction with innovation r = z - h(x), H = dh/dx, diagonal noise variances R.

    Returns the NIS r^T S^-1 r. Only if it is <= gate are dx = K r written and P replaced
    by the Joseph form (I - K H) P (I - K H)^T + K R K^T (symmetric); otherwise (or if S is
    not positive definite, NIS = inf) nothing changes.
    """
    return kalman_update_ld(P, H, R, r, gate, dx)[0]


@njit(cache=True)
def kalman_update_ld(P, H, R, r, gate, dx):
    """:func:`kalman_update`, returning (NIS, log det S): the sample's Gaussian log-likelihood is
    -(NIS + log det S + m log 2 pi) / 2 (the prediction-error method's term; (inf, nan) if S is
    not positive definite). log det S comes from the Cholesky factor the update needs anyway."""
    nx = P.shape[0]
    nz = H.shape[0]
    PHt = P @ H.T
    S = H @ PHt
    for i in range(nz):
        S[i, i] += R[i]
    # Cholesky of S (small), scaled to unit diagonal for robustness.
    sc = np.empty(nz)
    for i in range(nz):
        if not S[i, i] > 0.0:
            return np.inf, np.nan
        sc[i] = 1.0 / np.sqrt(S[i, i])
    L = np.empty((nz, nz))
    for i in range(nz):
        for j in range(nz):
            L[i, j] = S[i, j] * sc[i] * sc[j]
    if not cholesky(L):
        return np.inf, np.nan
    # y = L^-1 (sc * r): NIS = |y|^2; det S = prod (L_ii / sc_i)^2
    y = np.empty(nz)
    logdet = 0.0
    for i in range(nz):
        s = r[i] * sc[i]
        for k in range(i):
            s -= L[i, k] * y[k]
        y[i] = s / L[i, i]
        logdet += 2.0 * np.log(L[i, i]) - 2.0 * np.log(sc[i])
    nis = 0.0
    for i in range(nz):
        nis += y[i] * y[i]
    if not nis <= gate:
        return nis, logdet
    # K = P H^T S^-1: solve S K^T = (P H^T)^T column by column, via the scaled factor.
    K = np.empty((nx, nz))
    z = np.empty(nz)
    for c in range(nx):
        for i in range(nz):
            z[i] = PHt[c, i] * sc[i]
        cholesky_solve(L, z)
        for i in range(nz):
            K[c, i] = z[i] * sc[i]
    for c in range(nx):
        s = 0.0
        for i in range(nz):
            s += K[c, i] * r[i]
        dx[c] = s
    # The Joseph form (I - K H) P (I - K H)^T + K R K^T, expanded so that every product has
    # the thin dimension nz inside: P - K (P H^T)^T - (P H^T) K^T + K S K^T with S = H P H^T + R.
    # Equal for any K (so as forgiving of round-off in K as the product form), but
    # O(nx^2 nz) instead of O(nx^3): on the Hexa's 66 states the update's largest cost.
    KS = K @ S
    for i in range(nx):
        for j in range(i + 1):
            v = P[i, j]
            for k in range(nz):
                v += KS[i, k] * K[j, k] - K[i, k] * PHt[j, k] - PHt[i, k] * K[j, k]
            P[i, j] = v
            P[j, i] = v
    return nis, logdet


@njit(cache=True)
def apply_correction(ma, q, qd, z, dx):
    """x <- x + dx on the tree state (q_ae, qd_ae) and the disturbance states z; q_p, qd_p
    re-solved from the closure.

    Returns (gap, pivot ratio) of the partitioning.
    """
    ae = ma.ae_index
    nae = ae.shape[0]
    for i in range(nae):
        q[ae[i]] += dx[i]
        qd[ae[i]] += dx[nae + i]
    for k in range(z.shape[0]):
        z[k] += dx[2 * nae + k]
    return partition(ma, q, qd, CLOSURE_TOL, np.int64(6))


@njit(cache=True)
def correct(ma, state, H, R, r, gate):
    """One correction of ``state`` (:class:`State`): :func:`kalman_update`, then x <- x + dx on
    the tree state (closure re-solved) and a covariance check. Returns (NIS, status, log det S):
    status 0 applied, 1 gated out, 2 the closure could not be re-solved, 3 P no longer positive
    definite."""
    q, qd, z, P = state[ST_Q], state[ST_QD], state[ST_Z], state[ST_P]
    dx = np.zeros(P.shape[0])
    nis, logdet = kalman_update_ld(P, H, R, r, gate, dx)
    if not nis <= gate:
        return nis, 1, logdet
    gap, ratio = apply_correction(ma, q, qd, z, dx)
    if not (gap <= 1e-9 and ratio >= SINGULAR_TOL):
        return nis, 2, logdet
    if not covariance_ok(P):
        return nis, 3, logdet
    return nis, 0, logdet


@njit(cache=True)
def encoder_correct(ma, state, enc, meas, gate):
    """Encoder positions of state joints (``enc``: :class:`EncoderPlan`): innovation
    meas - q[js], wrapped to (-pi, pi] where ``wrap`` (revolute), then :func:`correct`.
    Returns (NIS, status, log det S) as :func:`correct`, or (nan, -1, nan) untouched if a value
    is not finite."""
    H, R, js, wrap = enc
    q = state[ST_Q]
    k = js.shape[0]
    r = np.empty(k)
    for i in range(k):
        if not np.isfinite(meas[i]):
            return np.nan, -1, np.nan
        r[i] = meas[i] - q[js[i]]
        if wrap[i]:
            r[i] = (r[i] + np.pi) % (2 * np.pi) - np.pi
    return correct(ma, state, H, R, r, gate)


@njit(cache=True)
def disturbance_torques(Lz, z):
    """d = Lz z: the unknown torques on the disturbance joints from the disturbance states."""
    nd = Lz.shape[0]
    d = np.zeros(nd)
    for k in range(nd):
        for m in range(z.shape[0]):
            d[k] += Lz[k, m] * z[m]
    return d


@njit(cache=True)
def imu_residual(S, g, meas, a, r):
    """r = meas - S (a - g): the accelerometer's innovation for point acceleration ``a``."""
    for i in range(S.shape[0]):
        h = 0.0
        for c in range(3):
            h += S[i, c] * (a[c] - g[c])
        r[i] = meas[i] - h


@njit(cache=True)
def imu_correct(ma, fixed, proc, state, imu, tau, meas, gate, a):
    """Accelerometer correction (``imu``: :class:`ImuModel`): y = S (J qdd + Jdot qd - g) at the
    state under tau + Lz z; H = S Hpt. ``a`` (3) receives the point's acceleration at the prior
    (a deferred sample's weighing, :func:`imu_innovations`, takes it instead of evaluating it
    again). Returns (NIS, status, log det S) as :func:`correct`, status 4 if the model is
    singular."""
    point = fixed[FX_POINT]
    dist_idx, Lz = proc[PR_DIST_IDX], proc[PR_LZ]
    q, qd, z, Hpt = state[ST_Q], state[ST_QD], state[ST_Z], state[ST_HPT]
    S, g, R = imu
    d = disturbance_torques(Lz, z)
    if not point_acceleration(ma, q, qd, tau, dist_idx, d, point, a) >= SINGULAR_TOL:
        return np.inf, 4, np.nan
    r = np.empty(S.shape[0])
    imu_residual(S, g, meas, a, r)
    H = S @ Hpt
    return correct(ma, state, H, R, r, gate)


@njit(cache=True)
def innovation_nis(P, H, R, r):
    """(NIS r^T S^-1 r, log det S) of innovation r with S = H P H^T + diag(R) (as
    :func:`kalman_update` scales it); (inf, nan) if S is not positive definite."""
    nz = H.shape[0]
    S = H @ P @ H.T
    sc = np.empty(nz)
    for i in range(nz):
        S[i, i] += R[i]
        if not S[i, i] > 0.0:
            return np.inf, np.nan
        sc[i] = 1.0 / np.sqrt(S[i, i])
    for i in range(nz):
        for j in range(nz):
            S[i, j] *= sc[i] * sc[j]
    if not cholesky(S):
        return np.inf, np.nan
    nis = 0.0
    logdet = 0.0
    y = np.empty(nz)
    for i in range(nz):
        v = r[i] * sc[i]
        for k in range(i):
            v -= S[i, k] * y[k]
        y[i] = v / S[i, i]
        nis += y[i] * y[i]
        logdet += 2.0 * np.log(S[i, i]) - 2.0 * np.log(sc[i])
    return nis, logdet


@njit(cache=True)
def imu_innovations(ma, fixed, proc, state, imu, tau_before, tau_after, meas, gate, evidence, a_before, known):
    """The accelerometer sample predicted under both timing hypotheses at the same state (for
    ``imu.sample_timing: auto``): y_b under ``tau_before`` (the torque of the interval that ended
    at the sample, a(t_k-)) and y_a under ``tau_after`` (the torque acting from it on, a(t_k+));
    both innovations share S = H P H^T + R, H = S Hpt. Adds [min(NIS_b, gate), min(NIS_a, gate),
    log det(2 pi S), 1] to ``evidence``, so that the log-likelihoods of the samples so far are
    -(evidence[0 or 1] + evidence[2]) / 2: Gaussian, the NIS capped at the gate so that an
    outlier (beyond it under both) weighs nothing and a sample weighs at most gate / 2 nats for
    one hypothesis. ``known``: ``a_before`` (3) already holds the point's acceleration under
    tau_before at this state (:func:`imu_correct`'s), else it receives it. Returns (r_b, r_a,
    H, False if the model is singular there)."""
    point = fixed[FX_POINT]
    dist_idx, Lz = proc[PR_DIST_IDX], proc[PR_LZ]
    q, qd, z, P, Hpt = state[ST_Q], state[ST_QD], state[ST_Z], state[ST_P], state[ST_HPT]
    S, g, R = imu
    d = disturbance_torques(Lz, z)
    nz = S.shape[0]
    r_b = np.empty(nz)
    r_a = np.empty(nz)
    H = S @ Hpt
    a_b = a_before
    a_a = np.empty(3)
    if not known and not point_acceleration(ma, q, qd, tau_before, dist_idx, d, point, a_b) >= SINGULAR_TOL:
        return r_b, r_a, H, False
    same = True
    for i in range(tau_before.shape[0]):
        same = same and tau_before[i] == tau_after[i]
    if same:
        a_a[:] = a_b
    elif not point_acceleration(ma, q, qd, tau_after, dist_idx, d, point, a_a) >= SINGULAR_TOL:
        return r_b, r_a, H, False
    imu_residual(S, g, meas, a_b, r_b)
    imu_residual(S, g, meas, a_a, r_a)
    nis_b, logdet = innovation_nis(P, H, R, r_b)
    nis_a, _ = innovation_nis(P, H, R, r_a)
    if np.isfinite(nis_b) and np.isfinite(nis_a):
        evidence[0] += min(nis_b, gate)
        evidence[1] += min(nis_a, gate)
        evidence[2] += logdet + nz * np.log(2.0 * np.pi)
        evidence[3] += 1.0
    return r_b, r_a, H, True


@njit(cache=True)
def imu_correct_auto(ma, fixed, proc, state, imu, tau_before, tau_after, use_after, meas, gate, evidence):
    """:func:`imu_innovations` (the evidence), then the correction under the after hypothesis if
    ``use_after``, else the before one (the same numbers as :func:`imu_correct` with that torque).
    Returns (NIS, status, log det S) as :func:`imu_correct`."""
    r_b, r_a, H, ok = imu_innovations(ma, fixed, proc, state, imu, tau_before, tau_after, meas, gate, evidence,
                                      np.empty(3), np.bool_(False))
    if not ok:
        return np.inf, 4, np.nan
    return correct(ma, state, H, imu[IM_R], r_a if use_after else r_b, gate)
