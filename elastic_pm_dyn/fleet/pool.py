"""The local engine: a supervisor of its own worker processes, one item per worker at a time.

Why not ``concurrent.futures.ProcessPoolExecutor``: when one of its workers dies the whole
pool breaks and every item in flight fails with it, so the others' items had to be run
again. Here the supervisor knows which item each worker holds (it hands a worker its next
item only when the worker has returned the last one), so a worker that dies costs only its
own item: that item goes to a fresh worker, at most ``retries`` more times, then it is a
failed row "worker died (signal N)"; every other item runs once. A worker whose item runs
past its time limit (:mod:`~elastic_pm_dyn.fleet.timeouts`: hung, or SIGSTOPped) is killed
and treated the same way ("timed out after N s").

Each worker is started once per batch (``spawn``: no fork of a process with threads and
numba state) and warms up before it takes items (:func:`~elastic_pm_dyn.fleet.warm.warm_up`:
the imports and the compiled kernels of the batch's job), so an item's cost is its work.
Workers talk to the supervisor over one pipe each: ``"ready"`` once warm, then one record
per item received. A worker whose parent is gone (the batch SIGKILLed) ends quietly: no
BrokenPipeError traceback, no item finished for nobody.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from multiprocessing.connection import Connection, wait
from pathlib import Path

from elastic_pm_dyn.errors import ElasticPmDynError
from elastic_pm_dyn.fleet import store
from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.fleet.progress import Watch
from elastic_pm_dyn.fleet.runners import run_item
from elastic_pm_dyn.fleet.warm import warm_up

OnRecord = Callable[[dict], None]
READY = "ready"


class WorkersDieError(ElasticPmDynError):
    """Worker processes die before they take an item (no memory, a broken install)."""


def _serve(conn: Connection, warm: Item | None) -> None:
    """A worker's life: warm up, say ready, then run each item it is sent until ``None``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the batch's: it stops the workers
    _end_with_parent()
    try:
        if warm is not None:
            warm_up(warm)
        conn.send(READY)
        while (job := conn.recv()) is not None:
            item, out, attempt = job
            conn.send(run_item(item, out, attempt))
    except (EOFError, OSError):  # the batch is gone (BrokenPipeError is an OSError): nobody to tell
        os._exit(0)


