"""The compiled view of a model: kinematics, closure and the tree terms at a state."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import SingularConfigurationError
from elastic_pm_dyn.kinematics.kernels import (
    all_closure_rows,
    chain_points,
    chain_points_many,
    point_buffers,
    tree_terms,
)
from elastic_pm_dyn.model.arrays import ModelArrays, pack
from elastic_pm_dyn.model.description import ACTIVE, ELASTIC, PASSIVE, Model
from elastic_pm_dyn.model.layout import JF_MASS


@dataclass
class TreeTerms:
    """Everything the formulations need at one state (eqs 8, 9, 19, 33)."""

    M: np.ndarray  # (n_t, n_t) block-diagonal tree mass matrix M_t
    h: np.ndarray  # (n_t,) bias: Coriolis/centrifugal, gravity, K q, D qd, friction
    J: np.ndarray  # (n_points, 3, n_t) attachment-point Jacobians in tree columns (chain ends first)
    a_tip: np.ndarray  # (n_points, 3) their bias accelerations Jdot qd
    p_tip: np.ndarray  # (n_points, 3) their positions
    # (with welds: J and a_tip 6 wide, angular rows last; p_tip 12, each frame's world R after xyz)
    A: np.ndarray  # (m, n_t) closure Jacobian dh/dq_t
    gamma: np.ndarray  # (m,) -Adot qd_t
    residual: np.ndarray  # (m,) h(q_t)


def unit_indices(axes: np.ndarray) -> list[int] | None:
    """The base axis each row of ``axes`` (k, 3) is, if every row is one (x-y, y-z, spatial:
    their components are then picked, the same numbers, no products), else None. What
    :func:`~elastic_pm_dyn.kinematics.kernels.unit_axis` tells the kernels row by row."""
    axes = np.asarray(axes)
    if all(np.count_nonzero(a) == 1 and a.max() == 1.0 for a in axes):
        return [int(np.argmax(a)) for a in axes]
    return None


class Mechanism:
    """A model compiled for evaluation. Coordinates are tree coordinates q_t (n_t,).

    Index sets (tree order): ``active``, ``elastic``, ``passive``, ``ae`` = [q_a, q_e].
    """

    def __init__(self, model: Model):
        self.model = model
        self.arrays: ModelArrays = pack(model)
        self.n = len(model.joints)
        self.n_chains = len(model.chains)
        self.n_points = len(model.point_list())
        self.m = model.closure.size if model.closure is not None else 0
        self.active = model.indices(ACTIVE)
        self.elastic = model.indices(ELASTIC)
        self.passive = model.indices(PASSIVE)
        self.ae = model.ae_indices
        self.joint_names = model.joint_names
        self.active_names = [self.joint_names[i] for i in self.active]
        # the one place the motors' transmission is built: tau_t = B u (model.transmission)
        self.transmission = model.transmission()
        n_a = len(self.active)
        self.spread = not np.array_equal(self.transmission[self.active], np.eye(n_a)) \
            or bool(np.any(self.transmission[np.setdiff1d(np.arange(self.n), self.active)]))
        # B's rows on the motors' own coordinates: square, and solved for the inputs a motion needs
        self._motor_rows = self.transmission[self.active]
        if self.spread and np.any(self.transmission[self.passive]):
            raise ValueError("a motor's transmission acts on a passive joint: give it through the couplings' rates")
        if self.spread and np.linalg.matrix_rank(self._motor_rows) < n_a:
            raise ValueError("the motors' transmissions do not drive their own joints independently")
        self.ee_components = np.array(model.ee_components)
        self.ee_axes = model.ee_axes  # (k, 3) world directions of the end effector's components
        self.ee_names = model.ee_names
        # the base axes the end effector's components are (x-y, y-z, spatial), None if in-plane
        # u, v: those take the coordinates themselves (the same numbers, no products)
        self.ee_unit = unit_indices(self.ee_axes)
        self.closure_axes = model.closure.axes if model.closure is not None else np.zeros((0, 3))
        joints = model.joints
        self.stiffness = np.array([j.stiffness for j in joints])
        self.damping = np.array([j.damping for j in joints])
        self.rest = np.array([j.rest for j in joints])
        self.branch_joints = np.array([self.joint_names.index(b.joint) for b in model.branches], dtype=np.int64)

    # ----------------------------------------------------------------- evaluation
    def terms(self, q: np.ndarray, qd: np.ndarray | None = None) -> TreeTerms:
        n, m = self.n, self.m
        q = np.ascontiguousarray(q, dtype=float)
        qd = np.zeros(n) if qd is None else np.ascontiguousarray(qd, dtype=float)
        M, h = np.empty((n, n)), np.empty(n)
        ma = self.arrays
        J, a_tip, p_tip = point_buffers(ma.points, n)
        tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_tip, p_tip)
        A, gamma, res = np.zeros((m, n)), np.zeros(m), np.zeros(m)
        if m:
            all_closure_rows(ma.closure_pairs, ma.closure_axes, ma.points, ma.couplings, q, J, a_tip, p_tip, A, gamma,
                             res)
        return TreeTerms(M, h, J, a_tip, p_tip, A, gamma, res)

    def points(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World positions of joint origins (n_t, 3), body centres (n_t, 3) and attachment
        points (n_points, 3; the chain ends first, so row i is chain i's end)."""
        n = self.n
        origins, coms, tips = np.empty((n, 3)), np.empty((n, 3)), np.empty((self.n_points, 3))
        ma = self.arrays
        chain_points(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, np.ascontiguousarray(q, dtype=float),
                     origins, coms, tips)
        return origins, coms, tips

    def end_effector(self, q: np.ndarray) -> np.ndarray:
        """End-effector point: the end of the closure's first chain (the platform's reference
        point where there is one); its in-plane components (:attr:`ee_axes`) on a planar model."""
        return self.ee_of(self.points(q)[2][self.model.end_effector_chain])

    def ee_of(self, xyz: np.ndarray) -> np.ndarray:
        """The end effector's components of world vectors (..., 3) (or 3 x n Jacobian rows: axis 0)."""
        if self.ee_unit is not None:
            return xyz[..., self.ee_unit]
        return xyz @ self.ee_axes.T

    def end_effector_jacobian(self, terms: TreeTerms) -> tuple[np.ndarray, np.ndarray]:
        """(J_ee, Jdot_ee qd) of the end-effector point in tree coordinates."""
        chain = self.model.end_effector_chain
        J, a = terms.J[chain][:3], terms.a_tip[chain][:3]
        if self.ee_unit is not None:
            return J[self.ee_unit], a[self.ee_unit]
        return self.ee_axes @ J, self.ee_axes @ a

    def gap(self, q: np.ndarray) -> float:
        """Closure gap |h(q_t)| [m] (the paper's Fig. 4), from forward kinematics alone."""
        closure = self.model.closure
        if closure is None:
            return 0.0
        if closure.welds or closure.reduced or closure.projected or closure.couplings:  # rows beyond positions
            return float(np.linalg.norm(self.terms(q).residual))
        _, _, p = self.points(q)
        pairs = np.asarray(closure.pairs)
        d = (p[pairs[:, 0]] - p[pairs[:, 1]]) @ self.closure_axes.T
        return float(np.linalg.norm(d))

    # -------------------------------------------------------------- coordinates
    def passive_map(self, terms: TreeTerms) -> tuple[np.ndarray, np.ndarray]:
        """W = dq_t/dq_ae (eq 18) and Wdot qd_ae, from the closure (eqs 9, 12).

        Raises SingularConfigurationError where dh/dq_p is singular (a parallel
        singularity: the passive joints are not determined by q_ae).
        """
        A_p = terms.A[:, self.passive]
        A_ae = terms.A[:, self.ae]
        W = np.zeros((self.n, len(self.ae)))
        W[self.ae, np.arange(len(self.ae))] = 1.0
        c = np.zeros(self.n)
        if self.m:
            try:
                sol = np.linalg.solve(A_p, np.column_stack([A_ae, terms.gamma]))
            except np.linalg.LinAlgError:
                raise SingularConfigurationError(
                    "dh/dq_p is singular: the passive joints are not determined by q_ae (parallel singularity)",
                    residual=float(np.linalg.norm(terms.residual))) from None
            W[self.passive] = -sol[:, :-1]
            c[self.passive] = sol[:, -1]
        return W, c

    def tree_velocity(self, q: np.ndarray, qd_ae: np.ndarray) -> np.ndarray:
        """qd_t = W qd_ae (eq 12)."""
        W, _ = self.passive_map(self.terms(q))
        return W @ np.asarray(qd_ae, dtype=float)

    def split_tau(self, tau_active: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Tree generalised forces B u of the motor inputs ``tau_active`` (..., n_a): each on its
        own joint, or spread through its transmission (a fixed tendon's coefficients); into
        ``out`` (..., n_t) where given (a plant's period, a simulator's torque polynomial)."""
        u = np.asarray(tau_active, dtype=float)
        if out is None:
            out = np.empty(u.shape[:-1] + (self.n,))
        if self.spread:
            return np.matmul(u, self.transmission.T, out=out)
        out[...] = 0.0
        out[..., self.active] = u  # a selection: the same numbers, no products
        return out

    def motor_inputs(self, forces_ae: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The motor inputs u that generalised forces on q_ae (..., n_ae; the inverse dynamics'
        W^T (M_t qdd + h_t)) need, and the elastic rows' forces the inputs leave: the motors'
        rows B_a u = f_a fix u (no actuator but the motors acts there), f_e - B_e u is left.
        W^T B = B on q_ae since B has no rows on passive joints (model/from_tree.py puts a
        tendon's coupled terms through the couplings' rates)."""
        f = np.asarray(forces_ae, dtype=float)
        n_a = len(self.active)
        if not self.spread:
            return f[..., :n_a].copy(), f[..., n_a:].copy()
        u = np.linalg.solve(self._motor_rows, f[..., :n_a, None])[..., 0] if f.ndim > 1 \
            else np.linalg.solve(self._motor_rows, f[:n_a])
        return u, f[..., n_a:] - u @ self.transmission[self.elastic].T

    # ----------------------------------------------------------------- energy
    def energy(self, q: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
        """Kinetic and potential (gravity + springs) energy [J]."""
        t = self.terms(q)
        kinetic = 0.5 * float(qd @ t.M @ qd)
        _, coms, _ = self.points(q)
        gravity = -float(np.sum(self.arrays.jf[:, JF_MASS] * (coms @ self.arrays.gravity)))
        spring = 0.5 * float(np.sum(self.stiffness * (np.asarray(q) - self.rest) ** 2))
        return kinetic, gravity + spring

    def spring_forces(self, q: np.ndarray, qd: np.ndarray, out: np.ndarray | None = None,
                      work: np.ndarray | None = None) -> np.ndarray:
        """Per tree joint: K (q - q_rest) + D qd of its spring and damper (0 where none); into
        ``out`` (``work``: scratch of the same size) without allocating where both are given."""
        out = np.empty(self.n) if out is None else out
        work = np.empty(self.n) if work is None else work
        np.subtract(q, self.rest, out=out)
        np.multiply(self.stiffness, out, out=out)
        np.multiply(self.damping, qd, out=work)
        np.add(out, work, out=out)
        return out

    def sample_outputs(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(end effector, branch forces, gap) at each row of q, qd (N x n_t): the values of
        :meth:`end_effector`, :meth:`branch_forces` and :meth:`gap` row by row, with the
        forward kinematics of all rows in one compiled call."""
        q = np.ascontiguousarray(q, dtype=float).reshape(-1, self.n)
        qd = np.asarray(qd, dtype=float).reshape(-1, self.n)
        ma = self.arrays
        tips = np.empty((len(q), self.n_points, 3))
        chain_points_many(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, q, tips)
        end = tips[:, self.model.end_effector_chain]
        # unit axes pick coordinates (exact in any order); others as end_effector() and gap() do,
        # row by row (a stacked matmul may round differently)
        ee = self.ee_of(end) if self.ee_unit is not None else np.array([self.ee_of(e) for e in end])
        ee = ee.reshape(len(q), len(self.ee_axes))
        j = self.branch_joints
        forces = self.stiffness[j] * (q[:, j] - self.rest[j]) + self.damping[j] * qd[:, j]
        closure = self.model.closure
        axes = self.closure_axes
        if closure is None:
            gap = np.zeros(len(q))
        elif closure.welds or closure.reduced or closure.projected or closure.couplings:  # as gap()
            gap = np.array([self.gap(qk) for qk in q])
        else:
            pairs = np.asarray(closure.pairs)
            diff = tips[:, pairs[:, 0]] - tips[:, pairs[:, 1]]
            unit = unit_indices(axes)
            if unit is not None:
                d = diff[:, :, unit].reshape(len(q), -1)
            else:
                d = np.array([(dk @ axes.T).ravel() for dk in diff]).reshape(len(q), -1)
            # as gap(): the BLAS dot of each row (a vectorised sum would round differently)
            gap = np.array([np.sqrt(dk.dot(dk)) for dk in d])
        return ee, forces, gap

    def branch_forces(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """F = K u + D du/dt for each named branch, tension positive [N]."""
        j = self.branch_joints
        return self.stiffness[j] * (np.asarray(q)[j] - self.rest[j]) + self.damping[j] * np.asarray(qd)[j]


def as_mechanism(model: Mechanism | Model | str | Path) -> Mechanism:
    """The mechanism of ``model``: a model file (YAML, URDF, MJCF), a loaded :class:`Model`, or
    a :class:`Mechanism` (returned as it is). The public functions that take a robot
    (``epd.observe``, ``epd.analyze``) take it in any of these forms."""
    if isinstance(model, Mechanism):
        return model
    if isinstance(model, Model):
        return Mechanism(model)
    from elastic_pm_dyn.model.loader import load_model  # the loader only where a file is given

    return Mechanism(load_model(model))
