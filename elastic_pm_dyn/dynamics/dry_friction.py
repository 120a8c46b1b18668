"""Coulomb's law at rest: the friction forces of the joints that do not slide.

A joint with dry friction F (MJCF ``frictionloss``, URDF ``<dynamics friction>``) and no slip
speed (layout.JF_SLIP = 0, the default) feels -F sign(qd) while it slides (|qd| > STICK_SPEED,
in the tree's bias h, kinematics/kernels.py). At rest its force f is whatever keeps it at rest,
as long as |f| <= F; beyond, it slips, against F. For the joints at rest together (S), the
accelerations are affine in their friction forces, a = a0 + G f, with a0 the accelerations
without them and G the machine's response to unit forces on them (its inverse inertia on S,
the loops' constraints included: symmetric, positive semi-definite). Coulomb's law is then the
box-constrained problem

    -F <= f <= F,   a_j = 0 where |f_j| < F_j,   a_j >= 0 where f_j = -F_j,   a_j <= 0 where f_j = F_j,

the optimality conditions of min 1/2 f^T G f + a0^T f over the box (a convex problem: unique
accelerations). :func:`coulomb_at_rest` solves it by projected Gauss-Seidel and then solves the
sticking joints' forces exactly on the set it found. The joints that stick get an acceleration of
exactly 0 (dynamics/evaluate.py), so that a stick stays exactly at rest in any integrator whose
stages are sums of accelerations.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.model.layout import JF_COULOMB, JF_SLIP, STICK_SPEED
from elastic_pm_dyn.small_linalg import lu_factor, lu_solve

MAX_SWEEPS = 500  # projected Gauss-Seidel sweeps (one joint at rest: one sweep)
SWEEP_TOL = 1e-15  # a sweep changing no force by more than this share of its F ends them
LOCKED = 1e-12  # a joint whose response G_jj is below this share of the largest cannot move
EXACT = 1e-12  # an acceleration below this share of its terms is a rounding error of 0


@njit(cache=True)
def count_at_rest(jf, qd):
    """How many joints have Coulomb friction (no slip speed) and are at rest (|qd| <= STICK_SPEED)."""
    c = 0
    for k in range(jf.shape[0]):
        if jf[k, JF_COULOMB] > 0.0 and jf[k, JF_SLIP] == 0.0 and abs(qd[k]) <= STICK_SPEED:
            c += 1
    return c


@njit(cache=True)
def joints_at_rest(jf, qd, c):
    """The indices of the ``c`` joints :func:`count_at_rest` counts."""
    idx = np.empty(c, dtype=np.int64)
    i = 0
    for k in range(jf.shape[0]):
        if jf[k, JF_COULOMB] > 0.0 and jf[k, JF_SLIP] == 0.0 and abs(qd[k]) <= STICK_SPEED:
            idx[i] = k
            i += 1
    return idx


@njit(cache=True)
def coulomb_at_rest(a0, G, F, f, stick):
    """The friction forces f (into ``f``) of joints at rest with accelerations a0 without them,
    response G to unit forces and friction F: Coulomb's law (module doc). ``stick[j]``: joint j
    stays at rest (|f_j| < F_j, or it cannot move at all)."""
    c = a0.shape[0]
    scale = 0.0
    for j in range(c):
        scale = max(scale, G[j, j])
    f[:] = 0.0
    for _ in range(MAX_SWEEPS):
        change = 0.0
        for j in range(c):
            if G[j, j] <= LOCKED * scale:
                continue
            r = a0[j]
            for k in range(c):
                r += G[j, k] * f[k]
            new = min(max(f[j] - r / G[j, j], -F[j]), F[j])
            change = max(change, abs(new - f[j]) / F[j])
            f[j] = new
        if change <= SWEEP_TOL:
            break
    for j in range(c):  # at rest where |f| < F; where |f| = F too if that leaves no acceleration (the bound reached)
        r = a0[j]
        for k in range(c):
            r += G[j, k] * f[k]
        stick[j] = G[j, j] <= LOCKED * scale or abs(f[j]) < F[j] or abs(r) <= EXACT * (abs(a0[j]) + F[j] * G[j, j])
    _polish(a0, G, F, f, stick, scale)


@njit(cache=True)
def _polish(a0, G, F, f, stick, scale):
    """The sticking joints' forces solved exactly (G_SS f_S = -(a0_S + G_SC f_C)) where the solution
    stays within their bounds; else the Gauss-Seidel forces are kept."""
    c = a0.shape[0]
    rows = np.empty(c, dtype=np.int64)
    ns = 0
    for j in range(c):
        if stick[j] and G[j, j] > LOCKED * scale:
            rows[ns] = j
            ns += 1
    if ns == 0:
        return
    S = np.empty((ns, ns))
    x = np.empty(ns)
    for i in range(ns):
        r = a0[rows[i]]
        for k in range(c):
            if not stick[k]:
                r += G[rows[i], k] * f[k]
        x[i] = -r
        for j in range(ns):
            S[i, j] = G[rows[i], rows[j]]
    piv = np.empty(ns, dtype=np.int64)
    if lu_factor(S, piv) < 1e-13:  # joints at rest coupled so that their forces are not unique: Gauss-Seidel's
        return
    lu_solve(S, piv, x)
    for i in range(ns):
        if not abs(x[i]) <= F[rows[i]]:
            return
    for i in range(ns):
        f[rows[i]] = x[i]
