"""Compiled per-subtree kinematics and dynamics terms.

The tree is cut at the closure into subtrees from the base (a serial chain is the
special case where every joint's parent is the previous joint). For each subtree i
(paper, eq 33) this computes, in one forward sweep:
- the mass matrix M_i (bodies plus reflected rotor inertia),
- the bias h_i = C_i qd_i + eta_i + K_i (q_i - q_rest) + D_i qd_i (Coriolis/centrifugal,
  gravity, springs, dampers and viscous friction), i.e. everything but M_i qdd_i,
- the positions of the attachment points on its bodies (chain ends, platform joints,
  closure frames on any body), their Jacobians J_i and bias accelerations Jdot_i qd_i.

Method: velocities and bias accelerations (qdd = 0) of every body are propagated from the
base outwards, each body from its parent's; generalised forces are projected with the body
Jacobians (Kane's form of Newton-Euler), whose columns are the body's ancestors' joints,
so a subtree's mass matrix couples a joint only with its ancestors and descendants. All
vectors are world-frame. Subtrees are independent, so the tree terms of eq 19 are the
subtree terms stacked block-diagonally.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from elastic_pm_dyn.kinematics import vec3 as v
from elastic_pm_dyn.model.layout import (
    JF_AXIS,
    JF_COM,
    JF_COULOMB,
    JF_DAMPING,
    JF_FRICTION,
    JF_INERTIA,
    JF_MASS,
    JF_ORIGIN_P,
    JF_ORIGIN_R,
    JF_REST,
    JF_ROTOR,
    JF_SLIP,
    JF_STIFFNESS,
    JI_KEEP,
    JI_PARENT,
    JI_SUBTREE,
    JI_TYPE,
    STICK_SPEED,
)

IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
ZERO = (0.0, 0.0, 0.0)


class Tree(NamedTuple):
    """The model arrays the tree sweep reads: a mechanism's own ``Mechanism.arrays`` has them
    under the same names and is passed as it is (this bundle is for callers holding the parts)."""

    jf: np.ndarray  # (n_t, ...) joint floats (model.layout JF_*)
    ji: np.ndarray  # (n_t, ...) joint integers (JI_*)
    chain_start: np.ndarray  # (n_chains + 1,) first tree index of each subtree
    points: np.ndarray  # (n_points, 3 or 12) attachment points in their bodies' frames
    point_body: np.ndarray  # (n_points,) the body (tree index) of each point, -1 the base
    gravity: np.ndarray  # (3,) in the world


class TreeTerms(NamedTuple):
    """What the sweep writes (eq 19): M (n_t x n_t; 0 x 0: not asked), h (n_t; empty: the
    kinematics alone), J (n_points x 3 or 6 x n_t), a_pt (n_points x 3 or 6), p_pt (n_points x 3 or 12)."""

    M: np.ndarray
    h: np.ndarray
    J: np.ndarray
    a_pt: np.ndarray
    p_pt: np.ndarray


class TreeSweep(NamedTuple):
    """The sweep's scratch: joint axes wz and origins wo in the world, a body centre's
    Jacobian columns jv (linear) and jw (angular), all (n_t, 3), and the stored frames fr (n_t, 18)."""

    wz: np.ndarray
    wo: np.ndarray
    jv: np.ndarray
    jw: np.ndarray
    fr: np.ndarray


@njit(cache=True)
def _store(a, i, t):
    a[i, 0] = t[0]
    a[i, 1] = t[1]
    a[i, 2] = t[2]


@njit(cache=True)
def _load_frame(fr, wo, k):
    """Body k's stored R, origin, angular velocity, angular and origin bias accelerations."""
    R = (fr[k, 0], fr[k, 1], fr[k, 2], fr[k, 3], fr[k, 4], fr[k, 5], fr[k, 6], fr[k, 7], fr[k, 8])
    return (R, (wo[k, 0], wo[k, 1], wo[k, 2]), (fr[k, 9], fr[k, 10], fr[k, 11]),
            (fr[k, 12], fr[k, 13], fr[k, 14]), (fr[k, 15], fr[k, 16], fr[k, 17]))


