"""The results table while the batch runs: ``results.csv`` rewritten as each record arrives
(``batch.json`` with the counts on each heartbeat), each by an atomic rename (a reader never
sees half a file; a batch killed any moment leaves the table of everything finished until
then).

Why rewrite rather than append: the columns are the items' figures, known only as they
arrive, and a CSV's header cannot grow in place. A rewrite costs about a millisecond for
tens of rows and is done for every record; once it costs more than ``CHEAP_S`` it waits at
least ``SHARE`` times its cost since the last one (the heartbeat writes what waits), so it
never takes more than a few per cent of the batch. The next run builds the table anew from
the item folders (complete items' ``item.json``) before it runs anything.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from elastic_pm_dyn.fleet import table
from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.output_files import write_text

SHARE = 20
CHEAP_S = 0.01


class LiveTable:
    """The records of ``items`` so far, written to ``out`` on each :meth:`add`. Each row's CSV
    line is formatted once (again only when a new column appears)."""

    def __init__(self, out: Path, kind: str, items: Sequence[Item], records: dict[str, dict],
                 counts: Callable[[], dict]):
        self.out, self.kind, self.records, self.counts = out, kind, records, counts
        self._ids = {it.id for it in items}
        self._rows: dict[str, dict] = {}
        self._seen: dict[str, None] = {}  # every column so far
        self._names: list[str] = []
        self._lines: dict[str, str] = {}  # id -> its CSV line under self._names
        for record in records.values():
            self._take(record)
        self._lock = threading.Lock()  # the batch adds, the heartbeat flushes
        self._table_due = self._status_due = True
        self._last, self._cost = -1e9, 0.0
        self.flush()

    def _take(self, record: dict) -> None:
        if record["id"] in self._ids:
            row = table.rows([record])[0]
            self._rows[record["id"]] = row
            self._lines.pop(record["id"], None)
            self._seen.update(dict.fromkeys(row))

    def add(self, record: dict) -> None:
        with self._lock:
            self.records[record["id"]] = record
            self._take(record)
            self._table_due = self._status_due = True
        self.flush(force=False)

    def _csv(self) -> str:
        if len(self._seen) != len(self._names):  # a new column: every line again
            self._names = table.columns([self._seen])
            self._lines = {}
        for i, row in self._rows.items():
            if i not in self._lines:
                self._lines[i] = table.csv_line([table.text(row.get(c)) for c in self._names])
        return table.csv_line(self._names) + "".join(self._lines[i] for i in sorted(self._rows))

    def flush(self, force: bool = True) -> None:
        """Write the table if anything changed (``force``, the heartbeat's: whatever it costs,
        and ``batch.json`` too, state running)."""
        with self._lock:
            now = time.monotonic()
            if self._table_due and (force or self._cost <= CHEAP_S or now - self._last >= SHARE * self._cost):
                if self._rows:
                    write_text(self.out / "results.csv", self._csv())
                self._table_due = False
                self._last = time.monotonic()
                self._cost = self._last - now
            if force and self._status_due:
                write_text(self.out / "batch.json", json.dumps({"kind": self.kind, "state": "running",
                                                                "counts": self.counts()}, indent=1) + "\n")
                self._status_due = False
