"""Where the items run: a local process pool (default) or a Dask distributed cluster.

Both hand each item to :func:`~elastic_pm_dyn.fleet.runners.run_item` in a worker process
and pass every record back as it arrives. A worker killed mid-item (the OOM killer, a node
lost) costs only its own item: the local pool (:mod:`~elastic_pm_dyn.fleet.pool`) gives it
to a fresh worker, Dask reschedules it itself (``distributed.scheduler.allowed-failures``).
An item whose folder is complete when the kill is noticed is taken from disk, never run twice.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from pathlib import Path

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet import store
from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.fleet.pool import LocalPool, killed_record
from elastic_pm_dyn.fleet.runners import one_line, run_item
from elastic_pm_dyn.fleet.warm import warm_up

OnRecord = Callable[[dict], None]


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
            with contextlib.suppress(Exception):  # the workers there now; a warm-up is an extra
                client.run(warm_up, items[0])
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
                            record = killed_record(it, retries + 1, "worker died")
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
