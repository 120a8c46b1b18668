"""Measurement models: joint encoders, an end-effector accelerometer, branch-force sensors.

Each model turns one incoming sample into (innovation r = z - h(x), H = dh/dx, noise
variances R) at the filter's current state; the filter does the correction and gating.

- Encoders (``sensor_msgs/JointState`` position and/or velocity, any tree joint): an
  active or elastic joint is a state; a passive joint's position/rate follow from the
  closure, H = the joint's row of W = dq_t/dq_ae (the curvature term dW/dq qd_ae of a
  passive rate is neglected: it is O(|qd| dq) against the rate noise). Revolute angle
  innovations are wrapped to (-pi, pi], so wrapped encoders work too.
- Accelerometer (``sensor_msgs/Imu`` linear_acceleration): at the end of a chain (default
  the end-effector point), axes fixed in the world frame up to a constant rotation
  ``rpy`` (the reference five-bar's end effector is a point that translates).
  y = S R^T (J qdd + Jdot qd - g) for a specific-force sensor; qdd from the SCDD model at
  the state plus the disturbance states, under the torque on one side of the sample
  (``imu.sample_timing``): the torque held over the interval that ended at it
  (``before_command``: the sample at t_k shows the command of [t_k-1, t_k), as a controller
  reads sensors before it applies the next command) or the one acting from it on
  (``after_command``, a(t_k+)); ``auto`` weighs both (:mod:`~elastic_pm_dyn.observer.schedule.sample_timing`).
  qdd, and so y, jumps where the torque jumps: the sensor has feed-through. H comes from
  the prediction's linearisation (columns d a / d x, exact for d).
- Branch forces (strain gauges; ``elastic_pm_dyn_msgs/BranchForces`` force or JointState
  effort of the elastic joint): F = c (u - u_rest) + d du/dt, linear in x. No feed-through:
  u and du/dt are states, continuous where the torque jumps, so a gauge sample reads the
  same on either side of a command.

A sensor object holds its geometry (built once, in the fixed
:class:`~elastic_pm_dyn.observer.core.observer_model.ObserverModel`) and its noise levels;
``with_noise`` gives a copy with the noise levels of another configuration (an
:class:`~elastic_pm_dyn.observer.core.ekf.Ekf`'s own), the geometry shared.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import ACTIVE, ELASTIC, PASSIVE, REVOLUTE, rpy_to_matrix
from elastic_pm_dyn.observer.config import ObserverConfig

ROLE_WORDS = {"active": (ACTIVE,), "elastic": (ELASTIC,), "passive": (PASSIVE,),
              "all": (ACTIVE, ELASTIC, PASSIVE), "none": ()}


def resolve_joints(mech: Mechanism, names: list[str], key: str, roles: tuple[str, ...] | None = None) -> list[int]:
    """Tree indices of a joint list with role keywords expanded, in tree order of first mention."""
    out: list[int] = []
    joints = mech.model.joints
    for name in names:
        if name in ROLE_WORDS:
            idx = [i for i, j in enumerate(joints) if j.role in ROLE_WORDS[name]]
        elif name in mech.joint_names:
            idx = [mech.joint_names.index(name)]
        else:
            raise InputError(f"observer.{key}: unknown joint {name!r} (joints: {', '.join(mech.joint_names)})")
        for i in idx:
            if roles is not None and joints[i].role not in roles:
                raise InputError(f"observer.{key}: joint {joints[i].name!r} is {joints[i].role}, "
                                 f"expected {' or '.join(roles)}")
            if i not in out:
                out.append(i)
    return out


def motor_positions(mech: Mechanism, names, position) -> np.ndarray | None:
    """Measured positions of every active joint (tree order of ``mech.active``) in a joint state
    with ``names`` and ``position``, or None if one is missing or not finite."""
    lookup = {n: k for k, n in enumerate(names)}
    out = np.empty(len(mech.active))
    for i, j in enumerate(mech.active):
        k = lookup.get(mech.joint_names[j])
        if k is None or k >= len(position) or not np.isfinite(position[k]):
            return None
        out[i] = float(position[k])
    return out


def broadcast(values: list[float], n: int, key: str) -> np.ndarray:
    if len(values) == 1:
        return np.full(n, values[0])
    if len(values) != n:
        raise InputError(f"observer.{key}: {len(values)} values for {n} entries (give one, or one per entry)")
    return np.asarray(values, dtype=float)


@dataclass
class Sample:
    """One measurement prepared for the correction; ``dropped`` lists NaN/unknown entries."""

    sensor: str
    r: np.ndarray
    H: np.ndarray
    R: np.ndarray
    labels: list[str]
    dropped: list[str]


class FieldPlan(NamedTuple):
    """What a joint state's positions or velocities give (:meth:`Encoders.sample`), for one list of names."""

    kind: str  # position | velocity
    idx: np.ndarray  # message indices of the joints used
    js: np.ndarray  # their tree indices
    var: np.ndarray  # their noise variances
    H: np.ndarray | None  # their rows, passive joints' left empty (None: no joint)
    passive: list  # (row, tree index) of the passive joints (their rows from the closure)
    offset: int  # the rows' first column (positions 0, rates n_ae)
    labels: list[str]  # <joint>.<kind>