@njit(cache=True, inline="always")
def _jacobian_column(ji, wz, wo, c, jv, jw, j):
    """Column j of the Jacobian of the point c (velocity jv, angular velocity jw)."""
    zj = (wz[j, 0], wz[j, 1], wz[j, 2])
    if ji[j, JI_TYPE] == 1:
        _store(jv, j, zj)
        _store(jw, j, ZERO)
    else:
        _store(jv, j, v.cross(zj, v.sub(c, (wo[j, 0], wo[j, 1], wo[j, 2]))))
        _store(jw, j, zj)


@njit(cache=True)
def _project(jv, jw, f, t_rot, Ic, h, a):
    """h[a] += the body's inertial and gravity force projected on column a; returns column
    a's velocity part and Ic times its angular part."""
    jva = (jv[a, 0], jv[a, 1], jv[a, 2])
    jwa = (jw[a, 0], jw[a, 1], jw[a, 2])
    h[a] += v.dot(jva, f) + v.dot(jwa, t_rot)
    return jva, v.mv(Ic, jwa)


@njit(cache=True)
def _mass_entry(jv, jw, m, jva, Ijwa, M, a, b):
    """The body's share of M[a, b] = M[b, a]."""
    val = m * v.dot(jva, (jv[b, 0], jv[b, 1], jv[b, 2])) + v.dot((jw[b, 0], jw[b, 1], jw[b, 2]), Ijwa)
    M[a, b] += val
    if a != b:
        M[b, a] += val


@njit(cache=True)
def _point_column(ji, wz, wo, pt, J, ip, j, spatial):
    """Column j of point ip's Jacobian (its angular velocity's too where ``spatial``)."""
    zj = (wz[j, 0], wz[j, 1], wz[j, 2])
    prismatic = ji[j, JI_TYPE] == 1
    col = zj if prismatic else v.cross(zj, v.sub(pt, (wo[j, 0], wo[j, 1], wo[j, 2])))
    J[ip, 0, j] = col[0]
    J[ip, 1, j] = col[1]
    J[ip, 2, j] = col[2]
    if spatial and not prismatic:
        J[ip, 3, j] = zj[0]
        J[ip, 4, j] = zj[1]
        J[ip, 5, j] = zj[2]


@njit(cache=True, inline="always")
def _body_loads(jf, k, m, g, R, o, w, al, ao):
    """Body k of mass m (frame R at o, rates w, al, ao): its centre c, world inertia Ic, and the
    inertial-plus-gravity force f and moment t_rot that its Jacobian columns project (Kane)."""
    c = v.add(o, v.mv(R, v.row3(jf, k, JF_COM)))
    r = v.sub(c, o)
    ac = v.add(v.add(ao, v.cross(al, r)), v.cross(w, v.cross(w, r)))
    Ic = v.mmt(v.mm(R, v.row9(jf, k, JF_INERTIA)), R)
    return c, Ic, v.scale(v.sub(ac, g), m), v.add(v.mv(Ic, al), v.cross(w, v.mv(Ic, w)))


@njit(cache=True, inline="always")
def _joint_elements(jf, s, e, q, qd, M, h):
    """What acts in the joints s..e-1 themselves: rotor inertia on M's diagonal (if M is not
    empty); spring, damper, viscous and dry friction forces in h. Dry (Coulomb) friction: F sign(qd)
    on a sliding joint (|qd| > STICK_SPEED), none on one at rest, whose force Coulomb's law leaves
    to the accelerations (dynamics/dry_friction.py); regularised instead, F tanh(qd / v_s), where
    the joint has a slip speed v_s > 0."""
    mass = M.shape[0] > 0
    for k in range(s, e):
        if mass:
            M[k, k] += jf[k, JF_ROTOR]
        h[k] += jf[k, JF_STIFFNESS] * (q[k] - jf[k, JF_REST]) + \
            (jf[k, JF_DAMPING] + jf[k, JF_FRICTION]) * qd[k]
        if jf[k, JF_COULOMB] != 0.0:
            if jf[k, JF_SLIP] > 0.0:
                h[k] += jf[k, JF_COULOMB] * np.tanh(qd[k] / jf[k, JF_SLIP])
            elif qd[k] > STICK_SPEED:
                h[k] += jf[k, JF_COULOMB]
            elif qd[k] < -STICK_SPEED:
                h[k] -= jf[k, JF_COULOMB]


