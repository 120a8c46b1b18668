"""What the plant node reports about itself on /diagnostics: counters since start and timing
over the window since the last report.

The figures, named for what they are (docs/ros.md, "Real-time figures"):
- ``cycle_load_mean`` / ``cycle_load_max``: cycle time (one period's integration plus its
  publishing) / control period. Above 1 the plant cannot keep up with the wall clock;
  ``headroom`` = 1 - ``cycle_load_max``, the share of a period left in the worst cycle of the
  window (0 or less: at least one cycle took a whole period or more).
- ``delivered_rate_hz``: periods advanced per wall-clock second over the window.
- ``real_time_factor``: simulated time advanced / wall time, over the window;
  ``real_time_factor_total`` since the node started. Paused wall time is left out of both
  (~/step advances simulated time in none).
- ``late_periods``: realtime periods advanced more than half a period after their scheduled
  wall time (caught up in a later tick), each counted. More than ``max_catch_up`` behind
  (``overruns``: the ticks that found it so): ``slowed_periods``, the periods by which the
  plant's clock fell behind the wall clock (``realtime.overrun: slow``, every period
  simulated and stamped on the grid); ``slipped_periods``, the periods the stamps jumped over
  (``skip``), never simulated in time.
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
        self.late_periods = self.slipped_periods = self.slowed_periods = 0
        self.max_lateness = 0.0  # [s] since start
        self.window_overwritten = 0  # commands_overwritten at the start of the window
        self.step: list[float] = []
        self.cycle: list[float] = []
        self.latency: list[float] = []
        self.fresh = 0  # periods of the window that started with a new command
        self.gc_time = 0.0  # [s] spent in the collections run between periods (realtime)
        self.paused_wall = 0.0  # [s] wall time spent paused (pauses that ended)
        self.paused_since: float | None = None  # monotonic [s]: paused now, since
        self.start_wall = time.monotonic()
        self.new_window(0.0, 0, self.start_wall)

    def pause(self, wall: float) -> None:
        if self.paused_since is None:
            self.paused_since = wall

    def resume(self, wall: float) -> None:
        if self.paused_since is not None:
            self.paused_wall += wall - self.paused_since
            self.paused_since = None

    def running(self, wall: float) -> float:
        """Wall time [s] since start, paused time left out."""
        paused = self.paused_wall + (wall - self.paused_since if self.paused_since is not None else 0.0)
        return wall - self.start_wall - paused

    def add(self, step: float, cycle: float) -> None:
        self.step.append(step)
        self.cycle.append(cycle)

    def late(self, periods: int, lateness: float) -> None:
        self.late_periods += periods
        self.max_lateness = max(self.max_lateness, lateness)
        self.window_max_lateness = max(self.window_max_lateness, lateness)

    def new_window(self, sim: float, k: int, wall: float) -> None:
        self.window_sim, self.window_k, self.window_wall = sim, k, wall
        self.window_running = self.running(wall)
        self.window_rejected, self.window_stale = self.rejected, self.stale
        self.window_late = self.late_periods
        self.window_slowed, self.window_slipped = self.slowed_periods, self.slipped_periods
        self.window_max_lateness = 0.0
        self.step.clear()
        self.cycle.clear()
        self.latency.clear()
        self.fresh = 0

    def real_time_factor(self, t: float, wall: float) -> float | None:
        """Simulated / wall time over the window (paused time left out); None without running time."""
        running = self.running(wall) - self.window_running
        return (t - self.window_sim) / running if running > 0 else None

    def values(self, period: float, t: float, k: int, wall: float) -> dict[str, str]:
        """The window's figures as /diagnostics key-values (``t``: simulated time since start)."""
        elapsed = wall - self.window_wall
        factor, running = self.real_time_factor(t, wall), self.running(wall)
        periods = k - self.window_k
        load_mean, load_max = _mean(self.cycle) / period, _max(self.cycle) / period
        lat = np.asarray(self.latency) * 1e3
        return {
            "real_time_factor": f"{factor:.4g}" if factor is not None else "0",
            "real_time_factor_total": f"{t / running:.4g}" if running > 0 else "0",
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
            "slowed_periods": str(self.slowed_periods),
            "slowed_periods_window": str(self.slowed_periods - self.window_slowed),
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
