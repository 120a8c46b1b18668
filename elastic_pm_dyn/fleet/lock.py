"""One batch at a time per output folder: an exclusive ``flock`` on ``OUT/.batch.lock``.

Two overlapping runs on one folder (cron starting the next before the last ended) would
both run the same items and both write the table. The lock is the kernel's: it goes with
the process that holds it, however that process ends (SIGKILL included), so a stale lock
file never blocks a later run. The file keeps the holder's pid, host and start time for the
refusal's line. (On NFS, ``flock`` needs a server that supports locks, as NFSv4 does.)
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from elastic_pm_dyn.errors import InputError

NAME = ".batch.lock"


class FolderInUse(InputError):
    """Another batch holds the output folder."""


def _holder(f) -> str:
    f.seek(0)
    text = f.read(200).strip()
    return f" ({text})" if text else ""


@contextlib.contextmanager
def held(out: Path, wait: bool = False, say: Callable[[str], None] | None = None) -> Iterator[None]:
    """Hold ``out``'s lock for the block; another holder: refuse (``FolderInUse``) or, with
    ``wait``, wait for it (saying so once)."""
    path = out / NAME
    with open(path, "a+") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if not wait:
                raise FolderInUse(f"{out}: another batch is running on this output folder{_holder(f)}: wait for it "
                                  "to end, or give --wait") from None
            if say:
                say(f"elastic-pm-dyn: waiting for the batch running on {out}{_holder(f)}")
            fcntl.flock(f, fcntl.LOCK_EX)
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on {socket.gethostname()}, since {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        f.flush()
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                f.truncate(0)
            fcntl.flock(f, fcntl.LOCK_UN)
