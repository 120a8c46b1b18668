"""Compiled parts of the observer: linearisation, discretisation, propagation, update.

State x = [q_ae (n_ae), qd_ae (n_ae), z (n_z)]: the non-redundant coordinates, their
rates and the augmented disturbance states z of a linear model whose output d = Lz z
are torques on chosen joints. The tree state
(q_t, qd_t) is carried along and always consistent with x: q_p, qd_p follow from the
closure (coordinate partitioning, ``sim.kernels.partition``).

One prediction interval [t, t + T] (T <= 1 ms) costs, for the five-bar:
- the continuous Jacobian A = df/dx at the interval's start by one-sided differences of
  the compiled SCDD accelerations (1 + 3 n_ae evaluations: positions, rates, unit
  generalised forces; the forces enter linearly, so their columns are exact);
- Phi = expm(A T) and Q = int_0^T expm(A s) G Q_c G^T expm(A s)^T ds (Van Loan's integral)
  from one scaled Taylor series and squaring, after diagonal balancing (the state mixes
  radians and micrometres, and the 550 Hz spring mode makes |A| ~ 1e7 unbalanced);
- the state itself by the exact nonlinear model: steps of SCDD by the plant's integrators
  (``process.integrator``: ETD2, or RK4 with no stabilisation inside the interval; the
  closure is restored by partitioning at the end, which is exactly the q_ae -> q_t map of
  the state definition).
The end-effector acceleration columns (for an accelerometer) come with the same
perturbed evaluations.

The observer-level kernels take their arrays in a few bundles (plain tuples in the order of the
NamedTuple that documents them; a kernel reads a field by the constant that names its position,
``state[ST_P]``, which numba resolves when it compiles): :class:`Fixed` (built once per
:class:`~elastic_pm_dyn.observer.core.observer_model.ObserverModel`), :class:`Process` (the
disturbance model and noise intensities of one configuration), :class:`State` (the filter's
state, changed in place), :class:`ImuModel` and :class:`EncoderPlan` (a sensor's arrays). Plain
tuples because numba types a namedtuple argument on its slow path (about 1 us a bundle and
call, against 0.2 us for a tuple); ``ma`` (the mechanism's ``ModelArrays``) stays an argument
of its own for the same reason (a tuple holding it would take the slow path too).
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.evaluate import SCDD, SINGULAR_TOL, accelerations_into, workspace
from elastic_pm_dyn.dynamics.kernels import passive_map
from elastic_pm_dyn.kinematics.kernels import point_buffers, unit_axis
from elastic_pm_dyn.model.layout import JF_STIFFNESS, JI_ROLE, ROLE_CODES
from elastic_pm_dyn.observer.core.propagation import (
    balance,
    discretize_structured,
    linearization_workspace,
    one_norm,
    rate_columns,
    spring_columns,
)
from elastic_pm_dyn.sim.exponential import DEFAULT_PHASE_STEP, elastic_gains
from elastic_pm_dyn.sim.integrators import ETD2, RK4, StepSettings, fixed_steps
from elastic_pm_dyn.sim.kernels import OK, STAB_PROJECTION, _closure, partition, transmit
from elastic_pm_dyn.small_linalg import positive_definite

ROLE_ACTIVE = ROLE_CODES["active"]  # a motor's joint in ma.ji[:, JI_ROLE]

# Process.method's entries: the mean's integrator (sim/integrators.py's METHODS: its method
# and scheme), the linearisation and discretisation of the covariance, and the closure
# stabilisation of the mean's steps (sim.kernels' STAB_* bits)
INTEGRATOR, LINEARIZATION, SCHEME, STABILIZATION = range(4)
DIFFERENCES, SPRINGS = 0, 1  # Process.method[LINEARIZATION]
# the mean's stabilisation per integrator method: RK4 steps freely, the closure restored by
# partitioning at the interval's end (the q_ae -> q_t map of the state definition); ETD2 projects
# after each step, as the plant does
MEAN_STABILIZATION = {RK4: 0, ETD2: STAB_PROJECTION}
CLOSURE_TOL = 1e-14  # [m] partitioning target after a prediction or a correction
PERTURBED_TOL = 1e-10  # [m] accepted gap of a first-order perturbed pose (see linearize)
COVARIANCE_LOST = 10  # predict_checked: the prediction went through but P is no longer positive definite


class Fixed(NamedTuple):
    """What the kernels need of the fixed observer model (the mechanism and the sensor geometry)."""

    eps_q: np.ndarray  # (n_ae,) difference steps of the positions (linearize)
    eps_v: np.ndarray  # (n_ae,) ... and of the rates
    point: int  # the accelerometer's point (the end effector's without one)
    with_point: bool  # an accelerometer is used: its Jacobian Hpt is linearised too
    transmission: np.ndarray  # (n_t, n_a) B: tree forces per unit motor input, tau_t = B u (Mechanism.transmission)
    ee_point: int  # the end-effector point (its position in the estimates)
    ee_axes: np.ndarray  # (k, 3) world directions of its components in the estimates (Mechanism.ee_axes)
    branch_joint: np.ndarray  # (n_b,) tree index of each branch's elastic joint
    stiff: np.ndarray  # (n_b,) its stiffness c
    damp: np.ndarray  # (n_b,) its damping d
    rest: np.ndarray  # (n_b,) its rest position


FX_EPS_Q, FX_EPS_V, FX_POINT, FX_WITH_POINT, FX_TRANSMISSION, FX_EE_POINT, FX_EE_AXES, FX_BRANCH_JOINT, FX_STIFF, \
    FX_DAMP, FX_REST = range(11)  # Fixed's fields


class Process(NamedTuple):
    """The process model of one configuration: disturbance states z (d = Lz z on tree joints
    ``dist_idx``, q_ae columns ``dist_col``; z' = Fz z + w) and the white-noise intensities
    (``psd_ae`` generalised forces on q_ae, ``rel_ae`` vibration-relative, ``psd_z`` on z;
    grown in place by a recovery)."""

    dist_idx: np.ndarray
    dist_col: np.ndarray
    Lz: np.ndarray
    Fz: np.ndarray
    psd_ae: np.ndarray
    rel_ae: np.ndarray
    psd_z: np.ndarray
    method: np.ndarray  # [integrator method (RK4, ETD2), linearisation (DIFFERENCES, SPRINGS), scheme, stabilisation]
    zkey: np.ndarray  # [T, psd_z]: what the cached z block (Phi_z, Qd_z) was computed for (NaN: nothing)
    Phi_z: np.ndarray  # (4, n_z, n_z): expm(Fz T j / 4), j = 1..4 (z_block)
    Qd_z: np.ndarray  # (n_z, n_z): the z block's noise over T
    # The end-effector wrench (process.wrench; n_w = 0: none): its n_w states are the last of z and
    # its joint forces the last n_ae rows of Lz (on every q_ae joint: dist_idx ends with ae), the
    # block G = W^T (J_p^T f + J_w^T m) per component, refreshed at each linearisation
    # (``wrench_kernels.refresh_wrench``, called by ``period.advance`` before the prediction).
    wrench_points: np.ndarray  # (k,) int64: the end-effector point, then the other points of its body
    wrench_axes: np.ndarray  # (n_w, 6): each component's [force; couple] axes


PR_DIST_IDX, PR_DIST_COL, PR_LZ, PR_FZ, PR_PSD_AE, PR_REL_AE, PR_PSD_Z, PR_METHOD, PR_ZKEY, PR_PHI_Z, \
    PR_QD_Z, PR_WRENCH_POINTS, PR_WRENCH_AXES = range(13)  # Process's fields


class State(NamedTuple):
    """The filter's state, changed in place: the consistent tree state (q, qd), the disturbance
    states z, the covariance P, the last linearisation (Phi, Qd over its interval, the point
    acceleration's Jacobian Hpt) and info = [worst conditioning, closure gap]."""

    q: np.ndarray
    qd: np.ndarray
    z: np.ndarray
    P: np.ndarray
    Phi: np.ndarray
    Qd: np.ndarray
    Hpt: np.ndarray
    info: np.ndarray


ST_Q, ST_QD, ST_Z, ST_P, ST_PHI, ST_QD_NOISE, ST_HPT, ST_INFO = range(8)  # State's fields (Qd: ST_QD_NOISE)


class ImuModel(NamedTuple):
    """An accelerometer: y = S (a - g) with noise variances R."""

    S: np.ndarray  # (m, 3) measured axes in world coordinates
    g: np.ndarray  # (3,) gravity for a specific-force sensor, else 0
    R: np.ndarray  # (m,)


IM_S, IM_G, IM_R = range(3)  # ImuModel's fields


class EncoderPlan(NamedTuple):
    """Encoder positions of state joints ``js`` (H their constant rows, R the variances;
    ``wrap``: revolute, the innovation wrapped to (-pi, pi])."""

    H: np.ndarray
    R: np.ndarray
    js: np.ndarray
    wrap: np.ndarray


@njit(cache=True)
def _work(ma, n):
    """The kinematics' arrays of :func:`_kinematics`: point Jacobians, biases, positions, closure rows."""
    m = ma.p_index.shape[0]
    J, a_pt, p_pt = point_buffers(ma.points, n)
    return J, a_pt, p_pt, np.empty((m, n)), np.empty(m), np.empty(m)


@njit(cache=True)
def point_from_scratch(ws, point, qdd, out):
    """World acceleration J qdd + Jdot qd of ``point`` from the tree terms that the last
    ``accelerations_into`` left in its workspace ``ws``."""
    J = ws[2]
    a_pt = ws[3]
    n = qdd.shape[0]
    for r in range(3):
        s = a_pt[point, r]
        for j in range(n):
            s += J[point, r, j] * qdd[j]
        out[r] = s


@njit(cache=True)
def fast_evaluate(ma, q, qd, tau, point, with_point, ws, qdd, lam, a_pt_out):
    """SCDD accelerations ``qdd`` at (q, qd, tau) on the work arrays ``ws`` and, if with_point,
    the world acceleration J qdd + Jdot qd of attachment point ``point``. Returns the
    conditioning."""
    cond, _ = accelerations_into(np.int64(SCDD), ma, q, qd, tau, 0.0, 0.0, qdd, qdd, lam, ws)
    if with_point:
        point_from_scratch(ws, point, qdd, a_pt_out)
    return cond


@njit(cache=True)
def _kinematics(ma, q, J, a_pt, p_pt, A, gamma, res):
    """Point Jacobians, positions and the closure rows at (q, qd = 0): an empty M and h, so no
    inertia terms (as ``partition`` evaluates them)."""
    _closure(ma, q, np.zeros(q.shape[0]), np.empty((0, 0)), np.empty(0), J, a_pt, p_pt, A, gamma, res)


@njit(cache=True)
def _passive_rows_from(ma, A, gamma, W):
    """W = dq_t/dq_ae (n_t x n_ae) from the closure rows A; returns the pivot ratio of dh/dq_p."""
    nae = ma.ae_index.shape[0]
    m = ma.p_index.shape[0]
    W[:, :] = 0.0
    for j in range(nae):
        W[ma.ae_index[j], j] = 1.0
    if m == 0:
        return 1.0
    Wp = np.empty((m, nae))
    cp = np.empty(m)
    ratio = passive_map(A, gamma, ma.ae_index, ma.p_index, Wp, cp)
    for i in range(m):
        for j in range(nae):
            W[ma.p_index[i], j] = Wp[i, j]
    return ratio


@njit(cache=True)
def passive_rows(ma, q, W):
    """W = dq_t/dq_ae (n_t x n_ae) at q; returns the pivot ratio of dh/dq_p."""
    n = q.shape[0]
    J, a_pt, p_pt, A, gamma, res = _work(ma, n)
    _kinematics(ma, q, J, a_pt, p_pt, A, gamma, res)
    return _passive_rows_from(ma, A, gamma, W)


@njit(cache=True)
def pose_outputs(ma, q, point, W, Jp, p):
    """W = dq_t/dq_ae, the point's Jacobian Jp (3 x n_t) and position p (3) at q."""
    n = q.shape[0]
    J, a_pt, p_pt, A, gamma, res = _work(ma, n)
    _kinematics(ma, q, J, a_pt, p_pt, A, gamma, res)
    ratio = _passive_rows_from(ma, A, gamma, W)
    for r in range(3):
        p[r] = p_pt[point, r]
        for j in range(n):
            Jp[r, j] = J[point, r, j]
    return ratio


# reassociated sums: the quadratic forms below vectorise (the Hexa's 18 passive joints x 18 x 18 terms)
@njit(cache=True, fastmath={"reassoc", "contract"})
def outputs(ma, q, qd, P, point, ee_axes, branch_joint, stiff, damp, rest, q_std, qd_std, F, F_std, ee, ee_std):
    """Estimated outputs with standard deviations from (q, qd, P): every tree joint (through
    W), branch forces F = c (u - rest) + d du/dt, and the end-effector point's components."""
    n = q.shape[0]
    nae = ma.ae_index.shape[0]
    W = np.empty((n, nae))
    Jp, p = np.empty((3, n)), np.empty(3)
    pose_outputs(ma, q, point, W, Jp, p)
    # every tree joint is a state joint (active, elastic) or a passive one: both loops fill them all
    for a in range(nae):  # a state joint's row of W is a unit vector: its own variance
        i = ma.ae_index[a]
        q_std[i] = np.sqrt(max(P[a, a], 0.0))
        qd_std[i] = np.sqrt(max(P[nae + a, nae + a], 0.0))
    for i in ma.p_index:
        sq = 0.0
        sv = 0.0
        for a in range(nae):
            for b in range(nae):
                sq += W[i, a] * P[a, b] * W[i, b]
                sv += W[i, a] * P[nae + a, nae + b] * W[i, b]
        q_std[i] = np.sqrt(max(sq, 0.0))
        qd_std[i] = np.sqrt(max(sv, 0.0))
    for k in range(branch_joint.shape[0]):
        j = branch_joint[k]
        a = 0
        for i in range(nae):
            if ma.ae_index[i] == j:
                a = i
        F[k] = stiff[k] * (q[j] - rest[k]) + damp[k] * qd[j]
        v = (stiff[k] ** 2 * P[a, a] + 2 * stiff[k] * damp[k] * P[a, nae + a]
             + damp[k] ** 2 * P[nae + a, nae + a])
        F_std[k] = np.sqrt(max(v, 0.0))
    for r in range(ee_axes.shape[0]):
        c = unit_axis(ee_axes, r)
        e0, e1, e2 = ee_axes[r, 0], ee_axes[r, 1], ee_axes[r, 2]
        ee[r] = p[c] if c >= 0 else e0 * p[0] + e1 * p[1] + e2 * p[2]
        row = np.zeros(nae)
        for a in range(nae):
            for j in range(n):
                row[a] += (Jp[c, j] if c >= 0 else e0 * Jp[0, j] + e1 * Jp[1, j] + e2 * Jp[2, j]) * W[j, a]
        v = 0.0
        for a in range(nae):
            for b in range(nae):
                v += row[a] * P[a, b] * row[b]
        ee_std[r] = np.sqrt(max(v, 0.0))


@njit(cache=True)
def estimate_flat(ma, fixed, proc, state, tau_last, t, out):
    """Every output of ``Observer.estimate`` into one flat array ``out``:
    [t, q, qd, q_std, qd_std, effort (n_t each), F, F_std, deflection, deflection rate (n_b each),
    ee, ee_std, d, d_std, wrench, wrench_std, x, P (row-major)]; d: the motor disturbances alone
    (the wrench's joint forces are not in d, nor in the motors' effort)."""
    transmission, point, ee_axes = fixed[FX_TRANSMISSION], fixed[FX_EE_POINT], fixed[FX_EE_AXES]
    branch_joint, stiff, damp, rest = fixed[FX_BRANCH_JOINT], fixed[FX_STIFF], fixed[FX_DAMP], fixed[FX_REST]
    dist_idx, Lz = proc[PR_DIST_IDX], proc[PR_LZ]
    q, qd, z, P = state[ST_Q], state[ST_QD], state[ST_Z], state[ST_P]
    n = q.shape[0]
    nb = branch_joint.shape[0]
    ne = ee_axes.shape[0]
    nae = ma.ae_index.shape[0]
    nw = proc[PR_WRENCH_AXES].shape[0]
    nd = dist_idx.shape[0] - (nae if nw > 0 else 0)  # the motor disturbances' rows of Lz
    nz = z.shape[0]
    nx = P.shape[0]
    out[0] = t
    o = 1
    oq, oqd, oqs, oqds, oeff = o, o + n, o + 2 * n, o + 3 * n, o + 4 * n
    o += 5 * n
    oF, oFs, odf, odr = o, o + nb, o + 2 * nb, o + 3 * nb
    o += 4 * nb
    oee, oees = o, o + ne
    o += 2 * ne
    od, ods = o, o + nd
    o += 2 * nd
    ow, ows = o, o + nw
    o += 2 * nw
    ox = o
    oP = o + nx
    outputs(ma, q, qd, P, point, ee_axes, branch_joint, stiff, damp, rest, out[oqs:oqs + n], out[oqds:oqds + n],
            out[oF:oF + nb], out[oFs:oFs + nb], out[oee:oee + ne], out[oees:oees + ne])
    for i in range(n):
        out[oq + i] = q[i]
        out[oqd + i] = qd[i]
        out[oeff + i] = 0.0
    forces = np.empty(n)
    transmit(transmission, tau_last, forces)
    for i in range(n):  # a motor's joint: what the inputs do there (B u; its own input unless spread)
        if ma.ji[i, JI_ROLE] == ROLE_ACTIVE:
            out[oeff + i] = forces[i]
    for k in range(nd):
        s = 0.0
        for m in range(nz):
            s += Lz[k, m] * z[m]
        out[od + k] = s
        out[oeff + dist_idx[k]] += s
        v = 0.0
        for j in range(nz):
            for m in range(nz):
                v += Lz[k, j] * P[2 * nae + j, 2 * nae + m] * Lz[k, m]
        out[ods + k] = np.sqrt(max(v, 0.0))
    for c in range(nw):  # the wrench states: the last n_w of z
        m = nz - nw + c
        out[ow + c] = z[m]
        out[ows + c] = np.sqrt(max(P[2 * nae + m, 2 * nae + m], 0.0))
    for k in range(nb):
        j = branch_joint[k]
        out[oeff + j] = out[oF + k]
        out[odf + k] = q[j] - rest[k]
        out[odr + k] = qd[j]
    for i in range(nae):
        out[ox + i] = q[ma.ae_index[i]]
        out[ox + nae + i] = qd[ma.ae_index[i]]
    for k in range(nz):
        out[ox + 2 * nae + k] = z[k]
    for i in range(nx):
        for j in range(nx):
            out[oP + i * nx + j] = P[i, j]


@njit(cache=True)
def difference_columns(ma, q, qd, tau, point, with_point, eps_q, eps_v, W, ws, lam, qdd0, a0, skip_position,
                       rates, Aq, Av, Eq, Ev):
    """One-sided differences from (qdd0, a0) at (q, qd): the position columns of Aq, Eq (but those
    ``skip_position`` marks) and, with ``rates``, every rate column of Av, Ev. A position column moves q_p to first
    order along W and takes qd_p from the closure at the perturbed pose (partitioning with a loose
    tolerance: one closure evaluation); a rate column moves qd_p along W. Returns the worst
    conditioning met."""
    n = q.shape[0]
    ae = ma.ae_index
    nae = ae.shape[0]
    worst = 1.0
    qdd1 = np.empty(n)
    a1 = np.zeros(3)
    qp = np.empty(n)
    vp = np.empty(n)
    for j in range(nae):
        if not skip_position[j]:
            e = eps_q[j]
            for i in range(n):
                qp[i] = q[i] + W[i, j] * e
                vp[i] = qd[i]
            partition(ma, qp, vp, PERTURBED_TOL, np.int64(2))
            worst = min(worst, fast_evaluate(ma, qp, vp, tau, point, with_point, ws, qdd1, lam, a1))
            for i in range(nae):
                Aq[i, j] = (qdd1[ae[i]] - qdd0[ae[i]]) / e
            for r in range(3):
                Eq[r, j] = (a1[r] - a0[r]) / e if with_point else 0.0
        if not rates:
            continue
        e = eps_v[j]
        for i in range(n):
            vp[i] = qd[i] + W[i, j] * e
        worst = min(worst, fast_evaluate(ma, q, vp, tau, point, with_point, ws, qdd1, lam, a1))
        for i in range(nae):
            Av[i, j] = (qdd1[ae[i]] - qdd0[ae[i]]) / e
        for r in range(3):
            Ev[r, j] = (a1[r] - a0[r]) / e if with_point else 0.0
    return worst


@njit(cache=True)
def linearize(ma, q, qd, tau, point, with_point, eps_q, eps_v, Aq, Av, Bf, Eq, Ev, Ef, qdd0, a0):
    """Jacobians of the q_ae accelerations (and of the point acceleration) at a consistent state.

    Aq = d qdd_ae / d q_ae, Av = d qdd_ae / d qd_ae, Bf = d qdd_ae / d f_ae (unit
    generalised forces on the q_ae joints); Eq, Ev, Ef the same for the point's world
    acceleration (3 rows): every column a one-sided difference of full evaluations
    (:func:`difference_columns`; moving q_p along W is as accurate as the difference itself).
    Returns the worst conditioning.
    """
    n = q.shape[0]
    ae = ma.ae_index
    nae = ae.shape[0]
    m = ma.p_index.shape[0]
    lam = np.empty(m)
    ws = workspace(ma)
    qdd1 = np.empty(n)
    a1 = np.empty(3)
    W = np.empty((n, nae))
    cond = fast_evaluate(ma, q, qd, tau, point, with_point, ws, qdd0, lam, a0)
    # W from the closure rows that evaluation left in ws (A depends on q alone)
    worst = min(cond, _passive_rows_from(ma, ws.A, ws.gamma, W))
    worst = min(worst, difference_columns(ma, q, qd, tau, point, with_point, eps_q, eps_v, W, ws, lam, qdd0, a0,
                                          np.zeros(nae, dtype=np.bool_), np.bool_(True), Aq, Av, Eq, Ev))
    tp = tau.copy()
    for j in range(nae):
        # Linear in the force: a unit step is exact. The point acceleration changes by J dqdd
        # only (same q, qd), taken here as the difference of full evaluations for simplicity.
        tp[ae[j]] += 1.0
        cond = fast_evaluate(ma, q, qd, tp, point, with_point, ws, qdd1, lam, a1)
        tp[ae[j]] -= 1.0
        worst = min(worst, cond)
        for i in range(nae):
            Bf[i, j] = qdd1[ae[i]] - qdd0[ae[i]]
        for r in range(3):
            Ef[r, j] = a1[r] - a0[r]
    return worst


@njit(cache=True)
def linearize_springs(ma, q, qd, tau, point, with_point, eps_q, eps_v, Aq, Av, Bf, Eq, Ev, Ef, qdd0, a0, lws):
    """:func:`linearize` from the model's structure (:mod:`~elastic_pm_dyn.observer.core.propagation`):
    Bf and Ef from one factorisation (the gains of unit forces on every q_ae joint), the elastic
    joints' position columns from their springs, the other position columns (motors and free
    joints) by the same one-sided differences as :func:`linearize`, and every rate column as
    the same difference of the velocity terms alone (``propagation.rate_columns``).
    ``lws``: :func:`linearization_workspace`.
    Returns the worst conditioning (0 if the gains' Schur complement is singular)."""
    gws, G, extra = lws
    n = q.shape[0]
    ae = ma.ae_index
    nae = ae.shape[0]
    m = ma.p_index.shape[0]
    lam = np.empty(m)
    ws = workspace(ma)
    W = np.empty((n, nae))
    cond = fast_evaluate(ma, q, qd, tau, point, with_point, ws, qdd0, lam, a0)
    # W from the closure rows that evaluation left in ws (A depends on q alone)
    worst = min(cond, _passive_rows_from(ma, ws.A, ws.gamma, W))
    ratio = elastic_gains(ma, ae, ws[0], ws[5], extra, G, gws)
    if ratio == 0.0:
        return 0.0
    analytic = np.zeros(nae, dtype=np.bool_)
    spring_columns(ma, G, point, with_point, ws[2], Aq, Bf, Eq, Ef, analytic)
    # the rates from the evaluation's own M, A and bias terms, before the position columns reuse ws
    if rate_columns(ma, q, qd, point, with_point, eps_v, W, ws, Bf, Av, Ev) == 0.0:
        return 0.0
    return min(worst, difference_columns(ma, q, qd, tau, point, with_point, eps_q, eps_v, W, ws, lam, qdd0, a0,
                                         analytic, np.bool_(False), Aq, Av, Eq, Ev))


@njit(cache=True)
def z_block(Fz, psd_z, T, zkey, Phi_z, Qd_z):
    """The disturbance states' own transition at the quarters of T, Phi_z[j] = expm(Fz (j + 1) T / 4),
    and their noise Qd_z over T; recomputed only when T or psd_z changed (zkey)."""
    nz = Fz.shape[0]
    same = zkey[0] == T
    for k in range(nz):
        same = same and zkey[1 + k] == psd_z[k]
    if same:
        return
    Qc = np.zeros((nz, nz))
    for k in range(nz):
        Qc[k, k] = psd_z[k]
    Z1, Q1 = np.empty((nz, nz)), np.empty((nz, nz))
    discretize(Fz, Qc, T / 4.0, Z1, Q1)
    Z2 = Z1 @ Z1
    Q2 = Z1 @ Q1 @ Z1.T + Q1
    Phi_z[0] = Z1
    Phi_z[1] = Z2
    Phi_z[2] = Z2 @ Z1
    Phi_z[3] = Z2 @ Z2
    Qd_z[:, :] = Z2 @ Q2 @ Z2.T + Q2
    zkey[0] = T
    zkey[1:] = psd_z


@njit(cache=True)
def continuous_model(Aq, Av, Bf, dist_col, Lz, Fz, psd_ae, psd_z, Ac, Qc):
    """A = df/dx and the white-noise intensity G Q_c G^T of x = [q_ae, qd_ae, z].

    The disturbance states z (n_z) follow z' = Fz z + w (intensities psd_z); the torques
    are d = Lz z (n_d), d_k acting on q_ae column dist_col[k] (e.g. Fz = 0, Lz = I: random
    walks; a bias plus a band-limited part: z = [b, f, f'], Lz = [I, I, 0]). psd_ae are
    white generalised-force intensities on the q_ae joints (model error).
    """
    nae = Aq.shape[0]
    nd = dist_col.shape[0]
    nz = Fz.shape[0]
    Ac[:, :] = 0.0
    Qc[:, :] = 0.0
    for i in range(nae):
        Ac[i, nae + i] = 1.0
        for j in range(nae):
            Ac[nae + i, j] = Aq[i, j]
            Ac[nae + i, nae + j] = Av[i, j]
        for m in range(nz):
            s = 0.0
            for k in range(nd):
                s += Bf[i, dist_col[k]] * Lz[k, m]
            Ac[nae + i, 2 * nae + m] = s
    for k in range(nz):
        for m in range(nz):
            Ac[2 * nae + k, 2 * nae + m] = Fz[k, m]
        Qc[2 * nae + k, 2 * nae + k] = psd_z[k]
    for i in range(nae):
        for j in range(nae):
            s = 0.0
            for k in range(nae):
                s += Bf[i, k] * psd_ae[k] * Bf[j, k]
            Qc[nae + i, nae + j] = s


@njit(cache=True)
def discretize(Ac, Qc, T, Phi, Qd):
    """Phi = expm(A T), Qd = int_0^T expm(A s) Qc expm(A s)^T ds (Van Loan), by Taylor + squaring.

    In balanced coordinates B = D^-1 A D: with h = T / 2^s and |B h|_1 <= 1/4, twelve Taylor
    terms give Phi(h) and the series Q(h) = sum_k G_k, G_0 = Qc h,
    G_{k+1} = (B h G_k + G_k (B h)^T) / (k + 2) (the integral's exact expansion) to round-off;
    then s doublings Phi(2h) = Phi(h)^2, Q(2h) = Phi(h) Q(h) Phi(h)^T + Q(h).
    """
    n = Ac.shape[0]
    d = np.empty(n)
    B = balance(Ac, d)
    Qb = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            Qb[i, j] = Qc[i, j] / (d[i] * d[j])
    norm = one_norm(B)
    s = 0
    while norm * T / 2.0**s > 0.25:
        s += 1
    h = T / 2.0**s
    Bh = B * h
    P = np.eye(n)
    term = np.eye(n)
    G = Qb * h
    Q = G.copy()
    for k in range(1, 13):
        term = term @ Bh / k
        P += term
        G = (Bh @ G + G @ Bh.T) / (k + 1)
        Q += G
    for _ in range(s):
        Q = P @ Q @ P.T + Q
        P = P @ P
    for i in range(n):
        for j in range(n):
            Phi[i, j] = P[i, j] * d[i] / d[j]
            v = 0.5 * (Q[i, j] + Q[j, i])
            Qd[i, j] = v * d[i] * d[j]


@njit(cache=True)
def predict(ma, fixed, proc, state, tau, relinearize, T, n_sub):
    """Propagate ``state`` (:class:`State`) over [t, t + T] with tree forces ``tau`` held.

    tau (n_t): commanded generalised forces; the disturbance torques d = Lz z (on tree
    joints dist_idx) are added. With ``relinearize`` the model is linearised at the
    interval's start and Phi, Qd (transition and discrete process noise over T) and Hpt
    (3 x n_x: the Jacobian of the point's world acceleration w.r.t. x, the accelerometer
    model's H) are recomputed in place; otherwise the given ones are used (the caller
    reuses a linearisation for a few intervals of the same length). The white
    generalised-force intensity on q_ae joint i is psd_ae[i] + rel_ae[i] F_v^2, F_v the
    vibration-force amplitude of an elastic joint: model error (stiffness, damping, the
    integrator's phase error) grows with the vibration.
    In place: q, qd (consistent tree state), z (mean propagated by expm(Fz T) = Phi's z
    block), P. info: [worst conditioning, closure gap after partitioning]. Returns
    ``sim.kernels`` status codes.
    """
    eps_q, eps_v, point, with_point = fixed[FX_EPS_Q], fixed[FX_EPS_V], fixed[FX_POINT], fixed[FX_WITH_POINT]
    dist_idx, dist_col, Lz, Fz = proc[PR_DIST_IDX], proc[PR_DIST_COL], proc[PR_LZ], proc[PR_FZ]
    psd_ae, rel_ae, psd_z, method = proc[PR_PSD_AE], proc[PR_REL_AE], proc[PR_PSD_Z], proc[PR_METHOD]
    zkey, Phi_z, Qd_z = proc[PR_ZKEY], proc[PR_PHI_Z], proc[PR_QD_Z]
    q, qd, z, P = state[ST_Q], state[ST_QD], state[ST_Z], state[ST_P]
    Phi, Qd, Hpt, info = state[ST_PHI], state[ST_QD_NOISE], state[ST_HPT], state[ST_INFO]
    structured = method[LINEARIZATION] == SPRINGS
    n = q.shape[0]
    nae = ma.ae_index.shape[0]
    nd = dist_idx.shape[0]
    nz = z.shape[0]
    nx = 2 * nae + nz
    tt = tau.copy()
    for k in range(nd):
        for m in range(nz):
            tt[dist_idx[k]] += Lz[k, m] * z[m]
    cond = 1.0
    if relinearize:
        Aq, Av, Bf = np.empty((nae, nae)), np.empty((nae, nae)), np.empty((nae, nae))
        Eq, Ev, Ef = np.empty((3, nae)), np.empty((3, nae)), np.empty((3, nae))
        qdd0, a0 = np.empty(n), np.empty(3)
        if structured:
            cond = linearize_springs(ma, q, qd, tt, point, with_point, eps_q, eps_v, Aq, Av, Bf, Eq, Ev, Ef,
                                     qdd0, a0, linearization_workspace(ma))
        else:
            cond = linearize(ma, q, qd, tt, point, with_point, eps_q, eps_v, Aq, Av, Bf, Eq, Ev, Ef, qdd0, a0)
        info[0] = cond
        if not cond >= SINGULAR_TOL:
            return 1
        psd = psd_ae.copy()
        for i in range(nae):
            w2 = -Aq[i, i]
            if rel_ae[i] > 0.0 and w2 > 0.0:
                # Vibration-force amplitude of elastic joint j: F_v^2 = (m a)^2 + (c v / w)^2 with
                # m = c / w^2 (w^2 = -dqdd_j/dq_j); the quasi-static motion has a, v ~ 0.
                j = ma.ae_index[i]
                c = ma.jf[j, JF_STIFFNESS]
                psd[i] += rel_ae[i] * ((c / w2 * qdd0[j]) ** 2 + c * c / w2 * qd[j] ** 2)
        if structured:
            z_block(Fz, psd_z, T, zkey, Phi_z, Qd_z)
            discretize_structured(Aq, Av, Bf, dist_col, Lz, Fz, psd, psd_z, T, Phi_z, Qd_z, Phi, Qd)
        else:
            Ac, Qc = np.empty((nx, nx)), np.empty((nx, nx))
            continuous_model(Aq, Av, Bf, dist_col, Lz, Fz, psd, psd_z, Ac, Qc)
            discretize(Ac, Qc, T, Phi, Qd)
        for r in range(3):
            for j in range(nae):
                Hpt[r, j] = Eq[r, j]
                Hpt[r, nae + j] = Ev[r, j]
            for m in range(nz):
                s = 0.0
                for k in range(nd):
                    s += Ef[r, dist_col[k]] * Lz[k, m]
                Hpt[r, 2 * nae + m] = s
    Pn = Phi @ P @ Phi.T + Qd
    for i in range(nx):
        for j in range(nx):
            P[i, j] = 0.5 * (Pn[i, j] + Pn[j, i])
    # The disturbance's mean moves inside the interval (z' = Fz z): its second-order Taylor
    # polynomial, d(s) = Lz (z + s Fz z + s^2/2 Fz^2 z), drives the substeps, as the
    # covariance model assumes (a held d would lag a band-limited one by half a period).
    coef = np.zeros((3, n))
    coef[0, :] = tt
    Fzz = Fz @ z
    Fzzz = Fz @ Fzz
    for k in range(nd):
        for m in range(nz):
            coef[1, dist_idx[k]] += Lz[k, m] * Fzz[m]
            coef[2, dist_idx[k]] += 0.5 * Lz[k, m] * Fzzz[m]
    lam = np.empty(ma.p_index.shape[0])
    rk_info = np.zeros(3)
    # the plant's integrators and their dispatch (sim/integrators.py); np.int64(): a literal constant
    # would compile the kernels a second time (a Literal[int] signature)
    settings = StepSettings(method[STABILIZATION], 0.0, 0.0, CLOSURE_TOL, SINGULAR_TOL, DEFAULT_PHASE_STEP)
    status = fixed_steps(method[INTEGRATOR], method[SCHEME], np.int64(SCDD), ma, q, qd, coef, T / n_sub, n_sub,
                         settings, np.zeros(n), lam, rk_info)
    info[0] = min(cond, rk_info[1])
    if status != OK:
        return status
    gap, ratio = partition(ma, q, qd, CLOSURE_TOL, np.int64(4))
    info[1] = gap
    if not ratio >= SINGULAR_TOL or not gap <= 1e-9:
        return 1
    zn = np.zeros(nz)
    for k in range(nz):
        for m in range(nz):
            zn[k] += Phi[2 * nae + k, 2 * nae + m] * z[m]
    z[:] = zn
    return OK


@njit(cache=True)
def predict_checked(ma, fixed, proc, state, tau, relinearize, T, n_sub):
    """:func:`predict`, then :func:`covariance_ok` (status COVARIANCE_LOST if not): one call per interval."""
    status = predict(ma, fixed, proc, state, tau, relinearize, T, n_sub)
    if status != OK:
        return status
    return OK if covariance_ok(state[ST_P]) else COVARIANCE_LOST


@njit(cache=True)
def point_acceleration(ma, q, qd, tau, dist_idx, d, point, out):
    """World acceleration of attachment point ``point`` at (q, qd) under tau + disturbance torques d."""
    n = q.shape[0]
    tt = tau.copy()
    for k in range(dist_idx.shape[0]):
        tt[dist_idx[k]] += d[k]
    qdd = np.empty(n)
    lam = np.empty(ma.p_index.shape[0])
    # the tree terms the accelerations leave in the workspace give the point's Jacobian and
    # bias: no second evaluation of the kinematics
    return fast_evaluate(ma, q, qd, tt, point, np.bool_(True), workspace(ma), qdd, lam, out)


@njit(cache=True)
def covariance_ok(P):
    """True if P is finite, symmetric and positive definite (Cholesky of its correlation matrix)."""
    n = P.shape[0]
    d = np.empty(n)
    for i in range(n):
        if not (np.isfinite(P[i, i]) and P[i, i] > 0.0):
            return False
        d[i] = 1.0 / np.sqrt(P[i, i])
    L = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            v = P[i, j]
            if not np.isfinite(v):
                return False
            L[i, j] = v * d[i] * d[j]
    return positive_definite(L, 1e-14)
