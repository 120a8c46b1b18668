"""How the plant node's periods are paced: one small class per ``sync_mode`` behind one interface.

The node holds the machine, its inputs and outputs and steps one period at a time
(:meth:`PlantNode.step_period`); a sync mode decides *when*, as a ros2_control hardware
interface's read/write is called by its controller manager:

- :class:`Realtime`: a steady-clock timer at ``publish_rate``; late ticks catch up, a plant
  further behind slows its clock or skips (:mod:`~elastic_pm_dyn.ros.plant.realtime_schedule`);
- :class:`Fast`: as fast as possible, in slices that keep the executor responsive;
- :class:`Lockstep`: one period per command (a guard condition), and before the first
  command the state and its samples published again for a controller that subscribed late.

Each takes the node and uses what it publishes, holds and counts; the node calls the same
methods whatever the mode: :meth:`SyncMode.start`, :meth:`~SyncMode.command_taken`,
:meth:`~SyncMode.command_rejected`, :meth:`~SyncMode.step_torque`, :meth:`~SyncMode.resume`,
:meth:`~SyncMode.waiting` and :meth:`~SyncMode.apply_parameter`.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from rclpy.qos import DurabilityPolicy

from elastic_pm_dyn.ros.plant.realtime_schedule import RealtimeSchedule
from elastic_pm_dyn.ros.realtime_process import prepare

FAST_SLICE = 0.005  # [s] fast mode: wall time per executor turn (amortises its ~0.2 ms; stays responsive)
# (the executor turn's cost measured 2026-11-22 on the 2-core dev machine)
WAITING_LOG_EVERY = 5.0  # [s] lockstep: the "waiting for a command" line


class SyncMode:
    """What every sync mode does alike: the torque of a period is the held command (see
    :class:`~elastic_pm_dyn.ros.plant.command_hold.CommandHold`), no wait to report."""

    name = ""
    answers_every_command = False  # lockstep: each command is one period, answered even when rejected
    own_clock = True  # the stamps are the plant's clock (simulated time), published on topics.clock
    keep_gc_out = False  # the node collects the young generations between periods (realtime)

    def __init__(self, node: Any, p: dict[str, Any], period: float):
        self.node = node

    def start(self, p: dict[str, Any], period: float) -> str:
        """Timers made, the first state shown where the mode does; text for the start-up line."""
        return ""

    def command_taken(self) -> None:
        """A valid command was held."""

    def command_rejected(self, arrival: float) -> None:
        """A command was refused (already counted and said)."""

    def step_torque(self) -> tuple[np.ndarray, float | None]:
        """The torque of one ``~/step`` period and its command's arrival (None: no new command)."""
        return self.node.held_torque(), self.node.hold.take_arrival()

    def resume(self, publish: bool) -> None:
        """Stepping goes on after pause, reset or set_state; ``publish``: show the state now."""
        if publish:
            self.node.publish_state()

    def waiting(self) -> str:
        """What the plant waits for, if it waits (empty otherwise)."""
        return ""

    def diagnostic_values(self) -> dict[str, str]:
        """The mode's own /diagnostics values."""
        return {}

    def apply_parameter(self, name: str, value: Any) -> bool:
        """Take a runtime parameter of this mode; False if it is not one."""
        return False


class Realtime(SyncMode):
    """A steady-clock timer at ``publish_rate``; behind by more than ``realtime.max_catch_up``
    periods, the clock slows (``realtime.overrun: slow``) or the stamps jump (``skip``)."""

    name = "realtime"

    def __init__(self, node: Any, p: dict[str, Any], period: float):
        super().__init__(node, p, period)
        self.overrun: str = p["realtime.overrun"]
        self.schedule = RealtimeSchedule(period, p["realtime.max_catch_up"], self.overrun)
        self.keep_gc_out: bool = p["realtime.keep_gc_out"]
        self.own_clock = self.overrun == "slow"  # skip: the stamps follow the wall clock

    def start(self, p: dict[str, Any], period: float) -> str:
        node = self.node
        node.step_timer = node.create_timer(period, self.tick, clock=node.steady)
        prepared = prepare(node.get_logger(), p["realtime.cpu_affinity"], p["realtime.priority"],
                           self.keep_gc_out, p["realtime.nice"])
        return f" ({', '.join(prepared)})" if prepared else ""

    def resume(self, publish: bool) -> None:
        self.schedule.stop()  # a fresh schedule; its first tick publishes the state

    def diagnostic_values(self) -> dict[str, str]:
        return {"overrun": self.overrun}

    def tick(self) -> None:
        node = self.node
        now = time.monotonic()
        schedule = self.schedule
        if not schedule.started:
            schedule.start(now, node.plant.k)
            if not (node.stamp_set and self.overrun == "slow"):  # skip: the stamps follow the wall clock again
                node.stamp_base = node.get_clock().now().nanoseconds - node.plant.k * node.period_ns
                node.stamp_set = True
            node.publish_state()
            return
        tick = schedule.tick(now, node.plant.k)
        s, warn = node.stats, node.warn
        if tick.slowed:
            s.overruns += 1
            s.slowed_periods += tick.slowed
            warn.warning("slowed", f"realtime: the clock slowed by {tick.slowed} period(s) "
                         f"({s.slowed_periods} so far; more than {schedule.max_catch_up} periods behind); "
                         "the stamps stay on the simulated-time grid")
        elif tick.skipped:
            s.overruns += 1
            s.slipped_periods += tick.skipped
            node.stamp_base += tick.skipped * node.period_ns
            warn.warning("slipped", f"realtime: {s.slipped_periods} period(s) slipped so far, "
                         f"{tick.skipped} now (more than {schedule.max_catch_up} periods behind); the stamps jump")
        if tick.late:
            s.late(tick.late, tick.lateness)
            warn.warning("late", f"realtime: {tick.late} period(s) caught up, the first "
                         f"{tick.lateness * 1e3:.2f} ms late ({s.late_periods} late so far; cycle_load in "
                         "/diagnostics)")
        for _ in range(tick.due):
            if not node.step_period(node.held_torque(), node.hold.take_arrival()):
                return


