"""Compiled per-chain kinematics and dynamics terms.

For each serial chain i (paper, eq 33) this computes, in one forward sweep:
- the mass matrix M_i (bodies plus reflected rotor inertia),
- the bias h_i = C_i qd_i + eta_i + K_i (q_i - q_rest) + D_i qd_i (Coriolis/centrifugal,
  gravity, springs, dampers and viscous friction), i.e. everything but M_i qdd_i,
- the positions of the chain's attachment points (its end, platform joints), their
  Jacobians J_i and bias accelerations Jdot_i qd_i.

Method: velocities and bias accelerations (qdd = 0) of every body are propagated from the
base outwards; generalised forces are projected with the body Jacobians (Kane's form of
Newton-Euler). All vectors are world-frame. Chains are independent, so the tree terms of
eq 19 are the chain terms stacked block-diagonally.
"""

import numpy as np
from numba import njit

from elastic_pm_dyn.kinematics import vec3 as v
from elastic_pm_dyn.model.layout import (
    JF_AXIS,
    JF_COM,
    JF_DAMPING,
    JF_FRICTION,
    JF_INERTIA,
    JF_MASS,
    JF_ORIGIN_P,
    JF_ORIGIN_R,
    JF_REST,
    JF_ROTOR,
    JF_STIFFNESS,
    JI_TYPE,
)

IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
ZERO = (0.0, 0.0, 0.0)


@njit(cache=True)
def _store(a, i, t):
    a[i, 0] = t[0]
    a[i, 1] = t[1]
    a[i, 2] = t[2]


@njit(cache=True)
def chain_terms(jf, ji, chain, s, e, points, point_chain, grav, q, qd, M, h, J, a_pt, p_pt, wz, wo, jv, jw):
    """Terms of the chain with index ``chain``, whose joints are tree indices s..e-1 (written in place).

    M (n_t x n_t) receives its diagonal block, h its segment; for every attachment point
    of the chain (all on its last body), J (n_points x 3 x n_t) receives its Jacobian
    columns, a_pt / p_pt (n_points x 3) its bias acceleration and position.
    wz, wo, jv, jw are (n_t, 3) scratch arrays.
    """
    g = (grav[0], grav[1], grav[2])
    R = IDENTITY
    o = ZERO
    w = ZERO  # angular velocity of the current body
    al = ZERO  # its angular bias acceleration
    ao = ZERO  # bias acceleration of its origin o
    for k in range(s, e):
        R0 = v.row9(jf, k, JF_ORIGIN_R)
        ax = v.row3(jf, k, JF_AXIS)
        oj = v.add(o, v.mv(R, v.row3(jf, k, JF_ORIGIN_P)))
        Rj = v.mm(R, R0)
        z = v.mv(Rj, ax)
        zq = v.scale(z, qd[k])
        if ji[k, JI_TYPE] == 1:  # prismatic: the origin slides along z
            on = v.add(oj, v.scale(z, q[k]))
            d = v.sub(on, o)
            ao = v.add(v.add(ao, v.cross(al, d)),
                       v.add(v.cross(w, v.cross(w, d)), v.scale(v.cross(w, zq), 2.0)))
            o = on
            R = Rj
        else:  # revolute: the child frame turns about z through oj
            d = v.sub(oj, o)
            ao = v.add(v.add(ao, v.cross(al, d)), v.cross(w, v.cross(w, d)))
            al = v.add(al, v.cross(w, zq))
            w = v.add(w, zq)
            o = oj
            R = v.mm(Rj, v.axis_rotation(ax, q[k]))
        _store(wz, k, z)
        _store(wo, k, o)

        m = jf[k, JF_MASS]
        if m <= 0.0:
            continue
        c = v.add(o, v.mv(R, v.row3(jf, k, JF_COM)))
        r = v.sub(c, o)
        ac = v.add(v.add(ao, v.cross(al, r)), v.cross(w, v.cross(w, r)))
        Ic = v.mmt(v.mm(R, v.row9(jf, k, JF_INERTIA)), R)
        for j in range(s, k + 1):
            zj = (wz[j, 0], wz[j, 1], wz[j, 2])
            if ji[j, JI_TYPE] == 1:
                _store(jv, j, zj)
                _store(jw, j, ZERO)
            else:
                _store(jv, j, v.cross(zj, v.sub(c, (wo[j, 0], wo[j, 1], wo[j, 2]))))
                _store(jw, j, zj)
        f = v.scale(v.sub(ac, g), m)
        t_rot = v.add(v.mv(Ic, al), v.cross(w, v.mv(Ic, w)))
        for a in range(s, k + 1):
            jva = (jv[a, 0], jv[a, 1], jv[a, 2])
            jwa = (jw[a, 0], jw[a, 1], jw[a, 2])
            h[a] += v.dot(jva, f) + v.dot(jwa, t_rot)
            Ijwa = v.mv(Ic, jwa)
            for b in range(s, a + 1):
                val = m * v.dot(jva, (jv[b, 0], jv[b, 1], jv[b, 2])) + \
                    v.dot((jw[b, 0], jw[b, 1], jw[b, 2]), Ijwa)
                M[a, b] += val
                if a != b:
                    M[b, a] += val

    for ip in range(points.shape[0]):
        if point_chain[ip] != chain:
            continue
        pt = v.add(o, v.mv(R, (points[ip, 0], points[ip, 1], points[ip, 2])))
        r = v.sub(pt, o)
        at = v.add(v.add(ao, v.cross(al, r)), v.cross(w, v.cross(w, r)))
        for i in range(3):
            p_pt[ip, i] = pt[i]
            a_pt[ip, i] = at[i]
        for j in range(s, e):
            zj = (wz[j, 0], wz[j, 1], wz[j, 2])
            col = zj if ji[j, JI_TYPE] == 1 else v.cross(zj, v.sub(pt, (wo[j, 0], wo[j, 1], wo[j, 2])))
            J[ip, 0, j] = col[0]
            J[ip, 1, j] = col[1]
            J[ip, 2, j] = col[2]
    for k in range(s, e):
        M[k, k] += jf[k, JF_ROTOR]
        h[k] += jf[k, JF_STIFFNESS] * (q[k] - jf[k, JF_REST]) + \
            (jf[k, JF_DAMPING] + jf[k, JF_FRICTION]) * qd[k]


