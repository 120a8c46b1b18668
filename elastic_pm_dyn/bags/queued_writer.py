"""A :class:`~elastic_pm_dyn.bags.writer.BagWriter` on a thread of its own: callers only queue.

Why: a recorder's subscription callbacks run on the ROS executor. Writing there (an mcap
chunk, a sqlite3 commit every 0.5 s) makes the executor late, the middleware's queues fill
up and messages are lost. Here :meth:`QueuedWriter.put` only appends to a queue (a few
microseconds), and one thread creates the bag, writes, flushes at least every
``flush_period`` seconds of wall clock, reports each flush (``on_flush``, so "recording
<topic>" can still mean "its first message is in the file") and closes it. Everything that
touches the bag runs on that thread (sqlite3 connections belong to the thread that made them).

The queue is bounded in bytes (:data:`MAX_QUEUED_BYTES`): a disk slower than the stream
drops messages (counted per connection in :attr:`QueuedWriter.dropped`) instead of
exhausting memory. A write error (disk full) stops the writing, keeps the bag as flushed
so far and is kept in :attr:`QueuedWriter.error`; later messages are dropped and counted.
"""

from __future__ import annotations

import queue
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any

from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.writer import BagWriter

MAX_QUEUED_BYTES = 256 * 2**20  # ~30 s of the plant's 1 kHz topics; more means the disk cannot keep up
_STOP = object()


class _Call:
    """A function to run on the writer thread, and its outcome."""

    def __init__(self, fn: Callable[[BagWriter], Any]):
        self.fn = fn
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None


class QueuedWriter:
    """The bag ``make()`` creates, owned by a thread until :meth:`close`. ``make`` runs on that
    thread; its :class:`BagError` is raised here. Call :meth:`add_connection`, :meth:`put`
    and :meth:`close` from one thread."""

    def __init__(self, make: Callable[[], BagWriter], on_flush: Callable[[BagWriter], None] = lambda w: None,
                 max_queued_bytes: int = MAX_QUEUED_BYTES):
        self.on_flush = on_flush
        self.max_queued_bytes = max_queued_bytes
        self.error: BagError | None = None
        self.dropped: Counter[int] = Counter()  # connection id -> messages not written (queue full, write error)
        self.written: Counter[int] = Counter()  # connection id -> messages handed to the writer
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        # queued = put - taken. The writer thread alone counts taken bytes; put bytes and drops
        # are counted under a lock (put may come from several threads, drops also from the writer).
        self._put_bytes = 0
        self._put_lock = threading.Lock()
        self._taken_bytes = 0
        self.writer: BagWriter | None = None
        started = _Call(lambda _: make())
        self._thread = threading.Thread(target=self._run, args=(started,), name="bag-writer", daemon=True)
        self._thread.start()
        started.done.wait()
        if started.error is not None:
            self._thread.join()
            raise started.error
        self.writer = started.result
        self.typestore = self.writer.typestore  # read-only here; new types are registered before their connection

    def call(self, fn: Callable[[BagWriter], Any]) -> Any:
        """``fn(writer)`` on the writer thread, after everything queued before; its result or exception."""
        c = _Call(fn)
        self._queue.put(c)
        c.done.wait()
        if c.error is not None:
            raise c.error
        return c.result

    def add_connection(self, topic: str, msgtype: str) -> Any:
        return self.call(lambda w: w.add_connection(topic, msgtype))

    def put(self, conn: Any, t_ns: int, raw: bytes | memoryview) -> bool:
        """Queue one message (raw CDR received at ``t_ns``); False if it was dropped. Safe to call
        from several threads (a recorder's second participant spins in its own)."""
        with self._put_lock:
            if self.error is not None or self._put_bytes - self._taken_bytes > self.max_queued_bytes:
                self.dropped[conn.id] += 1
                return False
            self._put_bytes += len(raw)
        self._queue.put((conn, t_ns, raw))
        return True

    def queued_bytes(self) -> int:
        return self._put_bytes - self._taken_bytes

    def _run(self, started: _Call) -> None:
        self._do(started, None)
        if started.error is not None:
            return
        w: BagWriter = started.result
        idle = (w.flush_period or 0.5) / 2  # wake up this often without messages, to flush what is pending
        stop = False
        while not stop:
            try:
                batch = [self._queue.get(timeout=idle)]
            except queue.Empty:
                batch = []
            while True:  # everything already waiting, in one go
                try:
                    batch.append(self._queue.get_nowait())
                except queue.Empty:
                    break
            flushed = False
            for item in batch:
                if item is _STOP:
                    stop = True
                elif isinstance(item, _Call):
                    self._do(item, w)
                else:
                    flushed |= self._write(w, *item)
            if not batch and self.error is None:
                try:
                    flushed |= w.flush()
                except BagError as err:
                    self.error = err
            if flushed:
                self.on_flush(w)

    def _write(self, w: BagWriter, conn: Any, t_ns: int, raw: bytes | memoryview) -> bool:
        self._taken_bytes += len(raw)
        if self.error is None:
            try:
                flushed = w.write(conn, t_ns, raw)
                self.written[conn.id] += 1
                return flushed
            except BagError as err:
                self.error = err
        with self._put_lock:
            self.dropped[conn.id] += 1
        return False

    @staticmethod
    def _do(c: _Call, w: BagWriter | None) -> None:
        try:
            c.result = c.fn(w)
        except BaseException as err:  # handed to the caller, which raises it
            c.error = err
        c.done.set()

    def close(self) -> None:
        """Write what is queued, finish the bag and stop the thread (raises the first write error)."""
        def finish(w: BagWriter) -> None:
            if self.error is not None:
                w.abort()
                raise self.error
            w.close()
            self.on_flush(w)
        try:
            self.call(finish)
        finally:
            self._queue.put(_STOP)
            self._thread.join()