@njit(cache=True, inline="always")
def _joint_step(jf, ji, k, q, qd, R, o, w, al, ao):
    """Body k's frame R, origin o, angular velocity w and bias accelerations al, ao from its
    parent body's (all world-frame), and its joint axis z in the world."""
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
        return Rj, on, w, al, ao, z
    # revolute: the child frame turns about z through oj
    d = v.sub(oj, o)
    ao = v.add(v.add(ao, v.cross(al, d)), v.cross(w, v.cross(w, d)))
    al = v.add(al, v.cross(w, zq))
    w = v.add(w, zq)
    return v.mm(Rj, v.axis_rotation(ax, q[k])), oj, w, al, ao, z


@njit(cache=True)
def serial_chain_terms(tree, s, e, q, qd, out, sweep):
    """:func:`subtree_terms` of a serial chain (joint k's parent k - 1) whose points all sit
    on its last body and have no frames (``ji[s, JI_SUBTREE] == 0``): the sweep carries one
    body's frame and rates along, every body's Jacobian has the columns s..k. The general
    sweep's parent lookups and stored frames cost such a chain 7 % (bench/benchmarks/bench_tree_sweep.py).
    An empty M (0 x 0) and h ask for the kinematics alone (points, their Jacobians and bias
    accelerations): no inertia, M and h untouched; an empty M with a full h for the bias
    forces without the mass matrix. ``tree``: :class:`Tree` (or ``Mechanism.arrays``), ``out``:
    :class:`TreeTerms`, ``sweep``: :class:`TreeSweep`."""
    jf, ji, points, point_body, grav = tree.jf, tree.ji, tree.points, tree.point_body, tree.gravity
    M, h, J, a_pt, p_pt = out
    wz, wo, jv, jw = sweep.wz, sweep.wo, sweep.jv, sweep.jw
    g = (grav[0], grav[1], grav[2])
    inertia = h.shape[0] > 0
    mass = M.shape[0] > 0
    R = IDENTITY
    o = ZERO
    w = ZERO  # angular velocity of the current body
    al = ZERO  # its angular bias acceleration
    ao = ZERO  # bias acceleration of its origin o
    for k in range(s, e):
        R, o, w, al, ao, z = _joint_step(jf, ji, k, q, qd, R, o, w, al, ao)
        _store(wz, k, z)
        _store(wo, k, o)

        m = jf[k, JF_MASS]
        if m <= 0.0 or not inertia:
            continue
        c, Ic, f, t_rot = _body_loads(jf, k, m, g, R, o, w, al, ao)
        for j in range(s, k + 1):
            _jacobian_column(ji, wz, wo, c, jv, jw, j)
        for a in range(s, k + 1):
            jva = (jv[a, 0], jv[a, 1], jv[a, 2])
            jwa = (jw[a, 0], jw[a, 1], jw[a, 2])
            h[a] += v.dot(jva, f) + v.dot(jwa, t_rot)
            if not mass:
                continue
            Ijwa = v.mv(Ic, jwa)
            for b in range(s, a + 1):
                val = m * v.dot(jva, (jv[b, 0], jv[b, 1], jv[b, 2])) + \
                    v.dot((jw[b, 0], jw[b, 1], jw[b, 2]), Ijwa)
                M[a, b] += val
                if a != b:
                    M[b, a] += val

    for ip in range(points.shape[0]):
        if point_body[ip] < s or point_body[ip] >= e:
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
    if inertia:
        _joint_elements(jf, s, e, q, qd, M, h)


