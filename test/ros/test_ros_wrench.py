"""The external wrench on the nodes: the plant node's scenario, input and truth topics, and the
observer node's wrench estimate and contact events, live = offline ``observe``."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.bags.msgtypes import IMU, JOINT_STATE, stamp_ns
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.observer.config import load_config
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.simulator import SimulationOptions
from elastic_pm_dyn.sim.wrench import ExternalWrench, StepWrench

CONFIG = Path(__file__).resolve().parents[2] / "config"
PARAMS_FILE = CONFIG / "plant_observer.yaml"
DOMAIN = domain_id(6)
PUSH = [2.0, -1.0, 0.0, 0.0, 0.0, 0.0]


@pytest.fixture
def ros():
    h = RosHarness(DOMAIN)
    yield h
    h.close()


def _node(h: RosHarness, cls: Any, **params: Any) -> Any:
    from rclpy.parameter import Parameter
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(cls(context=h.context, parameter_overrides=overrides))


def _wrench(msg: Any) -> np.ndarray:
    f, m = msg.wrench.force, msg.wrench.torque
    return np.array([f.x, f.y, f.z, m.x, m.y, m.z])


def test_plant_step_scenario_and_input(ros: RosHarness, five_bar: Any) -> None:
    """A lockstep plant under ``wrench.scenario: step`` moves as the library's Plant under the
    same wrench (the same numbers), publishes the true wrench with each state's stamp, adds a
    received wrench, and refuses a bad one in one line while it keeps stepping."""
    require("rclpy")
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS
    _node(ros, PlantNode, sync_mode="lockstep", **{"wrench.scenario": "step", "wrench.value": PUSH,
                                                    "wrench.start": 0.01, "wrench.input": True})
    drv = ros.node("driver")
    states, truth = [], []
    cmd = drv.create_publisher(JointState, "torque_command", COMMAND_QOS)
    push = drv.create_publisher(WrenchStamped, "wrench_input", COMMAND_QOS)

    def on_state(msg: Any) -> None:
        states.append((stamp_ns(msg.header.stamp), np.array(msg.position)))
        if len(states) <= 40:
            cmd.publish(JointState(name=["left_motor", "right_motor"], effort=[0.0, 0.0]))

    drv.create_subscription(JointState, "joint_states", on_state, STATE_QOS)
    drv.create_subscription(WrenchStamped, "wrench", lambda m: truth.append((stamp_ns(m.header.stamp), _wrench(m))),
                            STATE_QOS)
    ros.wait_until(lambda: len(states) >= 41 and len(truth) >= 41, 20.0, "41 states and true wrenches")
    plant = Plant(five_bar, SimulationOptions(), 1e-3, wrench=ExternalWrench([StepWrench(0.01, PUSH)]))
    for k in range(40):
        assert np.array_equal(states[k][1], plant.q), k
        plant.step(np.zeros(2))
    by_stamp = dict(truth)
    assert np.array_equal(by_stamp[states[5][0]], np.zeros(6)) and np.array_equal(by_stamp[states[20][0]], PUSH)
    # the input: held and added; a NaN one refused (the last valid one holds)
    seen = len(truth)
    msg = WrenchStamped()
    msg.wrench.force.y = 0.5
    push.publish(msg)
    bad = WrenchStamped()
    bad.wrench.force.x = float("nan")
    ros.spin_for(0.2)
    push.publish(bad)
    ros.spin_for(0.2)
    cmd.publish(JointState(name=["left_motor", "right_motor"], effort=[0.0, 0.0]))
    ros.wait_until(lambda: len(truth) > seen, 10.0, "the next state")
    assert np.allclose(truth[-1][1], np.array(PUSH) + [0, 0.5, 0, 0, 0, 0])


class Feeder:
    """Sends a recording to the observer node message by message (accelerometer, encoders, command)."""

    TOPICS: ClassVar[dict[str, tuple[str, str]]] = {"torque_command": ("/torque_command", JOINT_STATE),
                                                   "joint_state": ("/measured_joint_states", JOINT_STATE),
                                                   "imu": ("/ee_imu", IMU)}

    def __init__(self, h: RosHarness, plant: Any):
        from geometry_msgs.msg import WrenchStamped
        from sensor_msgs.msg import Imu, JointState

        from elastic_pm_dyn.ros.qos import OBSERVER_INPUT_QOS, STATE_QOS
        self.h, self.session = h, plant.observer.session
        self.node = h.node("feeder")
        types = {"torque_command": JointState, "joint_state": JointState, "imu": Imu}
        self.pubs = {k: self.node.create_publisher(types[k], topic, OBSERVER_INPUT_QOS)
                     for k, (topic, _) in self.TOPICS.items()}
        self.out: dict[str, list] = {"wrench": [], "wrench_stddev": [], "contact": [], "contact_release": []}
        for key in self.out:
            self.node.create_subscription(WrenchStamped, f"/plant/{key}", self.out[key].append, STATE_QOS)
        self.sent: list[tuple[str, Any]] = []
        h.wait_until(lambda: all(p.get_subscription_count() for p in self.pubs.values())
                     and plant.observer.wrench.pubs["wrench"].get_subscription_count(), 10.0, "discovery")

    def send(self, kind: str, msg: Any) -> None:
        n = self.session.received[kind]
        self.pubs[kind].publish(msg)
        self.sent.append((kind, msg))
        self.h.wait_until(lambda: self.session.received[kind] > n, 5.0, f"the node to take a {kind} message")

    def sample(self, rec: Any, k: int, accel: np.ndarray) -> None:
        from geometry_msgs.msg import Vector3
        from sensor_msgs.msg import Imu, JointState
        from std_msgs.msg import Header

        from elastic_pm_dyn.ros.messages import stamp
        t = stamp(int(rec.stamp_ns[k]))
        self.send("imu", Imu(header=Header(stamp=t), linear_acceleration=Vector3(x=float(accel[0]),
                                                                                  y=float(accel[1]),
                                                                                  z=float(accel[2]))))
        self.send("joint_state", JointState(header=Header(stamp=t), name=rec.active_names,
                                            position=[float(v) for v in rec.encoder[k]]))
        self.send("torque_command", JointState(header=Header(stamp=t), name=rec.active_names,
                                               effort=[float(v) for v in rec.tau_cmd[k]]))

    def write_bag(self, path: Path) -> None:
        from rclpy.serialization import serialize_message
        with BagWriter(path) as w:
            conns = {k: w.add_connection(topic, msgtype) for k, (topic, msgtype) in self.TOPICS.items()}
            for i, (kind, msg) in enumerate(self.sent):
                w.write(conns[kind], 1000 + i, serialize_message(msg))


def test_observer_wrench_and_contact_live_equal_offline(ros: RosHarness, five_bar: Any, tmp_path: Path) -> None:
    """The wrench estimate, its standard deviations and the contact events the node publishes
    equal what ``observe`` writes into its estimates bag for the same messages, bit for bit; an
    accelerometer that reads a push (+4 m/s^2 along x from sample 60 on) makes a contact."""
    require("rclpy")
    from elastic_pm_dyn.bags.reader import open_bag
    from elastic_pm_dyn.observer.offline import observe_bag
    from elastic_pm_dyn.ros.plant.node import PlantNode
    rec = manoeuvre_recording(five_bar, duration=0.12, seed=4)
    params = {"mode": "observer", "observer.sensors": ["encoders", "imu"], "observer.process.wrench": "random_walk",
              "observer.imu.sample_timing": "before_command"}
    plant = _node(ros, PlantNode, **params)
    feeder = Feeder(ros, plant)
    for k in range(len(rec.t)):
        feeder.sample(rec, k, rec.accel[k] + (np.array([4.0, 0.0, 0.0]) if k >= 60 else 0.0))
    n = len(rec.t)
    ros.wait_until(lambda: len(feeder.out["wrench"]) >= n and len(feeder.out["wrench_stddev"]) >= n, 10.0,
                   "every wrench estimate")
    ros.spin_for(0.05)
    assert len(feeder.out["contact"]) == 1
    bag = tmp_path / "sent"
    feeder.write_bag(bag)
    cfg = load_config(CONFIG / "observer.yaml").with_overrides(
        sensors=["encoders", "imu"], process__wrench="random_walk", imu__sample_timing="before_command")
    observe_bag(five_bar, cfg, bag, tmp_path / "out", order="arrival", log=lambda s: None)
    offline: dict[str, list] = {}
    with open_bag(tmp_path / "out" / "estimates") as bag:
        conns = [c for c in bag.connections if c.topic.startswith("/observer/") and "wrench" in c.msgtype.lower()]
        for conn, _, msg in bag.decoded(conns):
            offline.setdefault(conn.topic.rsplit("/", 1)[1], []).append((stamp_ns(msg.header.stamp), msg))
    for key, live in feeder.out.items():
        off = offline.get(key, [])
        assert len(off) == len(live), key
        for m, (ns, o) in zip(live, off, strict=True):
            assert stamp_ns(m.header.stamp) == ns
            assert np.array_equal(_wrench(m), _wrench(o)), key
    assert stamp_ns(feeder.out["contact"][0].header.stamp) >= int(rec.stamp_ns[60])