class Fast(SyncMode):
    """As fast as possible: periods in slices of FAST_SLICE wall time per executor turn."""

    name = "fast"

    def start(self, p: dict[str, Any], period: float) -> str:
        self.node.step_timer = self.node.create_timer(0.0, self.tick, clock=self.node.steady)
        return ""

    def tick(self) -> None:
        node = self.node
        end = time.perf_counter() + FAST_SLICE
        while time.perf_counter() < end:
            if not node.step_period(node.held_torque(), node.hold.take_arrival()):
                return


class Lockstep(SyncMode):
    """One period per command, every command answered (a rejected one holds the last valid
    command); before the first command the state and its samples are published again."""

    name = "lockstep"
    answers_every_command = True

    def __init__(self, node: Any, p: dict[str, Any], period: float):
        super().__init__(node, p, period)
        self.republish_period: float = p["lockstep.waiting_republish_period"]
        self.republish_timer: Any = None
        self.trigger: Any = None
        self.waiting_logged = 0.0
        self.matched_since: float | None = None  # a volatile state subscriber there since (monotonic)

    def start(self, p: dict[str, Any], period: float) -> str:
        node = self.node
        self.trigger = node.create_guard_condition(self.on_commands)
        self.republish_timer = node.create_timer(self.republish_period / 5, self.republish_waiting,
                                                 clock=node.steady)
        node.publish_state()
        return ""

    def command_taken(self) -> None:
        self.trigger.trigger()

    def command_rejected(self, arrival: float) -> None:
        self.node.hold.take_rejected(arrival)  # answered all the same: the last valid command holds
        self.trigger.trigger()

    def step_torque(self) -> tuple[np.ndarray, float | None]:
        return self.node.hold.next_queued()

    def resume(self, publish: bool) -> None:
        super().resume(publish)
        if self.node.hold.queue:
            self.trigger.trigger()

    def apply_parameter(self, name: str, value: Any) -> bool:
        if name != "lockstep.waiting_republish_period":
            return False
        node = self.node
        self.republish_period = value
        node.destroy_timer(self.republish_timer)
        self.republish_timer = node.create_timer(value / 5, self.republish_waiting, clock=node.steady)
        return True

    def on_commands(self) -> None:
        """One period per command (a rejected one holds the last valid command). Every command
        is answered, so a controller that waits for the state never waits more than one period:
        while integration is stopped (ERROR in /diagnostics until ~/reset or ~/set_state) the
        last good state is published again, with its own stamp (time does not advance).
        Paused: the commands wait in the queue (~/step or ~/unpause takes them)."""
        node = self.node
        while node.hold.queue and not node.paused:
            tau, arrival = node.hold.queue.popleft()
            if node.plant.fault is not None:
                node.stats.rejected += 1
                node.warn.warning("stopped", f"command ignored, integration stopped: {node.plant.fault}; "
                                  "call ~/reset or ~/set_state")
                node.publish_state()
            elif not node.step_period(tau, arrival):
                node.publish_state()  # the last good state: the plant keeps it on a fault

    def republish_waiting(self) -> None:
        """Before the first command: everything published per period again (states, clock,
        sensors, disturbance truth; the same bytes and stamp), for a controller that subscribed
        after it was published (a volatile subscriber gets no history), whichever of these
        topics it reads. Only while a volatile subscriber of one of them is there (a
        transient-local one got the state when it matched), once it has been there for a whole
        republish period and the state is that old: a controller that answers within the period
        never sees a state twice."""
        node = self.node
        if not node.hold.awaiting_first or node.paused:
            return
        now = time.monotonic()
        if not any(r.qos_profile.durability == DurabilityPolicy.VOLATILE
                   for pub in node.period_publishers()
                   for r in node.get_subscriptions_info_by_topic(pub.topic_name)):
            self.matched_since = None
            return
        if self.matched_since is None:
            self.matched_since = now
        if now - self.matched_since < self.republish_period or now - node.last_state_wall < self.republish_period:
            return
        node.publish_state(again=True)
        if now - self.waiting_logged >= WAITING_LOG_EVERY:
            self.waiting_logged = now
            node.get_logger().info(
                f"lockstep: waiting for the first command on '{node.command_sub.topic_name}' "
                f"({self._command_publishers()}); the state of t = {node.plant.t:.6g} s and its samples are "
                f"published again every {self.republish_period:g} s until one arrives")

    def _command_publishers(self) -> str:
        """Who publishes on the command topic, for the waiting line."""
        infos = self.node.get_publishers_info_by_topic(self.node.command_sub.topic_name)
        if not infos:
            return "no publisher yet"
        names = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos})
        return f"publishers: {', '.join(names)}"

    def waiting(self) -> str:
        node = self.node
        if node.hold.queue or node.plant.fault is not None:
            return ""
        if node.hold.awaiting_first:
            return (f"waiting for the first command (state of t = {node.plant.t:.6g} s re-published every "
                    f"{self.republish_period:g} s while a volatile subscriber is there)")
        idle = time.monotonic() - node.last_command_wall
        return f"waiting for a command for {idle:.3g} s" if idle > 1.0 else ""


SYNC_MODES: dict[str, type[SyncMode]] = {mode.name: mode for mode in (Realtime, Fast, Lockstep)}
