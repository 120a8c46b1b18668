"""An external wrench on the end effector: its sources (steps, ramps, a wall) and its joint forces.

The wrench w = [f; m] (world frame; f [N] acts at the end-effector point, m [N m] is a couple
on the body that carries that point) is what the world does to the tool. It enters the tree
dynamics (seed eq 33) as the generalised force

    tau_t = J_p^T f + J_w^T m

with J_p the end-effector point's Jacobian in tree coordinates (the chain that carries it,
``model.end_effector_chain``) and J_w that body's angular Jacobian. Projected on the
non-redundant coordinates, W^T tau_t (W = dq_t/dq_ae, eq 18) equals the parallel Jacobian's
G^{+T} w of eq 31 (``dynamics.jacobian.parallel_jacobian_transpose``): two tree-force sets
that differ by closure forces A^T lambda move the machine alike (test_wrench.py checks both
and the static equilibrium they imply).

J_w comes from the points the model attaches to the same body (a platform's leg points):
v_b = v_c - [r_b]x w for every such point b (r_b = p_b - p_c), solved for w's Jacobian in
the least-squares sense. A machine whose end-effector body holds no two further points that
span a plane with it (the five-bar's and the Triglide's end points) takes forces only.

Sources (:class:`WrenchSource`), summed by :class:`ExternalWrench`:
- :class:`StepWrench`: zero until ``start``, then ``wrench`` (``ramp`` > 0: a linear ramp
  over that many seconds);
- :class:`Wall`: a plane (a point on it, its normal pointing into free space) that pushes
  back along the normal with stiffness k and damping c when the end effector is inside:
  f = n max(0, k delta - c (v . n)), delta = -(p - p0) . n > 0 (no pull: a wall does not
  hold on to the tool).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism

WRENCH_SIZE = 6  # [fx, fy, fz, mx, my, mz]
MAX_WRENCH = 1.0e6  # [N, N m] per component: far beyond any tool; larger only makes the plant diverge


def _vector(value, size: int, what: str) -> np.ndarray:
    v = np.asarray(value, dtype=float).reshape(-1)
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise InputError(f"{what} must be {size} finite numbers, got {value!r}")
    return v


class WrenchSource:
    """A wrench [f; m] (world frame) as a function of time and the end effector's position and velocity."""

    def __call__(self, t: float, p: np.ndarray, v: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class StepWrench(WrenchSource):
    """``wrench`` from ``start`` on (``ramp`` > 0: reached linearly over ``ramp`` seconds)."""

    start: float
    wrench: np.ndarray
    ramp: float = 0.0

    def __post_init__(self) -> None:
        self.wrench = _vector(self.wrench, WRENCH_SIZE, "a step's wrench")
        if np.any(np.abs(self.wrench) > MAX_WRENCH):
            raise InputError(f"a step's wrench components must lie within +-{MAX_WRENCH:g}")
        if not (np.isfinite(self.start) and np.isfinite(self.ramp) and self.ramp >= 0):
            raise InputError(f"a step needs a finite start and a ramp >= 0, got {self.start!r}, {self.ramp!r}")

    def __call__(self, t: float, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        if t < self.start:
            return np.zeros(WRENCH_SIZE)
        if self.ramp > 0:
            return self.wrench * min(1.0, (t - self.start) / self.ramp)
        return self.wrench.copy()


@dataclass
class Wall(WrenchSource):
    """A plane through ``point`` with unit ``normal`` into free space, stiffness [N/m] and damping [N s/m]."""

    point: np.ndarray
    normal: np.ndarray
    stiffness: float
    damping: float = 0.0

    def __post_init__(self) -> None:
        self.point = _vector(self.point, 3, "a wall's point")
        n = _vector(self.normal, 3, "a wall's normal")
        if not np.linalg.norm(n) > 0:
            raise InputError("a wall's normal must not be zero")
        self.normal = n / np.linalg.norm(n)
        if not (np.isfinite(self.stiffness) and self.stiffness > 0 and np.isfinite(self.damping)
                and self.damping >= 0):
            raise InputError(f"a wall needs stiffness > 0 and damping >= 0, got {self.stiffness!r}, {self.damping!r}")

    def depth(self, p: np.ndarray) -> float:
        """How far ``p`` is inside the wall [m] (negative: in free space)."""
        return float(-(np.asarray(p) - self.point) @ self.normal)

    def __call__(self, t: float, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        out = np.zeros(WRENCH_SIZE)
        delta = self.depth(p)
        if delta > 0:
            out[:3] = self.normal * max(0.0, self.stiffness * delta - self.damping * float(np.asarray(v) @ self.normal))
        return out


@dataclass
class ExternalWrench:
    """The sum of ``sources`` plus a held wrench (``held``: e.g. the plant node's input topic)."""

    sources: list[WrenchSource] = field(default_factory=list)
    held: np.ndarray = field(default_factory=lambda: np.zeros(WRENCH_SIZE))

    def __call__(self, t: float, p: np.ndarray, v: np.ndarray) -> np.ndarray:
        w = self.held.copy()
        for s in self.sources:
            w += s(t, p, v)
        return w

    def hold(self, wrench) -> None:
        """Hold ``wrench`` (6 finite numbers within +-MAX_WRENCH) from now on (InputError, nothing
        changed, if not)."""
        w = _vector(wrench, WRENCH_SIZE, "an external wrench")
        if np.any(np.abs(w) > MAX_WRENCH):
            raise InputError(f"an external wrench's components must lie within +-{MAX_WRENCH:g}, got {w.tolist()}")
        self.held = w


class WrenchMap:
    """Where a wrench acts on ``mech``: the end-effector point and the points sharing its body."""

    def __init__(self, mech: Mechanism):
        self.mech = mech
        ma = mech.arrays
        self.point = int(mech.model.end_effector_chain)
        body = ma.point_body[self.point]
        self.body_points = [i for i in range(len(ma.point_body)) if i != self.point and ma.point_body[i] == body]
        self.turns = self._spans_plane(initial_state(mech))

    def _spans_plane(self, q: np.ndarray) -> bool:
        if len(self.body_points) < 2:
            return False
        _, _, p = self.mech.points(q)
        r = p[self.body_points] - p[self.point]
        return bool(np.linalg.matrix_rank(r, tol=1e-9) >= 2)

    def jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(J_p (3 x n_t), J_w (3 x n_t) or None where the body cannot turn, the point's position p)."""
        t = self.mech.terms(q)
        Jp = t.J[self.point][:3]
        p = t.p_tip[self.point][:3]
        Jw = None
        if self.turns:
            # v_b - v_c = -[r_b]x w  ->  [r_b]x J_w = J_c - J_b, every body point b stacked
            rows, rhs = [], []
            for b in self.body_points:
                r = t.p_tip[b][:3] - p
                rows.append(np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]]))
                rhs.append(Jp - t.J[b][:3])
            Jw = np.linalg.lstsq(np.vstack(rows), np.vstack(rhs), rcond=None)[0]
        return Jp, Jw, p

    def tree_forces(self, q: np.ndarray, wrench: np.ndarray) -> np.ndarray:
        """tau_t = J_p^T f + J_w^T m at ``q`` (InputError for a couple on an end effector that cannot turn)."""
        Jp, Jw, _ = self.jacobians(q)
        tau = Jp.T @ wrench[:3]
        if np.any(wrench[3:] != 0):
            if Jw is None:
                raise InputError("this end effector cannot take a couple (its body holds no points that span a "
                                 "plane): give forces only")
            tau += Jw.T @ wrench[3:]
        return tau

    def point_state(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The end-effector point's world position and velocity."""
        t = self.mech.terms(q)
        return t.p_tip[self.point][:3].copy(), t.J[self.point][:3] @ qd
