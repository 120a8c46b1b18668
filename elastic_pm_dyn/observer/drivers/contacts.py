"""The contact events of an ``observe`` run: ``contacts.csv`` and the ``contacts`` list of summary.json.

With wrench states (``process.wrench``) :class:`~elastic_pm_dyn.observer.core.contact.ContactDetector`
runs over the estimate rows as the live node runs it over its estimates (the estimates bag's
``/observer/contact`` and ``/observer/contact_release`` carry the same events): each event with
its row's exact stamp, the filter time, the test statistic, the threshold and the wrench estimate
then. Without wrench states there are no events and neither file nor key is written.
"""

from __future__ import annotations

import csv
from pathlib import Path

from elastic_pm_dyn.observer.core.contact import ContactDetector, ContactEvent
from elastic_pm_dyn.observer.drivers.rows import Rows


def contact_events(rows: Rows) -> list[tuple[int, ContactEvent]] | None:
    """(stamp [ns], event) of every contact and release in ``rows``; None without wrench states."""
    if rows.layout is None or not rows.layout.wrench_names:
        return None
    detector = ContactDetector(rows.layout)
    events = []
    for ns, row in zip(rows.t, rows.flat, strict=True):  # row by row: no stacked copy of every covariance
        event = detector.update(row)
        if event is not None:
            events.append((int(ns), event))
    return events


def summary_entries(events: list[tuple[int, ContactEvent]]) -> list[dict]:
    """The ``contacts`` list of summary.json: kind, stamp_ns, t, statistic, threshold, wrench."""
    return [{"kind": e.kind, "stamp_ns": ns, "t": e.t, "statistic": e.statistic, "threshold": e.threshold,
             "wrench": [float(w) for w in e.wrench]} for ns, e in events]


def write_csv(path: Path, rows: Rows, events: list[tuple[int, ContactEvent]]) -> None:
    """``contacts.csv``: one line per event (a header only when there was none)."""
    names = rows.layout.wrench_names
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["kind", "stamp_ns", "t", "statistic", "threshold", *(f"wrench_{n}" for n in names)])
        for ns, e in events:
            w.writerow([e.kind, ns, repr(e.t), repr(e.statistic), repr(e.threshold),
                        *(repr(float(x)) for x in e.wrench)])