@njit(cache=True)
def tree_terms(jf, ji, chain_start, points, point_chain, grav, q, qd, M, h, J, a_pt, p_pt):
    """Tree structure terms (eq 19) chain by chain (eq 33).

    M (n_t x n_t) block diagonal, h (n_t), J (n_points x 3 x n_t) attachment-point
    Jacobians in tree columns, a_pt / p_pt (n_points x 3) their bias accelerations
    Jdot qd and positions. Points 0..n_chains-1 are the chain ends.
    """
    n = q.shape[0]
    tree_terms_into(jf, ji, chain_start, points, point_chain, grav, q, qd, M, h, J, a_pt, p_pt,
                    np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)))


@njit(cache=True)
def tree_terms_into(jf, ji, chain_start, points, point_chain, grav, q, qd, M, h, J, a_pt, p_pt, wz, wo, jv, jw):
    """:func:`tree_terms` with its four (n_t x 3) work arrays given (no allocation)."""
    M[:, :] = 0.0
    h[:] = 0.0
    J[:, :, :] = 0.0
    for c in range(chain_start.shape[0] - 1):
        chain_terms(jf, ji, c, chain_start[c], chain_start[c + 1], points, point_chain, grav, q, qd,
                    M, h, J, a_pt, p_pt, wz, wo, jv, jw)


@njit(cache=True)
def closure_rows(closure_pairs, closure_components, J, a_pt, p_pt, A, gamma, res):
    """Closure residual h(q_t) (eq 8), its Jacobian A = dh/dq_t and gamma = -Adot qd_t.

    Row block k holds S (p_a - p_b) for the k-th point pair (a, b), so that
    A qdd_t = gamma holds on the constraint manifold.
    """
    nc = closure_components.shape[0]
    for k in range(closure_pairs.shape[0]):
        pa = closure_pairs[k, 0]
        pb = closure_pairs[k, 1]
        for i in range(nc):
            comp = closure_components[i]
            r = k * nc + i
            for j in range(A.shape[1]):  # element-wise: a row expression would allocate
                A[r, j] = J[pa, comp, j] - J[pb, comp, j]
            res[r] = p_pt[pa, comp] - p_pt[pb, comp]
            gamma[r] = -(a_pt[pa, comp] - a_pt[pb, comp])


@njit(cache=True)
def chain_points(jf, ji, chain_start, points, point_chain, q, origins, coms, p_pt):
    """Forward kinematics only: joint origins, body centres of mass, attachment points (world)."""
    for c in range(chain_start.shape[0] - 1):
        R = IDENTITY
        o = ZERO
        for k in range(chain_start[c], chain_start[c + 1]):
            ax = v.row3(jf, k, JF_AXIS)
            oj = v.add(o, v.mv(R, v.row3(jf, k, JF_ORIGIN_P)))
            Rj = v.mm(R, v.row9(jf, k, JF_ORIGIN_R))
            if ji[k, JI_TYPE] == 1:
                o = v.add(oj, v.scale(v.mv(Rj, ax), q[k]))
                R = Rj
            else:
                o = oj
                R = v.mm(Rj, v.axis_rotation(ax, q[k]))
            _store(origins, k, o)
            _store(coms, k, v.add(o, v.mv(R, v.row3(jf, k, JF_COM))))
        for ip in range(points.shape[0]):
            if point_chain[ip] == c:
                _store(p_pt, ip, v.add(o, v.mv(R, (points[ip, 0], points[ip, 1], points[ip, 2]))))
