"""Plant node with real rclpy nodes and messages, in this process.

Lockstep equals offline simulate; JointState and Float64MultiArray commands; every
bad-command class is rejected while the node keeps publishing; a stale command means
zero torque; a singular configuration stops integration and ~/reset recovers; ~/set_state.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import line_torques
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable

FIVE_BAR = Path(__file__).resolve().parents[2] / "config" / "five_bar.yaml"
RATE = 1000.0
REFERENCE_LINE = REFERENCE_MANOEUVRE.line
OPTIONS = dict(formulation="scdd", integrator="rk4", dt=1e-4, stabilization="projection")
TAU = np.array([0.01, -0.02])  # a small valid command (active order: left_motor, right_motor)


@pytest.fixture(scope="module")
def reference() -> dict[str, Any]:
    """The reference manoeuvre's ZOH torque table and its offline simulation."""
    model = load_model(FIVE_BAR)
    mech = Mechanism(model)
    times, torques, names = line_torques(model, REFERENCE_LINE, RATE)
    table = TorqueTable(times, torques, "zoh")
    result = Simulator(mech, SimulationOptions(sample=1.0 / RATE, **OPTIONS)).run(table, REFERENCE_LINE.duration)
    return {"mech": mech, "torques": torques, "names": names, "offline": result}


@pytest.fixture
def ros():
    h = RosHarness(domain_id(83))
    yield h
    h.close()


def make_plant(h: RosHarness, **params: Any) -> Any:
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(PlantNode(context=h.context, parameter_overrides=overrides))


class Driver:
    """Listens to the plant's outputs; in lockstep answers state k with command row k."""

    def __init__(self, h: RosHarness, command_type: str = "joint_state", rows: np.ndarray | None = None,
                 order: list[str] | None = None):
        require("rclpy")
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS
        self.node = h.node("driver")
        self.command_type = command_type
        self.order = order or ["left_motor", "right_motor"]
        self.rows = rows
        self.states: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []  # (stamp ns, q, qd, effort)
        self.names: list[str] = []
        msg_type = JointState if command_type == "joint_state" else Float64MultiArray
        self.pub = self.node.create_publisher(msg_type, "torque_command", COMMAND_QOS)
        self.node.create_subscription(JointState, "joint_states", self._on_state, STATE_QOS)

    def _on_state(self, msg: Any) -> None:
        from elastic_pm_dyn.bags.msgtypes import stamp_ns
        ns = stamp_ns(msg.header.stamp)
        self.names = list(msg.name)
        self.states.append((ns, np.array(msg.position), np.array(msg.velocity), np.array(msg.effort)))
        if self.rows is not None:
            k = round(ns / 1e6)
            if k < len(self.rows):
                self.send(self.rows[k])

    def send(self, tau: np.ndarray) -> None:
        """tau in active order (left_motor, right_motor), sent in the driver's form and order."""
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        values = [float(tau[["left_motor", "right_motor"].index(n)]) for n in self.order]
        if self.command_type == "joint_state":
            self.pub.publish(JointState(name=self.order, effort=values))
        else:
            self.pub.publish(Float64MultiArray(data=values))

    def active_effort(self) -> np.ndarray:
        return self.states[-1][3][[self.names.index("left_motor"), self.names.index("right_motor")]]


@pytest.mark.parametrize(("command_type", "order", "duration"), [
    ("joint_state", ["right_motor", "left_motor"], REFERENCE_LINE.duration),
    ("float64_multi_array", ["right_motor", "left_motor"], 0.1),
], ids=["joint_state", "float64_multi_array"])
def test_lockstep_equals_offline_simulate(ros: RosHarness, reference: dict, command_type: str,
                                          order: list[str], duration: float) -> None:
    n = round(duration * RATE)
    make_plant(ros, sync_mode="lockstep", publish_rate=RATE, command_type=command_type, command_joints=order,
               **OPTIONS)
    driver = Driver(ros, command_type, reference["torques"][:n], order)
    ros.wait_until(lambda: len(driver.states) >= n + 1, 60.0, f"{n + 1} lockstep states")
    ros.spin_for(0.05)
    assert len(driver.states) == n + 1  # exactly one state per command, none without
    off = reference["offline"]
    mech = reference["mech"]
    idx = [driver.names.index(name) for name in mech.joint_names]
    stamps = np.array([s[0] for s in driver.states])
    np.testing.assert_array_equal(stamps, np.arange(n + 1) * 1_000_000)  # simulated time, exact
    q = np.array([s[1][idx] for s in driver.states])
    qd = np.array([s[2][idx] for s in driver.states])
    assert np.abs(q - off.q[: n + 1]).max() <= 1e-9
    assert np.abs(qd - off.qd[: n + 1]).max() <= 1e-9
    # effort of the motors = the torque held over the period that ended at the stamp
    effort = np.array([s[3][idx] for s in driver.states])[1:, mech.active]
    np.testing.assert_array_equal(effort, reference["torques"][:n])