@njit(cache=True)
def subtree_terms(tree, s, e, q, qd, out, sweep):
    """Terms of the subtree whose joints are tree indices s..e-1 (written in place).

    Each joint's parent (``ji[k, JI_PARENT]``) is -1 (the base) or an earlier joint of the
    subtree; a serial chain has parent k - 1. Each body continues from its parent's frame
    and rates (stored in fr for the bodies flagged JI_KEEP), its Jacobian's columns are its
    ancestors' joints. M (n_t x n_t) receives the subtree's diagonal block, h its segment;
    every attachment point on one of its bodies (``point_body``) gets its Jacobian columns
    in J (n_points x 3 x n_t; rows 3-5 the angular velocity's where J has 6), its bias
    acceleration in a_pt and position in p_pt (n_points x 3; with 12 columns also the
    world orientation of the point's frame, row-major, ``points`` then holding its
    orientation in the body frame). ``tree``: :class:`Tree` (or ``Mechanism.arrays``), ``out``:
    :class:`TreeTerms` (M, h, J, a_pt, p_pt), ``sweep``: :class:`TreeSweep` (the scratch).
    An empty M (0 x 0) and h ask for the kinematics alone: no inertia, M and h untouched; an
    empty M with a full h for the bias forces without the mass matrix.
    """
    jf, ji, points, point_body, grav = tree.jf, tree.ji, tree.points, tree.point_body, tree.gravity
    M, h, J, a_pt, p_pt = out
    wz, wo, jv, jw, fr = sweep
    g = (grav[0], grav[1], grav[2])
    inertia = h.shape[0] > 0
    mass = M.shape[0] > 0
    R = IDENTITY
    o = ZERO
    w = ZERO  # angular velocity of the current body
    al = ZERO  # its angular bias acceleration
    ao = ZERO  # bias acceleration of its origin o
    for k in range(s, e):
        par = ji[k, JI_PARENT]
        if par < 0:
            R, o, w, al, ao = IDENTITY, ZERO, ZERO, ZERO, ZERO
        elif par != k - 1:  # a branch: continue from the parent's body, not the previous one
            R, o, w, al, ao = _load_frame(fr, wo, par)
        R, o, w, al, ao, z = _joint_step(jf, ji, k, q, qd, R, o, w, al, ao)
        _store(wz, k, z)
        _store(wo, k, o)
        if ji[k, JI_KEEP] != 0:
            for i in range(9):
                fr[k, i] = R[i]
            for i in range(3):
                fr[k, 9 + i] = w[i]
                fr[k, 12 + i] = al[i]
                fr[k, 15 + i] = ao[i]

        m = jf[k, JF_MASS]
        if m <= 0.0 or not inertia:
            continue
        c, Ic, f, t_rot = _body_loads(jf, k, m, g, R, o, w, al, ao)
        j = k
        while j >= 0:  # the body moves with its ancestors' joints only
            _jacobian_column(ji, wz, wo, c, jv, jw, j)
            j = ji[j, JI_PARENT]
        a = k
        while a >= 0:
            jva, Ijwa = _project(jv, jw, f, t_rot, Ic, h, a)
            b = a if mass else -1
            while b >= 0:
                _mass_entry(jv, jw, m, jva, Ijwa, M, a, b)
                b = ji[b, JI_PARENT]
            a = ji[a, JI_PARENT]

    spatial = J.shape[1] == 6
    last = (R, o, w, al, ao)  # the last body's, as the sweep left them
    for ip in range(points.shape[0]):
        body = point_body[ip]
        if body < s or body >= e:
            continue
        R, o, w, al, ao = last if body == e - 1 else _load_frame(fr, wo, body)
        pt = v.add(o, v.mv(R, (points[ip, 0], points[ip, 1], points[ip, 2])))
        r = v.sub(pt, o)
        at = v.add(v.add(ao, v.cross(al, r)), v.cross(w, v.cross(w, r)))
        for i in range(3):
            p_pt[ip, i] = pt[i]
            a_pt[ip, i] = at[i]
        if spatial:
            Rp = v.mm(R, v.row9(points, ip, 3))
            for i in range(9):
                p_pt[ip, 3 + i] = Rp[i]
            for i in range(3):
                a_pt[ip, 3 + i] = al[i]
        j = body
        while j >= 0:  # the point moves with its body's ancestors' joints only
            _point_column(ji, wz, wo, pt, J, ip, j, spatial)
            j = ji[j, JI_PARENT]
    if inertia:
        _joint_elements(jf, s, e, q, qd, M, h)


