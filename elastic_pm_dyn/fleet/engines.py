"""Where the items run: a local process pool (default) or a Dask distributed cluster.

Both hand each item to :func:`~elastic_pm_dyn.fleet.runners.run_item` in a worker process
and pass every record back as it arrives. A worker killed mid-item (the OOM killer, a node
lost) costs only its own item: the local pool (:mod:`~elastic_pm_dyn.fleet.pool`) gives it
to a fresh worker, Dask reschedules it itself (``distributed.scheduler.allowed-failures``).
An item whose folder is complete when the kill is noticed is taken from disk, never run twice.

On Dask a finished item is never computed again: its result is taken and its future
released as soon as it finishes (the scheduler keeps no result that a dying worker could
"lose" and recompute), and a task the scheduler runs again anyway (its worker died before
the result was taken) finds the item complete on disk and returns that record. Attempts are
counted on disk (``OUT/attempts/``), a hung item ends by its worker's watchdog
(:mod:`~elastic_pm_dyn.fleet.watchdog`), and every second the engine looks at what each
worker holds, to log a worker that is gone with its item. A worker whose watchdog cannot run
(SIGSTOPped, wedged in native code) is ended from outside once its item is ``OVERDUE_S`` past
its limit: SIGKILLed where it runs on this host (its nanny starts a fresh one), else removed
by the scheduler; either way the scheduler runs the item again or gives it up.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet import store
from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.fleet.pool import LocalPool, killed_record
from elastic_pm_dyn.fleet.progress import Watch
from elastic_pm_dyn.fleet.runners import one_line, run_item
from elastic_pm_dyn.fleet.warm import warm_up

OnRecord = Callable[[dict], None]
LOOK_S = 1.0  # how often the engine looks at the workers (a result that arrives wakes it sooner)
OVERDUE_S = 10.0  # [s] past an item's limit, its worker's own watchdog has had its chance


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

    def run(self, items: list[Item], out: Path, on_record: OnRecord, retries: int = 2,
            timeouts: Mapping[str, float] | None = None, watch: Watch | None = None) -> None:
        import dask
        from distributed import Client, LocalCluster
        watch = watch or Watch()
        # one task at a time per worker thread: what a dead worker held is what it ran
        settings = {"distributed.scheduler.allowed-failures": retries, "distributed.scheduler.worker-saturation": 1.0}
        with dask.config.set(settings), contextlib.ExitStack() as stack:
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
            with contextlib.suppress(Exception):  # the workers there now; a warm-up is an extra
                client.run(warm_up, items[0])
            limits = timeouts or {}
            futures = {client.submit(run_item, it, str(out), None, limits.get(it.id), key=f"epd-{it.id}-{it.key}",
                                     pure=False): it for it in items}
            try:
                _collect(client, futures, out, on_record, retries, watch, limits)
            except BaseException:  # Ctrl-C: cancel what has not finished; finished items stay
                with contextlib.suppress(Exception):
                    client.cancel(list(futures))
                raise
        store.sweep_items(out)  # every task has ended: what is half-written is a dead worker's


def _collect(client, futures: dict, out: Path, on_record: OnRecord, retries: int, watch: Watch,
             limits: Mapping[str, float]) -> None:
    """Each record as its task ends (its future released at once); the workers looked at
    every ``LOOK_S``."""
    from distributed import wait
    pending = dict(futures)
    by_key = {str(f.key): it for f, it in pending.items()}
    workers = _Workers(client, out, watch, limits)
    while pending:
        with contextlib.suppress(TimeoutError):
            wait(list(pending), timeout=LOOK_S, return_when="FIRST_COMPLETED")
        for fut in [f for f in pending if f.done()]:
            it = pending.pop(fut)
            record = _record(fut, it, out, retries)
            fut.release()  # the scheduler forgets the result: nothing to recompute when a worker dies
            workers.tell_lost(it)  # those a look missed (a worker lost between two looks)
            on_record(record)
        left = {it.id for it in pending.values()}
        workers.look({k: it for k, it in by_key.items() if it.id in left})


def _record(fut, item: Item, out: Path, retries: int) -> dict:
    try:
        return fut.result()
    except Exception as err:  # KilledWorker: its workers died allowed-failures + 1 times
        record = store.complete(out, item)
        if record is not None:
            return record
        limit = store.timed_out(out, item)
        record = killed_record(item, max(1, len(store.attempts(out, item))),
                               f"timed out after {limit:g} s" if limit else "worker died")
        if type(err).__name__ != "KilledWorker":  # lost otherwise (a worker without the package)
            record["error"] = one_line(f"{type(err).__name__}: {err}")
        store.write_failure(out, record)
        return record


def _whoami() -> str:
    """A worker's "pid host", as its items' start lines in OUT/attempts/ name it."""
    import os
    import socket
    return f"{os.getpid()} {socket.gethostname()}"


class _Workers:
    """What each worker held at the last look, and which worker processes they are: a worker
    gone since is logged with the items it was running (and its half-written folders
    removed); each lost start of an item is told once."""

    def __init__(self, client, out: Path, watch: Watch, limits: Mapping[str, float] | None = None):
        self.client, self.out, self.watch = client, out, watch
        self.limits = limits or {}
        self.held: dict[str, list[str]] = {}
        self.who: dict[str, str] = {}  # address -> "pid host"
        self.asked: set[str] = set()  # addresses asked for it
        self.told: set[tuple[str, int]] = set()  # (item, attempt)

    def look(self, running: dict[str, Item]) -> None:
        try:
            now = {str(a): [str(k) for k in keys] for a, keys in self.client.processing().items()}
        except Exception:  # the scheduler busy or gone: the next look, or the results, will tell
            return
        for address in now:
            self._ask_who(address)
        for address, keys in self.held.items():
            if address not in now:
                for key in keys:
                    if key in running:
                        self._lost(address, running[key])
        self.held = now
        self.watch.running(sum(len(k) for k in now.values()))
        for address, keys in now.items():
            for key in keys:
                if key in running:
                    self._end_if_overdue(address, running[key])

    def _ask_who(self, address: str) -> None:
        """Learn a new worker's process, in a thread of its own: a stopped worker never answers,
        and the looks (which end it when it is overdue) must go on meanwhile."""
        if address in self.asked:
            return
        self.asked.add(address)

        def ask() -> None:
            with contextlib.suppress(Exception):  # gone or stopped: its items' start lines still name it
                self.who.update({str(a): w for a, w in self.client.run(_whoami, workers=[address]).items()})
        threading.Thread(target=ask, name=f"who is {address}", daemon=True).start()

    def _end_if_overdue(self, address: str, item: Item) -> None:
        """End the worker of an item ``OVERDUE_S`` past its limit (its watchdog did not fire)."""
        limit, since = self.limits.get(item.id), store.running_since(self.out, item)
        if limit is None or since is None or time.time() - since < limit + OVERDUE_S:
            return
        store.note_timeout(self.out, item, limit)  # its row says timed out, as the watchdog's would
        starts = store.attempts(self.out, item)
        who = starts[-1]
        self.told.add((item.id, len(starts)))  # this line says it; the worker's loss needs no second one
        pid, _, host = who.partition(" ")
        if host == _whoami().split(" ", 1)[1] and pid.isdigit():
            with contextlib.suppress(OSError):
                os.kill(int(pid), signal.SIGKILL)  # a stopped process dies too; its nanny starts a fresh one
            how = "killed"
        else:
            with contextlib.suppress(Exception):
                self.client.run_on_scheduler(_remove_worker, address)
            how = "removed from the scheduler"
        self.watch.say(f"elastic-pm-dyn: worker {address} (pid {who.replace(' ', ' on ', 1)}) {how}: item {item.id} "
                       f"ran {limit + OVERDUE_S:g} s past its start, {OVERDUE_S:g} s over its {limit:g} s limit, and "
                       "its own watchdog did not end it (a stopped or wedged worker)")

    def _lost(self, address: str, item: Item) -> None:
        starts = store.attempts(self.out, item)
        mine = [n for n, line in enumerate(starts, start=1) if line == self.who.get(address)]
        if not mine:  # queued there and never started, or a worker not seen yet: its record tells
            return
        attempt = mine[-1]
        if (item.id, attempt) in self.told:  # said already (ended from outside when overdue)
            return
        self.told.add((item.id, attempt))
        pid = int(starts[attempt - 1].split()[0])
        if starts[attempt - 1].split(" ", 1)[1] == _whoami().split(" ", 1)[1]:  # a pid of this host
            store.remove_temporaries(self.out, item.id, pid)
        limit = store.timed_out(self.out, item) if attempt == len(starts) else None
        why = f"killed its item after {limit:g} s (timed out)" if limit else "died"
        self.watch.say(f"elastic-pm-dyn: worker {address} (pid {starts[attempt - 1].replace(' ', ' on ', 1)}) {why} "
                       f"holding item {item.id} (attempt {attempt}): the scheduler runs it again or gives it up")

    def tell_lost(self, item: Item) -> None:
        """A line for each earlier start of ``item`` (its worker lost) not logged yet."""
        starts = store.attempts(self.out, item)
        for n, line in enumerate(starts[:-1] if store.timed_out(self.out, item) is None else starts, start=1):
            if (item.id, n) not in self.told:
                self.told.add((item.id, n))
                self.watch.say(f"elastic-pm-dyn: worker pid {line.replace(' ', ' on ', 1)} was lost holding item "
                               f"{item.id} (attempt {n})")


async def _remove_worker(address: str, dask_scheduler=None) -> None:
    """On the scheduler: forget a worker that does not answer; its tasks go to the others."""
    await dask_scheduler.remove_worker(address=address, stimulus_id="elastic-pm-dyn-item-overdue", close=False)


def engine(cluster: str | None = None, workers: int | None = None) -> LocalPool | DaskEngine:
    """The engine the user asks for: none -> the local pool (``workers`` processes)."""
    if workers is not None and not 1 <= workers <= 4096:
        raise InputError(f"--jobs must be 1 to 4096, got {workers}")
    return DaskEngine(cluster) if cluster else LocalPool(workers)
