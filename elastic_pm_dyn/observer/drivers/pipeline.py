"""``observe_bag(pipeline=True)``: reading, filtering and writing at once, in three threads.

A reading thread decodes the bag in batches (:data:`CHUNK_EVENTS` events), the calling
thread filters, a writing thread writes the finished rows into a staging directory
(:data:`_STAGE` in the output directory, moved into place at the end; without it, when
``estimates/`` is there already, the files are written at the end); the compiled filter
kernel releases the GIL, and reading and writing wait while the filter runs Python. The
results, files and summary keys are those of one after the other (``pipeline=False``).

The filter takes the events in chunks of whole stamp groups. ``order="stamp"``: events are
released to it once the bag has reached stamps :data:`STAMP_LAG_NS` later; an event stamped
before what has been released already (a bag not stamp-ordered within that lag) makes the
filter start over, one after the other, on all events. ``order="arrival"``: released in bag
order, less the last stamp's events; an event stamped before the first released ones (the
observer's start time) makes it start over alike. In the summary, ``wall_read_s`` is then the
time until the bag is read, ``wall_filter_s`` and ``wall_write_s`` the time spent filtering
and writing (they overlap). Python's thread switch interval is :data:`SWITCH_INTERVAL_S`
meanwhile.
"""

from __future__ import annotations

import contextlib
import os
import queue
import shutil
import sys
import threading
import time
from pathlib import Path

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.drivers import event_filter, results
from elastic_pm_dyn.observer.drivers.bag_input import Event, Topics, iter_events
from elastic_pm_dyn.observer.drivers.bag_output import EstimatesBag, write_outputs
from elastic_pm_dyn.observer.drivers.results import FilterPass, OfflineResult
from elastic_pm_dyn.observer.drivers.rows import Rows, write_csv
from elastic_pm_dyn.observer.schedule.observer import Observer

STAMP_LAG_NS = 500_000_000
"""``observe_bag(pipeline=True, order="stamp")``: how far (header stamps) the bag must have
gone past an event before the filter takes it; later events stamped earlier than that make
the filter start over on all events, one stage after the other."""

CHUNK_EVENTS = 1000
"""``observe_bag(pipeline=True)``: events per batch from the reading thread."""

_STAGE = ".observe-partial"
_WRITE_ROWS = 64

SWITCH_INTERVAL_S = 0.001
"""``observe_bag(pipeline=True)``: Python's thread switch interval while it runs (restored
after). The filter thread leaves the GIL for every compiled call and must get it back from a
reading or writing thread busy in Python: with the default 5 ms, that wait doubled the time
filtering took; 1 ms makes it small."""

_switch_lock = threading.Lock()
_switch = {"depth": 0, "saved": 0.0}


@contextlib.contextmanager
def _short_switch_interval():
    with _switch_lock:
        if _switch["depth"] == 0:
            _switch["saved"] = sys.getswitchinterval()
            sys.setswitchinterval(min(SWITCH_INTERVAL_S, _switch["saved"]))
        _switch["depth"] += 1
    try:
        yield
    finally:
        with _switch_lock:
            _switch["depth"] -= 1
            if _switch["depth"] == 0:
                sys.setswitchinterval(_switch["saved"])


def _read_worker(bag: Path, topics: Topics, cfg: ObserverConfig, counts: dict, q: queue.Queue,
                 stop: threading.Event, gate: threading.Event) -> None:
    """Reading thread: ("batch", events)..., then ("done", time) or ("error", exception)."""
    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    gen = iter_events(bag, topics, cfg, counts, CHUNK_EVENTS, gate)
    try:
        for batch in gen:
            if not put(("batch", batch)):
                return
        put(("done", time.perf_counter()))
    except BaseException as exc:  # re-raised by the filtering thread
        put(("error", exc))
    finally:
        gen.close()


