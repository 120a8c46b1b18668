"""What the plant node reports about itself on /diagnostics: counters since start and timing
over the window since the last report.

The figures, named for what they are (docs/ros.md, "Real-time figures"):
- ``cycle_load_mean`` / ``cycle_load_max``: cycle time (one period's integration plus its
  publishing) / control period. Above 1 the plant cannot keep up with the wall clock;
  ``headroom`` = 1 - ``cycle_load_max``, the share of a period left in the worst cycle of the
  window (0 or less: at least one cycle took a whole period or more).
- ``delivered_rate_hz``: periods advanced per wall-clock second over the window.
- ``late_periods``: realtime periods advanced more than half a period after their scheduled
  wall time (caught up in a later tick), each counted; ``slipped_periods``: periods the
  schedule gave up (more than ``max_catch_up`` behind), never simulated in time.
- ``latency_*_ms``: from a command's arrival in the node to the publication of the first
  state computed with it (p50, p99, max over the window).
- ``fresh_command_share``: share of the window's periods that started with a command not
  used before (1 in lockstep; in realtime below 1 when the controller is slower than the plant).
"""

from __future__ import annotations

import time

import numpy as np


class PlantStats:
    """Counters since start; timing and latency lists over the current window."""

    def __init__(self) -> None:
        self.accepted = self.rejected = self.stale = self.overruns = 0
        self.late_periods = self.slipped_periods = 0
        self.max_lateness = 0.0  # [s] since start
        self.window_overwritten = 0  # commands_overwritten at the start of the window
        self.step: list[float] = []
        self.cycle: list[float] = []
        self.latency: list[float] = []
        self.fresh = 0  # periods of the window that started with a new command
        self.gc_time = 0.0  # [s] spent in the collections run between periods (realtime)
        self.new_window(0.0, 0, time.monotonic())

    def add(self, step: float, cycle: float) -> None:
        self.step.append(step)
        self.cycle.append(cycle)

    def late(self, periods: int, lateness: float) -> None:
        self.late_periods += periods
        self.max_lateness = max(self.max_lateness, lateness)
        self.window_max_lateness = max(self.window_max_lateness, lateness)

    def new_window(self, sim: float, k: int, wall: float) -> None:
        self.window_sim, self.window_k, self.window_wall = sim, k, wall
        self.window_rejected, self.window_stale, self.window_overruns = self.rejected, self.stale, self.overruns
        self.window_late = self.late_periods
        self.window_max_lateness = 0.0
        self.step.clear()
        self.cycle.clear()
        self.latency.clear()
        self.fresh = 0

    def values(self, period: float, t: float, k: int, wall: float) -> dict[str, str]:
        """The window's figures as /diagnostics key-values."""
        elapsed = wall - self.window_wall
        periods = k - self.window_k
        load_mean, load_max = _mean(self.cycle) / period, _max(self.cycle) / period
        lat = np.asarray(self.latency) * 1e3
        return {
            "real_time_factor": f"{(t - self.window_sim) / elapsed:.4g}" if elapsed > 0 else "0",
            "delivered_rate_hz": f"{periods / elapsed:.1f}" if elapsed > 0 else "0",
            "step_time_mean_us": f"{_mean(self.step) * 1e6:.1f}", "step_time_max_us": f"{_max(self.step) * 1e6:.1f}",
            "cycle_time_mean_us": f"{_mean(self.cycle) * 1e6:.1f}",
            "cycle_time_max_us": f"{_max(self.cycle) * 1e6:.1f}",
            "cycle_load_mean": f"{load_mean:.4g}", "cycle_load_max": f"{load_max:.4g}",
            "headroom": f"{1.0 - load_max:.4g}",
            "late_periods": str(self.late_periods), "late_periods_window": str(self.late_periods - self.window_late),
            "max_lateness_ms": f"{self.max_lateness * 1e3:.3f}",
            "max_lateness_window_ms": f"{self.window_max_lateness * 1e3:.3f}",
            "slipped_periods": str(self.slipped_periods),
            "latency_p50_ms": f"{np.percentile(lat, 50):.3f}" if lat.size else "",
            "latency_p99_ms": f"{np.percentile(lat, 99):.3f}" if lat.size else "",
            "latency_max_ms": f"{lat.max():.3f}" if lat.size else "",
            "fresh_command_share": f"{self.fresh / periods:.3f}" if periods > 0 else "",
            "gc_time_ms": f"{self.gc_time * 1e3:.3f}",
        }


def _mean(x: list[float]) -> float:
    return float(np.mean(x)) if x else 0.0


def _max(x: list[float]) -> float:
    return float(np.max(x)) if x else 0.0
