"""A progress line with counts, rate and ETA: redrawn in place on a terminal; in a log or a
pipe one line every ``every`` seconds from a heartbeat thread (whether or not an item ended:
a log that says nothing for minutes looks like a hung batch) and one at the end.

:class:`Watch` is what an engine tells the batch besides records: how many items run now,
and a line when a worker is lost.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

COUNTERS = {"ok": "done", "failed": "failed", "skipped": "skipped"}  # record status -> count


def _clock(seconds: float) -> str:
    s = max(0, round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


def _ignore(*_: object) -> None:
    pass


@dataclass
class Watch:
    """An engine's reports: ``running(n)`` items in workers now, ``say(line)`` (a worker lost)."""

    running: Callable[[int], None] = _ignore
    say: Callable[[str], None] = _ignore


class Progress:
    """Counts of done, failed, skipped and running items of ``total``; rate and ETA from the
    items run so far."""

    def __init__(self, total: int, stream: TextIO | None = None, every: float = 10.0, width: int = 24):
        self.total, self.done, self.failed, self.skipped, self.running = total, 0, 0, 0, 0
        self.stream = sys.stderr if stream is None else stream
        self.every, self.width = every, width
        self.start = time.monotonic()
        self._last = -1e9
        self._lock = threading.Lock()  # the heartbeat thread and the batch both write
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    @property
    def finished(self) -> int:
        return self.done + self.failed + self.skipped

    def rate(self) -> float | None:
        """Items run here per minute (skipped ones cost nothing)."""
        ran = self.done + self.failed
        elapsed = time.monotonic() - self.start
        return ran / elapsed * 60 if ran and elapsed > 0 else None

    def eta(self) -> float | None:
        """Seconds left at the rate of the items run here."""
        left = self.total - self.finished
        if left == 0:
            return 0.0
        rate = self.rate()
        return None if rate is None else left / rate * 60

    def line(self) -> str:
        share = self.finished / self.total if self.total else 1.0
        bar = "#" * round(share * self.width) + "." * (self.width - round(share * self.width))
        eta, rate = self.eta(), self.rate()
        return (f"[{bar}] {self.finished}/{self.total}  done {self.done}, running {self.running}, failed "
                f"{self.failed}, skipped {self.skipped}  rate " + ("?" if rate is None else f"{rate:.3g}/min")
                + f"  elapsed {_clock(time.monotonic() - self.start)}  ETA " + ("?" if eta is None else _clock(eta)))

    def update(self, status: str) -> None:
        counter = COUNTERS[status]
        with self._lock:
            setattr(self, counter, getattr(self, counter) + 1)
        self.show()

    def set_running(self, n: int) -> None:
        self.running = n

    def show(self, final: bool = False) -> None:
        with self._lock:
            now = time.monotonic()
            if self.tty:
                self.stream.write("\r" + self.line() + ("\n" if final else ""))
            elif final or now - self._last >= self.every:
                self.stream.write(self.line() + "\n")
                self._last = now
            else:
                return
            self.stream.flush()

    def beat(self, also: Callable[[], None] | None = None) -> Progress:
        """Start the heartbeat: the line every ``every`` seconds until :meth:`close` (and
        ``also`` called each second or so)."""
        def run() -> None:
            while not self._stop.wait(min(1.0, self.every / 4)):  # show() keeps a log's lines `every` apart
                self.show()
                if also is not None:
                    also()

        self._beat = threading.Thread(target=run, daemon=True, name="epd-batch-heartbeat")
        self._beat.start()
        return self

    def close(self) -> None:
        """Stop the heartbeat and write the last line."""
        self._stop.set()
        if self._beat is not None:
            self._beat.join(5)
        self.show(final=True)
