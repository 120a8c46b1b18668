"""What ``observe`` gives: the summary and the result of a pass.

:func:`summary` and :func:`finish` make the :class:`ObserveSummary` (``summary.json`` as an
object, :meth:`ObserveSummary.to_dict` its content) from a :class:`FilterPass`; the estimate
rows and their ``estimates.csv`` are :mod:`~elastic_pm_dyn.observer.drivers.rows`'.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from elastic_pm_dyn.observer.core.estimate import Estimate
from elastic_pm_dyn.observer.drivers import contacts
from elastic_pm_dyn.observer.drivers.rows import (  # noqa: F401 - all but Rows: their old import path
    SENSORS,
    Rows,
    csv_header,
    csv_table,
    seconds_text,
    write_csv,
)
from elastic_pm_dyn.observer.drivers.stream import NAME_PROBLEMS
from elastic_pm_dyn.observer.schedule.observer import Observer


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
    contacts: list[dict] | None = None  # with wrench states: the contact events (drivers/contacts.py), else no key
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
        for key in ("contacts", "smoothing", "wall_write_s"):
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
        recoveries=[vars(r) | {"text": r.text()} for r in obs.recoveries],  # schedule.recovery
        duration_s=duration, wall_read_s=wall_read, wall_filter_s=run.wall,
        observability=report.text(),
    )


def finish(summary: ObserveSummary, out: str | Path | None, wall0: float, rows: Rows, obs: Observer,
           filtered: Rows | None = None) -> OfflineResult:
    """Total wall time (since ``wall0``) and speed into ``summary``, written as ``out/summary.json``."""
    events = contacts.contact_events(rows)
    if events is not None:
        summary.contacts = contacts.summary_entries(events)
        if out is not None:
            contacts.write_csv(Path(out) / "contacts.csv", rows, events)
    summary.wall_total_s = time.perf_counter() - wall0
    summary.speed_factor = summary.duration_s / summary.wall_total_s if summary.wall_total_s > 0 else float("inf")
    if out is not None:
        summary.write(Path(out) / "summary.json")
    return OfflineResult(rows, summary, obs, filtered)


def estimates_equal(a: list[Estimate], b: list[Estimate]) -> float:
    """Largest difference of states and covariances between two estimate sequences (inf if lengths differ)."""
    if len(a) != len(b):
        return float("inf")
    worst = 0.0
    for x, y in zip(a, b, strict=True):
        worst = max(worst, float(np.max(np.abs(x.x - y.x))), float(np.max(np.abs(x.P - y.P))), abs(x.t - y.t))
    return worst
