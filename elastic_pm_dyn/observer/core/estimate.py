"""The estimate row as a value: :class:`Estimate` and the :class:`EstimateLayout` of its flat form.

The filter writes every output of a stamp into one float array, its estimate row
(``kernels.estimate_flat``: one compiled call, the offline fast path fills many at once):
[t, q, qd, q_std, qd_std, effort (n_t each), F, F_std, deflection, deflection rate (n_b each),
ee, ee_std (its components), d, d_std (n_d each), wrench, wrench_std (n_w each), x, P (row-major)].
The layout says where each field sits, its width, the names of what the columns hold, the ``estimates.csv`` columns, and
unpacks a row into an :class:`Estimate`. It is made once per observer model and state size
(:meth:`EstimateLayout.of`); rows, writers and the smoother take it, never the live filter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from elastic_pm_dyn.observer.core.observer_model import ObserverModel

# The fields of an estimate row, in order, and their widths ("n": tree joints, "nb": branches,
# "ne": end-effector components, "nd": disturbance joints, "nw": end-effector wrench components
# (0 without process.wrench), "nx": filter states, "nx2": nx * nx)
ROW_FIELDS = (("t", "1"), ("q", "n"), ("qd", "n"), ("q_std", "n"), ("qd_std", "n"), ("effort", "n"),
              ("branch_force", "nb"), ("branch_force_std", "nb"), ("deflection", "nb"), ("deflection_rate", "nb"),
              ("ee", "ne"), ("ee_std", "ne"), ("disturbance", "nd"), ("disturbance_std", "nd"),
              ("wrench", "nw"), ("wrench_std", "nw"), ("x", "nx"), ("P", "nx2"))


@dataclass
class Estimate:
    """Estimates at time t with 1-sigma standard deviations (tree order / model branch order)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    q_std: np.ndarray
    qd_std: np.ndarray
    effort: np.ndarray  # active: command + disturbance estimate; elastic: spring force; passive: 0
    branch_names: list[str]
    branch_force: np.ndarray
    branch_force_std: np.ndarray
    deflection: np.ndarray
    deflection_rate: np.ndarray
    ee: np.ndarray
    ee_std: np.ndarray
    disturbance_joints: list[str]
    disturbance: np.ndarray
    disturbance_std: np.ndarray
    x: np.ndarray
    P: np.ndarray
    initialised: bool = True
    wrench_names: list[str] | None = None  # the end-effector wrench components (process.wrench), world frame
    wrench: np.ndarray | None = None  # [N] forces at the end-effector point, [N m] couples on its body
    wrench_std: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class EstimateLayout:
    """Where each :class:`Estimate` field sits in an estimate row, and what its columns name."""

    slices: dict[str, slice]  # field -> its columns in a row
    width: int  # columns of a row
    nx: int  # filter states (x, and P's side)
    joint_names: list[str]  # tree joints (q, qd, effort and their standard deviations)
    branch_names: list[str]  # branches (F, deflection and its rate)
    ee_names: list[str]  # end-effector components (ee)
    disturbance_joints: list[str]  # joints of the disturbance torques (d)
    ee_unit: np.ndarray | None  # the ee components' base-frame axes (None: a tilted plane, see ee_axes)
    ee_axes: np.ndarray  # (k, 3) world directions of the ee components
    wrench_names: list[str] | None = None  # the end-effector wrench components (empty: no wrench states)
    wrench_axes: np.ndarray | None = None  # (n_w, 6) each component's [force; torque] axes in the world

    @classmethod
    def of(cls, model: ObserverModel, nx: int) -> EstimateLayout:
        """The layout of an :class:`~elastic_pm_dyn.observer.core.observer_model.ObserverModel`'s rows
        with ``nx`` filter states (the disturbance model sets how many)."""
        mech = model.mech
        widths = {"1": 1, "n": mech.n, "nb": len(model.branch_joint), "ne": len(model.ee_axes),
                  "nd": len(model.dist_idx), "nw": len(model.wrench_names), "nx": nx, "nx2": nx * nx}
        slices, o = {}, 0
        for key, width in ROW_FIELDS:
            slices[key] = slice(o, o + widths[width])
            o += widths[width]
        return cls(slices, o, nx, list(mech.joint_names), list(model.branch_names), list(mech.ee_names),
                   list(model.dist_names), mech.ee_unit, mech.ee_axes, list(model.wrench_names), model.wrench_axes)

    def __getitem__(self, key: str) -> slice:
        return self.slices[key]

    def unpack(self, flat: np.ndarray, initialised: bool = True) -> Estimate:
        """The :class:`Estimate` of a row (fields are views into it)."""
        s, nx = self.slices, self.nx
        return Estimate(float(flat[0]), *(flat[s[k]] for k in ("q", "qd", "q_std", "qd_std", "effort")),
                        self.branch_names, *(flat[s[k]] for k in ("branch_force", "branch_force_std",
                                                                  "deflection", "deflection_rate", "ee", "ee_std")),
                        self.disturbance_joints, flat[s["disturbance"]], flat[s["disturbance_std"]], flat[s["x"]],
                        flat[s["P"]].reshape(nx, nx), initialised, self.wrench_names, flat[s["wrench"]],
                        flat[s["wrench_std"]])

    def csv_columns(self) -> list[str]:
        """The estimate's columns of ``estimates.csv`` (after ``t`` and ``stamp_ns``), in order:
        every tree joint, ``<joint>_vel``, ``F_<branch>``, the standard deviation of each, ``ee_<c>``
        (+ std), ``d_<joint>`` (+ std), with wrench states ``wrench_<component>`` (+ std);
        :meth:`csv_index` says where they sit in a row."""
        vel = [f"{n}_vel" for n in self.joint_names]
        F = [f"F_{b}" for b in self.branch_names]
        ee = [f"ee_{c}" for c in self.ee_names]
        d = [f"d_{j}" for j in self.disturbance_joints]
        w = [f"wrench_{c}" for c in self.wrench_names or ()]
        cols = [*self.joint_names, *vel, *F]
        cols += [f"{c}_std" for c in (*self.joint_names, *vel, *F)]
        return [*cols, *ee, *[f"{c}_std" for c in ee], *d, *[f"{c}_std" for c in d], *w, *[f"{c}_std" for c in w]]

    def csv_index(self) -> np.ndarray:
        """The row columns of :meth:`csv_columns`, in that order."""
        s = self.slices
        return np.r_[s["q"], s["qd"], s["branch_force"], s["q_std"], s["qd_std"], s["branch_force_std"], s["ee"],
                     s["ee_std"], s["disturbance"], s["disturbance_std"], s["wrench"], s["wrench_std"]]

    def wrench6(self, values: np.ndarray) -> np.ndarray:
        """Wrench rows (n_w components each, or their standard deviations: the axes are unit
        vectors along x, y, z) as [fx, fy, fz, mx, my, mz] in the world frame."""
        return np.asarray(values, dtype=float) @ np.abs(self.wrench_axes)

    def ee_xyz(self, ee: np.ndarray) -> np.ndarray:
        """End-effector rows (k components each) as base-frame points (rows of 3): the unit axes'
        coordinates, or on a tilted plane the point's projection on the plane through the origin."""
        if self.ee_unit is not None:
            xyz = np.zeros((len(ee), 3))
            xyz[:, self.ee_unit] = ee
            return xyz
        return ee @ self.ee_axes