@njit(cache=True)
def point_buffers(points, n):
    """Empty (J, a_pt, p_pt) for the tree terms: 3 rows/columns per point, or with frames
    (``points`` of 12 columns, for welds) 6 rows of J and a_pt and 12 columns of p_pt."""
    npt = points.shape[0]
    if points.shape[1] == 12:
        return np.empty((npt, 6, n)), np.empty((npt, 6)), np.empty((npt, 12))
    return np.empty((npt, 3, n)), np.empty((npt, 3)), np.empty((npt, 3))


@njit(cache=True)
def tree_terms(jf, ji, chain_start, points, point_body, grav, q, qd, M, h, J, a_pt, p_pt):
    """Tree structure terms (eq 19) subtree by subtree (eq 33).

    M (n_t x n_t) block diagonal, h (n_t), J (n_points x 3 x n_t) attachment-point
    Jacobians in tree columns, a_pt / p_pt (n_points x 3) their bias accelerations
    Jdot qd and positions (see :func:`subtree_terms` for the wider forms with frames).
    """
    n = q.shape[0]
    tree_terms_into(Tree(jf, ji, chain_start, points, point_body, grav), q, qd, TreeTerms(M, h, J, a_pt, p_pt),
                    tree_sweep(n))


@njit(cache=True)
def tree_sweep(n):
    """A :class:`TreeSweep` for n_t joints (allocate once, reuse)."""
    return TreeSweep(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 18)))


@njit(cache=True)
def tree_terms_into(tree, q, qd, out, sweep):
    """:func:`tree_terms` into ``out`` (:class:`TreeTerms`) with the scratch ``sweep``
    (:class:`TreeSweep`); ``tree``: :class:`Tree` or ``Mechanism.arrays``. With an empty M
    (0 x 0) and h, the kinematics alone (what a closure residual needs); with an empty M and a
    full h, the bias forces without the mass matrix (what a change of velocity changes)."""
    out.M[:, :] = 0.0
    out.h[:] = 0.0
    out.J[:, :, :] = 0.0
    chain_start, ji = tree.chain_start, tree.ji
    for c in range(chain_start.shape[0] - 1):
        s, e = chain_start[c], chain_start[c + 1]
        # The dispatch here, not in a function of its own: a compiled call that is not inlined
        # passes every array field by field and cost a serial machine half its time.
        if ji[s, JI_SUBTREE] == 0:
            serial_chain_terms(tree, s, e, q, qd, out, sweep)
        else:
            subtree_terms(tree, s, e, q, qd, out, sweep)
    fixed_points(tree.points, tree.point_body, out.a_pt, out.p_pt)


@njit(cache=True)
def fixed_points(points, point_body, a_pt, p_pt):
    """Points on the fixed base (body -1, the last points): given in the world, at rest (J stays 0)."""
    ip = points.shape[0] - 1
    while ip >= 0 and point_body[ip] < 0:
        for i in range(p_pt.shape[1]):
            p_pt[ip, i] = points[ip, i]
        for i in range(a_pt.shape[1]):
            a_pt[ip, i] = 0.0
        ip -= 1


@njit(cache=True)
def unit_axis(axes, i):
    """The base axis (0 x, 1 y, 2 z) row i of ``axes`` is, -1 if none: those rows take the
    components themselves (the same numbers, no products)."""
    for c in range(3):
        if axes[i, c] == 1.0 and axes[i, (c + 1) % 3] == 0.0 and axes[i, (c + 2) % 3] == 0.0:
            return c
    return -1