class FastEncoderPlan(NamedTuple):
    """A joint state that gives positions of state joints only: ``correction.encoder_correct``'s part."""

    idx: np.ndarray  # message indices of the positions
    H: np.ndarray  # their constant rows
    R: np.ndarray  # their noise variances
    js: np.ndarray  # their tree indices
    wrap: np.ndarray  # revolute: the innovation wrapped to (-pi, pi]
    with_rates: bool  # rates are measured too: a message with velocities takes :meth:`Encoders.sample`

    @property
    def bundle(self) -> tuple:
        """The kernels' :class:`~elastic_pm_dyn.observer.core.kernels.EncoderPlan` (a plain tuple)."""
        return self[1:5]


class Encoders:
    """Joint positions and rates of any tree joints."""

    name = "encoders"

    def __init__(self, mech: Mechanism, cfg: ObserverConfig, x_of_ae: dict[int, int], nae: int):
        e = cfg.encoders
        self.mech = mech
        self.pos = resolve_joints(mech, e.position_joints, "encoders.position_joints")
        self.vel = resolve_joints(mech, e.velocity_joints, "encoders.velocity_joints")
        if not self.pos and not self.vel:
            raise InputError("observer.encoders: no joints configured (position_joints and velocity_joints)")
        self.pos_var = broadcast(e.position_stddev, len(self.pos), "encoders.position_stddev") ** 2
        self.vel_var = broadcast(e.velocity_stddev, len(self.vel), "encoders.velocity_stddev") ** 2
        self.x_of_ae = x_of_ae
        self.nae = nae
        self.revolute = np.array([j.type == REVOLUTE for j in mech.model.joints])
        self.needs_w = any(j not in x_of_ae for j in self.pos + self.vel)
        self._index = {n: i for i, n in enumerate(mech.joint_names)}
        self._plans: dict[tuple, list[FieldPlan]] = {}
        self._fast: dict[tuple, FastEncoderPlan | None] = {}
        self._nx = 2 * nae

    def with_noise(self, cfg: ObserverConfig) -> Encoders:
        """This geometry with the noise levels of ``cfg`` (the plans, which hold them, afresh)."""
        e = cfg.encoders
        out = copy.copy(self)
        out.pos_var = broadcast(e.position_stddev, len(self.pos), "encoders.position_stddev") ** 2
        out.vel_var = broadcast(e.velocity_stddev, len(self.vel), "encoders.velocity_stddev") ** 2
        out._plans, out._fast, out._nx = {}, {}, 2 * self.nae
        return out

    def rows(self, joints: list[int], W: np.ndarray | None, nx: int, offset: int) -> np.ndarray:
        H = np.zeros((len(joints), nx))
        for r, j in enumerate(joints):
            if j in self.x_of_ae:
                H[r, offset + self.x_of_ae[j]] = 1.0
            else:
                H[r, offset:offset + self.nae] = W[j]
        return H

    def _plan(self, names: tuple) -> list[FieldPlan]:
        """The positions' and the velocities' :class:`FieldPlan` of a message with these names."""
        plan = self._plans.get(names)
        if plan is None:
            where = {}
            for k, n in enumerate(names):
                if n in self._index:
                    where.setdefault(self._index[n], k)
            plan = []
            for kind, joints, var, offset in (("position", self.pos, self.pos_var, 0),
                                              ("velocity", self.vel, self.vel_var, self.nae)):
                use = [(r, j) for r, j in enumerate(joints) if j in where]
                js = [j for _, j in use]
                H = self.rows(js, None, self._nx, offset) if js else None
                passive = [(i, j) for i, j in enumerate(js) if j not in self.x_of_ae]
                plan.append(FieldPlan(kind, np.array([where[j] for j in js], dtype=np.int64),
                                      np.array(js, dtype=np.int64), var[[r for r, _ in use]], H, passive, offset,
                                      [f"{self.mech.joint_names[j]}.{kind}" for j in js]))
            if len(self._plans) > 64:
                self._plans.clear()
            self._plans[names] = plan
        return plan

    def fast_plan(self, names, nx: int) -> FastEncoderPlan | None:
        """The :class:`FastEncoderPlan` of a message with these names when it gives positions of
        state joints only (no passive row): what ``correction.encoder_correct`` needs; else None (use
        :meth:`sample`)."""
        key = tuple(names)
        hit = self._fast.get(key, False)
        if hit is False:
            self._nx = nx
            pos, vel = self._plan(key)
            hit = None
            if len(pos.js) and not pos.passive and pos.H.shape[1] == nx:
                hit = FastEncoderPlan(pos.idx, np.ascontiguousarray(pos.H), pos.var, pos.js,
                                      self.revolute[pos.js].copy(), len(vel.js) > 0)
            if len(self._fast) > 64:
                self._fast.clear()
            self._fast[key] = hit
        return hit

    def sample(self, names, position, velocity, q: np.ndarray, qd: np.ndarray, W: np.ndarray | None,
               nx: int) -> Sample | None:
        self._nx = nx
        plan = self._plan(tuple(names))
        rs, Hs, Rs, labels, dropped = [], [], [], [], []
        for field, values, state in zip(plan, (position, velocity), (q, qd), strict=True):
            kind, js, var, H, passive, labs = field.kind, field.js, field.var, field.H, field.passive, field.labels
            if not len(js) or values is None or len(values) == 0:
                continue
            if len(values) != len(names):
                raise InputError(f"joint state: {len(names)} names but {len(values)} {kind} values")
            z = np.asarray(values, dtype=float)[field.idx]
            r = z - state[js]
            if kind == "position":
                wrap = self.revolute[js]
                r[wrap] = (r[wrap] + np.pi) % (2 * np.pi) - np.pi
            H = H.copy() if passive else H
            for i, j in passive:
                H[i, field.offset:field.offset + self.nae] = W[j]
            ok = np.isfinite(z)
            if not ok.all():
                dropped += [lab for lab, good in zip(labs, ok, strict=True) if not good]
                r, H, var, labs = r[ok], H[ok], var[ok], [lab for lab, good in zip(labs, ok, strict=True) if good]
            rs.append(r)
            Hs.append(H)
            Rs.append(var)
            labels += labs
        if not rs:
            return Sample(self.name, np.zeros(0), np.zeros((0, nx)), np.zeros(0), [], dropped) if dropped else None
        if len(rs) == 1:
            return Sample(self.name, rs[0], Hs[0], Rs[0], labels, dropped)
        return Sample(self.name, np.concatenate(rs), np.vstack(Hs), np.concatenate(Rs), labels, dropped)


