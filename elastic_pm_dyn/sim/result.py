"""Simulation results: sampled tree states plus derived outputs, and their CSV form."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from elastic_pm_dyn.kinematics.mechanism import Mechanism


@dataclass
class SimulationResult:
    """Samples of one run. Angles are continuous (never wrapped)."""

    mech: Mechanism
    t: np.ndarray  # (N,)
    q: np.ndarray  # (N, n_t)
    qd: np.ndarray  # (N, n_t)
    tau: np.ndarray  # (N, n_a) applied motor torques (the held sample under ZOH)
    formulation: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        mech, n = self.mech, len(self.t)
        self.ee = np.empty((n, len(mech.ee_components)))
        self.branch_forces = np.empty((n, len(mech.model.branches)))
        self.gap = np.empty(n)
        for k in range(n):
            self.ee[k] = mech.end_effector(self.q[k])
            self.branch_forces[k] = mech.branch_forces(self.q[k], self.qd[k])
            self.gap[k] = mech.gap(self.q[k])

    def header(self) -> list[str]:
        mech = self.mech
        names = mech.joint_names
        ee = [("ee_x", "ee_y", "ee_z")[c] for c in mech.ee_components]  # a planar machine's two axes
        return (["t", *names, *[f"{n}_vel" for n in names], *ee,
                 *[f"F_{b.name}" for b in mech.model.branches], "gap",
                 *[f"tau_{n}" for n in mech.active_names]])

    def table(self) -> np.ndarray:
        return np.column_stack([self.t, self.q, self.qd, self.ee, self.branch_forces, self.gap, self.tau])

    def to_csv(self, path: str | Path) -> None:
        """Write the table; through a temporary file renamed at the end, so an interrupted
        write never leaves a cut CSV (or destroys the one that was there)."""
        path = Path(path)
        if path.exists() and not path.is_file():  # a device or pipe (/dev/stdout): no rename
            np.savetxt(path, self.table(), delimiter=",", header=",".join(self.header()), comments="", fmt="%.17g")
            return
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            np.savetxt(tmp, self.table(), delimiter=",", header=",".join(self.header()), comments="",
                       fmt="%.17g")
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)

    def column(self, name: str) -> np.ndarray:
        return self.table()[:, self.header().index(name)]
