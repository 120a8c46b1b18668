"""The task coordinates a path prescribes, and the tree motion that has them (no dynamics).

Which coordinates fix the machine's output: a platform's own joint coordinates where the
closure has a platform chain with as many coordinates as motors (Triglide: x, y, z; Hexa:
x, y, z, yaw, pitch, roll), else the end-effector point (the planar five-bar: x, y). The
tree motion with given task coordinates (and given elastic coordinates) then follows from
the closure alone (eqs 8, 9, 12: h = 0, A qd = 0, A qdd = gamma), with the motors and the
remaining passive joints free: the servo constraints of the inverse dynamics.
"""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.errors import AssemblyError, InputError
from elastic_pm_dyn.kinematics.assembly import solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism


class Task:
    """The task coordinates of a machine and the motion that realises them (see module doc)."""

    def __init__(self, mech: Mechanism):
        self.mech = mech
        n_a = len(mech.active)
        closure = mech.model.closure
        platform = self._platform_joints(mech)
        if platform is not None and len(platform) == n_a:
            self.kind = "platform"
            self.joints = platform  # tree indices of the platform's coordinates
            self.names = [mech.joint_names[j] for j in platform]
        elif closure is not None and closure.hub >= 0 and len(mech.ee_components) != n_a:
            have = 0 if platform is None else len(platform)
            raise InputError(f"{mech.model.name}: {n_a} motors but the platform has {have} coordinates: "
                             "no square inverse for a path of the platform")
        elif len(mech.ee_components) == n_a:
            self.kind = "point"
            self.joints = np.zeros(0, dtype=np.int64)
            self.names = list(mech.ee_names)
        else:
            raise InputError(f"{mech.model.name}: {n_a} motors but the end effector has "
                             f"{len(mech.ee_components)} coordinates: the machine is not non-redundant for this task")
        fixed = set(mech.elastic.tolist()) | set(self.joints.tolist())
        # Motors and the passive joints that are not task coordinates: what the closure solves for
        self.free = np.array([j for j in range(mech.n) if j not in fixed], dtype=np.int64)
        self.fixed = np.array(sorted(fixed), dtype=np.int64)
        self.size = n_a

    @staticmethod
    def _platform_joints(mech: Mechanism) -> np.ndarray | None:
        closure = mech.model.closure
        if closure is None or closure.hub < 0:
            return None
        lo, hi = mech.arrays.chain_start[closure.hub], mech.arrays.chain_start[closure.hub + 1]
        idx = np.arange(lo, hi, dtype=np.int64)
        return idx if set(idx.tolist()) <= set(mech.passive.tolist()) else None

    def coordinates(self, q: np.ndarray) -> np.ndarray:
        """The task coordinates of a tree position."""
        if self.kind == "platform":
            return np.asarray(q, dtype=float)[self.joints].copy()
        return self.mech.end_effector(q)

    def pose(self, q_guess: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Tree position with task coordinates y; the elastic coordinates as in q_guess."""
        q = np.array(q_guess, dtype=float)
        if self.kind == "platform":
            q[self.joints] = y
            return solve_pose(self.mech, q, self.free)
        return solve_pose(self.mech, q, self.free, np.asarray(y, dtype=float))

    def rates(self, q: np.ndarray, qd_fixed: np.ndarray, yd: np.ndarray, terms=None) -> np.ndarray:
        """Tree velocity (or, with ``terms`` at (q, qd) and qd_fixed the fixed accelerations,
        the tree acceleration) with the given task and elastic rates: A qd = 0 / A qdd = gamma."""
        mech = self.mech
        t = mech.terms(q) if terms is None else terms
        acc = terms is not None
        jac, rhs = t.A, (t.gamma if acc else np.zeros(mech.m))
        out = np.array(qd_fixed, dtype=float)
        if self.kind == "platform":
            out[self.joints] = yd
        else:
            J_ee, a_ee = mech.end_effector_jacobian(t)
            jac = np.vstack([jac, J_ee])
            rhs = np.concatenate([rhs, np.asarray(yd, dtype=float) - (a_ee if acc else 0.0)])
        fixed = self.fixed
        a = jac[:, self.free]
        if a.shape[0] != a.shape[1]:
            raise AssemblyError(f"{a.shape[0]} equations for {a.shape[1]} unknowns: the machine is not "
                                "non-redundant for this task")
        out[self.free] = np.linalg.solve(a, rhs - jac[:, fixed] @ out[fixed])
        return out

    def jacobian(self, terms) -> np.ndarray:
        """The rows that hold: closure (A) and, for a point task, the end effector's (J_ee)."""
        if self.kind == "platform":
            return terms.A
        J_ee, _ = self.mech.end_effector_jacobian(terms)
        return np.vstack([terms.A, J_ee])

    def bias(self, terms) -> np.ndarray:
        """The right-hand side of the acceleration rows before the task's: gamma (and -Jdot_ee qd)."""
        if self.kind == "platform":
            return terms.gamma
        _, a_ee = self.mech.end_effector_jacobian(terms)
        return np.concatenate([terms.gamma, -a_ee])
