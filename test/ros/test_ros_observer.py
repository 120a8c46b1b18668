"""The plant node in ``mode: observer``: real rclpy nodes and messages, in this process.

A feeder publishes a simulated recording (the reference manoeuvre with an unknown
disturbance and sensor noise, scenarios.manoeuvre_recording) one message at a time, each
after the node has taken the previous one, so the node sees exactly the order sent:
1. the live estimates equal ``elastic-pm-dyn observe`` over a bag of the same messages;
2. a NaN and wildly inconsistent samples are gated out and reported, the node keeps publishing;
3. a fault and a divergence are ERROR in /diagnostics, ~/reset and ~/set_state recover;
4. a wrong parameter stops the start with one line.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import yaml
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES, IMU, JOINT_STATE, stamp_ns
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.observer.config import flatten, load_config
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

CONFIG = Path(__file__).resolve().parents[2] / "config"
PARAMS_FILE = CONFIG / "plant_observer.yaml"
SENSORS = ["encoders", "imu", "branch_forces"]
DOMAIN = domain_id(74)


@pytest.fixture(scope="module")
def rec(five_bar):
    return manoeuvre_recording(five_bar, duration=0.2, seed=4)  # 201 samples at 1 kHz, ~1 s to simulate


@pytest.fixture
def ros():
    h = RosHarness(DOMAIN, args=["test", "--ros-args", "--params-file", str(PARAMS_FILE)])
    yield h
    h.close()


def make_observer(h: RosHarness, **params: Any) -> Any:
    """The plant node from config/plant_observer.yaml with all three sensors and fast diagnostics."""
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    params = {"observer.sensors": SENSORS, "diagnostics_rate": 50.0, **params}
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(PlantNode(context=h.context, parameter_overrides=overrides))


class Feeder:
    """Sends a recording to the observer node message by message; collects what it publishes."""

    TOPICS: ClassVar[dict[str, tuple[str, str]]] = {
        "torque_command": ("/torque_command", JOINT_STATE),
        "joint_state": ("/measured_joint_states", JOINT_STATE),
        "imu": ("/ee_imu", IMU),
        "branch_forces": ("/measured_branch_forces", BRANCH_FORCES)}

    def __init__(self, h: RosHarness, plant: Any, rec: Any):
        require("rclpy")
        from diagnostic_msgs.msg import DiagnosticArray
        from elastic_pm_dyn_msgs.msg import BranchForces
        from geometry_msgs.msg import PoseStamped
        from sensor_msgs.msg import Imu, JointState

        from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS, OBSERVER_INPUT_QOS, STATE_QOS
        self.h, self.rec = h, rec
        self.session = plant.observer.session
        self.node = h.node("feeder")
        types = {"torque_command": JointState, "joint_state": JointState, "imu": Imu, "branch_forces": BranchForces}
        self.pubs = {k: self.node.create_publisher(types[k], topic, OBSERVER_INPUT_QOS)
                     for k, (topic, _) in self.TOPICS.items()}
        self.out: dict[str, list] = {"js": [], "bf": [], "pose": [], "std": [], "diag": []}
        for key, msg_type, topic, qos in (("js", JointState, "joint_states", STATE_QOS),
                                          ("bf", BranchForces, "branch_forces", STATE_QOS),
                                          ("pose", PoseStamped, "ee_pose", STATE_QOS),
                                          ("std", JointState, "/plant/joint_states_stddev", STATE_QOS),
                                          ("diag", DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)):
            self.node.create_subscription(msg_type, topic, self.out[key].append, qos)
        self.sent: list[tuple[str, Any]] = []
        obs_pubs = plant.observer
        h.wait_until(lambda: all(p.get_subscription_count() for p in self.pubs.values())
                     and obs_pubs.pub_joint_states.get_subscription_count()
                     and obs_pubs.pub_stddev.get_subscription_count(), 10.0, "discovery")

    def send(self, kind: str, msg: Any) -> None:
        n = self.session.received[kind]
        self.pubs[kind].publish(msg)
        self.sent.append((kind, msg))
        self.h.wait_until(lambda: self.session.received[kind] > n, 5.0, f"the node to take a {kind} message")

    def sample(self, k: int, encoder: Any = None, accel: Any = None, tau: Any = None) -> None:
        """Sample k as a robot would send it: accelerometer, strain gauges, encoders, then the command."""
        from elastic_pm_dyn_msgs.msg import BranchForces
        from geometry_msgs.msg import Vector3
        from sensor_msgs.msg import Imu, JointState
        from std_msgs.msg import Header

        from elastic_pm_dyn.ros.messages import stamp
        rec = self.rec
        t = stamp(int(rec.stamp_ns[k]))
        a = rec.accel[k] if accel is None else accel
        self.send("imu", Imu(header=Header(stamp=t, frame_id="ee_imu"),
                             linear_acceleration=Vector3(x=float(a[0]), y=float(a[1]), z=float(a[2]))))
        self.send("branch_forces", BranchForces(header=Header(stamp=t), name=rec.branch_names,
                                                force=[float(v) for v in rec.branch[k]]))
        position = rec.encoder[k] if encoder is None else encoder
        effort = rec.tau_cmd[k] if tau is None else tau
        self.send("joint_state", JointState(header=Header(stamp=t), name=rec.active_names,
                                            position=[float(v) for v in position]))
        self.send("torque_command", JointState(header=Header(stamp=t), name=rec.active_names,
                                               effort=[float(v) for v in effort]))

    def write_bag(self, path: Path) -> None:
        """What was sent, in the order sent, as a rosbag2. The CDR is rclpy's own; for empty
        float64[] fields it may carry a few trailing padding bytes (see test_ros_msgs.py),
        which ``observe``'s CDR reader, reading field by field, never looks at."""
        from rclpy.serialization import serialize_message

        with BagWriter(path) as w:
            conns = {k: w.add_connection(topic, msgtype) for k, (topic, msgtype) in self.TOPICS.items()}
            for i, (kind, msg) in enumerate(self.sent):
                w.write(conns[kind], 1000 + i, serialize_message(msg))  # bag time = send order

    def wait_estimates(self, n: int) -> list[int]:
        """Exactly n estimates arrived (none more within 20 ms); their stamps."""
        self.h.wait_until(lambda: len(self.out["js"]) >= n, 5.0, f"{n} estimates")
        self.h.spin_for(0.02)
        assert len(self.out["js"]) == n
        return _stamps(self.out["js"])

    def statuses(self) -> list[Any]:
        return [d.status[0] for d in self.out["diag"]]

    def wait_for_status(self, check: Any, what: str, timeout: float = 5.0) -> Any:
        seen = len(self.out["diag"])  # only reports made from now on
        self.h.wait_until(lambda: any(check(s) for s in self.statuses()[seen:]), timeout, what)
        return next(s for s in self.statuses()[seen:] if check(s))