def _pieces(events: list[Event], size: int):
    """``events`` in consecutive pieces of about ``size`` events, none splitting a stamp group."""
    a, n = 0, len(events)
    while a < n:
        b = min(a + max(size, 1), n)
        while b < n and events[b].stamp_ns == events[b - 1].stamp_ns:
            b += 1
        yield events[a:b]
        a = b


class _WriteWorker(threading.Thread):
    """Writing thread: CSV (and bag) of the finished rows lo..hi-1 put into ``q``, into ``stage``."""

    def __init__(self, stage: Path, rows: Rows, storage: str, with_bag: bool, gate: threading.Event):
        super().__init__(name="observe-write", daemon=True)
        self.stage, self.rows, self.storage, self.with_bag = stage, rows, storage, with_bag
        self.gate = gate
        self.q: queue.Queue = queue.Queue()
        self.error: BaseException | None = None
        self.busy = 0.0

    def run(self) -> None:
        fh = bag = None
        try:
            while True:
                item = self.q.get()
                if item is None:
                    break
                lo, hi = item
                for a in range(lo, hi, _WRITE_ROWS):  # in pieces: waits for the gate between them
                    b = min(a + _WRITE_ROWS, hi)
                    self.gate.wait()
                    t = time.perf_counter()
                    rows = self.rows.piece(a, b)
                    header = fh is None
                    if fh is None:
                        fh = open(self.stage / "estimates.csv", "w")  # noqa: SIM115 - closed below
                        if self.with_bag:
                            bag = EstimatesBag(self.stage / "estimates", rows.layout, self.storage)
                    write_csv(fh, rows, header)
                    if bag is not None:
                        bag.write(rows)
                    self.busy += time.perf_counter() - t
        except BaseException as exc:
            self.error = exc
        finally:
            for f in (fh, bag):
                if f is not None:
                    try:
                        f.close()
                    except BaseException as exc:
                        self.error = self.error or exc

    def finish(self) -> None:
        self.q.put(None)
        self.join()
        if self.error is not None:
            raise self.error


def observe_pipelined(mech: Mechanism, cfg: ObserverConfig, bag: Path, out, topics: Topics, order: str,
                      storage: str, write_estimates_bag: bool, log, wall0: float) -> OfflineResult:
    """:func:`~elastic_pm_dyn.observer.offline.observe_bag` with ``pipeline=True`` (``order``
    "stamp" or "arrival"; ``wall0``: its start time), Python's thread switch interval
    :data:`SWITCH_INTERVAL_S` meanwhile."""
    with _short_switch_interval():
        return _observe_pipelined(mech, cfg, bag, out, topics, order, storage, write_estimates_bag, log, wall0)


