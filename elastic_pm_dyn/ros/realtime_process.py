"""Keeping a realtime loop's process out of its own way: the garbage collector, CPU affinity,
SCHED_FIFO priority (Linux). Each is best effort: what the system does not permit is one
warning line and the node runs on without it."""

from __future__ import annotations

import gc
import os
import time
from collections.abc import Sequence
from typing import Any

from elastic_pm_dyn.ros.params import Param, ParameterError

# The process settings a node of a realtime loop takes (the plant in sync_mode realtime, the observer
# node always): without them a loop beside other load gets its fair share of the CPUs, not what it needs.
PROCESS_PARAMS = [
    Param("realtime.cpu_affinity", [], "realtime: CPUs the process runs on (empty: any)", item=int),
    Param("realtime.priority", 0, "realtime: SCHED_FIFO priority 1-99 where permitted (0: normal scheduling)"),
    Param("realtime.nice", 0, "nice value -20..19 of every thread of the process (negative where permitted: "
          "ahead of other load under normal scheduling)"),
]


def refusal(p: dict[str, Any]) -> str | None:
    """Why the :data:`PROCESS_PARAMS` values in ``p`` are refused, or None."""
    if not 0 <= p["realtime.priority"] <= 99:
        return f"parameter 'realtime.priority' must lie in 0-99 (0: normal scheduling), got {p['realtime.priority']}"
    if not -20 <= p["realtime.nice"] <= 19:
        return f"parameter 'realtime.nice' must lie in -20..19, got {p['realtime.nice']}"
    if any(c < 0 for c in p["realtime.cpu_affinity"]):
        return f"parameter 'realtime.cpu_affinity' must list CPU numbers >= 0, got {p['realtime.cpu_affinity']}"
    return None


def schedule_process(node: Any, p: dict[str, Any]) -> None:
    """A node that is part of a realtime loop but has no period of its own (observer, recorder): the
    :data:`PROCESS_PARAMS` checked (ParameterError) and applied, its garbage collector left on."""
    if (why := refusal(p)) is not None:
        raise ParameterError(why)
    if applied := prepare(node.get_logger(), p["realtime.cpu_affinity"], p["realtime.priority"], False,
                          p["realtime.nice"]):
        node.get_logger().info(f"realtime: {', '.join(applied)}")


def prepare(logger: Any, cpus: Sequence[int], priority: int, keep_gc_out: bool, nice: int = 0) -> list[str]:
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
            for tid in _threads():
                os.sched_setaffinity(tid, set(cpus))
            applied.append(f"CPUs {sorted(set(cpus))}")
        except (OSError, AttributeError, ValueError) as err:
            logger.warning(f"realtime.cpu_affinity {list(cpus)} not applied: {err}")
    if nice:
        try:
            for tid in _threads():
                os.setpriority(os.PRIO_PROCESS, tid, nice)
            applied.append(f"nice {nice}")
        except (OSError, AttributeError) as err:  # EPERM below 0 without CAP_SYS_NICE / a nice limit
            logger.warning(f"realtime.nice {nice} not applied: {err} "
                           "(needs CAP_SYS_NICE or a nice limit, e.g. /etc/security/limits.conf)")
    if priority:
        try:
            # the calling thread only: with the middleware's threads on SCHED_FIFO too, a plant that
            # fell behind starved every reader below it (a recorder got 1 of 3000 states)
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            applied.append(f"SCHED_FIFO {priority}")
        except (OSError, AttributeError, ValueError) as err:  # EPERM without CAP_SYS_NICE / rtprio limit
            logger.warning(f"realtime.priority {priority} (SCHED_FIFO) not applied: {err} "
                           "(needs CAP_SYS_NICE or an rtprio limit, e.g. /etc/security/limits.conf)")
    return applied


def _threads() -> list[int]:
    """Every thread of this process: the middleware's receive threads started with rclpy, before any
    node, and a setting made for the calling thread alone would leave them behind the other load
    (a recorder on SCHED_FIFO lost 85 % of its messages that way)."""
    try:
        return sorted(int(t) for t in os.listdir("/proc/self/task"))
    except OSError:  # no /proc: the calling thread alone
        return [0]


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