class Accelerometer:
    """Specific force (or acceleration) of a chain end, on world-fixed axes rotated by rpy."""

    name = "imu"

    def __init__(self, mech: Mechanism, cfg: ObserverConfig):
        c = cfg.imu
        model = mech.model
        names = [ch.name for ch in model.chains]
        if c.chain:
            if c.chain not in names:
                raise InputError(f"observer.imu.chain: unknown chain {c.chain!r} (chains: {', '.join(names)})")
            self.point = names.index(c.chain)  # chain ends come first in the point list
        else:
            self.point = int(model.end_effector_chain)
        axes = [("x", "y", "z").index(a) for a in c.axes]
        R = rpy_to_matrix(np.asarray(c.rpy, dtype=float))
        self.S = R.T[axes]  # rows: the measured sensor axes, in world coordinates
        self.axes = axes
        self.var = broadcast(c.stddev, len(axes), "imu.stddev") ** 2
        self.g = np.asarray(model.gravity, dtype=float) if c.specific_force else np.zeros(3)
        self.frame_id = c.frame_id
        self.labels = [f"imu.{a}" for a in c.axes]

    def with_noise(self, cfg: ObserverConfig) -> Accelerometer:
        """This geometry with the noise levels of ``cfg``."""
        out = copy.copy(self)
        out.var = broadcast(cfg.imu.stddev, len(self.axes), "imu.stddev") ** 2
        return out

    def predicted(self, a_world: np.ndarray) -> np.ndarray:
        return self.S @ (a_world - self.g)

    def sample(self, accel: np.ndarray, a_world: np.ndarray, Hpt: np.ndarray) -> Sample:
        z = np.asarray(accel, dtype=float)[self.axes]
        ok = np.isfinite(z)
        dropped = [lab for lab, good in zip(self.labels, ok, strict=True) if not good]
        r = (z - self.predicted(a_world))[ok]
        return Sample(self.name, r, (self.S @ Hpt)[ok], self.var[ok], [lab for lab, g in zip(self.labels, ok,
                                                                                         strict=True) if g], dropped)


