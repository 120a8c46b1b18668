"""What ``observe`` gives: the estimate rows, the summary, the ``estimates.csv`` table.

:class:`Rows` (one per distinct stamp once the filter runs) fill up while the filter runs
(:mod:`~elastic_pm_dyn.observer.drivers.event_filter`); :func:`summary` and :func:`finish` make
``summary.json``; :func:`csv_header` and :func:`write_csv` the CSV: ``t`` (seconds since
the time origin, the first stamp, exact to the nanosecond), ``stamp_ns`` (the header stamp,
an integer), every tree joint, ``<joint>_vel``, ``F_<branch>``, the standard deviation of
each (``<column>_std``), ``ee_x``, ``ee_y`` (``ee_z`` if spatial; + std), the disturbance
estimates ``d_<joint>`` (+ std) and the NIS of each sensor at that stamp.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from elastic_pm_dyn.observer.drivers.stream import NAME_PROBLEMS
from elastic_pm_dyn.observer.schedule.ekf import Estimate, Observer

SENSORS = ("encoders", "imu", "branch_forces")  # the NIS columns of a row, in this order


@dataclass
class Rows:
    """One row per estimate: stamp [ns], ``Observer.estimate_flat`` array, NIS per sensor;
    ``origin_ns``: the stamp of filter time 0 (the estimates' ``t`` count from there)."""

    obs: Observer | None = None
    t: list = field(default_factory=list)
    flat: list = field(default_factory=list)
    nis: list = field(default_factory=list)
    origin_ns: int = 0

    @property
    def est(self) -> list[Estimate]:
        """The rows as :class:`Estimate` objects (views into the flat arrays)."""
        return [self.obs.unpack_estimate(f, True) for f in self.flat]

    def table(self) -> np.ndarray:
        """The flat estimates stacked (rows x width)."""
        width = self.obs.flat_layout()["P"].stop
        return np.array(self.flat).reshape(len(self.flat), width)


@dataclass
class OfflineResult:
    """``rows``: the estimates (smoothed with a smoother, then ``filtered`` holds the filter's)."""

    rows: Rows
    summary: dict
    observer: Observer
    filtered: Rows | None = None


@dataclass
class FilterPass:
    """What the filter made of a bag's events: the observer, its observability report, the rows,
    the stream (with its bad commands), the fault ("" if none) and the wall time it took [s]."""

    obs: Observer
    report: Any
    rows: Rows
    stream: Any
    fault: str
    wall: float


def summary(bag: str | Path, topics: Any, counts: dict, order: str, events: list, run: FilterPass,
            wall_read: float) -> dict:
    """``summary.json`` of a pass over ``events`` (its wall times so far; :func:`finish` adds the rest)."""
    stamps = [e.stamp_ns for e in events]
    duration = (max(stamps) - min(stamps)) * 1e-9
    rows, obs, stream, fault, report = run.rows, run.obs, run.stream, run.fault, run.report
    findings = obs.nis_findings()  # a sensor far off, with its likely cause
    return {
        "bag": str(bag), "topics": topics.__dict__, "messages": counts, "order": order,
        "time_origin_ns": int(stream.origin_ns or 0),  # filter time 0 (estimates.csv's t = 0) [ns]
        "rows": len(rows.t), "fault": fault, "health": list(obs.health()),
        "bad_commands": stream.bad_commands,
        "joint_states_rejected": {r: stream.joint_state_rejections[r] for r in NAME_PROBLEMS},
        "last_joint_state_problem": stream.last_joint_state_problem,
        "sensors": {s: {"accepted": st.accepted, "rejected": st.rejected, "late": st.late, "future": st.future,
                        "nan_entries": st.nan, "recoveries": st.recoveries, "mean_nis": obs.nis_band(s)[2],
                        "last_rejection": st.last_reason,
                        "diagnosis": findings.get(s, "")}
                    for s, st in obs.stats.items()},
        "sample_timing": obs.timing_summary(),
        "recoveries": [vars(r) | {"text": r.text()} for r in obs.recoveries],  # Observer._recover
        "duration_s": duration,
        "wall_read_s": wall_read, "wall_filter_s": run.wall,
        "observability": report.text(),
        "smoother": None,  # or the smoother's name (observe --smoother), its numbers in "smoothing"
    }


def finish(summary: dict, out: str | Path | None, wall0: float, rows: Rows, obs: Observer,
           filtered: Rows | None = None) -> OfflineResult:
    """Total wall time (since ``wall0``) and speed into ``summary``, written as ``out/summary.json``."""
    summary["wall_total_s"] = time.perf_counter() - wall0
    duration = summary["duration_s"]
    summary["speed_factor"] = duration / summary["wall_total_s"] if summary["wall_total_s"] > 0 else float("inf")
    if out is not None:
        (Path(out) / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    return OfflineResult(rows, summary, obs, filtered)


def csv_header(obs: Observer) -> list[str]:
    mech = obs.mech
    names = mech.joint_names
    vel = [f"{n}_vel" for n in names]
    F = [f"F_{b}" for b in obs.branch_names]
    ee = [f"ee_{c}" for c in mech.ee_names]
    d = [f"d_{mech.joint_names[j]}" for j in obs.dist_idx]
    cols = ["t", "stamp_ns", *names, *vel, *F]
    cols += [f"{c}_std" for c in (*names, *vel, *F)]
    cols += [*ee, *[f"{c}_std" for c in ee], *d, *[f"{c}_std" for c in d]]
    return [*cols, *[f"nis_{s}" for s in SENSORS]]


def csv_table(rows: Rows) -> np.ndarray:
    """The float columns of the CSV (all after ``t`` and ``stamp_ns``), one row per estimate."""
    lay = rows.obs.flat_layout()
    cols = np.r_[lay["q"], lay["qd"], lay["branch_force"], lay["q_std"], lay["qd_std"], lay["branch_force_std"],
                 lay["ee"], lay["ee_std"], lay["disturbance"], lay["disturbance_std"]]
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
        fh.write(",".join(csv_header(rows.obs)) + "\n")
    if not rows.t:
        return
    values = csv_table(rows)
    fmt = ",".join(["%.12g"] * values.shape[1])
    origin = int(rows.origin_ns)
    fh.writelines(f"{seconds_text(int(ns) - origin)},{int(ns)},{fmt % tuple(v)}\n"
                  for ns, v in zip(rows.t, values.tolist(), strict=True))


def estimates_equal(a: list[Estimate], b: list[Estimate]) -> float:
    """Largest difference of states and covariances between two estimate sequences (inf if lengths differ)."""
    if len(a) != len(b):
        return float("inf")
    worst = 0.0
    for x, y in zip(a, b, strict=True):
        worst = max(worst, float(np.max(np.abs(x.x - y.x))), float(np.max(np.abs(x.P - y.P))), abs(x.t - y.t))
    return worst
