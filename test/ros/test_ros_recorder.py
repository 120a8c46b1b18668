"""Recorder node: a bag of a lockstep plant run that rosbags reads back exactly (mcap, sqlite3)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES
from elastic_pm_dyn.bags.typestore import make_typestore

PERIODS = 20


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_recorded_branch_forces_deserialize_with_rosbags(storage: str, tmp_path: Path) -> None:
    require("rclpy")
    require("rosbags")
    from elastic_pm_dyn_msgs.msg import BranchForces
    from rclpy.parameter import Parameter
    from rosbags.highlevel import AnyReader
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.bags.series import read_series
    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS
    from elastic_pm_dyn.ros.recorder.node import RecorderNode

    bag = tmp_path / "bag"
    h = RosHarness(domain_id(86))
    try:
        plant = h.add(PlantNode(context=h.context, parameter_overrides=[Parameter("sync_mode", value="lockstep")]))
        recorder = h.add(RecorderNode(context=h.context, parameter_overrides=[
            Parameter("output", value=str(bag)), Parameter("storage", value=storage),
            Parameter("topics", value=["/joint_states", "branch_forces", "/torque_command"])]))
        driver = h.node("driver")
        published: list[BranchForces] = []
        driver.create_subscription(BranchForces, "branch_forces", published.append, STATE_QOS)
        pub = driver.create_publisher(JointState, "torque_command", COMMAND_QOS)
        # The recorder finds the topics in the graph; the first state was published before it
        # subscribed and still gets recorded (transient local).
        def recorded(topic: str) -> int:
            return recorder.count(topic)

        h.wait_until(lambda: recorded("/joint_states") and recorded("/branch_forces"), 10.0,
                     "the state at t = 0 in the bag")
        h.wait_until(lambda: pub.get_subscription_count() >= 1 and published, 10.0, "plant")
        for k in range(PERIODS):
            pub.publish(JointState(name=["left_motor", "right_motor"], effort=[0.2, -0.1 * k]))
            h.wait_until(lambda n=k + 2: len(published) == n, 5.0, f"state {k + 1}")
            if k == 0:
                h.wait_until(lambda: "/torque_command" in recorder.connections, 10.0, "torque_command recorded")
        h.spin_for(0.2)
        recorder.close()
    finally:
        h.close()

    assert list(bag.glob("*.mcap" if storage == "mcap" else "*.db3"))
    for default_ts in ("ours", None):  # with our typestore, and from the definitions in the bag alone
        with AnyReader([bag], default_typestore=make_typestore() if default_ts else None) as reader:
            conns = [c for c in reader.connections if c.topic == "/branch_forces"]
            assert [c.msgtype for c in conns] == [BRANCH_FORCES]
            msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
        assert len(msgs) == PERIODS + 1
        for got, sent in zip(msgs, published, strict=True):
            assert (got.header.stamp.sec, got.header.stamp.nanosec) == (sent.header.stamp.sec,
                                                                       sent.header.stamp.nanosec)
            assert list(got.name) == list(sent.name) == ["left", "right"]
            np.testing.assert_array_equal(got.force, sent.force)
            np.testing.assert_array_equal(got.deflection, sent.deflection)
            np.testing.assert_array_equal(got.deflection_rate, sent.deflection_rate)
            assert len(got.force_stddev) == 0
    topics = read_series(bag)
    assert len(topics["/joint_states"].t) == PERIODS + 1
    np.testing.assert_allclose(topics["/joint_states"].t, np.arange(PERIODS + 1) * 1e-3, rtol=0, atol=1e-12)
    assert len(topics["/torque_command"].t) >= PERIODS - 1  # subscribed once the driver's publisher was seen
    np.testing.assert_array_equal(topics["/joint_states"].column("position", "left_motor")[-1], plant.plant.q[0])


def _recorder_status(h: RosHarness) -> list[Any]:
    """Every recorder status on /diagnostics, in arrival order."""
    from diagnostic_msgs.msg import DiagnosticArray

    from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS
    statuses: list[Any] = []
    h.node("diagnostics_listener").create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda msg: statuses.extend(s for s in msg.status if s.name.endswith(": recorder")), DIAGNOSTICS_QOS)
    return statuses


def test_namespaced_recorder_records_its_namespace(tmp_path: Path) -> None:
    """``-r __ns:=/r1 -p topics:=[joint_states, ...]`` beside a plant in /r1: the relative names are
    /r1's (an absolute one stays absolute), and /diagnostics says "nothing lost" only once every
    topic has a publisher."""
    require("rclpy")
    require("rosbags")
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.bags.series import read_series
    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.recorder.node import RecorderNode

    bag = tmp_path / "bag"
    h = RosHarness(domain_id(86))
    try:
        statuses = _recorder_status(h)
        recorder = h.add(RecorderNode(context=h.context, namespace="/r1", parameter_overrides=[
            Parameter("output", value=str(bag)),
            Parameter("topics", value=["joint_states", "branch_forces", "/r1/ee_pose"])]))
        assert recorder.wanted == ["/r1/joint_states", "/r1/branch_forces", "/r1/ee_pose"]
        h.wait_until(lambda: statuses, 60.0, "the recorder's diagnostics")
        assert statuses[-1].level == DiagnosticStatus.WARN
        assert statuses[-1].message == "no publisher: /r1/joint_states, /r1/branch_forces, /r1/ee_pose"

        h.add(PlantNode(context=h.context, namespace="/r1", parameter_overrides=[
            Parameter("sync_mode", value="lockstep")]))  # publishes its t = 0 state, then waits
        h.wait_until(lambda: all(recorder.count(t) for t in recorder.wanted), 60.0, "the plant's /r1 topics recorded")
        n = len(statuses)
        h.wait_until(lambda: len(statuses) > n, 60.0, "the next diagnostics")
        assert statuses[-1].level == DiagnosticStatus.OK, statuses[-1].message
        assert statuses[-1].message == "recording, nothing lost"
        recorder.close()
    finally:
        h.close()
    topics = read_series(bag)
    assert set(topics) == {"/r1/joint_states", "/r1/branch_forces", "/r1/ee_pose"}


def test_recorder_says_which_topics_have_no_publisher(tmp_path: Path) -> None:
    require("rclpy")
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.parameter import Parameter
    from std_msgs.msg import String

    from elastic_pm_dyn.ros.recorder.node import RecorderNode
    h = RosHarness(domain_id(86))
    try:
        statuses = _recorder_status(h)
        recorder = h.add(RecorderNode(context=h.context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "bag")), Parameter("topics", value=["/talk", "nobody"]),
            Parameter("topic_types", value=["nobody std_msgs/msg/String"])]))  # subscribed at once, unmatched
        talker = h.node("talker")
        pub = talker.create_publisher(String, "/talk", 10)
        talker.create_timer(0.05, lambda: pub.publish(String(data="hello")))
        h.wait_until(lambda: recorder.count("/talk"), 60.0, "/talk recorded")
        n = len(statuses)
        h.wait_until(lambda: len(statuses) > n, 60.0, "the next diagnostics")
        status = statuses[-1]
        assert status.level == DiagnosticStatus.WARN
        assert status.message == "no publisher: /nobody"
        assert {kv.key: kv.value for kv in status.values}["no_publisher"] == "/nobody"
        recorder.close()
    finally:
        h.close()
