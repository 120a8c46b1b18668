"""Where a batch keeps its items, and whether an item is done.

::

    OUT/items/<id>/     the command's outputs and item.json (the item's record), written under a
                        hidden temporary name and renamed into place when complete
    OUT/failed/<id>.json  the record of an item that failed (removed when it succeeds later)
    OUT/attempts/<id>   one line per start of the item in this batch (pid host), "timeout S"
                        when a watchdog ended it: the attempts of engines that retry by themselves
    OUT/results.csv, results.parquet, overview plots, batch.json

An item is complete when ``items/<id>/item.json`` exists with the item's key: a re-run skips
it; any other state (missing, a failure, a key of other inputs) runs it again. A worker
killed mid-item leaves no folder (only a hidden temporary, swept on the next run).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
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
    """Remove the hidden temporaries a killed run left in ``items/`` and the last batch's
    attempt counts; returns how many temporaries."""
    shutil.rmtree(out / "attempts", ignore_errors=True)
    return sweep_items(out)


def sweep_items(out: Path) -> int:
    """Remove the hidden temporaries in ``items/`` (no worker of this batch may be running)."""
    folder = out / "items"
    if not folder.is_dir():
        return 0
    stale = [p for p in folder.iterdir() if p.name.startswith(".") and p.name.endswith(".tmp")]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def remove_temporaries(out: Path, item_id: str, pid: int | None) -> None:
    """The half-written folder of ``item_id`` that the dead process ``pid`` left (atomic_dir
    names it ``.<id>.<pid>.tmp``)."""
    if pid is not None:
        shutil.rmtree(out / "items" / f".{item_id}.{pid}.tmp", ignore_errors=True)


def _attempts_path(out: Path, item: Item) -> Path:
    return out / "attempts" / item.id


def begin_attempt(out: Path, item: Item) -> int:
    """Note a start of ``item`` (this process, this host); its attempt number in this batch."""
    path = _attempts_path(out, item)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:  # one short write: lines of two processes never mix
        f.write(f"{os.getpid()} {socket.gethostname()}\n")
    return len(attempts(out, item))


def note_timeout(out: Path, item: Item, seconds: float | None) -> None:
    with open(_attempts_path(out, item), "a") as f:
        f.write(f"timeout {seconds:g}\n")


def attempts(out: Path, item: Item) -> list[str]:
    """The start lines of ``item`` in this batch (see :func:`begin_attempt`)."""
    try:
        lines = _attempts_path(out, item).read_text().splitlines()
    except OSError:
        return []
    return [ln for ln in lines if not ln.startswith("timeout")]


def timed_out(out: Path, item: Item) -> float | None:
    """The limit a watchdog killed ``item``'s last attempt at, or None."""
    try:
        last = _attempts_path(out, item).read_text().splitlines()[-1]
    except (OSError, IndexError):
        return None
    return float(last.split()[1]) if last.startswith("timeout") else None


def running_since(out: Path, item: Item) -> float | None:
    """When ``item``'s last attempt started (epoch seconds) if it has not ended by a watchdog, else None."""
    path = _attempts_path(out, item)
    try:
        lines = path.read_text().splitlines()
        started = path.stat().st_mtime  # the last line written: that start
    except OSError:
        return None
    return started if lines and not lines[-1].startswith("timeout") else None


def last_pid(out: Path, item: Item) -> int | None:
    """The process of ``item``'s last start on this host (another host's pid means nothing here)."""
    for line in reversed(attempts(out, item)):
        pid, _, host = line.partition(" ")
        if host == socket.gethostname() and pid.isdigit():
            return int(pid)
    return None
