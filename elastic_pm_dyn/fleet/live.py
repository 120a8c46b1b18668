"""The results table while the batch runs: ``results.csv`` and ``batch.json`` rewritten as each
record arrives, each by an atomic rename (a reader never sees half a file; a batch killed any
moment leaves the table of everything finished until then).

Why rewrite rather than append: the columns are the items' figures, known only as they
arrive, and a CSV's header cannot grow in place. A rewrite costs milliseconds for thousands
of rows and is done for every record; once it costs more than ``CHEAP_S`` it waits at least
``SHARE`` times its cost since the last one (the heartbeat writes what waits), so it never
takes more than a few per cent of the batch. The next run
builds the table anew from the item folders (complete items' ``item.json``) before it runs
anything.
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
    """The records of ``items`` so far, written to ``out`` on each :meth:`add`."""

    def __init__(self, out: Path, kind: str, items: Sequence[Item], records: dict[str, dict],
                 counts: Callable[[], dict]):
        self.out, self.kind, self.items, self.records, self.counts = out, kind, items, records, counts
        self._lock = threading.Lock()  # the batch adds, the heartbeat flushes
        self._dirty = True
        self._last, self._cost = -1e9, 0.0
        self.flush()

    def add(self, record: dict) -> None:
        with self._lock:
            self.records[record["id"]] = record
            self._dirty = True
        self.flush(force=False)

    def flush(self, force: bool = True) -> None:
        """Write the table and ``batch.json`` (state running) if anything changed."""
        with self._lock:
            now = time.monotonic()
            if not self._dirty or (not force and self._cost > CHEAP_S and now - self._last < SHARE * self._cost):
                return
            ordered = [self.records[it.id] for it in self.items if it.id in self.records]
            if ordered:
                table.write_csv(self.out / "results.csv", sorted(table.rows(ordered), key=lambda r: str(r["id"])))
            write_text(self.out / "batch.json", json.dumps({"kind": self.kind, "state": "running",
                                                            "counts": self.counts()}, indent=1) + "\n")
            self._dirty = False
            self._last = time.monotonic()
            self._cost = self._last - now