@njit(cache=True, inline="always")
def _directed_row(A, gamma, res, r, J, a_pt, p_pt, pa, pb, e0, e1, e2):
    """Row r: the point pair (pa, pb)'s residual, Jacobian and bias along the direction (e0, e1, e2)."""
    for j in range(A.shape[1]):  # element-wise: a row expression would allocate
        A[r, j] = (e0 * (J[pa, 0, j] - J[pb, 0, j]) + e1 * (J[pa, 1, j] - J[pb, 1, j])
                   + e2 * (J[pa, 2, j] - J[pb, 2, j]))
    res[r] = e0 * (p_pt[pa, 0] - p_pt[pb, 0]) + e1 * (p_pt[pa, 1] - p_pt[pb, 1]) \
        + e2 * (p_pt[pa, 2] - p_pt[pb, 2])
    gamma[r] = -(e0 * (a_pt[pa, 0] - a_pt[pb, 0]) + e1 * (a_pt[pa, 1] - a_pt[pb, 1])
                 + e2 * (a_pt[pa, 2] - a_pt[pb, 2]))


@njit(cache=True)
def closure_rows(closure_pairs, closure_axes, J, a_pt, p_pt, A, gamma, res):
    """Closure residual h(q_t) (eq 8), its Jacobian A = dh/dq_t and gamma = -Adot qd_t.

    Row block k holds S (p_a - p_b) for the k-th point pair (a, b), so that
    A qdd_t = gamma holds on the constraint manifold. S's rows are ``closure_axes``:
    x, y[, z], or a planar machine's in-plane directions. Pairs projected on a body's
    directions (``closure_pairs[k, 2] >= 2``) have no block here: :func:`weld_rows` writes
    their rows.
    """
    nc = closure_axes.shape[0]
    for i in range(nc):
        comp = unit_axis(closure_axes, i)
        e0, e1, e2 = closure_axes[i, 0], closure_axes[i, 1], closure_axes[i, 2]
        kk = 0  # the block: pairs before k less the projected ones
        for k in range(closure_pairs.shape[0]):
            if closure_pairs[k, 2] >= 2:
                continue
            pa = closure_pairs[k, 0]
            pb = closure_pairs[k, 1]
            r = kk * nc + i
            kk += 1
            if comp >= 0:
                for j in range(A.shape[1]):  # element-wise: a row expression would allocate
                    A[r, j] = J[pa, comp, j] - J[pb, comp, j]
                res[r] = p_pt[pa, comp] - p_pt[pb, comp]
                gamma[r] = -(a_pt[pa, comp] - a_pt[pb, comp])
            else:
                _directed_row(A, gamma, res, r, J, a_pt, p_pt, pa, pb, e0, e1, e2)


