"""An item's own time limit inside its worker, for engines that cannot kill a hung task.

A Dask scheduler sees a worker whose task never ends as busy, not dead; the worker process
itself is the one place that can end it. Past the limit the watchdog notes why (the
engine reads it to write "timed out" rather than "worker died") and SIGKILLs its own
process: the nanny starts a fresh worker and the scheduler retries the item or gives it up.
The local pool watches its workers from outside instead (a SIGSTOPped worker runs no
watchdog).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator


@contextlib.contextmanager
def armed(timeout: float | None, before_kill: Callable[[], None]) -> Iterator[None]:
    """Kill this process if the block runs longer than ``timeout`` seconds (None: no limit)."""
    if timeout is None:
        yield
        return

    def fire() -> None:
        with contextlib.suppress(Exception):  # a note that cannot be written must not save the hung item
            before_kill()
        os.kill(os.getpid(), signal.SIGKILL)

    timer = threading.Timer(timeout, fire)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
