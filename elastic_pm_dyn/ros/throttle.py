"""Warnings throttled per kind: a steady stream of one kind (late commands) must not hide
another (NaN torques, unknown joint names), as one shared throttle per call site would."""

from __future__ import annotations

import time
from typing import Any


class KindThrottle:
    """At most one warning per ``every`` seconds (steady clock) for each kind."""

    def __init__(self, node: Any, every: float):
        self.node = node  # its logger is looked up at each line (tests replace get_logger)
        self.every = every
        self._last: dict[str, float] = {}
        self.suppressed: dict[str, int] = {}  # per kind, since its last line

    def warning(self, kind: str, text: str) -> bool:
        """Log ``text`` unless a line of ``kind`` went out less than ``every`` ago; True if logged."""
        now = time.monotonic()
        last = self._last.get(kind)
        if last is not None and now - last < self.every:
            self.suppressed[kind] = self.suppressed.get(kind, 0) + 1
            return False
        self._last[kind] = now
        hidden = self.suppressed.pop(kind, 0)
        self.node.get_logger().warning(f"{text} ({hidden} more like it since the last)" if hidden else text)
        return True
