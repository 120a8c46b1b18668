"""A progress line with counts and ETA: redrawn in place on a terminal, one line every
``every`` seconds (and at the end) into a log or a pipe."""

from __future__ import annotations

import sys
import time
from typing import TextIO

COUNTERS = {"ok": "done", "failed": "failed", "skipped": "skipped"}  # record status -> count


def _clock(seconds: float) -> str:
    s = max(0, round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


class Progress:
    """Counts of done, failed and skipped items of ``total``; ETA from the items run so far."""

    def __init__(self, total: int, stream: TextIO | None = None, every: float = 10.0, width: int = 24):
        self.total, self.done, self.failed, self.skipped = total, 0, 0, 0
        self.stream = sys.stderr if stream is None else stream
        self.every, self.width = every, width
        self.start = time.monotonic()
        self._last = -1e9
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    @property
    def finished(self) -> int:
        return self.done + self.failed + self.skipped

    def eta(self) -> float | None:
        """Seconds left at the rate of the items run here (skipped ones cost nothing)."""
        ran = self.done + self.failed
        left = self.total - self.finished
        if left == 0:
            return 0.0
        if ran == 0:
            return None
        return (time.monotonic() - self.start) / ran * left

    def line(self) -> str:
        share = self.finished / self.total if self.total else 1.0
        bar = "#" * round(share * self.width) + "." * (self.width - round(share * self.width))
        eta = self.eta()
        return (f"[{bar}] {self.finished}/{self.total}  done {self.done}, failed {self.failed}, skipped "
                f"{self.skipped}  elapsed {_clock(time.monotonic() - self.start)}  ETA "
                + ("?" if eta is None else _clock(eta)))

    def update(self, status: str) -> None:
        counter = COUNTERS[status]
        setattr(self, counter, getattr(self, counter) + 1)
        self.show()

    def show(self, final: bool = False) -> None:
        now = time.monotonic()
        if self.tty:
            self.stream.write("\r" + self.line() + ("\n" if final else ""))
        elif final or now - self._last >= self.every or self.finished == self.total:
            self.stream.write(self.line() + "\n")
            self._last = now
        self.stream.flush()
