"""Pinocchio on a URDF + closure sidecar, as Gepetto's example-parallel-robots loader builds it:
the peer of the own-robot tests (test_robot_files, test_robot_dynamics)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml


def retyped(pin, pm, side: dict):
    """The URDF model with the sidecar's joint_name/joint_type applied, rebuilt joint by joint
    as Gepetto's completeRobotLoader does, except that a SPHERICAL joint is three revolutes
    about its frame's x, y, z (<joint>_x, _y, _z, as ours: the same dynamics away from the
    middle one's +-90 degrees, compared coordinate by coordinate) and CARDAN or UJOINT_AB two (_X, _Y; _A, _B)."""
    kinds = dict(zip(side.get("joint_name", []), side.get("joint_type", []), strict=True))
    kinds = {k: v.upper() for k, v in kinds.items() if k in pm.names}
    if not kinds:
        return pm
    if "FIXED" in kinds.values():
        raise NotImplementedError("joint_type FIXED in the Pinocchio peer")
    about = {"X": pin.JointModelRX, "Y": pin.JointModelRY, "Z": pin.JointModelRZ}
    axes = {"SPHERICAL": [("_x", pin.JointModelRX), ("_y", pin.JointModelRY), ("_z", pin.JointModelRZ)],
            "CARDAN": [("_X", pin.JointModelRX), ("_Y", pin.JointModelRY)]}
    # Gepetto's UJOINT_AB: RA then RB at the joint's frame (<joint>_A, <joint>_B)
    axes |= {f"UJOINT_{a}{b}": [(f"_{a}", about[a]), (f"_{b}", about[b])] for a in "XYZ" for b in "XYZ" if a != b}
    new = pin.Model()
    new.gravity = pm.gravity
    last = {"universe": 0}  # old joint name -> the new joint carrying its body
    damping = []
    for jid in range(1, pm.njoints):
        name, place = pm.names[jid], pm.jointPlacements[jid]
        parent = last[pm.names[pm.parents[jid]]]
        if name in kinds:
            for k, (suffix, jm) in enumerate(axes[kinds[name]]):
                parent = new.addJoint(parent, jm(), place if k == 0 else pin.SE3.Identity(), name + suffix)
                damping.append(0.0)
            jnew = parent
        else:
            jnew = new.addJoint(parent, pm.joints[jid], place, name)
            damping.extend(pm.damping[pm.joints[jid].idx_v:pm.joints[jid].idx_v + pm.joints[jid].nv])
        new.appendBodyToJoint(jnew, pm.inertias[jid], pin.SE3.Identity())
        last[name] = jnew
    for f in pm.frames[1:]:
        if not new.existFrame(f.name):
            new.addFrame(pin.Frame(f.name, last[pm.names[f.parentJoint]], f.placement, f.type), False)
    new.damping[:] = np.array(damping)
    return new