BAD_JOINT_STATE = {
    "length mismatch": (["left_motor", "right_motor"], [0.1]),
    "unknown name": (["left_motor", "right_motr"], [0.1, 0.2]),
    "duplicate name": (["left_motor", "left_motor"], [0.1, 0.2]),
    "missing joint": (["left_motor"], [0.1]),
    "passive joint": (["left_motor", "right_motor", "left_elbow"], [0.1, 0.2, 0.3]),
    "NaN": (["left_motor", "right_motor"], [float("nan"), 0.2]),
    "Inf": (["left_motor", "right_motor"], [0.1, float("-inf")]),
    "empty": ([], []),
}
BAD_ARRAY = {"too short": [0.1], "too long": [0.1, 0.2, 0.3], "NaN": [0.1, float("nan")],
             "Inf": [float("inf"), 0.2], "empty": []}


@pytest.mark.parametrize("command_type", ["joint_state", "float64_multi_array"])
def test_bad_commands_rejected_node_keeps_publishing(ros: RosHarness, command_type: str) -> None:
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    plant = make_plant(ros, sync_mode="realtime", publish_rate=200.0, command_timeout=30.0,
                       command_type=command_type)
    driver = Driver(ros, command_type)
    ros.wait_until(lambda: driver.pub.get_subscription_count() > 0, 10.0, "plant subscription")
    driver.send(TAU)
    ros.wait_until(lambda: driver.states and np.array_equal(driver.active_effort(), TAU), 10.0,
                   "the valid command applied")
    bad = ({k: JointState(name=n, effort=e) for k, (n, e) in BAD_JOINT_STATE.items()}
           if command_type == "joint_state" else {k: Float64MultiArray(data=d) for k, d in BAD_ARRAY.items()})
    for label, msg in bad.items():
        rejected, published = plant.stats.rejected, len(driver.states)
        driver.pub.publish(msg)
        ros.wait_until(lambda r=rejected: plant.stats.rejected == r + 1, 5.0, f"rejection of {label}")
        ros.wait_until(lambda p=published: len(driver.states) >= p + 3, 5.0, f"states after {label}")
        np.testing.assert_array_equal(driver.active_effort(), TAU, err_msg=label)  # last valid command kept
    assert plant.plant.fault is None


def test_stale_command_means_zero_torque(ros: RosHarness) -> None:
    plant = make_plant(ros, sync_mode="realtime", publish_rate=200.0, command_timeout=0.2)
    driver = Driver(ros)
    ros.wait_until(lambda: driver.pub.get_subscription_count() > 0, 10.0, "plant subscription")
    driver.send(TAU)
    ros.wait_until(lambda: driver.states and np.array_equal(driver.active_effort(), TAU), 10.0,
                   "the command applied")
    stale_before = plant.stats.stale
    ros.spin_for(0.4)  # > timeout, no new command
    np.testing.assert_array_equal(driver.active_effort(), [0.0, 0.0])
    assert plant.stats.stale > stale_before