def _observe_pipelined(mech: Mechanism, cfg: ObserverConfig, bag: Path, out, topics: Topics, order: str,
                       storage: str, write_estimates_bag: bool, log, wall0: float) -> OfflineResult:
    counts: dict = {}
    q: queue.Queue = queue.Queue(maxsize=8)
    stop = threading.Event()
    gate = threading.Event()  # cleared while the filter runs Python: reading and writing wait then
    gate.set()
    reader = threading.Thread(target=_read_worker, args=(bag, topics, cfg, counts, q, stop, gate),
                              name="observe-read", daemon=True)
    out = Path(out) if out is not None else None
    overlap_write = out is not None and not (write_estimates_bag and (out / "estimates").exists())
    made: list[Path] = []  # directories this call created (removed again on an error)
    stage = out / _STAGE if out is not None else None
    events: list[Event] = []
    pending: list[Event] = []
    state = {"filter": None, "writer": None, "wall": 0.0, "t0": None}
    fallback = False
    released = None  # order="stamp": every event released so far is stamped before this
    top = None

    def release(chunk: list[Event]) -> None:
        filt = state["filter"]
        if filt is None:
            state["t0"] = min(e.stamp_ns for e in events)
            obs = Observer(mech, cfg, t0=0.0)  # filter time 0 at the first stamp, the time origin
            filt = state["filter"] = event_filter.EventFilter(obs, gate=gate, origin_ns=state["t0"])
            state["report"] = obs.observability()
            if overlap_write:
                for d in (out, *out.parents):
                    if d.exists():
                        break
                    made.append(d)
                out.mkdir(parents=True, exist_ok=True)
                if stage.exists():
                    shutil.rmtree(stage)
                stage.mkdir()
                state["writer"] = _WriteWorker(stage, filt.rows, storage, write_estimates_bag, gate)
                state["writer"].start()
        t = time.perf_counter()
        n0 = len(filt.rows.t)
        filt.feed(chunk)
        state["wall"] += time.perf_counter() - t
        if state["writer"] is not None and len(filt.rows.t) > n0:
            state["writer"].q.put((n0, len(filt.rows.t)))

    reader.start()
    try:
        try:
            while True:
                what, item = q.get()
                if what == "error":
                    raise item
                if what == "done":
                    wall_read = item - wall0
                    break
                events.extend(item)
                if fallback:
                    continue
                lo = min(e.stamp_ns for e in item)
                if order == "stamp":
                    if released is not None and lo < released:
                        fallback = True
                        continue
                    pending.extend(item)
                    hi = max(e.stamp_ns for e in item)
                    top = hi if top is None else max(top, hi)
                    cut = top - STAMP_LAG_NS
                    if released is None or cut > released:
                        chunk = [e for e in pending if e.stamp_ns < cut]
                        if chunk:
                            pending = [e for e in pending if e.stamp_ns >= cut]
                            chunk.sort(key=event_filter.order_key)
                            released = cut
                            release(chunk)
                else:
                    if state["t0"] is not None and lo < state["t0"]:
                        fallback = True
                        continue
                    pending.extend(item)
                    k, last = len(pending), pending[-1].stamp_ns
                    while k > 0 and pending[k - 1].stamp_ns == last:
                        k -= 1
                    if k:
                        chunk, pending = pending[:k], pending[k:]
                        release(chunk)
        finally:
            stop.set()
            reader.join()
        if not events:
            raise InputError(f"{bag}: no messages on the observer's topics")
        if not fallback and pending:
            if order == "stamp":
                pending.sort(key=event_filter.order_key)
            for piece in _pieces(pending, CHUNK_EVENTS // 2):  # the rows written while the next is filtered
                release(piece)
        writer = state["writer"]
        if fallback:  # start over, one stage after the other
            if writer is not None:
                writer.finish()
                state["writer"] = writer = None
                shutil.rmtree(stage, ignore_errors=True)
            run = event_filter.filter_all(mech, cfg, events, order, log)
        else:
            filt = state["filter"]
            run = FilterPass(filt.obs, state["report"], filt.rows, filt.stream, filt.fault, state["wall"])
            log(run.report.text())
            for decision in run.obs.timing_decisions:  # as event_filter.filter_all logs them
                log(decision.text())
            for recovery in run.obs.recoveries:
                log(recovery.text())
        obs, rows = run.obs, run.rows
        summary = results.summary(bag, topics, counts, order, events, run, wall_read)
        if out is not None:
            wall2 = time.perf_counter()
            if writer is not None:
                writer.finish()
                state["writer"] = None
                if rows.t:
                    os.replace(stage / "estimates.csv", out / "estimates.csv")
                    if write_estimates_bag:
                        os.rename(stage / "estimates", out / "estimates")
                shutil.rmtree(stage)
                summary.wall_write_s = writer.busy + time.perf_counter() - wall2
            else:
                out.mkdir(parents=True, exist_ok=True)
                write_outputs(out, rows, write_estimates_bag, storage)
                summary.wall_write_s = time.perf_counter() - wall2
    except BaseException:
        writer = state["writer"]
        if writer is not None:
            with contextlib.suppress(BaseException):  # the first error is the one to report
                writer.finish()
            shutil.rmtree(stage, ignore_errors=True)
            for d in made:
                try:
                    d.rmdir()
                except OSError:
                    break
        raise
    return results.finish(summary, out, wall0, rows, obs)