def _stamps(msgs: list[Any]) -> list[int]:
    return [stamp_ns(m.header.stamp) for m in msgs]


def _values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_parameter_file_is_the_observer_file() -> None:
    """config/plant_observer.yaml carries config/observer.yaml's observer block unchanged."""
    ours = yaml.safe_load(PARAMS_FILE.read_text())["/**"]["ros__parameters"]
    assert ours["mode"] == "observer"
    assert ours["observer"] == yaml.safe_load((CONFIG / "observer.yaml").read_text())["/**"]["ros__parameters"][
        "observer"]


def test_live_estimates_equal_offline_observe(ros: RosHarness, rec: Any, five_bar: Any, tmp_path: Path) -> None:
    from elastic_pm_dyn.observer.offline import observe_bag
    plant = make_observer(ros)
    # Every value of the parameter file reached the node, with its YAML type (two are overridden here).
    for key, value in flatten(yaml.safe_load(PARAMS_FILE.read_text())["/**"]["ros__parameters"]).items():
        if key in ("observer.sensors", "diagnostics_rate"):
            continue
        got = plant.get_parameter(key).value
        got = list(got) if isinstance(value, list) else got
        assert got == value and type(got) is type(value), key
    feeder = Feeder(ros, plant, rec)
    n = len(rec.t)
    for k in range(n):
        feeder.sample(k)
    out = feeder.out
    ros.wait_until(lambda: all(len(out[key]) >= n for key in ("js", "bf", "pose", "std")), 10.0, "every estimate")
    ros.spin_for(0.05)
    assert [len(out[key]) for key in ("js", "bf", "pose", "std")] == [n] * 4  # one per measured joint state
    for key in ("js", "bf", "pose", "std"):
        assert _stamps(out[key]) == [int(ns) for ns in rec.stamp_ns], key

    bag = tmp_path / "sent"
    feeder.write_bag(bag)
    cfg = load_config(PARAMS_FILE).with_overrides(sensors=SENSORS)
    offline = observe_bag(five_bar, cfg, bag, None, order="arrival", log=lambda s: None)
    assert offline.rows.t == [int(ns) for ns in rec.stamp_ns]
    assert list(out["js"][0].name) == five_bar.joint_names and list(out["bf"][0].name) == ["left", "right"]
    worst = 0.0
    comps = [int(c) for c in five_bar.ee_components]
    for e, js, bf, pose, std in zip(offline.rows.est, out["js"], out["bf"], out["pose"], out["std"], strict=True):
        p = pose.pose.position
        pairs = ((js.position, e.q), (js.velocity, e.qd), (js.effort, e.effort), (bf.force, e.branch_force),
                 (bf.force_stddev, e.branch_force_std), (bf.deflection, e.deflection),
                 (bf.deflection_rate, e.deflection_rate), (np.array([p.x, p.y, p.z])[comps], e.ee),
                 (std.position, e.q_std), (std.velocity, e.qd_std))
        for live, off in pairs:
            assert len(live) == len(off)
            worst = max(worst, float(np.max(np.abs(np.asarray(live) - off))))
    assert worst <= 1e-9, f"live and offline estimates differ by {worst:.3g}"
    # ... and they estimate: the branch forces after the first 50 ms, against the truth
    force = np.array([m.force for m in out["bf"]])
    assert np.sqrt(np.mean((force[50:] - rec.F[50:]) ** 2)) < 0.05
    assert np.all(np.array([m.force_stddev for m in out["bf"]]) > 0)


