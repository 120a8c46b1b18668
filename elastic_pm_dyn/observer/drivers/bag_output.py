"""The observer's estimates written out: ``estimates.csv`` and a bag of estimates.

- ``estimates.csv``: :func:`~elastic_pm_dyn.observer.drivers.rows.write_csv` (``t`` since the
  first stamp and the exact ``stamp_ns``, then the estimates);
- ``estimates/`` (:func:`write_bag`, a bag, mcap by default; header stamps exact) with ``/joint_states``
  (position, velocity, effort of every tree joint), ``/branch_forces`` (with
  ``force_stddev``) and ``/ee_pose`` for ``elastic-pm-dyn analyze``, plus
  ``/observer/joint_states_stddev`` (JointState whose position/velocity fields hold the
  standard deviations); with wrench states (``process.wrench``) ``/observer/wrench`` and
  ``/observer/wrench_stddev`` (WrenchStamped, world frame, at the end-effector point) and the
  contact events of :mod:`~elastic_pm_dyn.observer.core.contact` on ``/observer/contact`` and
  ``/observer/contact_release`` (WrenchStamped: stamped with the detecting row's stamp, the
  estimate then; the live observer node publishes the same);
- ``filtered.csv`` (with a smoother only: ``estimates.csv`` and the bag are then smoothed):
  the filter's estimates, the same columns.

Both can be written a chunk of rows after another (:class:`EstimatesBag` for the bag),
giving the same files as all rows at once. Every message of a chunk is encoded at once
(:mod:`~elastic_pm_dyn.bags.cdr`) and written with the writer's bulk path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from elastic_pm_dyn.bags import cdr
from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES, JOINT_STATE, POSE_STAMPED, WRENCH_STAMPED
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.observer.core.contact import ContactDetector
from elastic_pm_dyn.observer.core.estimate import EstimateLayout
from elastic_pm_dyn.observer.drivers.rows import Rows, write_csv


def write_outputs(out: Path, rows: Rows, write_estimates_bag: bool, storage: str, filtered: Rows | None = None
                  ) -> None:
    """``estimates.csv`` and (optionally) the ``estimates/`` bag of all rows into ``out`` (nothing
    if no rows); with ``filtered`` (the filter's rows when ``rows`` are smoothed) also
    ``filtered.csv`` (the same columns)."""
    if not rows.t:
        return
    with open(out / "estimates.csv", "w") as fh:
        write_csv(fh, rows)
    if filtered is not None:
        with open(out / "filtered.csv", "w") as fh:
            write_csv(fh, filtered)
    if write_estimates_bag:
        write_bag(out / "estimates", rows, storage)


def write_bag(path: Path, rows: Rows, storage: str = "mcap") -> None:
    """Estimates as a rosbag2: /joint_states, /branch_forces, /ee_pose, /observer/joint_states_stddev."""
    out = EstimatesBag(path, rows.layout, storage)
    try:
        out.write(rows)
    finally:
        out.close()


class EstimatesBag:
    """:func:`write_bag` a chunk of rows after another (the same file as all rows at once)."""

    def __init__(self, path: Path, layout: EstimateLayout, storage: str = "mcap"):
        self.layout = layout
        self.w = BagWriter(path, storage)
        try:
            self.conns = [self.w.add_connection("/joint_states", JOINT_STATE),
                          self.w.add_connection("/branch_forces", BRANCH_FORCES),
                          self.w.add_connection("/ee_pose", POSE_STAMPED),
                          self.w.add_connection("/observer/joint_states_stddev", JOINT_STATE)]
            self.wrench = bool(layout.wrench_names)
            if self.wrench:
                self.conns += [self.w.add_connection("/observer/wrench", WRENCH_STAMPED),
                               self.w.add_connection("/observer/wrench_stddev", WRENCH_STAMPED)]
                self.events = {kind: self.w.add_connection(f"/observer/{kind}", WRENCH_STAMPED)
                               for kind in ("contact", "contact_release")}
                self.detector = ContactDetector(layout)  # across chunks: the live node's verdicts
        except BaseException:
            self.w.close()
            raise

    def write(self, rows: Rows) -> None:
        lay = self.layout
        names = lay.joint_names
        table = rows.table()
        ns = np.array(rows.t, dtype=np.int64)
        xyz = lay.ee_xyz(table[:, lay["ee"]])  # the pose: back in the base frame
        self.w.write_rows(self.conns, ns, [
            cdr.encode_joint_state_batch(ns, names, table[:, lay["q"]], table[:, lay["qd"]], table[:, lay["effort"]]),
            cdr.encode_branch_forces_batch(ns, lay.branch_names, *(table[:, lay[k]] for k in (
                "branch_force", "deflection", "deflection_rate", "branch_force_std"))),
            cdr.encode_pose_stamped_batch(ns, xyz, "world"),
            cdr.encode_joint_state_batch(ns, names, table[:, lay["q_std"]], table[:, lay["qd_std"]],
                                         np.zeros((len(ns), 0)))] + ([
            cdr.encode_wrench_stamped_batch(ns, lay.wrench6(table[:, lay["wrench"]])),
            cdr.encode_wrench_stamped_batch(ns, lay.wrench6(table[:, lay["wrench_std"]]))] if self.wrench else []))
        if self.wrench:
            for k, row in enumerate(table):
                event = self.detector.update(row)
                if event is not None:
                    kind = "contact" if event.kind == "contact" else "contact_release"
                    self.w.write(self.events[kind], int(ns[k]),
                                 cdr.encode_wrench_stamped_batch(ns[k:k + 1], lay.wrench6(event.wrench))[0].tobytes())

    def close(self) -> None:
        self.w.close()