class PinocchioMachine:
    """Pinocchio's URDF parser + Gepetto-style 3D/6D contacts from the sidecar; springs and
    dampers as joint torques, rotor inertia as armature, the end-effector point mass split
    over the frames that meet at the first closure's first frame (exact for a point mass)."""

    def __init__(self, urdf: Path, model, baumgarte: tuple[float, float] = (0.0, 0.0)):
        import pinocchio as pin
        self.pin = pin
        side = yaml.safe_load((urdf.parent / "robot.yaml").read_text())
        pm = retyped(pin, pin.buildModelFromUrdf(str(urdf)), side)
        pm.gravity.linear = np.asarray(side.get("gravity", [0, 0, -9.81]), dtype=float)
        names = list(pm.names)
        ids = [names.index(n) for n in model.joint_names]
        self.continuous = [pm.joints[i].nq == 2 for i in ids]  # continuous joints: (cos, sin)
        self.iq = [pm.joints[i].idx_q for i in ids]
        self.iv = np.array([pm.joints[i].idx_v for i in ids])
        assert pm.nv == len(ids)
        self.k, self.rest = np.zeros(pm.nv), np.zeros(pm.nv)
        self.d = np.array(pm.damping, dtype=float)  # the URDF's <dynamics damping>
        for name, spec in side.get("elastic", {}).items():
            v = self.iv[model.joint_names.index(name)]
            self.k[v], self.rest[v] = spec["stiffness"], spec.get("rest", 0.0)
            self.d[v] = spec.get("damping", self.d[v])
        for name, value in side.get("rotor_inertia", {}).items():
            pm.armature[self.iv[model.joint_names.index(name)]] = value
        loops = side["closed_loop"]
        ee = side.get("end_effector", {}).get("mass", 0.0)
        if ee:
            first = loops[0][0]
            meet = [first] + [b if a == first else a for a, b in loops if first in (a, b)]
            for name in meet:
                f = pm.frames[pm.getFrameId(name)]
                pm.appendBodyToJoint(f.parentJoint, pin.Inertia(ee / len(meet), f.placement.translation,
                                                                np.zeros((3, 3))), pin.SE3.Identity())
        self.first_frame = pm.frames[pm.getFrameId(loops[0][0])]
        self.contacts = pin.StdVec_RigidConstraintModel()
        # Gepetto's loader: 3d or 3D a point, anything else (or nothing) a weld
        self.kinds = ["3d" if k.lower() == "3d" else "6d" for k in side.get("type", ["6d"] * len(loops))]
        self.frames_a = []
        for (a, b), kind in zip(loops, self.kinds, strict=True):
            fa, fb = pm.frames[pm.getFrameId(a)], pm.frames[pm.getFrameId(b)]
            self.frames_a.append(fa)
            ctype = pin.ContactType.CONTACT_6D if kind == "6d" else pin.ContactType.CONTACT_3D
            c = pin.RigidConstraintModel(ctype, pm, fa.parentJoint, fa.placement,
                                         fb.parentJoint, fb.placement, pin.ReferenceFrame.LOCAL)
            c.m_baumgarte_parameters.Kp, c.m_baumgarte_parameters.Kd = baumgarte
            self.contacts.append(c)
        self.pm, self.data = pm, pm.createData()
        self.datas = pin.StdVec_RigidConstraintData()
        for c in self.contacts:
            self.datas.append(c.createData())
        # mu ~ 1e-9: a planar machine's 3D contacts have all-zero z rows (docs/peers.md)
        self.prox = pin.ProximalSettings(1e-12, 1e-9, 50)
        pin.initConstraintDynamics(pm, self.data, self.contacts, self.datas)

    def config(self, q: np.ndarray) -> np.ndarray:
        out = np.zeros(self.pm.nq)
        for k, j in enumerate(self.iq):
            if self.continuous[k]:
                out[j:j + 2] = np.cos(q[k]), np.sin(q[k])
            else:
                out[j] = q[k]
        return out

    def accelerations(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        v, t, qv = np.zeros(self.pm.nv), np.zeros(self.pm.nv), np.zeros(self.pm.nv)
        v[self.iv], t[self.iv], qv[self.iv] = qd, tau, q
        t -= self.k * (qv - self.rest) + self.d * v
        # No convergence assertion: in a planar machine the contact's z row is all zero, and
        # with a flipped joint frame (the four-bar's rocker) the unobservable z force keeps
        # moving by ~1/mu per proximal iteration, so the solver never reports convergence
        # although the accelerations have converged to round-off.
        a = self.pin.constraintDynamics(self.pm, self.data, self.config(q), v, t, self.contacts, self.datas,
                                        self.prox)
        return np.asarray(a)[self.iv]

    def gap(self, q: np.ndarray) -> float:
        """Largest closure residual [m] (frame A minus frame B, world)."""
        pin = self.pin
        pin.forwardKinematics(self.pm, self.data, self.config(q))
        worst = 0.0
        for c in self.contacts:
            pa = self.data.oMi[c.joint1_id].act(c.joint1_placement).translation
            pb = self.data.oMi[c.joint2_id].act(c.joint2_placement).translation
            worst = max(worst, float(np.abs(pa - pb).max()))
        return worst

    def cut_force_world(self) -> np.ndarray:
        """The first contact's force on its frame A after :meth:`accelerations`, world frame
        (Pinocchio gives it in A's joint frame, LOCAL)."""
        fa = self.first_frame
        R = self.data.oMi[fa.parentJoint].rotation @ fa.placement.rotation
        return R @ np.array(self.datas[0].contact_force.linear)

    def cut_forces_world(self, components) -> np.ndarray:
        """Every contact's force (and a 6D contact's moment) on its frame A after
        :meth:`accelerations`, world frame, in our closure row order: the ``components``
        of each contact's force, then the moments of the 6D contacts (about z alone where
        the force has x, y: a planar machine)."""
        forces, moments = [], []
        for fa, kind, d in zip(self.frames_a, self.kinds, self.datas, strict=True):
            R = self.data.oMi[fa.parentJoint].rotation @ fa.placement.rotation
            forces.append((R @ np.array(d.contact_force.linear))[list(components)])
            if kind == "6d":
                moments.append((R @ np.array(d.contact_force.angular))[[2] if len(components) == 2 else [0, 1, 2]])
        return np.concatenate(forces + moments)
