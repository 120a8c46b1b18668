"""A realtime plant that cannot keep up (issue #37: "realtime that bends"), with real rclpy nodes.

Each period is made to cost three periods of wall time (a sleep after the step: the overrun
does not depend on the machine's speed). By default (``realtime.overrun: slow``) the plant
slows its clock: every state is stamped on the simulated-time grid (consecutive periods, no
gap), the same stamps go out on ``clock``, and /diagnostics say WARN with a real-time factor
below 1. With ``realtime.overrun: skip`` the stamps follow the wall clock and jump (the old
behaviour). A stall that stops the plant's clock does not make the held command stale in
``slow`` (its age is measured on the plant's clock); in ``skip`` it does (wall time).
Nothing here asserts a timing figure: only stamps, counters and the reported factor.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

RATE = 1000.0
PERIOD_NS = 1_000_000
OPTIONS = dict(formulation="scdd", integrator="rk4", dt=1e-4, stabilization="projection")
TAU = [0.01, -0.02]  # left_motor, right_motor


@pytest.fixture
def ros():
    h = RosHarness(domain_id(98))
    yield h
    h.close()


def make_plant(h: RosHarness, **params: Any) -> Any:
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(PlantNode(context=h.context, parameter_overrides=overrides))


def slow_down(plant: Any, seconds: float) -> None:
    """Every period of the plant takes at least ``seconds`` more of wall time."""
    step = plant.plant.step

    def slow_step(*args: Any) -> None:
        step(*args)
        time.sleep(seconds)

    plant.plant.step = slow_step


class Listener:
    """The plant's joint_states and clock stamps, its /diagnostics; publishes torque commands."""

    def __init__(self, h: RosHarness):
        require("rclpy")
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState

        from elastic_pm_dyn.ros.qos import CLOCK_QOS, COMMAND_QOS, DIAGNOSTICS_QOS, STATE_OUT_QOS
        self.node = h.node("listener")
        self.states: list[tuple[int, np.ndarray]] = []  # (stamp ns, effort)
        self.names: list[str] = []
        self.clock: list[int] = []
        self.diagnostics: list[Any] = []  # the plant's status of each report
        self.node.create_subscription(JointState, "joint_states", self._on_state, STATE_OUT_QOS)  # keeps 1000
        self.node.create_subscription(Clock, "clock", lambda m: self.clock.append(self._ns(m.clock)), CLOCK_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics",
                                      lambda m: self.diagnostics.append(m.status[0]), DIAGNOSTICS_QOS)
        self.pub = self.node.create_publisher(JointState, "torque_command", COMMAND_QOS)

    @staticmethod
    def _ns(t: Any) -> int:
        return t.sec * 1_000_000_000 + t.nanosec

    def _on_state(self, msg: Any) -> None:
        self.names = list(msg.name)
        self.states.append((self._ns(msg.header.stamp), np.array(msg.effort)))

    def stamps(self) -> np.ndarray:
        return np.array([s[0] for s in self.states])

    def effort(self) -> np.ndarray:
        return self.states[-1][1][[self.names.index("left_motor"), self.names.index("right_motor")]]

    def send(self) -> None:
        from sensor_msgs.msg import JointState
        self.pub.publish(JointState(name=["left_motor", "right_motor"], effort=TAU))

    def values(self, status: Any) -> dict[str, str]:
        return {kv.key: kv.value for kv in status.values}


