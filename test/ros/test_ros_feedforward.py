"""Feedforward node with real rclpy nodes, in this process.

In lockstep with the plant it reproduces offline ``simulate`` of the same torques; on a
timer it publishes the torque table's values; ``~/start``; Float64MultiArray order; the
JointTrajectory source, including bad trajectories (rejected, the node lives on).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import line_torques, rigid_feedforward
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable

FIVE_BAR = Path(__file__).resolve().parents[2] / "config" / "five_bar.yaml"
ACTIVE = ["left_motor", "right_motor"]
REFERENCE_LINE = REFERENCE_MANOEUVRE.line


@pytest.fixture
def ros():
    h = RosHarness(domain_id(65))
    yield h
    h.close()


def make(h: RosHarness, cls_name: str, **params: Any) -> Any:
    require("rclpy")
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.feedforward.node import FeedforwardNode
    from elastic_pm_dyn.ros.plant.node import PlantNode
    cls = {"plant": PlantNode, "feedforward": FeedforwardNode}[cls_name]
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(cls(context=h.context, parameter_overrides=overrides))


class Listener:
    """Collects the commands and reference states the feedforward publishes (and plant states)."""

    def __init__(self, h: RosHarness, command_type: str = "joint_state"):
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS
        self.node = h.node("listener")
        self.commands: list[Any] = []
        self.references: list[Any] = []
        self.states: list[Any] = []
        cmd_type = JointState if command_type == "joint_state" else Float64MultiArray
        self.node.create_subscription(cmd_type, "torque_command", self.commands.append, COMMAND_QOS)
        self.node.create_subscription(JointState, "reference_joint_states", self.references.append, STATE_QOS)
        self.node.create_subscription(JointState, "joint_states", self.states.append, STATE_QOS)


def _ns(msg: Any) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def test_lockstep_with_plant_reproduces_offline_simulate(ros: RosHarness) -> None:
    model = load_model(FIVE_BAR)
    mech = Mechanism(model)
    times, torques, _ = line_torques(model, REFERENCE_LINE, 1000.0)
    opts = dict(formulation="scdd", integrator="rk4", dt=1e-4, stabilization="projection")
    offline = Simulator(mech, SimulationOptions(sample=1e-3, **opts)).run(TorqueTable(times, torques, "zoh"),
                                                                        REFERENCE_LINE.duration)
    listener = Listener(ros)
    make(ros, "plant", sync_mode="lockstep", publish_rate=1000.0, **opts)
    ff = make(ros, "feedforward", trigger="state", exit_when_done=True, wait_for_subscribers=2)
    ros.wait_until(lambda: ff.done, 60.0, "the feedforward to finish the manoeuvre")
    ros.spin_for(0.05)
    n = len(times) - 1
    assert len(listener.commands) == n and len(listener.states) == n + 1
    sent = np.array([[c.effort[list(c.name).index(j)] for j in ACTIVE] for c in listener.commands])
    np.testing.assert_array_equal(sent, torques[:n])  # the offline table, bit for bit
    assert [_ns(c) for c in listener.commands] == [k * 1_000_000 for k in range(n)]
    idx = [list(listener.states[0].name).index(j) for j in mech.joint_names]
    q = np.array([np.array(s.position)[idx] for s in listener.states])
    qd = np.array([np.array(s.velocity)[idx] for s in listener.states])
    assert np.abs(q - offline.q).max() <= 1e-9
    assert np.abs(qd - offline.qd).max() <= 1e-9
    # reference_joint_states at t = 0.1 s: the rigid model's pose on the line (same warm starts)
    ff_ref = rigid_feedforward(model)
    q_line = [ff_ref.joint_motion(*REFERENCE_LINE(k / 1000.0))[0] for k in range(101)][-1]
    ref = listener.references[100]
    np.testing.assert_allclose([ref.position[list(ref.name).index(j)] for j in ff_ref.mech.joint_names], q_line,
                               rtol=0, atol=1e-12)


def test_elastic_method_in_lockstep_sends_the_elastic_table_and_the_plant_stays_quiet(ros: RosHarness) -> None:
    """method elastic: the commands are the offline elastic table bit for bit, and the plant
    (elastic, in lockstep) ends the reference manoeuvre's line without the rigid torques' ringing."""
    from elastic_pm_dyn.motion.feedforward import elastic_line_torques
    from elastic_pm_dyn.motion.trajectory import Line
    model = load_model(FIVE_BAR)
    line = Line(np.array(REFERENCE_MANOEUVRE.start), np.array(REFERENCE_MANOEUVRE.end), REFERENCE_MANOEUVRE.move,
                0.05, 4)  # 0.25 s in all: a sum without round-off, so the node stops where the table does
    times, torques, _, _ = elastic_line_torques(model, line, 1000.0)
    listener = Listener(ros)
    make(ros, "plant", sync_mode="lockstep", publish_rate=1000.0, formulation="scdd", integrator="rk4", dt=2e-5)
    ff = make(ros, "feedforward", trigger="state", exit_when_done=True, wait_for_subscribers=2, method="elastic",
              line__hold=0.05)
    ros.wait_until(lambda: ff.done, 60.0, "the feedforward to finish the manoeuvre")
    ros.spin_for(0.05)
    n = len(times) - 1
    sent = np.array([[c.effort[list(c.name).index(j)] for j in ACTIVE] for c in listener.commands])
    np.testing.assert_array_equal(sent, torques[:n])
    mech = Mechanism(model)
    idx = [list(listener.states[0].name).index(j) for j in mech.joint_names]
    q = np.array([np.array(s.position)[idx] for s in listener.states])
    qd = np.array([np.array(s.velocity)[idx] for s in listener.states])
    _, forces, _ = mech.sample_outputs(q, qd)
    assert np.abs(forces[int(line.move * 1000):]).max() < 1e-3  # N; the rigid torques ring at ~0.1 N


def test_shaped_method_builds_the_shaped_line(ros: RosHarness) -> None:
    """method shaped: the line through the ZVD shaper of the five-bar's modes, 3.6 ms longer; its
    torques at the grid are the rigid table of the shaped path."""
    from elastic_pm_dyn.motion.feedforward import path_torques
    from elastic_pm_dyn.motion.shaping import ShapedPath
    ff = make(ros, "feedforward", method="shaped", autostart=False)
    assert isinstance(ff.line.line, ShapedPath)
    assert 0.003 < ff.line.line.move - REFERENCE_MANOEUVRE.move < 0.004
    _, table, _, _ = path_torques(load_model(FIVE_BAR), REFERENCE_LINE, 1000.0, "shaped", "zvd")
    for k in (0, 50, 100, 150, 203):
        np.testing.assert_allclose(ff.line.sample(k / 1000.0).tau, table[k], rtol=0, atol=1e-9)


def test_timer_trigger_publishes_table_values_and_start_service(ros: RosHarness) -> None:
    """Timer mode, Float64MultiArray in a custom order, started by ~/start."""
    from std_srvs.srv import Trigger
    model = load_model(FIVE_BAR)
    _, torques, _ = line_torques(model, REFERENCE_LINE, 200.0)
    listener = Listener(ros, "float64_multi_array")
    make(ros, "feedforward", rate=200.0, autostart=False, command_type="float64_multi_array",
         command_joints=["right_motor", "left_motor"])
    ros.spin_for(0.2)
    assert not listener.commands  # nothing before ~/start
    response = ros.call(listener.node.create_client(Trigger, "/feedforward/start"), Trigger.Request())
    assert response.success
    ros.wait_until(lambda: len(listener.references) >= 20, 10.0, "20 timer commands")
    t0 = _ns(listener.references[0])
    for ref, cmd in zip(listener.references, listener.commands, strict=False):
        k = round((_ns(ref) - t0) / 5_000_000)
        assert _ns(ref) - t0 == k * 5_000_000  # stamped on the control grid
        np.testing.assert_array_equal(cmd.data, torques[min(k, len(torques) - 1)][::-1])


def _trajectory_msg(names: list[str], times: list[float], positions: np.ndarray, velocities: np.ndarray | None,
                    accelerations: np.ndarray | None) -> Any:
    from builtin_interfaces.msg import Duration
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    points = []
    for k, t in enumerate(times):
        p = JointTrajectoryPoint(positions=[float(x) for x in positions[k]],
                                 time_from_start=Duration(sec=int(t), nanosec=round((t % 1) * 1e9)))
        if velocities is not None:
            p.velocities = [float(x) for x in velocities[k]]
        if accelerations is not None:
            p.accelerations = [float(x) for x in accelerations[k]]
        points.append(p)
    return JointTrajectory(joint_names=names, points=points)


def test_joint_trajectory_source(ros: RosHarness) -> None:
    """Waypoints of the line's joint motion: torques at the waypoints equal the line's."""
    from trajectory_msgs.msg import JointTrajectory

    from elastic_pm_dyn.ros.qos import COMMAND_QOS
    model = load_model(FIVE_BAR)
    ff_ref = rigid_feedforward(model)
    times = [0.0, 0.05, 0.1, 0.15, 0.2]
    motion = [ff_ref.joint_motion(*REFERENCE_LINE(t)) for t in times]
    act = ff_ref.mech.active
    pos, vel, acc = (np.array([m[i][act] for m in motion]) for i in range(3))
    line_tau = np.array([ff_ref.torques(*REFERENCE_LINE(t)) for t in times])

    listener = Listener(ros)
    ff = make(ros, "feedforward", source="trajectory", rate=200.0, wait_for_subscribers=0)
    pub = listener.node.create_publisher(JointTrajectory, "trajectory", COMMAND_QOS)
    ros.wait_until(lambda: pub.get_subscription_count() > 0, 10.0, "trajectory subscription")
    bad = [_trajectory_msg(["left_motor", "elbow"], times, pos, None, None),  # unknown joint
           _trajectory_msg(ACTIVE, [0.0, 0.1, 0.1, 0.2, 0.3], pos, None, None),  # times not increasing
           _trajectory_msg(ACTIVE, times, pos * np.nan, None, None),  # NaN
           _trajectory_msg(ACTIVE, times, pos[:, :1], None, None),  # one position per point
           _trajectory_msg(ACTIVE, times, pos, None, acc),  # accelerations without velocities
           _trajectory_msg(ACTIVE, [], pos[:0], None, None)]  # no points
    for msg in bad:
        pub.publish(msg)
    ros.spin_for(0.3)
    assert ff.reference is None and not listener.commands  # all rejected, node alive

    # reversed joint order in the message, full derivatives: quintic Hermite through the points
    pub.publish(_trajectory_msg(ACTIVE[::-1], times, pos[:, ::-1], vel[:, ::-1], acc[:, ::-1]))
    ros.wait_until(lambda: ff.reference is not None, 5.0, "trajectory accepted")
    for t, tau in zip(times, line_tau, strict=True):
        np.testing.assert_allclose(ff.reference.sample(t).tau, tau, rtol=1e-9, atol=1e-9)
    ros.wait_until(lambda: len(listener.commands) >= 5, 5.0, "commands of the trajectory")
    assert all(list(c.name) == ACTIVE and np.all(np.isfinite(c.effort)) for c in listener.commands)


def test_fast_plant_clock_drives_feedforward_with_use_sim_time(ros: RosHarness) -> None:
    """A fast plant owns time (/clock); the feedforward's timer and stamps follow it."""
    plant = make(ros, "plant", sync_mode="fast", command_timeout=0.05)
    listener = Listener(ros)
    make(ros, "feedforward", use_sim_time=True, rate=200.0)
    ros.wait_until(lambda: len(listener.commands) >= 20 and plant.stats.accepted >= 20, 20.0,
                   "commands paced by simulated time")
    stamps = np.array([_ns(c) for c in listener.commands]) * 1e-9
    assert np.all(np.diff(stamps) > 0)
    assert stamps[-1] <= plant.plant.t + 1e-9  # simulated time, not the wall clock (~1.8e9 s)


def test_line_parameters_default_to_the_reference_manoeuvre() -> None:
    require("rclpy")
    from elastic_pm_dyn.ros.feedforward.node import PARAMS

    defaults = {p.name: p.default for p in PARAMS}
    m = REFERENCE_MANOEUVRE
    assert defaults["rate"] == m.control_rate
    assert (defaults["line.start"], defaults["line.end"]) == (list(m.start), list(m.end))
    assert (defaults["line.move"], defaults["line.hold"]) == (m.move, m.hold)
