"""``epd.batch(...)``: many items of one kind, complete ones skipped, into one output folder.

    import elastic_pm_dyn as epd
    res = epd.batch("observe", ["recordings/"], "runs/fleet", model="config/five_bar.yaml",
                    options={"sensors": ["encoders", "imu"]})
    res = epd.batch("simulate", study="studies/stiffness.yaml", out="runs/study", cluster="local:4")
    print(res.counts, res.table[0])
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet import engines, lock, plots, store, table
from elastic_pm_dyn.fleet.checks import check_options
from elastic_pm_dyn.fleet.items import Inputs, Item, check_unique, discover
from elastic_pm_dyn.fleet.live import LiveTable
from elastic_pm_dyn.fleet.progress import Progress, Watch
from elastic_pm_dyn.fleet.study import study_items
from elastic_pm_dyn.fleet.timeouts import item_timeout
from elastic_pm_dyn.output_files import write_text


@dataclass
class BatchResult:
    """Every item's record (skipped ones read from their folders), the table rows and counts."""

    out: Path
    records: list[dict]
    table: list[dict]
    counts: dict[str, int]
    engine: str
    wall_s: float
    files: list[Path] = field(default_factory=list)
    interrupted: bool = False

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.records if r["status"] == "failed"]


def items_of(kind: str, inputs: Sequence[str | Path] = (), model: str | Path | None = None,
             options: Mapping[str, object] | None = None, study: str | Path | None = None) -> list[Item]:
    """The items a batch call names (see :func:`batch`)."""
    if study is not None:
        if kind != "simulate":
            raise InputError(f"--study: simulate only, not {kind}")
        if inputs:
            raise InputError("--study replaces the inputs: give one or the other")
        if options:
            raise InputError("--study: the study file's 'fixed' settings replace item options")
        return check_unique(study_items(study))
    if not inputs:
        raise InputError("no inputs: give folders, globs or a manifest (or --study for simulate)")
    return discover([str(i) for i in inputs], Inputs(kind, None if model is None else str(model), dict(options or {})))


def _inside(source: str, out: Path) -> bool:
    """Whether an input lies in the output folder (an item's own estimates bag, found again)."""
    return bool(source) and Path(source).resolve().is_relative_to(out.resolve())


def batch(kind: str, inputs: Sequence[str | Path] = (), out: str | Path = "runs/batch", *,
          model: str | Path | None = None, options: Mapping[str, object] | None = None,
          study: str | Path | None = None, jobs: int | None = None, cluster: str | None = None,
          retries: int = 2, item_timeout_s: float | None = None, wait: bool = False,
          progress: bool = True, every: float = 10.0, plots_on: bool = True,
          log: Callable[[str], None] | None = None,
          engine: engines.LocalPool | engines.DaskEngine | None = None) -> BatchResult:
    """Run ``kind`` (observe, tune, analyze, simulate) over ``inputs`` (folders, globs, bags or
    torque tables, CSV/YAML manifests) or a simulate ``study`` file, one folder per item in
    ``out/items``, then ``out/results.csv`` (+ ``.parquet``) and overview plots.

    ``model`` and ``options`` (the command's long options without dashes, e.g.
    ``{"sensors": ["encoders", "imu"], "set": ["process.dt=5e-5"]}``) apply to every item; a
    manifest row's columns override them; both are checked before any worker starts. ``jobs``:
    local worker processes (default: every core); ``cluster``: ``"local:N"`` or a Dask
    scheduler address instead. Complete items are skipped; an item that fails is a row with
    its one-line error; a worker killed mid-item, or an item running past ``item_timeout_s``
    (default: from its recording's length, see :mod:`~elastic_pm_dyn.fleet.timeouts`), is
    retried ``retries`` times. One batch at a time per ``out`` (another one running: refused,
    or waited for with ``wait``). ``results.csv`` is written as the items finish; with
    ``progress`` a line every ``every`` seconds in a log. ``engine``: an engine of your own
    instead of ``jobs``/``cluster`` (``with LocalPool(4) as pool:`` keeps its warm workers for
    every batch in the block). On Ctrl-C the table of what is finished is written and the
    KeyboardInterrupt goes on.
    """
    started = time.perf_counter()
    say = log or (lambda s: print(s, file=sys.stderr, flush=True))
    if not 0 <= retries <= 100:
        raise InputError(f"--retries must be 0 to 100, got {retries}")
    if item_timeout_s is not None and not item_timeout_s > 0:
        raise InputError(f"--item-timeout must be a positive number of seconds, got {item_timeout_s}")
    if not every > 0:
        raise InputError(f"--heartbeat must be a positive number of seconds, got {every}")
    out = Path(out)
    items = [it for it in items_of(kind, inputs, model, options, study) if not _inside(it.source, out)]
    if not items:
        raise InputError(f"no items outside the output folder {out}")
    check_options(items)
    runner = engine if engine is not None else engines.engine(cluster, jobs)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    with lock.held(out, wait, say):
        return _run(kind, items, out, runner, retries, item_timeout_s, progress, every, plots_on, say, started)