def test_overrun_slows_the_clock_and_the_stamps_stay_on_the_grid(ros: RosHarness) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus
    plant = make_plant(ros, sync_mode="realtime", publish_rate=RATE, diagnostics_rate=10.0,
                       realtime__keep_gc_out=False, **OPTIONS)
    assert plant.sync.overrun == "slow" and plant.pub_clock is not None  # the default; the clock is published
    slow_down(plant, 3 / RATE)
    out = Listener(ros)
    ros.wait_until(lambda: any(s.level == DiagnosticStatus.WARN for s in out.diagnostics[1:])
                   and len(out.states) >= 100 and len(out.clock) >= 20, 120.0,
                   "100 states and a report of the slowed plant")
    stamps = out.stamps()
    np.testing.assert_array_equal(np.diff(stamps), PERIOD_NS)  # every period, on the grid, no gap
    assert (stamps[0] - plant.stamp_base) % PERIOD_NS == 0
    clock = np.array(out.clock)  # the same clock: on the grid, forward (a volatile depth-10 reader may miss some)
    assert np.all((clock - plant.stamp_base) % PERIOD_NS == 0) and np.all(np.diff(clock) > 0)
    assert clock[-1] <= plant._stamp_ns()
    s = plant.stats
    assert s.slowed_periods > 0 and s.slipped_periods == 0 and s.overruns > 0
    # the plant's clock is behind the wall clock by the periods it slowed (half a period of rounding)
    wall_ns = plant.get_clock().now().nanoseconds
    assert wall_ns - plant._stamp_ns() >= (s.slowed_periods - 0.5) * PERIOD_NS

    status = next(x for x in reversed(out.diagnostics) if x.level == DiagnosticStatus.WARN)
    assert "running slower than real time (factor" in status.message
    values = out.values(status)
    assert values["overrun"] == "slow" and values["slipped_periods"] == "0"
    assert int(values["slowed_periods"]) > 0 and int(values["slowed_periods_window"]) > 0
    assert 0 < float(values["real_time_factor"]) < 1
    assert 0 < float(values["real_time_factor_total"]) < 1


def test_overrun_skip_lets_the_stamps_jump(ros: RosHarness) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus
    plant = make_plant(ros, sync_mode="realtime", publish_rate=RATE, diagnostics_rate=10.0,
                       realtime__keep_gc_out=False, realtime__overrun="skip", **OPTIONS)
    assert plant.pub_clock is None  # the stamps are the wall clock: no clock of its own
    slow_down(plant, 3 / RATE)
    out = Listener(ros)
    ros.wait_until(lambda: any(s.level == DiagnosticStatus.WARN for s in out.diagnostics[1:])
                   and len(out.states) >= 100, 120.0, "100 states and a report of the slipping plant")
    steps = np.diff(out.stamps())
    assert np.all(steps % PERIOD_NS == 0) and steps.max() > PERIOD_NS  # the stamps jump
    s = plant.stats
    assert s.slipped_periods > 0 and s.slowed_periods == 0
    assert (steps // PERIOD_NS - 1).sum() <= s.slipped_periods  # each jump is counted
    status = next(x for x in reversed(out.diagnostics) if x.level == DiagnosticStatus.WARN)
    assert "the schedule slipped" in status.message and "slower than real time" not in status.message
    assert out.values(status)["overrun"] == "skip"


@pytest.mark.parametrize("overrun", ["slow", "skip"])
def test_a_stall_ages_the_command_on_the_plant_clock(ros: RosHarness, overrun: str) -> None:
    """0.5 s without the executor (the plant's clock stops in slow): in slow the command's age grows
    only with the plant's clock, which the stall stopped (so a command held before it is still
    applied after it); in skip it grows with the wall clock (0.2 s timeout: zero torque after)."""
    slow = overrun == "slow"
    plant = make_plant(ros, sync_mode="realtime", publish_rate=RATE, command_timeout=60.0 if slow else 0.2,
                       realtime__keep_gc_out=False, realtime__overrun=overrun, **OPTIONS)
    out = Listener(ros)
    ros.wait_until(lambda: out.pub.get_subscription_count() > 0 and plant.plant.k > 20, 60.0, "the plant running")
    out.send()
    ros.wait_until(lambda: out.states and np.array_equal(out.effort(), TAU), 10.0, "the command applied")
    stale = plant.stats.stale
    age, t = plant.hold.age(plant.command_clock()), plant.plant.t
    time.sleep(0.5)  # the executor does not run
    k = plant.plant.k
    ros.wait_until(lambda: plant.plant.k > k + 20, 30.0, "20 periods after the stall")
    last = plant._stamp_ns()
    ros.wait_until(lambda: out.states[-1][0] >= last, 10.0, "the states after the stall")
    if slow:
        # exactly the plant's time since (a loaded machine's own delays included), not the stall's 0.5 s
        assert plant.hold.age(plant.command_clock()) - age == pytest.approx(plant.plant.t - t, abs=1e-9)
        assert plant.stats.stale == stale
        np.testing.assert_array_equal(out.effort(), TAU)
        assert plant.stats.slowed_periods >= 400  # the stall's periods: the clock stopped, not skipped
    else:
        assert plant.stats.stale > stale
        np.testing.assert_array_equal(out.effort(), [0.0, 0.0])
        assert plant.stats.slipped_periods >= 400
