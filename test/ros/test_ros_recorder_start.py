"""The recorder subscribes to the topics whose type it is given at start-up (issue #25): the first
command of a run, published as soon as another subscriber (the plant) matched, is in the bag, and
so is the lockstep plant's t = 0 state that was published before the recorder's reader matched."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from ros_harness import RosHarness, domain_id, require

COMMANDS = 5


def test_first_messages_of_a_run_are_in_the_bag(tmp_path: Path) -> None:
    require("rclpy")
    require("rosbags")
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.bags.series import read_series
    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.recorder.node import DEMO_TYPES, RecorderNode

    bag = tmp_path / "bag"
    h = RosHarness(domain_id(89))
    try:
        recorder = h.add(RecorderNode(context=h.context, parameter_overrides=[
            Parameter("output", value=str(bag)), Parameter("topics", value=["/joint_states", "/torque_command"]),
            Parameter("topic_types", value=DEMO_TYPES)]))
        # Subscribed before any publisher exists; DEMO_TYPES' other topics are not wanted: not recorded.
        assert set(recorder.connections) == {"/joint_states", "/torque_command"}
        plant = h.add(PlantNode(context=h.context, parameter_overrides=[Parameter("sync_mode", value="lockstep")]))
        controller = h.node("controller")
        pub = controller.create_publisher(JointState, "torque_command", 10)
        # A controller that waits for the plant only (wait_for_subscribers: 1), then sends at once.
        h.wait_until(lambda: plant.command_sub.get_publisher_count() >= 1, 20.0, "the plant matched")
        h.wait_until(lambda: recorder.topics["/torque_command"].subscription.get_publisher_count() >= 1, 20.0,
                     "the recorder's reader matched too (it existed before the publisher)")
        for k in range(COMMANDS):
            pub.publish(JointState(name=["left_motor", "right_motor"], effort=[0.01 * k, 0.0]))
        h.wait_until(lambda: plant.plant.k == COMMANDS, 20.0, "the plant answered every command")
        h.wait_until(lambda: recorder.count("/torque_command") == COMMANDS and recorder.count("/joint_states")
                     >= COMMANDS + 1, 20.0, "everything recorded")
        recorder.close()
    finally:
        h.close()
    topics = read_series(bag)
    np.testing.assert_allclose(topics["/torque_command"].column("effort", "left_motor"),
                               0.01 * np.arange(COMMANDS), rtol=0, atol=0)
    stamps = np.unique(np.round(topics["/joint_states"].t * 1e3))  # the t = 0 state may be there twice
    np.testing.assert_array_equal(stamps, np.arange(COMMANDS + 1))


def test_fast_plant_with_a_state_triggered_feedforward_every_command_is_in_the_bag(tmp_path: Path) -> None:
    """Fast mode runs ahead of the controller (states it never answers are counted), but every
    command the feedforward sends reaches the plant's recorder: nothing sent is missing."""
    require("rclpy")
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.feedforward.node import FeedforwardNode
    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.recorder.node import DEMO_TYPES, RecorderNode

    h = RosHarness(domain_id(92))
    try:
        recorder = h.add(RecorderNode(context=h.context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "bag")), Parameter("topics", value=["/torque_command"]),
            Parameter("topic_types", value=DEMO_TYPES)]))
        h.add(PlantNode(context=h.context, parameter_overrides=[Parameter("sync_mode", value="fast")]))
        ff = h.add(FeedforwardNode(context=h.context, parameter_overrides=[
            Parameter("trigger", value="state"), Parameter("exit_when_done", value=True),
            Parameter("wait_for_subscribers", value=2)]))
        h.wait_until(lambda: ff.done, 120.0, "the feedforward's line")
        h.wait_until(lambda: recorder.count("/torque_command") >= ff.sent, 20.0, "every command recorded")
        h.spin_for(0.3)
        assert ff.sent > 10
        assert recorder.count("/torque_command") == ff.sent
        recorder.close()
    finally:
        h.close()
