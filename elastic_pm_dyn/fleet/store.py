"""Where a batch keeps its items, and whether an item is done.

::

    OUT/items/<id>/     the command's outputs and item.json (the item's record), written under a
                        hidden temporary name and renamed into place when complete
    OUT/failed/<id>.json  the record of an item that failed (removed when it succeeds later)
    OUT/results.csv, results.parquet, overview plots, batch.json

An item is complete when ``items/<id>/item.json`` exists with the item's key: a re-run skips
it; any other state (missing, a failure, a key of other inputs) runs it again. A worker
killed mid-item leaves no folder (only a hidden temporary, swept on the next run).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.output_files import write_text

RECORD = "item.json"


def item_dir(out: Path, item: Item) -> Path:
    return out / "items" / item.id


def failed_path(out: Path, item: Item) -> Path:
    return out / "failed" / f"{item.id}.json"


def read_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def complete(out: Path, item: Item) -> dict | None:
    """The record of ``item``'s finished folder, or None when it has to run."""
    record = read_json(item_dir(out, item) / RECORD)
    return record if record is not None and record.get("key") == item.key and record.get("status") == "ok" else None


def previous_failure(out: Path, item: Item) -> dict | None:
    record = read_json(failed_path(out, item))
    return record if record is not None and record.get("key") == item.key else None


def write_failure(out: Path, record: dict) -> None:
    path = out / "failed" / f"{record['id']}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(record, indent=1, default=str) + "\n")


def clear_failure(out: Path, item: Item) -> None:
    failed_path(out, item).unlink(missing_ok=True)


def sweep(out: Path) -> int:
    """Remove the hidden temporaries a killed run left in ``items/``; returns how many."""
    folder = out / "items"
    if not folder.is_dir():
        return 0
    stale = [p for p in folder.iterdir() if p.name.startswith(".") and p.name.endswith(".tmp")]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)