@njit(cache=True)
def weld_rows(closure_pairs, closure_axes, J, a_pt, p_pt, A, gamma, res):
    """Orientation rows of the welds (6d closures: ``closure_pairs[k, 2] == 1``), after the
    point rows: the frames of points a and b keep their relative orientation. Needs the
    frames (``points`` and p_pt of 12 columns, J and a_pt of 6 rows).

    Velocity level: w_a - w_b = 0, so A's rows are the angular-velocity Jacobians' difference
    and gamma = -(alpha_a - alpha_b) (bias angular accelerations). Position level: with
    E = R_a R_b^T (world orientations of the two frames), the residual is
    vee(E - E^T) / 2, which vanishes with the rotation and whose rate at E = I is w_a - w_b.
    The directions constrained are the world's three, or on a planar machine (point rows
    along its two in-plane directions) the plane's normal alone.

    Then the point pairs projected on a body's directions (``closure_pairs[k, 2] == 2``):
    two rows each, p_a - p_b along the first two columns u, v of point a's world frame (its
    body's orientation times the frame the model gives it), the row along the third holding
    by itself. On the manifold (p_a = p_b, and so also their rates) u's own rate drops out:
    the rows are u^T (J_a - J_b), gamma = -u^T (a_a - a_b), the residual u^T (p_a - p_b).

    Last the pairs projected on point a's frame with a mask (``closure_pairs[k, 2] = 3 + mask``,
    Closure.projected): the position rows along the frame's columns i with bit i of the mask,
    then, for a weld, the orientation rows (vee(E - E^T) / 2 and the angular rates) along the
    columns i with bit 3 + i; the rows left out hold by themselves.
    """
    planar = closure_axes.shape[0] == 2
    nc = 1 if planar else 3
    n0, n1, n2 = 0.0, 0.0, 1.0
    if planar:  # the normal, u x v (z for an x-y machine)
        n0 = closure_axes[0, 1] * closure_axes[1, 2] - closure_axes[0, 2] * closure_axes[1, 1]
        n1 = closure_axes[0, 2] * closure_axes[1, 0] - closure_axes[0, 0] * closure_axes[1, 2]
        n2 = closure_axes[0, 0] * closure_axes[1, 1] - closure_axes[0, 1] * closure_axes[1, 0]
    normal = 2 if n0 == 0.0 and n1 == 0.0 and n2 == 1.0 else 0 if n0 == 1.0 and n1 == 0.0 and n2 == 0.0 else -1
    n_proj = 0
    for k in range(closure_pairs.shape[0]):
        n_proj += closure_pairs[k, 2] >= 2
    r = (closure_pairs.shape[0] - n_proj) * closure_axes.shape[0]
    for k in range(closure_pairs.shape[0]):
        if closure_pairs[k, 2] != 1:
            continue
        pa = closure_pairs[k, 0]
        pb = closure_pairs[k, 1]
        Ra = v.row9(p_pt, pa, 3)
        Rb = v.row9(p_pt, pb, 3)
        E = v.mmt(Ra, Rb)
        err = (0.5 * (E[7] - E[5]), 0.5 * (E[2] - E[6]), 0.5 * (E[3] - E[1]))
        for i in range(nc):
            comp = normal if planar else i
            if comp >= 0:
                for j in range(A.shape[1]):
                    A[r, j] = J[pa, 3 + comp, j] - J[pb, 3 + comp, j]
                res[r] = err[comp]
                gamma[r] = -(a_pt[pa, 3 + comp] - a_pt[pb, 3 + comp])
            else:
                for j in range(A.shape[1]):
                    A[r, j] = (n0 * (J[pa, 3, j] - J[pb, 3, j]) + n1 * (J[pa, 4, j] - J[pb, 4, j])
                               + n2 * (J[pa, 5, j] - J[pb, 5, j]))
                res[r] = n0 * err[0] + n1 * err[1] + n2 * err[2]
                gamma[r] = -(n0 * (a_pt[pa, 3] - a_pt[pb, 3]) + n1 * (a_pt[pa, 4] - a_pt[pb, 4])
                             + n2 * (a_pt[pa, 5] - a_pt[pb, 5]))
            r += 1
    for k in range(closure_pairs.shape[0]):
        if closure_pairs[k, 2] != 2:
            continue
        pa = closure_pairs[k, 0]
        pb = closure_pairs[k, 1]
        for i in range(2):  # column i of the row-major world frame in p_pt[pa, 3:12]
            e0, e1, e2 = p_pt[pa, 3 + i], p_pt[pa, 6 + i], p_pt[pa, 9 + i]
            _directed_row(A, gamma, res, r, J, a_pt, p_pt, pa, pb, e0, e1, e2)
            r += 1
    for k in range(closure_pairs.shape[0]):
        if closure_pairs[k, 2] < 3:
            continue
        mask = closure_pairs[k, 2] - 3
        pa = closure_pairs[k, 0]
        pb = closure_pairs[k, 1]
        for i in range(3):
            if mask & (1 << i):
                e0, e1, e2 = p_pt[pa, 3 + i], p_pt[pa, 6 + i], p_pt[pa, 9 + i]
                _directed_row(A, gamma, res, r, J, a_pt, p_pt, pa, pb, e0, e1, e2)
                r += 1
        if mask < 8:
            continue
        E = v.mmt(v.row9(p_pt, pa, 3), v.row9(p_pt, pb, 3))
        err = (0.5 * (E[7] - E[5]), 0.5 * (E[2] - E[6]), 0.5 * (E[3] - E[1]))
        for i in range(3):
            if mask & (8 << i):
                e0, e1, e2 = p_pt[pa, 3 + i], p_pt[pa, 6 + i], p_pt[pa, 9 + i]
                for j in range(A.shape[1]):
                    A[r, j] = (e0 * (J[pa, 3, j] - J[pb, 3, j]) + e1 * (J[pa, 4, j] - J[pb, 4, j])
                               + e2 * (J[pa, 5, j] - J[pb, 5, j]))
                res[r] = e0 * err[0] + e1 * err[1] + e2 * err[2]
                gamma[r] = -(e0 * (a_pt[pa, 3] - a_pt[pb, 3]) + e1 * (a_pt[pa, 4] - a_pt[pb, 4])
                             + e2 * (a_pt[pa, 5] - a_pt[pb, 5]))
                r += 1