def _run(kind: str, items: list[Item], out: Path, runner, retries: int, limit: float | None, progress: bool,
         every: float, plots_on: bool, say: Callable[[str], None], started: float) -> BatchResult:
    """The batch once ``out`` is ours: the table of what is complete, then the rest run."""
    store.sweep(out)
    records: dict[str, dict] = {}
    todo = []
    bar = Progress(len(items), every=every) if progress else None
    for it in items:
        record = store.complete(out, it)
        if record is None:
            todo.append(it)
        else:
            records[it.id] = {**record, "skipped": True}
            if bar:
                bar.skipped += 1
    live = LiveTable(out, kind, items, records, lambda: _counts(items, list(records.values())))

    def on_record(record: dict) -> None:
        live.add(record)
        if record["status"] == "failed":
            say(f"elastic-pm-dyn: item {record['id']} failed: {record['error']}")
        if bar:
            bar.update(record["status"])

    say(f"batch {kind}: {len(items)} item(s), {len(items) - len(todo)} complete already, {len(todo)} to run "
        f"on the {runner.name} -> {out}")
    watch = Watch(say=say)
    if bar:
        watch.running = bar.set_running
    timeouts = {it.id: item_timeout(it, limit) for it in todo}
    interrupted = False
    if bar:
        bar.beat(also=live.flush)
    try:
        if todo:
            runner.run(todo, out, on_record, retries, timeouts, watch)
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        if bar:
            bar.set_running(0)
            bar.close()
        result = _finish(out, kind, items, records, runner.name, time.perf_counter() - started, plots_on,
                         interrupted)
        if interrupted:
            say(f"elastic-pm-dyn: interrupted (Ctrl-C): {result.counts['ok'] + result.counts['skipped']} item(s) "
                f"complete in {out}, {result.counts['missing']} left: run the same command again to finish them")
    return result


def _counts(items: list[Item], ordered: list[dict]) -> dict[str, int]:
    return {"items": len(items), "ok": sum(r["status"] == "ok" and not r.get("skipped") for r in ordered),
            "failed": sum(r["status"] == "failed" for r in ordered),
            "skipped": sum(bool(r.get("skipped")) for r in ordered), "missing": len(items) - len(ordered)}


def _finish(out: Path, kind: str, items: list[Item], records: dict[str, dict], engine: str, wall: float,
            plots_on: bool, interrupted: bool) -> BatchResult:
    """The results table and plots of the items that have a record, and batch.json."""
    ordered = [records[it.id] for it in items if it.id in records]
    counts = _counts(items, ordered)
    rows = table.rows(ordered)
    files = table.write(out, ordered) if ordered else []
    if plots_on and rows:
        figures = sorted({k for r in ordered for k in (r.get("figures") or {})})
        params = sorted({k for r in rows for k in r if k.startswith("param.")})
        try:
            files += plots.write(out, rows, figures, params)
        except (ValueError, OSError, MemoryError) as err:  # a plot is an extra: the table stands
            print(f"elastic-pm-dyn: warning: overview plots not written: {' '.join(str(err).split())}",
                  file=sys.stderr)
    summary = {"kind": kind, "state": "interrupted" if interrupted else "finished", "engine": engine, "wall_s": wall,
               "interrupted": interrupted, "counts": counts,
               "failed": {r["id"]: r["error"] for r in ordered if r["status"] == "failed"}}
    write_text(out / "batch.json", json.dumps(summary, indent=1) + "\n")
    return BatchResult(out, ordered, rows, counts, engine, wall, files, interrupted)
