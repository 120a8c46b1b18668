"""The estimate rows of a filter pass and their ``estimates.csv`` table.

:class:`Rows` (one per distinct stamp once the filter runs) fill up while the filter runs
(:mod:`~elastic_pm_dyn.observer.drivers.event_filter`); each is an estimate row of the
:class:`~elastic_pm_dyn.observer.core.estimate.EstimateLayout` they carry, so that writing them
needs no filter. :func:`write_csv` writes ``estimates.csv``: ``t`` (seconds since the time
origin, the first stamp, exact to the nanosecond), ``stamp_ns`` (the header stamp, an integer),
the layout's columns (every tree joint, ``<joint>_vel``, ``F_<branch>``, the standard deviation
of each, ``ee_x``, ``ee_y`` (``ee_z`` if spatial; + std), the disturbance estimates ``d_<joint>``
(+ std)) and the NIS of each sensor at that stamp.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TextIO

import numpy as np

from elastic_pm_dyn.observer.core.estimate import Estimate, EstimateLayout

SENSORS = ("encoders", "imu", "branch_forces")  # the NIS columns of a row, in this order


@dataclass
class Rows:
    """One row per estimate: stamp [ns], estimate row (``layout``), NIS per sensor;
    ``origin_ns``: the stamp of filter time 0 (the estimates' ``t`` count from there);
    ``stats``: the sensor statistics of the pass that made them (``Observer.stats``: its counts
    of accepted and gated samples, for scoring), None if not kept."""

    layout: EstimateLayout | None = None
    t: list = field(default_factory=list)
    flat: list = field(default_factory=list)
    nis: list = field(default_factory=list)
    origin_ns: int = 0
    stats: dict | None = None

    @property
    def est(self) -> list[Estimate]:
        """The rows as :class:`Estimate` objects (views into the flat arrays)."""
        return [self.layout.unpack(f, True) for f in self.flat]

    def table(self) -> np.ndarray:
        """The flat estimates stacked (rows x width)."""
        return np.array(self.flat).reshape(len(self.flat), self.layout.width)

    def piece(self, a: int, b: int) -> Rows:
        """Rows a..b-1 (the same lists' items, the same layout and origin)."""
        return Rows(self.layout, self.t[a:b], self.flat[a:b], self.nis[a:b], self.origin_ns)


def csv_header(layout: EstimateLayout) -> list[str]:
    return ["t", "stamp_ns", *layout.csv_columns(), *[f"nis_{s}" for s in SENSORS]]


def csv_table(rows: Rows) -> np.ndarray:
    """The float columns of the CSV (all after ``t`` and ``stamp_ns``), one row per estimate."""
    cols = rows.layout.csv_index()
    return np.column_stack([rows.table()[:, cols], np.array(rows.nis, dtype=float).reshape(len(rows.t), len(SENSORS))])


def seconds_text(ns: int) -> str:
    """An integer number of nanoseconds as exact decimal seconds (``1500`` -> ``0.0000015``)."""
    whole, frac = divmod(abs(int(ns)), 1_000_000_000)
    text = f"{whole}.{frac:09d}".rstrip("0").rstrip(".")
    return "-" + text if ns < 0 else text


def write_csv(fh: TextIO, rows: Rows, header: bool = True) -> None:
    """``estimates.csv`` rows (after its header line, if ``header``): ``t`` and ``stamp_ns``
    exact (from the integer stamps; a float would round epoch stamps to 0.24 us), the rest
    as ``%.12g``."""
    if header:
        fh.write(",".join(csv_header(rows.layout)) + "\n")
    if not rows.t:
        return
    values = csv_table(rows)
    fmt = ",".join(["%.12g"] * values.shape[1])
    origin = int(rows.origin_ns)
    fh.writelines(f"{seconds_text(int(ns) - origin)},{int(ns)},{fmt % tuple(v)}\n"
                  for ns, v in zip(rows.t, values.tolist(), strict=True))