@njit(cache=True)
def coupling_rows(couplings, q, A, gamma, res):
    """The linear couplings' rows, the last ``couplings.shape[0]`` rows of A: row k of
    ``couplings`` holds the coefficients on the tree joints, then the constant c (C q = c).
    Constant rows: no bias acceleration (gamma = 0)."""
    n = A.shape[1]
    r0 = A.shape[0] - couplings.shape[0]
    for k in range(couplings.shape[0]):
        r = r0 + k
        s = -couplings[k, n]
        for j in range(n):
            A[r, j] = couplings[k, j]
            s += couplings[k, j] * q[j]
        res[r] = s
        gamma[r] = 0.0


@njit(cache=True, inline="always")
def all_closure_rows(closure_pairs, closure_axes, points, couplings, q, J, a_pt, p_pt, A, gamma, res):
    """Every closure row: :func:`closure_rows`, where the points carry frames (``points`` of
    12 columns: welds, reduced pairs) :func:`weld_rows`, then :func:`coupling_rows`."""
    closure_rows(closure_pairs, closure_axes, J, a_pt, p_pt, A, gamma, res)
    if points.shape[1] == 12:
        weld_rows(closure_pairs, closure_axes, J, a_pt, p_pt, A, gamma, res)
    if couplings.shape[0] > 0:
        coupling_rows(couplings, q, A, gamma, res)


@njit(cache=True)
def chain_points(jf, ji, chain_start, points, point_body, q, origins, coms, p_pt):
    """Forward kinematics only: joint origins, body centres of mass, attachment points (world)."""
    n_sub = 0
    for c in range(chain_start.shape[0] - 1):
        n_sub += ji[chain_start[c], JI_SUBTREE]
    Rs = np.empty((q.shape[0] if n_sub else 0, 9))  # a subtree's body orientations, for children and points
    for c in range(chain_start.shape[0] - 1):
        s, e = chain_start[c], chain_start[c + 1]
        general = ji[s, JI_SUBTREE] != 0
        R = IDENTITY
        o = ZERO
        for k in range(s, e):
            par = ji[k, JI_PARENT]
            if par < 0:
                R, o = IDENTITY, ZERO
            elif par != k - 1:
                R = v.row9(Rs, par, 0)
                o = (origins[par, 0], origins[par, 1], origins[par, 2])
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
            if general:
                for i in range(9):
                    Rs[k, i] = R[i]
            _store(coms, k, v.add(o, v.mv(R, v.row3(jf, k, JF_COM))))
        for ip in range(points.shape[0]):
            b = point_body[ip]
            if b < s or b >= e:
                continue
            xyz = (points[ip, 0], points[ip, 1], points[ip, 2])
            if b == e - 1:  # the last body: as the sweep left it
                _store(p_pt, ip, v.add(o, v.mv(R, xyz)))
            else:  # an inner body's (a general subtree's)
                _store(p_pt, ip, v.add((origins[b, 0], origins[b, 1], origins[b, 2]), v.mv(v.row9(Rs, b, 0), xyz)))
    for ip in range(points.shape[0]):
        if point_body[ip] < 0:
            _store(p_pt, ip, (points[ip, 0], points[ip, 1], points[ip, 2]))


@njit(cache=True)
def chain_points_many(jf, ji, chain_start, points, point_body, Q, p_out):
    """Attachment points p_out[k] (n_points x 3) of :func:`chain_points` at each row Q[k]: the
    per-sample outputs of a run in one call."""
    n = Q.shape[1]
    origins, coms = np.empty((n, 3)), np.empty((n, 3))
    for k in range(Q.shape[0]):
        chain_points(jf, ji, chain_start, points, point_body, Q[k], origins, coms, p_out[k])