def test_nan_and_inconsistent_samples_are_gated_and_reported(ros: RosHarness, rec: Any, five_bar: Any) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Header

    from elastic_pm_dyn.observer.schedule.sensor_stats import ERROR
    from elastic_pm_dyn.ros.messages import stamp
    plant = make_observer(ros)
    feeder = Feeder(ros, plant, rec)
    n, k_jump, k_nan, k_acc, k_cmd = 80, 40, 50, 60, 65
    for k in range(n):
        enc, acc = rec.encoder[k].copy(), rec.accel[k].copy()
        if k == k_jump:
            enc[0] += 0.5  # a 0.5 rad encoder glitch
        if k == k_nan:
            enc[0] = np.nan
        if k == k_acc:
            acc[0] += 50.0  # 50 m/s^2 against a noise of 0.02
        feeder.sample(k, encoder=enc, accel=acc)
        if k == k_cmd:
            feeder.send("torque_command", JointState(header=Header(stamp=stamp(int(rec.stamp_ns[k]))),
                                                     name=rec.active_names, effort=[np.nan, 0.0]))
    assert feeder.wait_estimates(n) == [int(ns) for ns in rec.stamp_ns[:n]]  # also at the bad samples
    st = plant.observer.session.obs.stats
    assert (st["encoders"].rejected, st["encoders"].nan, st["imu"].rejected) == (1, 1, 1)
    # Reported: WARN in the report after each, and the counts and reasons in the key/values.
    warnings = " ".join(s.message for s in feeder.statuses() if s.level == DiagnosticStatus.WARN)
    for text in ("encoders samples gated out 1", "encoders NaN entries 1", "imu samples gated out 1",
                 "torque commands rejected 1"):
        assert text in warnings
    values = _values(feeder.wait_for_status(lambda s: True, "a report after the run"))
    assert (values["encoders.rejected"], values["encoders.nan_entries"], values["imu.rejected"],
            values["commands_rejected"]) == ("1", "1", "1", "1")
    assert "gated out" in values["imu.last_rejection"] and "NaN" in values["last_command_error"]
    assert "nis_mean" in " ".join(values) and values["estimates_published"] == str(n)
    # The estimate never took the bad samples.
    e = plant.observer.session.estimate()
    assert np.abs(e.q[five_bar.active] - rec.q[n - 1, five_bar.active]).max() < 5e-5
    assert plant.observer.session.obs.health()[0] != ERROR


