"""The observer's prediction at the loop's cost: the structure the model has, used.

Two costs dominated a 1 ms prediction on the spatial machines, both set by the stiffest
spring: the mean's RK4 sub-steps (160 SCDD evaluations a period on the Triglide at n_ek = 2)
and the dense expm of the whole linearisation (Hexa: 66 x 66, nine squarings). Here:

- **Mean**: the plant's own ETD2 step (:mod:`elastic_pm_dyn.sim.exponential`): the spring
  system integrated exactly, everything else as forcing evaluated on the step's average;
  two SCDD evaluations per step. The step is set by how fast the springs' coupling with the
  geometry must be followed, not by their stability (``ObserverModel.etd2_step``: 2 steps
  per 1 ms on the five-bar, 4 on the Hexa and 8 on the Triglide at n_ek = 2, against 20,
  80 and 160 RK4 sub-steps).
- **Linearisation** (:func:`~elastic_pm_dyn.observer.core.kernels.linearize_springs`): the
  response to unit generalised forces on every q_ae joint from one factorisation of the
  evaluation's M and A (the ETD2 gains, eqs 33-41 with tau - h = e_j and gamma = 0), so
  Bf = d qdd_ae / d f_ae and the accelerometer's Ef = J_pt G come without extra
  evaluations. An elastic joint's spring is linear, so its position columns are -c Bf (and
  -c Ef); what they leave out is the geometric change of a micro-deflection (the bending of
  an arm moving its masses by micrometres: 1e-5 of a column on the reference five-bar
  mid-manoeuvre, 2e-4 on the Triglide in a strong chirp). The rate columns stay one-sided
  differences (a rod's axial rate meets the arm's rotation in Coriolis terms as large as its
  damper's: 0.1-0.4 of the column in the reference manoeuvre), but of the velocity terms
  alone (:func:`rate_columns`): at a fixed pose the mass matrix and the closure rows do not
  change, so each column needs the bias forces and the closure's bias at the perturbed rates
  (no mass matrix, no factorisation) and the reduced inertia's inverse the gains already hold.
  So 1 + n_a full evaluations and n_ae bias sweeps instead of 1 + 3 n_ae evaluations.
- **Discretisation** (:func:`discretize_structured`): x = [m, z] with m = [q_ae, qd_ae]
  and z the disturbance states; z' = Fz z + w does not depend on m, so Phi_zz and Qd_zz
  are constant for a given interval and noise (computed once, cached), and m sees z only
  through the n_d torques d = Lz z. Over the interval d(s) = Lz e^(Fz s) z is a quartic in s
  to (|Fz| T)^5 / 120 (3e-5 at a 50 Hz corner and 1 ms), so Phi_mz = sum_k Psi_k Lz Fz^k
  with Psi_k = int_0^T e^(A_m (T - s)) C s^k / k! ds, C the forces' columns: the top right
  of the exponential of A_m augmented by a chain of the input's derivatives, carried through
  the same Taylor series and squarings as Phi_mm on thin (2 n_ae x 5 n_d) blocks. Qd_mm is
  Van Loan's integral of the mechanical noise on the 2 n_ae block; the noise z picks up
  within the interval reaches m through Phi_mz(u), integrated by Simpson's rule on quarters
  of the interval (Phi at T/4, T/2 from the squarings, 3T/4 from one thin product). Against
  the dense Van Loan of the whole state: Phi to 1e-11 relative, Qd to 1 % of
  sqrt(Qd_ii Qd_jj) (test_observer_propagation.py).
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.kinematics.kernels import TreeSweep, TreeTerms, all_closure_rows, point_buffers, tree_terms_into
from elastic_pm_dyn.model.layout import JF_STIFFNESS, JI_ROLE
from elastic_pm_dyn.sim.exponential import gains_workspace
from elastic_pm_dyn.small_linalg import lu_factor, lu_solve

ROLE_ELASTIC = 1
INPUT_ORDER = 5  # d and its first four derivatives over the interval (module docstring)
PHI_TERMS = 12  # Taylor terms of Phi at |B h| <= 1/4: 0.25^13 / 13! ~ 1e-18
Q_TERMS = 8  # Taylor terms of Van Loan's integral there: the ninth is ~1e-8 of the first


@njit(cache=True)
def linearization_workspace(ma):
    """Work arrays of :func:`linearize_springs` (allocate once per filter)."""
    n = ma.jf.shape[0]
    nae = ma.ae_index.shape[0]
    return gains_workspace(ma, ma.ae_index), np.empty((n, nae + 2)), np.zeros((2, n))


@njit(cache=True)
def spring_columns(ma, G, point, with_point, J, Aq, Bf, Eq, Ef, analytic):
    """Bf, Ef from the gains G (n_t x n_ae) and the point's Jacobian J; the elastic joints'
    position columns of Aq, Eq from their springs (``analytic[j]`` set for them)."""
    n = G.shape[0]
    ae = ma.ae_index
    nae = ae.shape[0]
    for j in range(nae):
        for i in range(nae):
            Bf[i, j] = G[ae[i], j]
        for r in range(3):
            s = 0.0
            if with_point:
                for t in range(n):
                    s += J[point, r, t] * G[t, j]
            Ef[r, j] = s
        jt = ae[j]
        analytic[j] = ma.ji[jt, JI_ROLE] == ROLE_ELASTIC
        if analytic[j]:
            c = ma.jf[jt, JF_STIFFNESS]
            for i in range(nae):
                Aq[i, j] = -c * Bf[i, j]
            for r in range(3):
                Eq[r, j] = -c * Ef[r, j]


@njit(cache=True)
def rate_columns(ma, q, qd, point, with_point, eps_v, W, ws, Bf, Av, Ev):
    """Every rate column of Av = d qdd_ae / d qd_ae and Ev (the point acceleration's): the
    one-sided differences (steps ``eps_v`` along W) that full evaluations would give, from the
    velocity terms alone.

    At a fixed pose M, the closure rows A and W stay. With qdd = W qdd_ae + c, c_p = A_p^-1
    gamma (eq 12) and W^T (M qdd + h - tau) = 0 (eq 26), a change dh of the bias forces and
    dgamma of the closure's bias changes the accelerations by dqdd_ae = M_r^-1 W^T (-dh - M dc),
    dc_p = A_p^-1 dgamma, with M_r^-1 = Bf (the gains of unit forces on the q_ae joints, eq 21).
    ``ws``: the workspace of the evaluation at (q, qd) (its M, h, J, a_pt, A and gamma; its
    sweep scratch is reused). Returns the pivot ratio of A_p (0: singular)."""
    n = q.shape[0]
    ae, pidx = ma.ae_index, ma.p_index
    nae, m = ae.shape[0], pidx.shape[0]
    M, J = ws.M, ws.J
    h0, gamma0 = ws.h.copy(), ws.gamma.copy()
    a0 = np.zeros(3)
    if with_point:
        for r in range(3):
            a0[r] = ws.a_pt[point, r]
    Ap = np.empty((m, m))
    piv = np.empty(m, dtype=np.int64)
    for i in range(m):
        for j in range(m):
            Ap[i, j] = ws.A[i, pidx[j]]
    ratio = lu_factor(Ap, piv) if m > 0 else 1.0
    if ratio == 0.0:
        return 0.0
    no_mass = np.empty((0, 0))
    hj = np.empty(n)
    J2, a2, p2 = point_buffers(ma.points, n)
    A2, g2, r2 = np.empty((m, n)), np.empty(m), np.empty(m)
    vp, f, wf, dqdd, dc = np.empty(n), np.empty(n), np.empty(nae), np.empty(n), np.empty(m)
    for j in range(nae):
        e = eps_v[j]
        for i in range(n):
            vp[i] = qd[i] + W[i, j] * e
        tree_terms_into(ma, q, vp, TreeTerms(no_mass, hj, J2, a2, p2), TreeSweep(ws.wz, ws.wo, ws.jv, ws.jw, ws.fr))
        all_closure_rows(ma.closure_pairs, ma.closure_axes, ma.points, ma.couplings, q, J2, a2, p2, A2, g2, r2)
        for i in range(m):
            dc[i] = (g2[i] - gamma0[i]) / e
        if m > 0:
            lu_solve(Ap, piv, dc)
        for t in range(n):
            f[t] = -(hj[t] - h0[t]) / e
        for i in range(m):
            pt = pidx[i]
            for t in range(n):
                f[t] -= M[t, pt] * dc[i]
        for k in range(nae):
            acc = 0.0
            for t in range(n):
                acc += W[t, k] * f[t]
            wf[k] = acc
        for i in range(nae):
            acc = 0.0
            for k in range(nae):
                acc += Bf[i, k] * wf[k]
            Av[i, j] = acc
        if not with_point:
            for r in range(3):
                Ev[r, j] = 0.0
            continue
        for t in range(n):
            acc = 0.0
            for k in range(nae):
                acc += W[t, k] * Av[k, j]
            dqdd[t] = acc
        for i in range(m):
            dqdd[pidx[i]] += dc[i]
        for r in range(3):
            acc = (a2[point, r] - a0[r]) / e
            for t in range(n):
                acc += J[point, r, t] * dqdd[t]
            Ev[r, j] = acc
    return ratio


@njit(cache=True)
def one_norm(B):
    """The largest column sum of |B| (the scaling and squaring's measure)."""
    norm = 0.0
    for j in range(B.shape[1]):
        c = 0.0
        for i in range(B.shape[0]):
            c += abs(B[i, j])
        norm = max(norm, c)
    return norm


@njit(cache=True)
def balance(A, d):
    """Osborne's diagonal scaling (powers of 2) of A: d such that D^-1 A D has balanced rows and columns."""
    n = A.shape[0]
    B = A.copy()
    d[:] = 1.0
    for _ in range(30):
        done = True
        for i in range(n):
            c = 0.0
            r = 0.0
            for j in range(n):
                if j != i:
                    c += abs(B[j, i])
                    r += abs(B[i, j])
            if c == 0.0 or r == 0.0:
                continue
            f = 1.0
            s = c + r
            while c < r / 2.0:
                c *= 2.0
                r /= 2.0
                f *= 2.0
            while c >= r * 2.0:
                c /= 2.0
                r *= 2.0
                f /= 2.0
            if (c + r) < 0.95 * s:
                done = False
                d[i] *= f
                for j in range(n):
                    B[i, j] /= f
                    B[j, i] *= f
        if done:
            break
    return B


@njit(cache=True)
def _z_columns(Psi, LF, nd, out):
    """Phi_mz = sum_k Psi_k Lz Fz^k (LF[k] = Lz Fz^k), from the input chain's responses Psi."""
    nm = Psi.shape[0]
    nz = out.shape[1]
    out[:, :] = 0.0
    for k in range(INPUT_ORDER):
        for i in range(nm):
            for m in range(nz):
                s = 0.0
                for c in range(nd):
                    s += Psi[i, k * nd + c] * LF[k, c, m]
                out[i, m] += s


@njit(cache=True)
def _add_z_noise(X, Z, psd_z, w, Qd, nm):
    """Qd += w [X; Z] diag(psd_z) [X; Z]^T in the mm and mz blocks (the zz block is exact elsewhere)."""
    nz = Z.shape[0]
    XQ = X * psd_z
    for i in range(nm):
        for j in range(nm):
            s = 0.0
            for m in range(nz):
                s += XQ[i, m] * X[j, m]
            Qd[i, j] += w * s
        for j in range(nz):
            s = 0.0
            for m in range(nz):
                s += XQ[i, m] * Z[j, m]
            Qd[i, nm + j] += w * s
            Qd[nm + j, i] += w * s


@njit(cache=True)
def _bh_times(X, up, Bbot):
    """Bh X for Bh = [[0, diag(up)], Bbot]: the top rows scale X's bottom rows, the bottom
    rows are one product of half the size."""
    nae = up.shape[0]
    out = np.empty(X.shape)
    for i in range(nae):
        for c in range(X.shape[1]):
            out[i, c] = up[i] * X[nae + i, c]
    out[nae:, :] = Bbot @ X
    return out


@njit(cache=True)
def _times_bh(X, up, Bq, Bv):
    """X Bh for Bh = [[0, diag(up)], [Bq, Bv]]: [X_2 Bq, X_1 diag(up) + X_2 Bv], X = [X_1, X_2]."""
    nae = up.shape[0]
    X2 = np.ascontiguousarray(X[:, nae:])
    out = np.empty(X.shape)
    out[:, :nae] = X2 @ Bq
    out[:, nae:] = X2 @ Bv
    for r in range(X.shape[0]):
        for i in range(nae):
            out[r, nae + i] += X[r, i] * up[i]
    return out


@njit(cache=True)
def discretize_structured(Aq, Av, Bf, dist_col, Lz, Fz, psd_m, psd_z, T, Phi_z, Qd_z, Phi, Qd):
    """Phi = expm(A T) and Van Loan's Qd of x = [q_ae, qd_ae, z] from their blocks (module docstring).

    A = [[0, I, 0], [Aq, Av, Bf_d Lz], [0, 0, Fz]] (Bf_d: Bf's columns ``dist_col``), white
    generalised forces of intensity psd_m on q_ae, white noise psd_z on z; Phi_z[j] =
    expm(Fz (j + 1) T / 4) and Qd_z the z block's noise over T (:func:`z_block`). The noise
    that z picks up within the interval reaches m through Phi_mz(u): its share of Qd,
    int_0^T Phi(u)_z Qz Phi(u)_z^T du, by Simpson's rule on quarters of the interval, at
    which the squarings give Phi (3 T / 4 = T / 2 + T / 4 from one more thin product).
    """
    nae = Aq.shape[0]
    nm = 2 * nae
    nd = dist_col.shape[0]
    nz = Fz.shape[0]
    nc = INPUT_ORDER * nd
    Am = np.zeros((nm, nm))
    for i in range(nae):
        Am[i, nae + i] = 1.0
        for j in range(nae):
            Am[nae + i, j] = Aq[i, j]
            Am[nae + i, nae + j] = Av[i, j]
    dsc = np.empty(nm)
    B = balance(Am, dsc)
    # balanced forcing columns C_b = D^-1 C and noise Q_b = D^-1 Qc D^-1
    Cb = np.zeros((nm, nd))
    for k in range(nd):
        for i in range(nae):
            Cb[nae + i, k] = Bf[i, dist_col[k]] / dsc[nae + i]
    Qb = np.zeros((nm, nm))
    for i in range(nae):
        for j in range(nae):
            s = 0.0
            for k in range(nae):
                s += Bf[i, k] * psd_m[k] * Bf[j, k]
            Qb[nae + i, nae + j] = s / (dsc[nae + i] * dsc[nae + j])
    norm = one_norm(B)
    n_sq = 2  # at least T / 4 and T / 2 among the squarings (the quadrature's nodes)
    while norm * T / 2.0 ** n_sq > 0.25:
        n_sq += 1
    h = T / 2.0 ** n_sq
    Bh = B * h
    # Bh = [[0, diag(up)], [Bq, Bv]] (balancing keeps the zero block and makes the identity a
    # diagonal): products with it need only its dense bottom half (:func:`_times_bh`)
    up = np.empty(nae)
    for i in range(nae):
        up[i] = Bh[i, nae + i]
    Bq = np.ascontiguousarray(Bh[nae:, :nae])
    Bv = np.ascontiguousarray(Bh[nae:, nae:])
    Bbot = np.ascontiguousarray(Bh[nae:, :])
    E = np.eye(nm)
    term = np.eye(nm)
    # Psi_k(h) = h^(k+1) sum_j (B h)^j C_b / (j + k + 1)!: the columns (k, input) side by side
    Psi = np.zeros((nm, nc))
    V = Cb.copy()
    fact = 1.0
    for j in range(PHI_TERMS + 1):
        if j > 0:
            term = _times_bh(term, up, Bq, Bv) / j
            E += term
            V = _bh_times(V, up, Bbot)
        fact *= j + 1  # (j + 1)!
        hk = h
        fk = fact
        for k in range(INPUT_ORDER):
            for i in range(nm):
                for c in range(nd):
                    Psi[i, k * nd + c] += hk * V[i, c] / fk
            hk *= h
            fk *= j + k + 2
    G = Qb * h
    Q = G.copy()
    for k in range(1, Q_TERMS + 1):
        X = _bh_times(G, up, Bbot)  # G stays symmetric: G Bh^T = (Bh G)^T
        G = (X + X.T) / (k + 1)
        Q += G
    Psi_quarter = Psi.copy()
    Psi_half = Psi.copy()
    E_half = E.copy()
    for level in range(1, n_sq + 1):
        Q = E @ Q @ E.T + Q
        # Psi(2h) = E Psi(h) + Psi(h) e^(N h): the input chain's exponential is a Taylor shift
        Pn = E @ Psi
        for k in range(INPUT_ORDER):
            w = 1.0
            for i in range(k, -1, -1):  # Psi_i h^(k-i) / (k-i)!
                for r in range(nm):
                    for c in range(nd):
                        Pn[r, k * nd + c] += Psi[r, i * nd + c] * w
                w *= h / (k - i + 1)
        Psi = Pn
        E = E @ E
        h *= 2.0
        if level == n_sq - 2:
            Psi_quarter[:, :] = Psi
        elif level == n_sq - 1:
            Psi_half[:, :] = Psi
            E_half[:, :] = E
    # Unbalance (the quadrature below works in the model's units)
    Phi[:, :] = 0.0
    Qd[:, :] = 0.0
    for i in range(nm):
        for j in range(nm):
            Phi[i, j] = E[i, j] * dsc[i] / dsc[j]
            Qd[i, j] = 0.5 * (Q[i, j] + Q[j, i]) * dsc[i] * dsc[j]
            E_half[i, j] *= dsc[i] / dsc[j]
        for c in range(nc):
            Psi[i, c] *= dsc[i]
            Psi_half[i, c] *= dsc[i]
            Psi_quarter[i, c] *= dsc[i]
    LF = np.empty((INPUT_ORDER, nd, nz))  # Lz Fz^k
    LF[0] = Lz
    for k in range(1, INPUT_ORDER):
        LF[k] = LF[k - 1] @ Fz
    X1, X2, X3, X4 = np.empty((nm, nz)), np.empty((nm, nz)), np.empty((nm, nz)), np.empty((nm, nz))
    _z_columns(Psi_quarter, LF, nd, X1)
    _z_columns(Psi_half, LF, nd, X2)
    _z_columns(Psi, LF, nd, X4)
    X3[:, :] = E_half @ X1 + X2 @ Phi_z[0]  # Phi(3T/4) = Phi(T/2) Phi(T/4), its z columns
    for i in range(nm):
        for m in range(nz):
            Phi[i, nm + m] = X4[i, m]
    for i in range(nz):
        for j in range(nz):
            Phi[nm + i, nm + j] = Phi_z[3, i, j]
            Qd[nm + i, nm + j] = Qd_z[i, j]
    # Simpson on [0, T] in quarters: weights T/12 (1, 4, 2, 4, 1); at u = 0, Phi_mz(0) = 0
    for X, Z, w in ((X1, Phi_z[0], 4.0), (X2, Phi_z[1], 2.0), (X3, Phi_z[2], 4.0), (X4, Phi_z[3], 1.0)):
        _add_z_noise(X, Z, psd_z, w * T / 12.0, Qd, nm)
