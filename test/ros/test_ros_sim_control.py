"""The plant node as a ROS simulator user drives it (issue #25), with real rclpy nodes in this process.

A default-QoS (volatile) controller and a SensorDataQoS one drive lockstep without deadlock;
pause / step N / unpause advance exactly N periods (fast and lockstep); two plants in two
namespaces give two clean clock streams and two distinguishable diagnostics; a runtime
change of command_timeout takes effect and a bad one is refused in one line; realtime late
and slowed (or, with overrun skip, slipped) periods are counted; an RK4 step too coarse for
the Triglide's modes is said.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

CONFIG = Path(__file__).resolve().parents[2] / "config"
RATE = 1000.0
PERIOD_NS = 1_000_000
OPTIONS = dict(formulation="scdd", integrator="rk4", dt=1e-4, stabilization="projection")
TAU = [0.01, -0.02]  # left_motor, right_motor


@pytest.fixture
def ros():
    h = RosHarness(domain_id(95))
    yield h
    h.close()


def make_plant(h: RosHarness, namespace: str = "", **params: Any) -> Any:
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(PlantNode(context=h.context, parameter_overrides=overrides, namespace=namespace))


def command(names: list[str] | None = None, effort: list[float] | None = None) -> Any:
    from sensor_msgs.msg import JointState
    return JointState(name=names or ["left_motor", "right_motor"], effort=effort or TAU)


class PlainController:
    """A controller as a new user writes it: plain default QoS (depth 10, volatile) or
    SensorDataQoS, answering each new state stamp once."""

    def __init__(self, h: RosHarness, qos: Any = 10, namespace: str = ""):
        require("rclpy")
        from sensor_msgs.msg import JointState
        self.node = h.add(h.rclpy.create_node("plain_controller", namespace=namespace, context=h.context))
        self.pub = self.node.create_publisher(JointState, "torque_command", 10)
        self.node.create_subscription(JointState, "joint_states", self._on_state, qos)
        self.stamps: list[int] = []
        self.answer = True

    def _on_state(self, msg: Any) -> None:
        from elastic_pm_dyn.bags.msgtypes import stamp_ns
        ns = stamp_ns(msg.header.stamp)
        if self.stamps and ns <= self.stamps[-1]:
            return  # the same state again (the plant re-publishes while it waits): answered already
        self.stamps.append(ns)
        if self.answer:
            self.pub.publish(command())


@pytest.mark.parametrize("qos", ["default", "sensor_data"])
def test_default_qos_controller_drives_lockstep(ros: RosHarness, qos: str) -> None:
    from rclpy.qos import qos_profile_sensor_data
    plant = make_plant(ros, sync_mode="lockstep", publish_rate=RATE, lockstep__waiting_republish_period=0.2,
                       **OPTIONS)
    ros.spin_for(0.3)  # the t = 0 state is out before the controller exists: a volatile reader missed it
    controller = PlainController(ros, qos_profile_sensor_data if qos == "sensor_data" else 10)
    ros.wait_until(lambda: len(controller.stamps) >= 51, 60.0, "50 lockstep periods driven by a plain controller")
    assert controller.stamps[:51] == [k * PERIOD_NS for k in range(51)]
    assert plant.stats.accepted >= 50


def test_lockstep_waiting_is_reported(ros: RosHarness) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    make_plant(ros, sync_mode="lockstep", publish_rate=RATE, diagnostics_rate=20.0,
               lockstep__waiting_republish_period=0.2, **OPTIONS)
    controller = PlainController(ros)
    controller.answer = False
    seen: list[int] = []
    controller.node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: seen.extend(
        [i for i, s in enumerate(m.status) if "waiting for the first command" in s.message
         and any(v.key == "waiting_for_command" and v.value == "true" for v in s.values)]), 10)
    received: list[int] = []
    from sensor_msgs.msg import JointState
    controller.node.create_subscription(JointState, "joint_states", lambda m: received.append(m.header.stamp.sec), 10)
    ros.wait_until(lambda: len(received) >= 3 and seen, 30.0, "the t = 0 state re-published and the waiting reported")
    assert set(received) == {0}  # the same state, no period advanced


@pytest.mark.parametrize("sync_mode", ["fast", "lockstep"])
def test_pause_step_unpause_exact_periods(ros: RosHarness, sync_mode: str) -> None:
    from elastic_pm_dyn_msgs.srv import StepPeriods
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger

    from elastic_pm_dyn.bags.msgtypes import stamp_ns
    plant = make_plant(ros, sync_mode=sync_mode, publish_rate=RATE, **OPTIONS)
    client = ros.node("sim_user")
    pause = client.create_client(Trigger, "/plant/pause")
    unpause = client.create_client(Trigger, "/plant/unpause")
    step = client.create_client(StepPeriods, "/plant/step")
    stamps: list[int] = []
    client.create_subscription(JointState, "joint_states", lambda m: stamps.append(stamp_ns(m.header.stamp)), 100)
    pub = client.create_publisher(JointState, "torque_command", 10)
    if sync_mode == "fast":
        ros.wait_until(lambda: plant.plant.k > 20, 60.0, "the fast plant running")
    refused = ros.call(step, StepPeriods.Request(periods=3))
    assert not refused.success and "pause" in refused.message
    assert ros.call(pause, Trigger.Request()).success
    ros.spin_for(0.2)  # anything in flight arrives; then nothing advances
    k0 = plant.plant.k
    n_before = len(stamps)
    if sync_mode == "lockstep":
        for _ in range(3):  # queued while paused: the step takes them first, then holds the last one
            pub.publish(command())
        ros.wait_until(lambda: len(plant.hold.queue) == 3, 10.0, "three commands queued while paused")
    ros.spin_for(0.2)
    assert plant.plant.k == k0 and len(stamps) == n_before  # paused: no period, no state
    response = ros.call(step, StepPeriods.Request(periods=7))
    assert response.success, response.message
    assert response.periods_advanced == 7
    assert plant.plant.k == k0 + 7
    assert response.sim_time == pytest.approx((k0 + 7) * 1e-3, abs=1e-12)
    ros.wait_until(lambda: len(stamps) >= n_before + 7, 10.0, "the 7 stepped states")
    ros.spin_for(0.2)
    assert stamps[n_before:] == [(k0 + i) * PERIOD_NS for i in range(1, 8)]  # exactly N periods, N states
    assert plant.plant.k == k0 + 7
    assert ros.call(unpause, Trigger.Request()).success
    if sync_mode == "fast":
        ros.wait_until(lambda: plant.plant.k > k0 + 50, 30.0, "the fast plant running again")
    else:
        pub.publish(command())
        ros.wait_until(lambda: plant.plant.k == k0 + 8, 10.0, "lockstep answering commands again")


def test_two_plants_in_two_namespaces(ros: RosHarness) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    for ns in ("r1", "r2"):
        make_plant(ros, namespace=ns, sync_mode="fast", publish_rate=RATE, diagnostics_rate=10.0, **OPTIONS)
    listener = ros.node("listener")
    clocks: dict[str, list[int]] = {"r1": [], "r2": []}
    for ns in clocks:
        listener.create_subscription(
            Clock, f"/{ns}/clock", lambda m, ns=ns: clocks[ns].append(m.clock.sec * 10**9 + m.clock.nanosec),
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    status: dict[str, set[str]] = {}
    listener.create_subscription(DiagnosticArray, "/diagnostics", lambda m: status.update(
        {s.name: {s.hardware_id} | status.get(s.name, set()) for s in m.status}), 10)
    ros.wait_until(lambda: all(len(c) > 200 for c in clocks.values()) and len(status) >= 2, 60.0,
                   "two clocks and two diagnostics")
    for ns, c in clocks.items():  # one plant's stream: strictly increasing on the period grid (the reader
        # may miss samples of a 10-deep writer; two interleaved plants would repeat or go back)
        steps = np.diff(c)
        assert np.all(steps > 0) and np.all(steps % PERIOD_NS == 0), f"/{ns}/clock is not one clean stream"
    assert set(status) == {"/r1/plant: plant", "/r2/plant: plant"}
    assert status["/r1/plant: plant"] == {"five_bar /r1/plant"}
    assert status["/r2/plant: plant"] == {"five_bar /r2/plant"}


def test_runtime_command_timeout(ros: RosHarness) -> None:
    from rclpy.parameter import Parameter
    plant = make_plant(ros, sync_mode="fast", publish_rate=RATE, **OPTIONS)
    driver = ros.node("driver")
    pub = driver.create_publisher(type(command()), "torque_command", 10)
    ros.wait_until(lambda: pub.get_subscription_count() > 0 and plant.plant.k > 10, 60.0, "the plant running")

    bad = plant.set_parameters([Parameter("command_timeout", value=-1.0)])[0]
    assert not bad.successful and "\n" not in bad.reason and "positive" in bad.reason
    wrong_type = plant.set_parameters([Parameter("command_timeout", value=1)])[0]
    assert not wrong_type.successful and "must be a float" in wrong_type.reason
    fixed = plant.set_parameters([Parameter("publish_rate", value=500.0)])[0]
    assert not fixed.successful
    assert plant.hold.timeout == 0.1  # unchanged by the refusals

    # A short timeout: one command, then zero torque after 2 ms of simulated time.
    assert plant.set_parameters([Parameter("command_timeout", value=0.002)])[0].successful
    assert plant.get_parameter("command_timeout").value == 0.002
    pub.publish(command())
    ros.wait_until(lambda: plant.hold.command is not None, 10.0, "the command")
    k0, stale0 = plant.plant.k, plant.stats.stale
    ros.wait_until(lambda: plant.plant.k > k0 + 100, 30.0, "100 periods")
    assert plant.stats.stale - stale0 >= (plant.plant.k - k0) - 5  # stale after ~2 periods

    # A long one: the next command holds for the whole window.
    assert plant.set_parameters([Parameter("command_timeout", value=10.0)])[0].successful
    pub.publish(command())
    arrived = plant.stats.accepted + 1
    ros.wait_until(lambda: plant.stats.accepted >= arrived, 10.0, "the second command")
    k1, stale1 = plant.plant.k, plant.stats.stale
    ros.wait_until(lambda: plant.plant.k > k1 + 100, 30.0, "100 periods")
    assert plant.stats.stale == stale1


@pytest.mark.parametrize("overrun", ["slow", "skip"])
def test_realtime_late_periods_are_counted(ros: RosHarness, overrun: str) -> None:
    plant = make_plant(ros, sync_mode="realtime", publish_rate=RATE, realtime__keep_gc_out=False,
                       realtime__overrun=overrun, **OPTIONS)
    ros.wait_until(lambda: plant.plant.k > 50, 60.0, "the realtime plant running")
    s = plant.stats
    late0, slipped0, slowed0 = s.late_periods, s.slipped_periods, s.slowed_periods
    time.sleep(0.06)  # the executor does not run: about 60 periods fall due
    ros.spin_for(0.05)
    # beyond max_catch_up (5): the clock slows (slow) or the periods are given up (skip), counted
    behind = s.slowed_periods - slowed0 if overrun == "slow" else s.slipped_periods - slipped0
    assert behind >= 40
    assert (s.slipped_periods if overrun == "slow" else s.slowed_periods) == 0
    assert plant.stats.late_periods - late0 >= 3  # the caught-up ones, each counted
    values = plant.stats.values(plant.plant.period, plant.plant.t, plant.plant.k, time.monotonic())
    assert float(values["max_lateness_ms"]) >= 1.5


def test_coarse_rk4_step_is_said() -> None:
    from elastic_pm_dyn.kinematics.assembly import initial_state
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.ros.plant.step_check import rk4_step_warning
    # README: the Triglide at n_ek = 2 has modes up to ~4.8 kHz: RK4 at 1e-4 s is not stable there
    mech = Mechanism(load_model(CONFIG / "triglide.yaml", elastic_dof_per_chain=2))
    q = initial_state(mech)
    text = rk4_step_warning(mech, q, 1e-4)
    assert text is not None and "stability limit" in text and "\n" not in text
    assert rk4_step_warning(mech, q, 1e-6) is None
    five_bar = Mechanism(load_model(CONFIG / "five_bar.yaml"))
    assert rk4_step_warning(five_bar, initial_state(five_bar), 1e-4) is None  # the five-bar's default is fine


def test_observer_rates_change_at_run_time_the_rest_is_refused(ros: RosHarness) -> None:
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.observer.node import ObserverNode
    node = ros.add(ObserverNode(context=ros.context))
    ok = node.set_parameters([Parameter("diagnostics_rate", value=5.0)])[0]
    assert ok.successful and node.get_parameter("diagnostics_rate").value == 5.0
    assert abs(node.observer.timers["diagnostics_rate"].timer_period_ns - 2e8) < 1  # the timer made anew
    bad = node.set_parameters([Parameter("diagnostics_rate", value=0.0)])[0]
    assert not bad.successful and "must be a positive number" in bad.reason
    fixed = node.set_parameters([Parameter("observer.process.max_interval", value=2e-3)])[0]
    assert not fixed.successful  # read-only: the filter's schedule is set up at start-up


def test_observer_noise_and_gate_change_at_run_time(ros: RosHarness) -> None:
    """``ros2 param set`` of the sensors' noise levels and the gate reaches the running filter;
    a bad value is refused in one line and leaves the filter as it was."""
    from rclpy.parameter import Parameter
    from scipy.stats import chi2

    from elastic_pm_dyn.ros.observer.node import ObserverNode
    node = ros.add(ObserverNode(context=ros.context, parameter_overrides=[
        Parameter("observer.sensors", value=["encoders", "imu"])]))
    obs = node.observer.session.obs
    ok = node.set_parameters([Parameter("observer.imu.stddev", value=[0.05]),
                              Parameter("observer.encoders.position_stddev", value=[1e-4]),
                              Parameter("observer.gating.probability", value=0.99)])
    assert all(r.successful for r in ok), [r.reason for r in ok]
    np.testing.assert_allclose(obs.imu.var, 0.05 ** 2)
    np.testing.assert_allclose(obs._imu[2], 0.05 ** 2)  # the compiled steps' bundle too
    np.testing.assert_allclose(obs.encoders.pos_var, 1e-8)
    assert obs.gate(2) == pytest.approx(chi2.ppf(0.99, 2))
    bad = node.set_parameters([Parameter("observer.imu.stddev", value=[-1.0])])[0]
    assert not bad.successful and "imu.stddev" in bad.reason and "\n" not in bad.reason
    np.testing.assert_allclose(obs.imu.var, 0.05 ** 2)  # unchanged