class BranchForces:
    """Axial branch forces F = c (u - u_rest) + d du/dt (strain gauges).

    Per branch of the model (``ObserverModel``'s arrays): ``joint_of`` its elastic joint's tree
    index, ``rows`` its row of H on [q_ae, qd_ae] and its offset c u_rest."""

    name = "branch_forces"

    def __init__(self, mech: Mechanism, cfg: ObserverConfig, nae: int, joint_of: dict[str, int],
                 rows: dict[str, tuple[np.ndarray, float]]):
        c = cfg.branch_forces
        all_names = list(joint_of)
        if not all_names:
            raise InputError("observer.branch_forces: the model has no branches")
        wanted = all_names if c.branches == ["all"] else c.branches
        for b in wanted:
            if b not in all_names:
                raise InputError(f"observer.branch_forces.branches: unknown branch {b!r} "
                                 f"(branches: {', '.join(all_names)})")
        self.names = list(wanted)
        self.source = c.source
        self.var = broadcast(c.stddev, len(self.names), "branch_forces.stddev") ** 2
        self.joint_of = joint_of
        self.rows = {b: rows[b] for b in self.names}
        self.by_joint = {mech.joint_names[self.joint_of[b]]: b for b in self.names}
        self.nae = nae

    def with_noise(self, cfg: ObserverConfig) -> BranchForces:
        """This geometry with the noise levels of ``cfg``."""
        out = copy.copy(self)
        out.var = broadcast(cfg.branch_forces.stddev, len(self.names), "branch_forces.stddev") ** 2
        return out

    def sample(self, names, force, x: np.ndarray, nx: int) -> Sample | None:
        if len(names) != len(force):
            raise InputError(f"branch forces: {len(names)} names but {len(force)} values")
        lookup = {n: k for k, n in enumerate(names)}
        rs, Hs, Rs, labels, dropped = [], [], [], [], []
        for i, b in enumerate(self.names):
            k = lookup.get(b)
            if k is None:
                continue
            v = float(force[k])
            if not np.isfinite(v):
                dropped.append(f"F_{b}")
                continue
            row, offset = self.rows[b]
            H = np.zeros(nx)
            H[:2 * self.nae] = row
            h = row @ x[:2 * self.nae] - offset
            rs.append(v - h)
            Hs.append(H)
            Rs.append(self.var[i])
            labels.append(f"F_{b}")
        if not rs:
            return Sample(self.name, np.zeros(0), np.zeros((0, nx)), np.zeros(0), [], dropped) if dropped else None
        return Sample(self.name, np.array(rs), np.vstack(Hs), np.array(Rs), labels, dropped)
