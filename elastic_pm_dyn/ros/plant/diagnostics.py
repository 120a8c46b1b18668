"""The plant node's status on /diagnostics: level and message from what changed since the last
report, and every figure of :class:`~elastic_pm_dyn.ros.plant.stats.PlantStats` (docs/ros.md,
"Real-time figures")."""

from __future__ import annotations

import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from elastic_pm_dyn.ros.realtime_process import collect_young


def plant_status(node: Any) -> DiagnosticStatus:
    """The status of ``node`` (a :class:`~elastic_pm_dyn.ros.plant.node.PlantNode`) now; starts the
    next window of its statistics."""
    s, plant, sync = node.stats, node.plant, node.sync
    if sync.keep_gc_out:  # between periods: the collection's time shows in gc_time_ms
        s.gc_time = collect_young()
    wall = time.monotonic()
    command_age = node.hold.age(node.command_clock())
    age = f"{command_age:.6g}" if command_age is not None else ""
    waiting = sync.waiting()
    status = DiagnosticStatus(name=f"{node.get_fully_qualified_name()}: plant", hardware_id=node.hardware_id)
    if plant.fault is not None:
        status.level, status.message = DiagnosticStatus.ERROR, f"integration stopped: {plant.fault}"
    else:
        issues = _issues(node, wall)
        status.level = DiagnosticStatus.WARN if issues else DiagnosticStatus.OK
        status.message = "; ".join(issues + ([waiting] if waiting else [])) or (
            "paused" if node.paused else "running")
        if node.paused and issues:
            status.message += "; paused"
    values = {
        "sync_mode": sync.name, "formulation": node.formulation, "paused": str(node.paused).lower(),
        "waiting_for_command": str(bool(waiting)).lower(), "sim_time_s": f"{plant.t:.6f}",
        "periods": str(plant.k),
        **s.values(plant.period, plant.t, plant.k, wall),
        "closure_gap_m": f"{plant.gap():.3g}", "command_age_s": age,
        "commands_accepted": str(s.accepted), "commands_rejected": str(s.rejected),
        "zero_torque_periods": str(s.stale), "overruns": str(s.overruns),
        "commands_overwritten": str(node.command_gaps.missed),
    }
    values |= sync.diagnostic_values()
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    s.new_window(plant.t, plant.k, wall)
    s.window_overwritten = node.command_gaps.missed
    return status


def _issues(node: Any, wall: float) -> list[str]:
    """What went wrong in the window (each a WARN reason)."""
    s = node.stats
    factor = s.real_time_factor(node.plant.t, wall)
    factor_text = f"{factor:.2g}" if factor is not None else "?"
    return [text for changed, text in (
        (s.window_rejected != s.rejected, "commands rejected"),
        (s.window_stale != s.stale, "zero torque (no command or a stale one)"),
        (s.window_late != s.late_periods,
         f"realtime: {s.late_periods - s.window_late} period(s) late, up to {s.window_max_lateness * 1e3:.2f} ms"),
        (s.window_slowed != s.slowed_periods,
         f"realtime: running slower than real time (factor {factor_text}, "
         f"{s.slowed_periods - s.window_slowed} period(s) slowed)"),
        (s.window_slipped != s.slipped_periods,
         f"realtime overrun: the schedule slipped ({s.slipped_periods - s.window_slipped} period(s))"),
        (s.window_overwritten != node.command_gaps.missed and node.sync.answers_every_command,
         "commands overwritten (unanswered)"))
        if changed]
