"""Recorder node: a bag of a lockstep plant run that rosbags reads back exactly (mcap, sqlite3)."""

from __future__ import annotations

from pathlib import Path

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
    from elastic_pm_dyn.ros.plant_node import PlantNode
    from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS
    from elastic_pm_dyn.ros.recorder import RecorderNode

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