def _end_with_parent(every: float = 0.5) -> None:
    """End this worker soon after the batch process dies (SIGKILL, the OOM killer): an orphan
    would finish its item for nobody, then print a BrokenPipeError."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(every)
        os._exit(0)

    threading.Thread(target=watch, daemon=True, name="epd-parent-watch").start()


def death(exitcode: int | None) -> str:
    """Why a worker process ended, for the failed row: "worker died (signal 9)"."""
    if exitcode is not None and exitcode < 0:
        return f"worker died (signal {-exitcode})"
    return f"worker died (exit status {exitcode})"


class _Worker:
    def __init__(self, context, warm: Item | None):
        self.conn, child = context.Pipe()
        self.proc = context.Process(target=_serve, args=(child, warm), daemon=True, name="epd-batch-worker")
        self.proc.start()
        child.close()
        self.ready = False
        self.job: tuple[Item, int] | None = None  # the item it runs and its attempt number
        self.deadline = float("inf")  # monotonic time its item runs out

    def take(self, item: Item, out: Path, attempt: int, limit: float) -> None:
        self.job = (item, attempt)
        self.deadline = time.monotonic() + limit
        self.conn.send((item, str(out), attempt))

    def receive(self) -> tuple[str, object]:
        """("message", m) if the worker sent something, ("dead", exitcode) if it is gone."""
        try:
            if self.conn.poll():
                return "message", self.conn.recv()
        except (EOFError, OSError):
            pass
        if self.proc.is_alive():
            return "none", None
        self.proc.join()
        return "dead", self.proc.exitcode

    def stop(self, now: bool) -> None:
        if not now and self.proc.is_alive():
            with contextlib.suppress(OSError, ValueError):
                self.conn.send(None)
            self.proc.join(10)
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(5)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.conn.close()


class LocalPool:
    """``workers`` processes on this machine (default: every core); ``warm``: warm each new
    worker up with the first item of the batch that starts it. The workers live for one
    batch, or, used as a context manager (``with LocalPool(4) as pool: epd.batch(...,
    engine=pool)``), for every batch run in the block."""

    def __init__(self, workers: int | None = None, warm: bool = True):
        self.workers = workers or os.cpu_count() or 1
        self.warm = warm
        self.name = f"local pool, {self.workers} process(es)"
        self._crew: list[_Worker] = []
        self._kept = False

    def __enter__(self) -> LocalPool:
        self._kept = True
        return self

    def __exit__(self, *exc: object) -> None:
        self._kept = False
        self.close(now=exc[0] is not None)

    def close(self, now: bool = False) -> None:
        """Stop the workers (``now``: without waiting for them to finish)."""
        for w in self._crew:
            w.stop(now)
        self._crew = []

    def run(self, items: list[Item], out: Path, on_record: OnRecord, retries: int = 2,
            timeouts: Mapping[str, float] | None = None, watch: Watch | None = None) -> None:
        """Run ``items``; ``on_record`` gets each item's record once. ``timeouts``: seconds per
        item id (default none); ``watch``: told the items running and each worker lost."""
        try:
            self._run(items, out, on_record, retries, timeouts or {}, watch or Watch())
        except BaseException:  # Ctrl-C or our own fault: stop the workers now; finished items stay in place
            self.close(now=True)
            store.sweep(out)  # the stopped items' half-written folders (every worker is gone)
            raise
        if not self._kept:
            self.close()

    def _run(self, items: list[Item], out: Path, on_record: OnRecord, retries: int, timeouts: Mapping[str, float],
             watch: Watch) -> None:
        context = multiprocessing.get_context("spawn")  # no fork of a process with threads and numba state
        sample = items[0] if self.warm and items else None
        queue = deque(items)
        attempts = dict.fromkeys((it.id for it in items), 0)
        left = len(items)
        start_deaths = 0
        crew = self._crew
        crew += [_Worker(context, sample) for _ in range(min(self.workers, len(items)) - len(crew))]
        while left:
            for w in crew:
                if w.ready and w.job is None and queue:
                    it = queue.popleft()
                    attempts[it.id] += 1
                    w.take(it, out, attempts[it.id], timeouts.get(it.id, float("inf")))
            watch.running(sum(w.job is not None for w in crew))
            wait([c for w in crew for c in (w.conn, w.proc.sentinel)], timeout=1.0)
            now = time.monotonic()
            for k, w in enumerate(crew):
                what, value = w.receive()
                why = death(value) if what == "dead" else ""
                if what == "none" and now > w.deadline:  # hung or stopped: SIGKILL reaches a stopped process too
                    why = f"timed out after {timeouts[w.job[0].id]:g} s" if w.job else "timed out"
                    w.proc.kill()
                    w.proc.join()
                    what = "dead"
                if what == "message" and value == READY:
                    w.ready = True
                elif what == "message":
                    w.job = None
                    w.deadline = float("inf")
                    left -= 1
                    on_record(value)
                elif what == "dead":
                    if w.job is None:  # died warming up or between items: it had nothing of ours
                        start_deaths += 1
                        if start_deaths > len(crew) * (retries + 1):
                            raise WorkersDieError(f"batch workers keep dying before they run an item "
                                                  f"({why}): out of memory?")
                    else:
                        item, attempt = w.job
                        store.remove_temporaries(out, item.id, w.proc.pid)
                        record = store.complete(out, item)  # it finished but died before it said so
                        again = record is None and attempt <= retries
                        watch.say(f"elastic-pm-dyn: worker pid {w.proc.pid} {why.removeprefix('worker ')} holding "
                                  f"item {item.id} (attempt {attempt})"
                                  + (": it runs again" if again else ": it is complete" if record else ""))
                        if again:
                            queue.appendleft(item)  # the next free worker takes it first
                        else:
                            left -= 1
                            if record is None:
                                record = killed_record(item, attempt, why)
                                store.write_failure(out, record)
                            on_record(record)
                    w.stop(now=True)
                    busy = sum(x.job is not None for x in crew if x is not w)
                    crew[k] = _Worker(context, sample) if left > busy else _Idle()
            crew[:] = [w for w in crew if not isinstance(w, _Idle)]


class _Idle:
    """A dead worker's slot when no item is left for a replacement."""


def killed_record(item: Item, attempts: int, reason: str) -> dict:
    why = "hung, or stopped" if reason.startswith("timed out") else "killed, or out of memory"
    return {"id": item.id, "kind": item.kind, "key": item.key, "attempt": attempts, "status": "failed",
            "error": f"{reason}, {attempts} time(s) running it ({why})",
            "wall_s": None, "figures": {}, "item": item.row()}
