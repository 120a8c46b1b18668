"""Simulation results: sampled tree states plus derived outputs, and their CSV form."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from elastic_pm_dyn.csv_text import write_table
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.output_files import atomic_file


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
        self.ee, self.branch_forces, self.gap = self.mech.sample_outputs(self.q, self.qd)

    def header(self) -> list[str]:
        mech = self.mech
        names = mech.joint_names
        ee = [f"ee_{c}" for c in mech.ee_names]
        return (["t", *names, *[f"{n}_vel" for n in names], *ee,
                 *[f"F_{b.name}" for b in mech.model.branches], "gap",
                 *[f"tau_{n}" for n in mech.active_names]])

    def table(self) -> np.ndarray:
        return np.column_stack([self.t, self.q, self.qd, self.ee, self.branch_forces, self.gap, self.tau])

    def to_csv(self, path: str | Path) -> None:
        """Write the table (numbers as '%.17g': every double round-trips); through a temporary
        file renamed at the end, so an interrupted write never leaves a cut CSV (or destroys the
        one that was there)."""
        path = Path(path)
        # what np.savetxt(fmt="%.17g", delimiter=",", comments="") wrote, formatted compiled; the
        # header in UTF-8 (joint names are the file's: Greek, CJK, a Gepetto 'sĥerical')
        head = (",".join(self.header()) + "\n").encode("utf-8")
        table = self.table()
        with atomic_file(path) as tmp, open(tmp, "wb") as f:  # a device or pipe (/dev/stdout) directly
            f.write(head)
            write_table(f, table)

    def column(self, name: str) -> np.ndarray:
        return self.table()[:, self.header().index(name)]
