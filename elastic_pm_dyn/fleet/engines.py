"""Where the items run: a local process pool (default) or a Dask distributed cluster.

Both hand each item to :func:`~elastic_pm_dyn.fleet.runners.run_item` in a worker process
and pass every record back as it arrives; neither schedules anything of its own. A worker
killed mid-item (the OOM killer, a node lost) is retried: the local pool starts a fresh
pool for the items that were not finished (an item counts an attempt only if it had
started: its hidden temporary folder is there), Dask reschedules them itself
(``distributed.scheduler.allowed-failures``). An item whose folder is complete when the
kill is noticed is taken from disk, never run twice.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet import store
from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.fleet.runners import one_line, run_item

OnRecord = Callable[[dict], None]


def killed_record(item: Item, attempts: int) -> dict:
    return {"id": item.id, "kind": item.kind, "key": item.key, "attempt": attempts, "status": "failed",
            "error": f"the worker process died {attempts} time(s) running it (killed, or out of memory)",
            "wall_s": None, "figures": {}, "item": item.row()}


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the batch, which stops them (no traceback from each)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _started(out: Path, item: Item) -> bool:
    """Whether a killed worker had begun ``item`` (atomic_dir's hidden folder is left)."""
    return any((out / "items").glob(f".{item.id}.*.tmp"))


class LocalPool:
    """``workers`` processes on this machine (default: every core)."""

    def __init__(self, workers: int | None = None):
        self.workers = workers or os.cpu_count() or 1
        self.name = f"local pool, {self.workers} process(es)"

    def run(self, items: list[Item], out: Path, on_record: OnRecord, retries: int = 2) -> None:
        attempts = dict.fromkeys((it.id for it in items), 0)
        todo = list(items)
        while todo:
            todo = self._round(todo, out, on_record, retries, attempts)

    def _round(self, items: list[Item], out: Path, on_record: OnRecord, retries: int,
               attempts: dict[str, int]) -> list[Item]:
        """Run ``items`` in a fresh pool; the items to run again after a worker died."""
        context = multiprocessing.get_context("spawn")  # no fork of a process with threads and numba state
        pool = ProcessPoolExecutor(min(self.workers, len(items)), mp_context=context, initializer=_ignore_sigint)
        again: list[Item] = []
        try:
            futures = {pool.submit(run_item, it, str(out), attempts[it.id] + 1): it for it in items}
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
                for fut in done:
                    it = futures[fut]
                    try:
                        record = fut.result()
                    except BrokenProcessPool:
                        record = store.complete(out, it)
                        if record is None:
                            if _started(out, it):
                                attempts[it.id] += 1
                            if attempts[it.id] > retries:
                                record = killed_record(it, attempts[it.id])
                                store.write_failure(out, record)
                            else:
                                again.append(it)
                                continue
                    on_record(record)
            store.sweep(out)  # the killed workers' half-written folders
            return again
        except BaseException:  # Ctrl-C: stop the workers now; finished items stay in place
            _stop(pool)
            store.sweep(out)  # the stopped items' half-written folders
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _stop(pool: ProcessPoolExecutor) -> None:
    """Terminate the pool's workers (no public API for it) and wait until they are gone."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for proc in procs:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            proc.terminate()
    for proc in procs:
        with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
            proc.join(5)
    pool.shutdown(wait=False, cancel_futures=True)


class DaskEngine:
    """Dask distributed: ``local:N`` for a LocalCluster of N worker processes, else a
    scheduler address (``tcp://host:8786``). Workers must see the models, the inputs and
    the output folder at the same paths (shared storage) and have this package installed."""

    def __init__(self, cluster: str):
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise InputError("--cluster needs Dask distributed: pip install 'elastic_pm_dyn[batch]' "
                             "(or dask[distributed])") from None
        self.cluster = cluster
        self.local = None
        if cluster.startswith("local:"):
            try:
                self.local = int(cluster.split(":", 1)[1])
            except ValueError:
                self.local = 0
            if not 1 <= self.local <= 1024:
                raise InputError(f"--cluster {cluster}: expected local:N with N workers, 1 to 1024")
        self.name = f"Dask LocalCluster, {self.local} worker(s)" if self.local else f"Dask cluster {cluster}"

    def run(self, items: list[Item], out: Path, on_record: OnRecord, retries: int = 2) -> None:
        import dask
        from distributed import Client, LocalCluster, as_completed
        with dask.config.set({"distributed.scheduler.allowed-failures": retries}), contextlib.ExitStack() as stack:
            if self.local:
                cluster = stack.enter_context(LocalCluster(n_workers=self.local, threads_per_worker=1, processes=True,
                                                           dashboard_address=None, silence_logs=logging.ERROR))
                client = stack.enter_context(Client(cluster))
            else:
                try:
                    client = stack.enter_context(Client(self.cluster, timeout="20s"))
                except (OSError, TimeoutError, ValueError) as err:
                    raise InputError(f"--cluster {self.cluster}: cannot connect: {' '.join(str(err).split())}"
                                     ) from None
            futures = {client.submit(run_item, it, str(out), 1, key=f"epd-{it.id}-{it.key}", pure=False): it
                       for it in items}
            try:
                for fut in as_completed(futures):
                    it = futures[fut]
                    try:
                        record = fut.result()
                    except Exception as err:  # KilledWorker: its workers died allowed-failures + 1 times
                        record = store.complete(out, it)
                        if record is None:
                            record = killed_record(it, retries + 1)
                            if type(err).__name__ != "KilledWorker":  # lost otherwise (a worker without the package)
                                record["error"] = one_line(f"{type(err).__name__}: {err}")
                            store.write_failure(out, record)
                    on_record(record)
            except BaseException:  # Ctrl-C: cancel what has not finished; finished items stay
                with contextlib.suppress(Exception):
                    client.cancel(list(futures))
                raise


def engine(cluster: str | None = None, workers: int | None = None) -> LocalPool | DaskEngine:
    """The engine the user asks for: none -> the local pool (``workers`` processes)."""
    if workers is not None and not 1 <= workers <= 4096:
        raise InputError(f"--jobs must be 1 to 4096, got {workers}")
    return DaskEngine(cluster) if cluster else LocalPool(workers)
