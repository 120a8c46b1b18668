"""Timing helpers shared by bench/benchmarks/bench_dynamics.py and bench_cost.py.

Items timed in batches (``Item``, ``calibrate``), rounds in a fresh random order each time
(``run_rounds``: load from other users of the machine hits all items alike), medians and
quartiles (``stats``), the dispatch-cost probes (a compiled no-op with the arguments of
``accelerations``, an overload's direct entry point), and what machine and commit a result
came from. Moved here from bench_dynamics.py unchanged, so that no bench script imports another.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common
from common import REPO

import elastic_pm_dyn
from elastic_pm_dyn.dynamics.evaluate import accelerations


@njit(cache=True)
def _noop_same_args(form, ma, q, qd, tau, a, b, qdd_prev, qdd, lam):
    return 1.0, 0.0


@njit(cache=True)
def _loop_accelerations(form, ma, q, qd, tau, qdd_prev, qdd, lam, n):
    s = 0.0
    for _ in range(n):
        c, g = accelerations(form, ma, q, qd, tau, 0.0, 0.0, qdd_prev, qdd, lam)
        s += c + g
    return s


def _entry_point(dispatcher, *args):
    """The direct entry point of the overload compiled for args (skips numba's argument typing).

    It still unboxes the arguments but trusts their types: wrong dtypes or layouts are
    not caught. A what-if for the dispatch cost, not an API.
    """
    from numba import typeof

    dispatcher(*args)
    return dispatcher.overloads[tuple(typeof(x) for x in args)].entry_point


class Item:
    """One timed thing: ``run(k)`` does k calls (or k inner iterations) and returns the
    number of units done; ``reset()`` runs untimed before each batch."""

    def __init__(self, name, run, reset=None, group="", unit="call", k=None, note=""):
        self.name, self.run, self.reset = name, run, reset
        self.group, self.unit, self.k, self.note = group, unit, k, note
        self.samples: list[float] = []  # seconds per unit, one per batch
        self.phase = ""  # "short" or "long": items of one phase are timed in the same rounds

    def time_batch(self) -> float:
        if self.reset is not None:
            self.reset()
        t0 = time.perf_counter_ns()
        units = self.run(self.k)
        return (time.perf_counter_ns() - t0) * 1e-9 / units


def _calls(f, *args):
    def run(k):
        for _ in range(k):
            f(*args)
        return k
    return run


def _inner(f, *args):
    """An item whose run(k) is one call doing k iterations inside compiled code."""
    def run(k):
        f(*args, k)
        return k
    return run


def calibrate(item: Item, target: float):
    if item.k is None:
        item.k = 1
        item.time_batch()  # warm-up (and JIT) first
        t = min(item.time_batch() for _ in range(3))
        item.k = max(1, round(target / t))
    else:
        item.time_batch()


def run_rounds(items: list[Item], rounds: int, rng: np.random.Generator, budget_s: float):
    t_end = time.perf_counter() + budget_s
    done = 0
    for _ in range(rounds):
        for i in rng.permutation(len(items)):
            items[i].samples.append(items[i].time_batch())
        done += 1
        if time.perf_counter() > t_end:
            break
    return done


def stats(samples: list[float]) -> dict:
    a = np.asarray(samples)
    q25, q50, q75 = np.percentile(a, [25, 50, 75])
    return {"median_us": q50 * 1e6, "q25_us": q25 * 1e6, "q75_us": q75 * 1e6, "iqr_us": (q75 - q25) * 1e6,
            "min_us": a.min() * 1e6, "n_batches": int(a.size)}


def git_commit() -> str:
    import subprocess

    try:
        out = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"], capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or "?"
    except (OSError, subprocess.SubprocessError):
        return "?"


def machine_info(peers: dict[str, str]) -> dict:
    cpu = platform.processor() or "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import numba

    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(),
            "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
            "elastic_pm_dyn": getattr(elastic_pm_dyn, "__version__", "?"),
            "pinocchio": peers.get("pinocchio"), "mujoco": peers.get("mujoco")}
