"""The results table: one row per item (its own columns, status, one-line error, wall time and
summary figures), as CSV and, with pyarrow installed, Parquet beside it."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path

from elastic_pm_dyn.output_files import atomic_file, write_text

FIRST = ("id", "kind", "status", "error", "robot", "date", "label", "wall_s", "attempt", "warnings")


def rows(records: Sequence[dict]) -> list[dict]:
    """Flat rows: the item's columns, the record's status fields, ``figures`` as columns."""
    out = []
    for r in records:
        row = {**(r.get("item") or {}), "id": r["id"], "kind": r["kind"], "status": r["status"],
               "error": r.get("error") or "", "wall_s": r.get("wall_s"), "attempt": r.get("attempt"),
               "warnings": r.get("warnings") or ""}
        row.update(r.get("figures") or {})
        out.append(row)
    return out


def columns(table: Sequence[dict]) -> list[str]:
    seen: dict[str, None] = {}
    for row in table:
        seen.update(dict.fromkeys(row))
    first = [c for c in FIRST if c in seen]
    return first + sorted(c for c in seen if c not in FIRST)


def text(v: object) -> str:
    """A cell: empty for None and NaN, every double as it round-trips."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return repr(v) if isinstance(v, float) else str(v)


def csv_line(cells: Sequence[str]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(cells)
    return buf.getvalue()


def write_csv(path: Path, table: Sequence[dict]) -> None:
    names = columns(table)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for row in table:
        w.writerow([text(row.get(c)) for c in names])
    write_text(path, buf.getvalue())


def _column(values: list) -> list:
    """One Parquet column: numbers stay numbers (int or float), anything else text."""
    present = [v for v in values if v is not None]
    if all(isinstance(v, bool) for v in present):
        return values
    if all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return values
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in present):
        return [None if v is None else float(v) for v in values]
    return [None if v is None else text(v) for v in values]


def write_parquet(path: Path, table: Sequence[dict]) -> bool:
    """False (nothing written) without pyarrow."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return False
    names = columns(table)
    arrays = {c: _column([row.get(c) for row in table]) for c in names}
    with atomic_file(path) as tmp:
        pq.write_table(pa.table(arrays), tmp)
    return True


def write(out: Path, records: Sequence[dict]) -> list[Path]:
    """results.csv (and results.parquet) in ``out``, rows sorted by id; the files written."""
    table = sorted(rows(records), key=lambda r: str(r["id"]))
    write_csv(out / "results.csv", table)
    written = [out / "results.csv"]
    if write_parquet(out / "results.parquet", table):
        written.append(out / "results.parquet")
    return written