def test_realtime_outputs(ros: RosHarness, reference: dict) -> None:
    """joint_states, branch_forces, ee_pose, markers and diagnostics agree with the model."""
    from diagnostic_msgs.msg import DiagnosticArray
    from elastic_pm_dyn_msgs.msg import BranchForces
    from geometry_msgs.msg import PoseStamped
    from visualization_msgs.msg import MarkerArray

    from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS, STATE_QOS, VIEWER_QOS
    make_plant(ros, sync_mode="realtime", publish_rate=200.0, diagnostics_rate=20.0, marker_rate=20.0)
    driver = Driver(ros)
    got: dict[str, list] = {"bf": [], "pose": [], "markers": [], "diag": []}
    node = driver.node
    node.create_subscription(BranchForces, "branch_forces", got["bf"].append, STATE_QOS)
    node.create_subscription(PoseStamped, "ee_pose", got["pose"].append, STATE_QOS)
    node.create_subscription(MarkerArray, "markers", got["markers"].append, VIEWER_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", got["diag"].append, DIAGNOSTICS_QOS)
    ros.wait_until(lambda: all(len(v) >= 2 for v in got.values()) and len(driver.states) >= 20, 10.0,
                   "all outputs")
    mech = reference["mech"]
    assert driver.names == mech.joint_names
    forces = {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec: m for m in got["bf"]}
    ns, q, qd, effort = next(s for s in reversed(driver.states) if s[0] in forces)  # same period
    bf = forces[ns]
    np.testing.assert_allclose(bf.force, mech.branch_forces(q, qd), rtol=0, atol=1e-12)
    spring = [mech.joint_names.index(n) for n in ("left_spring", "right_spring")]
    np.testing.assert_allclose(effort[spring], bf.force, rtol=0, atol=1e-12)  # spring force as effort
    assert list(bf.name) == ["left", "right"] and len(bf.force_stddev) == 0
    pose = got["pose"][-1].pose.position
    assert abs(pose.x - (-0.05)) < 1e-9 and abs(pose.y - 0.35) < 1e-9  # at rest at p_A
    assert len(got["markers"][-1].markers) == 4  # two chains, joints, end effector
    status = got["diag"][-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert {"step_time_mean_us", "real_time_factor", "closure_gap_m", "command_age_s"} <= set(values)
    assert float(values["closure_gap_m"]) < 1e-12


def test_singular_configuration_stops_and_reset_recovers(ros: RosHarness) -> None:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from std_srvs.srv import Trigger

    from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS
    plant = make_plant(ros, sync_mode="lockstep", diagnostics_rate=20.0)
    driver = Driver(ros)
    diags: list = []
    driver.node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, DIAGNOSTICS_QOS)
    reset = driver.node.create_client(Trigger, "/plant/reset")
    ros.wait_until(lambda: driver.states and driver.pub.get_subscription_count() > 0, 10.0, "initial state")
    driver.send(TAU)
    ros.wait_until(lambda: len(driver.states) == 2, 5.0, "one lockstep state")

    plant.plant.options.singular_tol = 1e300  # every configuration now counts as singular
    driver.send(TAU)
    ros.wait_until(lambda: plant.plant.fault is not None, 5.0, "the singular configuration")
    # every command is answered: the last good state again, time not advanced
    ros.wait_until(lambda: len(driver.states) == 3, 5.0, "the answer to the failing command")
    assert driver.states[2][0] == driver.states[1][0]
    np.testing.assert_array_equal(driver.states[2][1], driver.states[1][1])
    ros.wait_until(lambda: diags and diags[-1].status[0].level == DiagnosticStatus.ERROR, 5.0, "ERROR diagnostics")
    assert "integration stopped" in diags[-1].status[0].message
    rejected = plant.stats.rejected
    driver.send(TAU)  # ignored while stopped; the node stays up and answers
    ros.wait_until(lambda: plant.stats.rejected == rejected + 1, 5.0, "command ignored while stopped")
    ros.wait_until(lambda: len(driver.states) == 4, 5.0, "the answer while stopped")
    assert driver.states[3][0] == driver.states[1][0]

    plant.plant.options.singular_tol = SimulationOptions().singular_tol
    response = ros.call(reset, Trigger.Request())
    assert response.success, response.message
    ros.wait_until(lambda: len(driver.states) == 5, 5.0, "the reset state")
    np.testing.assert_array_equal(driver.states[-1][1], plant.plant.q0)
    assert driver.states[-1][0] == driver.states[1][0] + 1_000_000  # a new stamp; time never runs back
    driver.send(TAU)
    ros.wait_until(lambda: len(driver.states) == 6, 5.0, "stepping after reset")
    assert driver.states[-1][0] == driver.states[4][0] + 1_000_000


def test_set_state_service(ros: RosHarness, reference: dict) -> None:
    from elastic_pm_dyn_msgs.srv import SetJointState
    from sensor_msgs.msg import JointState
    plant = make_plant(ros, sync_mode="lockstep")
    driver = Driver(ros)
    client = driver.node.create_client(SetJointState, "/plant/set_state")
    ros.wait_until(lambda: bool(driver.states), 10.0, "initial state")
    mech = reference["mech"]
    q0 = plant.plant.q0
    target = {"left_motor": q0[0] + 0.01, "right_motor": q0[3] - 0.01}
    request = SetJointState.Request(state=JointState(name=list(target), position=list(target.values())))
    response = ros.call(client, request)
    assert response.success, response.message
    ros.wait_until(lambda: len(driver.states) == 2, 5.0, "the new state")
    q = driver.states[-1][1]
    assert q[0] == target["left_motor"] and q[3] == target["right_motor"]
    assert mech.gap(q) < 1e-12 and not np.allclose(q[[2, 5]], q0[[2, 5]])  # elbows follow by assembly

    for bad in (JointState(name=["left_motr"], position=[1.0]),
                JointState(name=["left_motor"], position=[1.0, 2.0]),
                JointState(name=["left_motor"], position=[float("nan")]),
                # arms stretched apart, one spring 0.5 m long: the forearms cannot close the loop
                JointState(name=["left_motor", "right_motor", "left_spring"], position=[np.pi, 0.0, 0.5])):
        response = ros.call(client, SetJointState.Request(state=bad))
        assert not response.success and response.message.startswith("set_state rejected:")
    np.testing.assert_array_equal(plant.plant.q, q)  # unchanged by the rejected requests