def test_fault_and_divergence_are_errors_reset_recovers(ros: RosHarness, rec: Any, five_bar: Any) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus
    from elastic_pm_dyn_msgs.srv import SetJointState
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger
    plant = make_observer(ros, observer__gating__max_consecutive_rejections=5, observer__gating__recover_after=0,
                          restart_on_fault=False)  # stopped until ~/reset (the restart: test_observer_clock)
    feeder = Feeder(ros, plant, rec)
    session = plant.observer.session
    reset = feeder.node.create_client(Trigger, "/plant/reset")
    set_state = feeder.node.create_client(SetJointState, "/plant/set_state")

    def error_in(motor_k: int) -> float:
        e = session.estimate()
        return float(np.abs(e.q[five_bar.active] - rec.q[motor_k, five_bar.active]).max())

    for k in range(40):
        feeder.sample(k)
    # 1. A command the machine never got (1e6 N m): the prediction fails, the filter stops.
    feeder.sample(40, tau=rec.tau_cmd[40] + 1e6)
    for k in range(41, 44):
        feeder.sample(k)
    assert session.faults == 1 and session.refused == 11  # the rest of sample 41, all of 42 and 43
    assert feeder.wait_estimates(41)[-1] == int(rec.stamp_ns[40])  # nothing published while stopped
    status = feeder.wait_for_status(lambda s: s.level == DiagnosticStatus.ERROR, "ERROR diagnostics")
    assert status.message.startswith("fault: prediction failed at t = 0.040000 s")
    response = ros.call(reset, Trigger.Request())
    assert response.success and "re-initialised from the measured joint state at t = 0.043000 s" in response.message
    for k in range(44, 70):
        feeder.sample(k)
    assert feeder.wait_estimates(41 + 26)[-1] == int(rec.stamp_ns[69]) and error_in(69) < 1e-4
    assert session.obs.fault is None and session.obs.stats["encoders"].consecutive_rejections == 0

    # 2. Torque commands 5 N m off for 10 ms: the encoders disagree, are gated out, ERROR (diverged).
    for k in range(70, 80):
        feeder.sample(k, tau=rec.tau_cmd[k] + 5.0)
    status = feeder.wait_for_status(lambda s: s.level == DiagnosticStatus.ERROR, "ERROR diagnostics")
    assert "consecutive samples gated out" in status.message and "reset needed" in status.message
    assert ros.call(reset, Trigger.Request()).success
    for k in range(80, 110):
        feeder.sample(k)
    assert error_in(109) < 1e-4 and session.obs.stats["encoders"].consecutive_rejections == 0
    status = feeder.wait_for_status(lambda s: True, "a report")
    assert status.level != DiagnosticStatus.ERROR

    # 3. ~/set_state: the estimate from a given joint state, at the filter's time; bad requests refused.
    request = SetJointState.Request(state=JointState(name=five_bar.joint_names, position=rec.q[109].tolist(),
                                                     velocity=rec.qd[109].tolist()))
    response = ros.call(set_state, request)
    assert response.success and response.message == "estimate set at t = 0.109000 s"
    assert np.abs(session.estimate().q - rec.q[109]).max() < 1e-9
    for bad in (JointState(name=["left_motr"], position=[1.0]), JointState(name=["left_motor"], position=[1.0])):
        response = ros.call(set_state, SetJointState.Request(state=bad))
        assert not response.success and response.message.startswith("set_state rejected:")
    for k in range(110, 120):
        feeder.sample(k)
    assert error_in(119) < 1e-4 and feeder.wait_estimates(41 + 26 + 10 + 30 + 10)[-1] == int(rec.stamp_ns[119])


@pytest.mark.parametrize(("param", "value", "reason"), [
    ("mode", "observe", "parameter 'mode' is 'observe', expected one of: plant, observer"),
    ("observer.gating.probability", 2.0,
     "parameter 'observer.gating.probability': expected a probability in (0.5, 1), got 2.0"),
    ("observer.process.dt", 1,
     "parameter 'observer.process.dt' must be a float (e.g. 1000.0, not 1000), got integer 1"),
    ("observer.sensors", ["encoders", "sonar"], "parameter 'observer.sensors': unknown sensor 'sonar'"),
    ("observer.encoders.position_joints", ["left_motr"],
     "parameter 'observer.encoders.position_joints': unknown joint 'left_motr'"),
    ("observer.gating.probabilty", 0.99,
     "unknown parameter(s) observer.gating.probabilty (did you mean observer.gating.probability?)"),
])
def test_wrong_observer_parameter_fails_with_reason(ros: RosHarness, param: str, value: Any, reason: str) -> None:
    from elastic_pm_dyn.ros.params import ParameterError
    with pytest.raises(ParameterError) as err:
        make_observer(ros, **{param.replace(".", "__"): value})
    assert str(err.value).startswith(reason) and "\n" not in str(err.value)


def test_node_process_refuses_to_start_with_one_line() -> None:
    require("rclpy")
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.run(
        [sys.executable, "-m", "elastic_pm_dyn.ros.plant.node", "--ros-args", "--params-file", str(PARAMS_FILE),
         "-p", "observer.imu.stddev:=[-0.02]"], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "plant_node: error: parameter 'observer.imu.stddev': needs one or more values > 0, got [-0.02]"]
