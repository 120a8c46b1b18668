"""Compiled exponential integration: the elastic joints' springs do not set the step.

The stiff part of the machine is linear: the spring-damper forces f = -K (q_e - rest) - D qd_e
of the elastic joints (n_f of them) act through the constrained inverse inertia

    G = P M^-1 E = M^-1 E - Y S^-1 A M^-1 E,   Y = M^-1 A^T,  S = A M^-1 A^T   (n_t x n_f),

(the accelerations SCDD gives to unit forces on the elastic joints, eqs 33-41 with
tau - h = e_j and gamma = 0). Frozen over a macro step H at its start state, the
linearisation z' = J z of the tree state z = (q, qd) in the springs alone,
J = [[0, I], [-G K E^T, -G D E^T]], is integrated exactly (to round-off, on sub-steps), and
everything else, N(z) = F(z) - J z (motion, Coriolis, gravity, closure, torques, the springs'
variation of G), enters as its forcing. The step (scheme AVERAGED, the ``etd2`` integrator):

    x(t) = z0 + t phi1(t J) F(z0),  0 <= t <= H              (exponential Euler, the predictor)
    zbar = (1/H) int_0^H x(t) dt                              (its average over the step)
    z1   = z0 + H phi1(H J) (F(z0) + N(zbar) - N(z0))         (= e^HJ z0 + H phi1(H J) N(zbar))

with F the full right-hand side at the step's start torque (one formulation evaluation each
at z0 and zbar); the torque's change over the step (tau(t) = tau0 + t d1 + t^2 d2) is forcing
of the frozen system too, through the gains P M^-1 d1, P M^-1 d2. zbar is z(H/2) to O(H^2),
so the method is of second order (the exponential midpoint rule); exact for the frozen linear
spring system, so an undamped mode keeps its frequency and energy at any H, and a stiff spring
under a slow load sits at its quasi-static deflection instead of ringing.

Why the average: the arm modes the step does not resolve (omega H up to ~70) oscillate inside
N (G's change with the deflection times the spring force, the vibrating arms' Coriolis
terms). Sampled at two instants (ETD2RK, Cox and Matthews 2002: N at z0 and at x(H), a ramp
between) those products alias into a slow forcing in phase with the modes, which pumped
energy into them: the undamped Hexa at n_ek = 4 gained up to 16x its deflection's energy
in 10 s at steps from 0.06 to 0.5 ms (bench/benchmarks/README_integrators.md). The average over the step
is a filter, the one of mollified impulse methods (Garcia-Archilla, Sanz-Serna and Skeel
1999; Hochbruck and Lubich 1999): a mode's oscillation reaches N reduced by
|sinc(omega H / 2)|, the slow motion unchanged. What it gives up is the vibration's rectified
part (the mean of the products): at omega H >> 1 a free, undamped machine drifts more slowly
than it should under its own vibration (docs/limits.md). ETD2RK is kept (scheme ETD2RK) for
that comparison. After each macro step (q, qd) is projected onto the constraint manifold,
positions in the metric M + H^2 K so that the correction does not shift the stiff springs
(:func:`elastic_pm_dyn.sim.kernels.project_springs`).

phi1 applied to a vector (and the averages) are responses of the linear system from rest to
a polynomial forcing. Only the elastic coordinates are dynamic in it (their n_f x n_f block
B = E^T G), the others integrate their forcing: those responses are Taylor-series sub-steps
(order from :func:`taylor_order`) of the 2 n_f elastic states plus the integrals of f, at
most ``phase_step`` rad of the fastest frozen mode each (an upper bound of its frequency from
Gershgorin's circles), i.e. O(n_f^2) operations per sub-step against a formulation
evaluation per macro step.

The impulse splitting (r-RESPA: kick H/2 with everything but the springs, the springs alone
over H, kick H/2; scheme IMPULSE) shares the sub-steps; bench/benchmarks/bench_integrators.py measured it
against ETD2 and it lost: a stiff spring under a slow load rings after every kick.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.evaluate import LDA, accelerations_into, workspace
from elastic_pm_dyn.dynamics.kernels import chain_size_max
from elastic_pm_dyn.model.layout import JF_DAMPING, JF_REST, JF_STIFFNESS, JI_CHAIN, JI_ROLE
from elastic_pm_dyn.sim.kernels import (
    DIVERGED,
    MAX_STEP_MOTION,
    NEAR_SINGULAR,
    OK,
    SINGULAR,
    STAB_BAUMGARTE,
    STAB_PROJECTION,
    _sane,
    _step_motion,
    add_chain_schur,
    chain_block,
    project_springs,
    projection_workspace,
    unsound_step,
)
from elastic_pm_dyn.small_linalg import cholesky_solve_rows, lu_factor, lu_solve_rows

ROLE_ELASTIC = 1

# Truncation of the sub-steps' Taylor series: the first term left out, theta^(K+1) / (K+1)!
# at theta rad of the fastest mode per sub-step, is below this (order 20 at 3 rad, 38 at
# 9 rad; 3 rad at order 20 was the fixed rule before). RK4 sub-steps would lose
# (h omega)^6 / 144 of a mode's energy each (all of an undamped kHz mode's within seconds).
TAYLOR_TOL = 2.1e-10
# [rad] per sub-step (SimulationOptions.phase_step) against a Gershgorin bound of the fastest
# rate, 1-11 % above the fastest mode on the shipped machines. The terms per rad fall with
# the sub-step (6.7 at 3 rad, 5 at 6 rad, 4.2 at 9 rad); the largest term, ~theta^theta /
# theta! (1e3 at 9 rad), costs that many units of round-off (2e-13 of the response).
DEFAULT_PHASE_STEP = 9.0

# [s] the step `check` suggests: it met the 1 % branch-force criterion for ZOH torques at
# 1 kHz on 6 of the 7 machines of bench/benchmarks/bench_integrators.py (bench/benchmarks/README_integrators.md)
RECOMMENDED_STEP = 5e-4

# Upper end of the sub-steps per macro step: a fastest mode 10^4 times the macro step's
# frequency means a step or a model beyond what the method is for.
MAX_SUBSTEPS = 100000


@njit(cache=True)
def fast_joints(ma):
    """Tree indices of the elastic joints with a spring or a damper: the frozen linear part."""
    n = ma.jf.shape[0]
    count = 0
    for i in range(n):
        if ma.ji[i, JI_ROLE] == ROLE_ELASTIC and (ma.jf[i, JF_STIFFNESS] != 0.0 or ma.jf[i, JF_DAMPING] != 0.0):
            count += 1
    fast = np.empty(count, dtype=np.int64)
    count = 0
    for i in range(n):
        if ma.ji[i, JI_ROLE] == ROLE_ELASTIC and (ma.jf[i, JF_STIFFNESS] != 0.0 or ma.jf[i, JF_DAMPING] != 0.0):
            fast[count] = i
            count += 1
    return fast


@njit(cache=True)
def gains_workspace(ma, fast):
    """Work arrays of :func:`elastic_gains` (allocate once per call, reuse every step)."""
    n = ma.jf.shape[0]
    m = ma.p_index.shape[0]
    nf = fast.shape[0]
    nmax = chain_size_max(ma.chain_start)
    n_ch = ma.chain_start.shape[0] - 1
    return (np.empty((n, nf + 2)), np.empty((n, m)), np.empty((m, m)), np.empty((m, nf + 2)),
            np.empty((nmax, nmax)), np.empty(nmax), np.empty((nmax, m + nf + 2)), np.empty(m, dtype=np.int64),
            np.empty((n_ch, m), dtype=np.int64), np.empty(n_ch, dtype=np.int64))


@njit(cache=True)
def elastic_gains(ma, fast, M, A, extra, G, gws):
    """G = P M^-1 [E, extra^T] (n_t x (n_f + 2)) at the tree terms M, A: the accelerations
    from unit forces on the elastic joints and from the two tree force vectors in the rows
    of ``extra`` (the torque's rate and curvature). Returns the pivot ratio of S (0 = singular).

    Chain by chain (eq 34): [Y_i, X_i] = M_i^-1 [A_i^T, E_i, extra_i^T] in one sweep,
    S = sum A_i Y_i; then G = X - Y S^-1 (A X). A chain's columns of A are non-zero in the few
    closure rows it takes part in (3 of a hexapod's 18 for a leg): only those are solved for.
    """
    X, Y, S, C, L, dinv, XY, piv, rows, n_rows = gws
    n = M.shape[0]
    m = A.shape[0]
    nf = fast.shape[0]
    nc = G.shape[1]
    S[:, :] = 0.0
    Y[:, :] = 0.0
    for c in range(ma.chain_start.shape[0] - 1):
        s = ma.chain_start[c]
        ne = ma.chain_start[c + 1] - s
        k = chain_block(M, A, s, ne, c, rows, n_rows, L, dinv)
        if k < 0:
            return 0.0
        for i in range(ne):
            for j in range(k):
                XY[i, j] = A[rows[c, j], s + i]
            for j in range(nf):
                XY[i, k + j] = 1.0 if fast[j] == s + i else 0.0
            for j in range(nf, nc):
                XY[i, k + j] = extra[j - nf, s + i]
        cholesky_solve_rows(L, dinv, ne, XY, 0, k + nc)
        for i in range(ne):
            for j in range(k):
                Y[s + i, rows[c, j]] = XY[i, j]
            for j in range(nc):
                X[s + i, j] = XY[i, k + j]  # for j < n_f zero outside the chain of fast joint j
        add_chain_schur(A, XY, s, ne, c, k, rows, S)
    for i in range(n):
        for j in range(nc):
            G[i, j] = X[i, j]
    if m == 0:
        return 1.0
    for j in range(nf):  # C = A X; column j of X lives in the chain of fast joint j
        c = ma.ji[fast[j], JI_CHAIN]
        for i in range(m):
            acc = 0.0
            for t in range(ma.chain_start[c], ma.chain_start[c + 1]):
                acc += A[i, t] * X[t, j]
            C[i, j] = acc
    for j in range(nf, nc):
        for i in range(m):
            acc = 0.0
            for t in range(n):
                acc += A[i, t] * X[t, j]
            C[i, j] = acc
    ratio = lu_factor(S, piv)
    if ratio == 0.0:
        return 0.0
    lu_solve_rows(S, piv, C)
    for c in range(ma.chain_start.shape[0] - 1):  # G -= Y C, Y's row i only in its chain's closure rows
        for i in range(ma.chain_start[c], ma.chain_start[c + 1]):
            for j in range(nc):
                acc = 0.0
                for a in range(n_rows[c]):
                    acc += Y[i, rows[c, a]] * C[rows[c, a], j]
                G[i, j] -= acc
    return ratio


@njit(cache=True)
def fastest_rate(G, fast, root_k, df):
    """Upper bound [rad/s] of the frozen spring system's fastest rate: Gershgorin on the
    symmetric K^1/2 B K^1/2 (B = E^T G; its eigenvalues are the squared natural
    frequencies), and on B D for the dampers' decay rates. root_k: the stiffnesses' square
    roots."""
    nf = fast.shape[0]
    w2 = 0.0
    d = 0.0
    for i in range(nf):
        rk = 0.0
        rd = 0.0
        for j in range(nf):
            b = abs(G[fast[i], j])
            rk += root_k[j] * b
            rd += b * df[j]
        w2 = max(w2, root_k[i] * rk)
        d = max(d, rd)
    return max(np.sqrt(w2), d)


@njit(cache=True)
def taylor_order(theta):
    """Terms K of a sub-step's Taylor series at theta rad of the fastest mode: the smallest K
    with theta^(K+1) / (K+1)! <= TAYLOR_TOL, at least 6 (the torque's quadratic forcing and
    its two integrals, exact whatever the springs)."""
    k = 1
    term = theta * theta / 2.0
    while (term > TAYLOR_TOL or k < 6) and k < 200:
        k += 1
        term *= theta / (k + 1)
    return k


# Elastic joints from which B f is summed column by column (contiguous, vectorised: 15-20 %
# faster at 12 on the Hexa at n_ek = 2) rather than as one dot product per row (faster at 6)
COLUMN_PRODUCT = 8


@njit(cache=True)
def phi_response(G, fast, kf, df, H, n_sub, order, bq, bv, u1, u2, xq, xv, fw, B, aq, av):
    """Deviation (xq, xv) after H of the frozen system from rest, forced by bq on q' and by
    bv + t u1 + t^2 u2 on qd' (t the time into the step): with u1 = u2 = 0 this is
    H phi1(H J) (bq, bv); with u2 = 0, u1 = w / H, H phi1(H J) (bq, bv) + H phi2(H J) (0, w).
    Where aq, av have n entries (else length 0) they receive the deviation's average over
    the step, int_0^H (xq, xv) dt / H.

    fw: (5, 5, n_f) and B (n_f x n_f) scratch. The elastic states take n_sub sub-steps of the
    Taylor series of the linear system's exact solution to ``order`` (the derivatives by its
    own recursion: d_k+1 = L d_k + the k-th derivative of the forcing), and the integrals
    p = int f, r = int p (f = -K dq_e - D dqd_e), for the averages rho = int r, the series of
    f's derivatives integrated term by term;
    every coordinate then follows in closed form: xv = H bv + H^2 u1 / 2 + H^3 u2 / 3 + G p(H),
    xq = H bq + H^2 bv / 2 + H^3 u1 / 6 + H^4 u2 / 12 + G r(H),
    aq = H bq / 2 + H^2 bv / 6 + H^3 u1 / 24 + H^4 u2 / 60 + G rho(H) / H, av = xq / H - bq.
    """
    nf = fast.shape[0]
    n = xq.shape[0]
    average = aq.shape[0] == n
    y, d, dn = fw[0], fw[1], fw[2]  # y: dq_e, dqd_e, p, r, rho; d, dn: derivatives of dq_e, dqd_e
    f = fw[3, 0]
    bqe, bve, u1e, u2e = fw[4, 0], fw[4, 1], fw[4, 2], fw[4, 3]
    for i in range(nf):
        bqe[i] = bq[fast[i]]
        bve[i] = bv[fast[i]]
        u1e[i] = u1[fast[i]]
        u2e[i] = u2[fast[i]]
        for j in range(nf):
            if nf < COLUMN_PRODUCT:
                B[i, j] = G[fast[i], j]
            else:  # transposed: the product below runs along its rows
                B[j, i] = G[fast[i], j]
    y[:, :] = 0.0
    h = H / n_sub
    for step in range(n_sub):
        t0 = step * h
        for j in range(nf):  # the integrals' start values carried over the sub-step
            y[4, j] += h * (y[3, j] + 0.5 * h * y[2, j])
            y[3, j] += h * y[2, j]
            d[0, j] = y[0, j]
            d[1, j] = y[1, j]
        coef = 1.0  # h^k / k!
        for k in range(order):
            # f's k-th derivative; it enters p, r, rho as h^(k+1) / (k+1)!, h^(k+2) / (k+2)!, ...
            for j in range(nf):
                f[j] = -kf[j] * d[0, j] - df[j] * d[1, j]
            acc = dn[1]
            if nf < COLUMN_PRODUCT:
                for i in range(nf):
                    a = 0.0
                    for j in range(nf):
                        a += B[i, j] * f[j]
                    acc[i] = a
                    dn[0, i] = d[1, i]
            else:  # column by column: the same sums, vectorised
                for i in range(nf):
                    acc[i] = 0.0
                    dn[0, i] = d[1, i]
                for j in range(nf):
                    fj = f[j]
                    Bj = B[j]
                    for i in range(nf):
                        acc[i] += Bj[i] * fj
            if k < 3:  # the forcing's derivatives at t0: bv + t u1 + t^2 u2, then u1 + 2 t u2, 2 u2
                for i in range(nf):
                    if k == 0:
                        acc[i] += bve[i] + t0 * (u1e[i] + t0 * u2e[i])
                        dn[0, i] += bqe[i]
                    elif k == 1:
                        acc[i] += u1e[i] + 2.0 * t0 * u2e[i]
                    else:
                        acc[i] += 2.0 * u2e[i]
            c1 = coef * h / (k + 1)
            c2 = c1 * h / (k + 2)
            for j in range(nf):
                y[0, j] += c1 * dn[0, j]
                y[1, j] += c1 * dn[1, j]
                y[2, j] += c1 * f[j]
                y[3, j] += c2 * f[j]
            if average:
                c3 = c2 * h / (k + 3)
                for j in range(nf):
                    y[4, j] += c3 * f[j]
            coef = c1
            d, dn = dn, d
    H2 = H * H
    for i in range(n):
        accq = H * bq[i] + H2 * (0.5 * bv[i] + H * (u1[i] / 6.0 + H * u2[i] / 12.0))
        accv = H * bv[i] + H2 * (0.5 * u1[i] + H * u2[i] / 3.0)
        for j in range(nf):
            accq += G[i, j] * y[3, j]
            accv += G[i, j] * y[2, j]
        xq[i] = accq
        xv[i] = accv
    if average:  # over the step: int_0^H x dt / H
        for j in range(nf):
            y[4, j] /= H
        for i in range(n):
            acc = 0.5 * H * bq[i] + H2 * (bv[i] / 6.0 + H * (u1[i] / 24.0 + H * u2[i] / 60.0))
            for j in range(nf):
                acc += G[i, j] * y[4, j]
            aq[i] = acc
            av[i] = xq[i] / H - bq[i]


AVERAGED = 0  # the etd2 integrator (module docstring)
IMPULSE = 1  # r-RESPA / impulse splitting, kept for the comparison in bench/benchmarks/bench_integrators.py
ETD2RK = 2  # N sampled at the step's ends, kept for the same comparison


@njit(cache=True)
def _spring_force(q, qd, fast, kf, df, rest, f):
    for j in range(fast.shape[0]):
        f[j] = -kf[j] * (q[fast[j]] - rest[j]) - df[j] * qd[fast[j]]


@njit(cache=True)
def _fail(cond, amax, g, info):
    """SINGULAR where the conditioning had fallen below NEAR_SINGULAR, else DIVERGED (as rk4_steps)."""
    info[1] = cond if cond < NEAR_SINGULAR else amax
    info[2] = g
    return SINGULAR if cond < NEAR_SINGULAR else DIVERGED


@njit(cache=True)
def _evaluate(form, ma, q, qd, tau_coef, s, tau, a, b, qdd_prev, acc, lam, ws, dt, singular_tol, limit, info):
    """Accelerations at (q, qd) and the time s into the call; status OK or why not."""
    n = q.shape[0]
    for i in range(n):
        tau[i] = tau_coef[0, i] + s * (tau_coef[1, i] + s * tau_coef[2, i])
    cond, g = accelerations_into(form, ma, q, qd, tau, a, b, qdd_prev, acc, lam, ws)
    qdd_prev[:] = acc
    motion, amax = _step_motion(qd, acc, dt)
    if not (_sane(q, qd, limit) and motion <= MAX_STEP_MOTION):
        return _fail(cond, amax, g, info), cond, g
    if cond < singular_tol:
        info[1] = cond
        info[2] = g
        return SINGULAR, cond, g
    return OK, cond, g


@njit(cache=True)
def exponential_steps(scheme, form, ma, q, qd, tau_coef, dt, n_steps, stab, alpha, beta, tol, singular_tol,
                      phase_step, qdd_prev, lam, info):
    """Advance (q, qd) in place by n_steps macro steps of dt (``scheme``: AVERAGED, or ETD2RK or the
    impulse splitting for the comparison bench).

    The contract of :func:`elastic_pm_dyn.sim.kernels.rk4_steps`: tau_coef (3, n_t) is the
    torque polynomial in the time since the call's start; info receives [steps done, worst
    conditioning, last gap]; returns OK, SINGULAR or DIVERGED with (q, qd) the state after
    the last good step. phase_step [rad]: sub-step of the frozen spring system against its
    fastest mode. L-D'A (an ODE in q_ae with Newton on q_p) is not supported: SINGULAR
    with info[1] = -1.
    """
    return exponential_steps_ws(scheme, form, ma, q, qd, tau_coef, dt, n_steps, stab, alpha, beta, tol,
                                singular_tol, phase_step, qdd_prev, lam, info, etd2_workspace(ma))


@njit(cache=True)
def etd2_workspace(ma):
    """The spring data and work arrays of :func:`exponential_steps_ws`, allocated once for
    many calls (sim/batch.py): every array is written before it is read in each step, or
    never written, so reusing them changes no result."""
    n = ma.jf.shape[0]
    fast = fast_joints(ma)
    nf = fast.shape[0]
    kf, df, rest = np.empty(nf), np.empty(nf), np.empty(nf)
    for j in range(nf):
        kf[j] = ma.jf[fast[j], JF_STIFFNESS]
        df[j] = ma.jf[fast[j], JF_DAMPING]
        rest[j] = ma.jf[fast[j], JF_REST]
    vectors = np.empty((11, n))  # tau, acc0, acc1, q1, v1, xq, xv, bq, bv, u1, u2
    return (fast, kf, df, rest, workspace(ma), gains_workspace(ma, fast), projection_workspace(ma),
            np.empty((n, nf + 2)), np.zeros((2, n)), vectors, np.empty((5, 5, nf)), np.empty((nf, nf)),
            np.empty((4, nf)), np.zeros(n), (np.empty((nf, nf)), np.empty(nf), np.empty(nf), np.empty(n)))


@njit(cache=True)
def exponential_steps_ws(scheme, form, ma, q, qd, tau_coef, dt, n_steps, stab, alpha, beta, tol, singular_tol,
                         phase_step, qdd_prev, lam, info, ew):
    """:func:`exponential_steps` on the work arrays ``ew`` of :func:`etd2_workspace`."""
    n = q.shape[0]
    info[0] = 0.0
    if form == LDA:
        info[1] = -1.0
        info[2] = np.nan
        return SINGULAR
    a = alpha if stab & STAB_BAUMGARTE else 0.0
    b = beta if stab & STAB_BAUMGARTE else 0.0
    fast, kf, df, rest, ws, gws, pws, G, extra, vectors, fw, B, ff, zero, sw = ew
    nf = fast.shape[0]
    tau, acc0, acc1, q1, v1, xq, xv, bq, bv, u1, u2 = (vectors[0], vectors[1], vectors[2], vectors[3], vectors[4],
                                                       vectors[5], vectors[6], vectors[7], vectors[8], vectors[9],
                                                       vectors[10])
    f0, f1, sk, root_k = ff[0], ff[1], ff[2], ff[3]
    for j in range(nf):
        root_k[j] = np.sqrt(kf[j])
        sk[j] = dt * root_k[j]
    worst = 1.0
    gap = 0.0
    limit = MAX_STEP_MOTION / dt
    for step in range(n_steps):
        s0 = step * dt
        status, cond, gap = _evaluate(form, ma, q, qd, tau_coef, s0, tau, a, b, qdd_prev, acc0, lam, ws, dt,
                                      singular_tol, limit, info)
        if status != OK:
            return status
        worst = min(worst, cond)
        M, A = ws[0], ws[5]
        for i in range(n):  # tau(s0 + t) = tau(s0) + t d1 + t^2 d2
            extra[0, i] = tau_coef[1, i] + 2.0 * s0 * tau_coef[2, i]
            extra[1, i] = tau_coef[2, i]
        ratio = elastic_gains(ma, fast, M, A, extra, G, gws)
        if ratio < singular_tol:
            info[1] = ratio
            info[2] = gap
            return SINGULAR
        rate = fastest_rate(G, fast, root_k, df)
        n_sub = max(1, int(np.ceil(dt * rate / phase_step)))
        if not n_sub <= MAX_SUBSTEPS:
            info[1] = np.max(np.abs(acc0))
            info[2] = gap
            return DIVERGED
        order = taylor_order(dt * rate / n_sub)
        if scheme != IMPULSE:
            # exponential Euler x(t) = z0 + t phi1(tJ) F(z0), the torque's change over the step
            # (P M^-1 (t d1 + t^2 d2), frozen like J) integrated with it; its average too
            for i in range(n):
                u1[i] = G[i, nf]
                u2[i] = G[i, nf + 1]
            mq, mv = bq, bv  # the average deviation (bq, bv serve the impulse splitting)
            phi_response(G, fast, kf, df, dt, n_sub, order, qd, acc0, u1, u2, xq, xv, fw, B, mq, mv)
            # the stage where N is evaluated: the predictor's average (AVERAGED) or its end (ETD2RK)
            sq, sv = (mq, mv) if scheme == AVERAGED else (xq, xv)
            for i in range(n):
                q1[i] = q[i] + sq[i]
                v1[i] = qd[i] + sv[i]
            # F there with the torque of the step's start: its change is in the forcing above
            status, cond, g = _evaluate(form, ma, q1, v1, tau_coef, s0, tau, a, b, qdd_prev, acc1, lam, ws,
                                        dt, singular_tol, limit, info)
            if status != OK:
                return status
            worst = min(worst, cond)
            # w = N(stage) - N(z0) = F(stage) - F(z0) - J (stage - z0): only its velocity rows are not zero
            for j in range(nf):
                f0[j] = -kf[j] * sq[fast[j]] - df[j] * sv[fast[j]]
            for i in range(n):
                acc = acc1[i] - acc0[i]
                for j in range(nf):
                    acc -= G[i, j] * f0[j]
                u1[i] = acc
                q1[i] = q[i] + xq[i]  # the predictor's end, x(H)
                v1[i] = qd[i] + xv[i]
            if scheme == AVERAGED:  # w held over the step: H phi1(HJ) (0, w)
                phi_response(G, fast, kf, df, dt, n_sub, order, zero, u1, zero, zero, xq, xv, fw, B, zero[:0],
                             zero[:0])
            else:  # a ramp from 0 at z0 to w at x(H): H phi2(HJ) (0, w)
                for i in range(n):
                    u1[i] /= dt
                phi_response(G, fast, kf, df, dt, n_sub, order, zero, zero, u1, zero, xq, xv, fw, B, zero[:0],
                             zero[:0])
            for i in range(n):
                q1[i] += xq[i]
                v1[i] += xv[i]
        else:
            # kick H/2 with everything but the springs, springs alone over H, kick H/2
            _spring_force(q, qd, fast, kf, df, rest, f0)
            for i in range(n):
                acc = acc0[i]
                for j in range(nf):
                    acc -= G[i, j] * f0[j]
                bq[i] = qd[i] + 0.5 * dt * acc
                s = 0.0
                for j in range(nf):
                    s += G[i, j] * f0[j]
                bv[i] = s
            # the springs' force changes with the kicked velocity too: restart from it
            for j in range(nf):
                f0[j] = -df[j] * (bq[fast[j]] - qd[fast[j]])
            for i in range(n):
                s = 0.0
                for j in range(nf):
                    s += G[i, j] * f0[j]
                bv[i] += s
            phi_response(G, fast, kf, df, dt, n_sub, order, bq, bv, zero, zero, xq, xv, fw, B, zero[:0], zero[:0])
            for i in range(n):
                q1[i] = q[i] + xq[i]
                v1[i] = bq[i] + xv[i]
            status, cond, g = _evaluate(form, ma, q1, v1, tau_coef, s0 + dt, tau, a, b, qdd_prev, acc1, lam, ws,
                                        dt, singular_tol, limit, info)
            if status != OK:
                return status
            worst = min(worst, cond)
            ratio = elastic_gains(ma, fast, ws[0], ws[5], extra, G, gws)
            if ratio < singular_tol:
                info[1] = ratio
                info[2] = g
                return SINGULAR
            _spring_force(q1, v1, fast, kf, df, rest, f1)
            for i in range(n):
                acc = acc1[i]
                for j in range(nf):
                    acc -= G[i, j] * f1[j]
                v1[i] += 0.5 * dt * acc
        if not _sane(q1, v1, limit):
            return unsound_step(worst, acc0, acc1, gap, info)
        q[:] = q1
        qd[:] = v1
        if stab & STAB_PROJECTION:
            # with the gains' Y, S^-1 (at the step's start; IMPULSE's at its end): no factorisation
            project_springs(ma, q, qd, tol, np.int64(3), pws, fast, sk, G, gws[1], gws[2], gws[7], gws[8], gws[9], sw)
        info[0] = step + 1
    info[1] = worst
    info[2] = gap
    return OK


def substeps_at(mech, q: np.ndarray, dt: float) -> tuple[float, int]:
    """(bound of the fastest frozen rate [rad/s], sub-steps per step of dt at the default
    phase step) at the pose q: what ETD2's step costs there."""
    ma = mech.arrays
    n = mech.n
    fast = fast_joints(ma)
    t = mech.terms(q)
    G = np.empty((n, fast.shape[0] + 2))
    elastic_gains(ma, fast, t.M, t.A, np.zeros((2, n)), G, gains_workspace(ma, fast))
    rate = fastest_rate(G, fast, np.sqrt(ma.jf[fast, JF_STIFFNESS]), ma.jf[fast, JF_DAMPING].copy())
    return rate, max(1, int(np.ceil(dt * rate / DEFAULT_PHASE_STEP)))
