"""Keeping a realtime loop's process out of its own way: the garbage collector, CPU affinity,
SCHED_FIFO priority (Linux). Each is best effort: what the system does not permit is one
warning line and the node runs on without it."""

from __future__ import annotations

import gc
import os
import time
from collections.abc import Sequence
from typing import Any


def prepare(logger: Any, cpus: Sequence[int], priority: int, keep_gc_out: bool) -> list[str]:
    """Apply the realtime settings; returns what was applied, for the start-up line."""
    applied = []
    if keep_gc_out:
        # Everything built at start-up (model, compiled kernels) is frozen out of future
        # collections; automatic collections are off, the node collects between periods.
        gc.collect()
        gc.freeze()
        gc.disable()
        applied.append("gc between periods")
    if cpus:
        try:
            os.sched_setaffinity(0, set(cpus))
            applied.append(f"CPUs {sorted(set(cpus))}")
        except (OSError, AttributeError, ValueError) as err:
            logger.warning(f"realtime.cpu_affinity {list(cpus)} not applied: {err}")
    if priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            applied.append(f"SCHED_FIFO {priority}")
        except (OSError, AttributeError, ValueError) as err:  # EPERM without CAP_SYS_NICE / rtprio limit
            logger.warning(f"realtime.priority {priority} (SCHED_FIFO) not applied: {err} "
                           "(needs CAP_SYS_NICE or an rtprio limit, e.g. /etc/security/limits.conf)")
    return applied


def restore(keep_gc_out: bool) -> None:
    """Undo :func:`prepare`'s collector settings (a node destroyed in a process that goes on: tests)."""
    if keep_gc_out:
        gc.unfreeze()
        gc.enable()


def collect_young() -> float:
    """One collection of the two young generations (the cycles made since the last); its duration [s]."""
    t0 = time.perf_counter()
    gc.collect(1)
    return time.perf_counter() - t0
