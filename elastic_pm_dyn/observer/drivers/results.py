"""What ``observe`` gives: the estimate rows, the summary, the ``estimates.csv`` table.

:class:`Rows` (one per distinct stamp once the filter runs) fill up while the filter runs
(:mod:`~elastic_pm_dyn.observer.drivers.event_filter`); :func:`summary` and :func:`finish` make
the :class:`ObserveSummary` (``summary.json`` as an object, :meth:`ObserveSummary.to_dict` its
content); :func:`csv_header` and :func:`write_csv` the CSV: ``t`` (seconds since the time
origin, the first stamp, exact to the nanosecond), ``stamp_ns`` (the header stamp, an
integer), every tree joint, ``<joint>_vel``, ``F_<branch>``, the standard deviation of each
(``<column>_std``), ``ee_x``, ``ee_y`` (``ee_z`` if spatial; + std), the disturbance
estimates ``d_<joint>`` (+ std) and the NIS of each sensor at that stamp.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, fields
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


@dataclass(frozen=True)
class SensorCounts:
    """What one sensor's samples came to (``summary.json`` ``sensors.<name>``)."""

    accepted: int  # used in an update
    rejected: int  # gated out
    late: int  # older than the filter time
    future: int  # stamped more than timing.max_future ahead of the filter
    nan_entries: int  # NaN entries dropped
    recoveries: int  # re-initialisations from this sensor after a run of gated samples
    mean_nis: float  # windowed mean NIS (NaN, written as NaN, with fewer than 10 samples)
    last_rejection: str  # why the last sample was not used ("" if none)
    diagnosis: str  # a sensor far off, with its likely cause ("" if none)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class ObserveSummary:
    """``summary.json`` of ``observe`` as an object; :meth:`to_dict` is the file's content
    (same keys, same order). Filled in stages: :func:`summary` after the filter pass, the
    smoother's and the writer's numbers by ``observe_bag``, the totals by :func:`finish`.

    The free-form parts stay dicts: ``topics`` (role -> topic), ``messages`` (topic -> count),
    ``sample_timing`` (``Observer.timing_summary``: settings and the ``auto`` decisions),
    ``recoveries`` (one dict per re-initialisation) and ``smoothing`` (the smoother's numbers,
    ``{"rows": 0}`` when there was nothing to smooth)."""

    # the input and what it held
    bag: str
    topics: dict[str, str]  # role -> topic read
    messages: dict[str, int]  # topic -> messages read
    order: str  # "stamp" or "arrival"
    time_origin_ns: int  # filter time 0 (estimates.csv's t = 0) [ns]
    # what the filter made of it
    rows: int  # estimate rows
    fault: str  # "" if none
    health: tuple[int, str]  # (level 0 OK / 1 WARN / 2 ERROR, one line); a list in JSON
    bad_commands: int
    joint_states_rejected: dict[str, int]  # name problem -> joint-state messages not used
    last_joint_state_problem: str
    sensors: dict[str, SensorCounts]
    sample_timing: dict
    recoveries: list[dict]
    duration_s: float  # stamp span of the bag's events [s]
    wall_read_s: float
    wall_filter_s: float
    observability: str  # the observability report (text)
    smoother: str | None = None  # the smoother's name (observe --smoother), its numbers in ``smoothing``
    smoothing: dict | None = None  # None: no smoother (no key in JSON)
    # wall times [s]: writing (None, no key, without an output folder), total; bag seconds per wall second
    wall_write_s: float | None = None
    wall_total_s: float = 0.0
    speed_factor: float = 0.0

    def to_dict(self) -> dict:
        """The ``summary.json`` content (``smoothing`` and ``wall_write_s`` only when set)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["health"] = list(self.health)
        d["sensors"] = {k: v.to_dict() for k, v in self.sensors.items()}
        for key in ("smoothing", "wall_write_s"):
            if d[key] is None:
                del d[key]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> ObserveSummary:
        """From ``summary.json``'s content (e.g. ``json.load``)."""
        kw = dict(d)
        kw["health"] = tuple(d["health"])
        kw["sensors"] = {k: SensorCounts(**v) for k, v in d["sensors"].items()}
        return cls(**kw)

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_dict(), indent=2, default=float))


@dataclass
class OfflineResult:
    """``rows``: the estimates (smoothed with a smoother, then ``filtered`` holds the filter's);
    ``summary``: the numbers of the pass (as written to ``summary.json``)."""

    rows: Rows
    summary: ObserveSummary
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
            wall_read: float) -> ObserveSummary:
    """``summary.json`` of a pass over ``events`` (its wall times so far; :func:`finish` adds the rest)."""
    stamps = [e.stamp_ns for e in events]
    duration = (max(stamps) - min(stamps)) * 1e-9
    rows, obs, stream, fault, report = run.rows, run.obs, run.stream, run.fault, run.report
    findings = obs.nis_findings()  # a sensor far off, with its likely cause
    level, message = obs.health()
    return ObserveSummary(
        bag=str(bag), topics=dict(vars(topics)), messages=counts, order=order,
        time_origin_ns=int(stream.origin_ns or 0),
        rows=len(rows.t), fault=fault, health=(level, message),
        bad_commands=stream.bad_commands,
        joint_states_rejected={r: stream.joint_state_rejections[r] for r in NAME_PROBLEMS},
        last_joint_state_problem=stream.last_joint_state_problem,
        sensors={s: SensorCounts(accepted=st.accepted, rejected=st.rejected, late=st.late, future=st.future,
                                 nan_entries=st.nan, recoveries=st.recoveries, mean_nis=obs.nis_band(s)[2],
                                 last_rejection=st.last_reason, diagnosis=findings.get(s, ""))
                 for s, st in obs.stats.items()},
        sample_timing=obs.timing_summary(),
        recoveries=[vars(r) | {"text": r.text()} for r in obs.recoveries],  # Observer._recover
        duration_s=duration, wall_read_s=wall_read, wall_filter_s=run.wall,
        observability=report.text(),
    )


def finish(summary: ObserveSummary, out: str | Path | None, wall0: float, rows: Rows, obs: Observer,
           filtered: Rows | None = None) -> OfflineResult:
    """Total wall time (since ``wall0``) and speed into ``summary``, written as ``out/summary.json``."""
    summary.wall_total_s = time.perf_counter() - wall0
    summary.speed_factor = summary.duration_s / summary.wall_total_s if summary.wall_total_s > 0 else float("inf")
    if out is not None:
        summary.write(Path(out) / "summary.json")
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
