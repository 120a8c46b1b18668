"""Lockstep under a burst of commands: each one is answered, or counted as overwritten.

A controller that publishes without waiting for the states (or a plant late on a loaded
machine) puts many commands in the plant's queue at once. Lockstep advances one period per
command it takes, so the states that come back must number the commands sent, less those
the plant reports as overwritten: none silently lost.
"""

from __future__ import annotations

from typing import Any

import pytest
from ros_harness import RosHarness, domain_id, require

TAU = [0.01, -0.02]


@pytest.fixture
def ros():
    h = RosHarness(domain_id(68))
    yield h
    h.close()


def _setup(ros: RosHarness, publisher_depth: int) -> tuple[Any, Any, list[int], list[Any]]:
    require("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.qos import COMMAND_QOS, DIAGNOSTICS_QOS, STATE_QOS

    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=[
        Parameter("sync_mode", value="lockstep"), Parameter("diagnostics_rate", value=20.0)]))
    node = ros.node("burst")
    stamps: list[int] = []
    diags: list[Any] = []
    deep_states = QoSProfile(depth=10_000, reliability=STATE_QOS.reliability, durability=STATE_QOS.durability)
    node.create_subscription(JointState, "joint_states",
                             lambda m: stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), deep_states)
    node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, DIAGNOSTICS_QOS)
    pub = node.create_publisher(JointState, "torque_command",
                                QoSProfile(depth=publisher_depth, reliability=COMMAND_QOS.reliability,
                                           durability=COMMAND_QOS.durability))
    ros.wait_until(lambda: stamps and pub.get_subscription_count() > 0, 30.0, "the initial state")
    # One command answered first: the plant has seen this publisher's sequence.
    pub.publish(JointState(name=["left_motor", "right_motor"], effort=TAU))
    ros.wait_until(lambda: len(stamps) == 2, 30.0, "the first answer")
    return plant, pub, stamps, diags


def _burst(ros: RosHarness, pub: Any, stamps: list[int], n: int, plant: Any) -> None:
    """Publish ``n`` commands back to back (the plant not spun in between), then spin until
    each is answered or counted as overwritten (the deadline only guards against a hang),
    and a little longer: no answer may come after that."""
    from sensor_msgs.msg import JointState
    for _ in range(n):
        pub.publish(JointState(name=["left_motor", "right_motor"], effort=TAU))
    ros.wait_until(lambda: len(stamps) - 2 + plant.command_gaps.missed >= n, 300.0,
                   f"{n} commands answered or counted as overwritten")
    ros.spin_for(0.5)


def _value(diags: list[Any], key: str) -> str:
    return {kv.key: kv.value for kv in diags[-1].status[0].values}[key]


def test_a_burst_of_200_commands_is_answered_in_full(ros: RosHarness) -> None:
    plant, pub, stamps, diags = _setup(ros, publisher_depth=10)  # a controller with the usual 10-deep queue
    _burst(ros, pub, stamps, 200, plant)
    assert len(stamps) == 2 + 200
    assert stamps == sorted(set(stamps))  # one period each, in order
    ros.wait_until(lambda: diags and _value(diags, "periods") == "201", 30.0, "diagnostics after the burst")
    assert _value(diags, "commands_overwritten") == "0"


def test_commands_beyond_the_queue_are_counted_as_overwritten(ros: RosHarness) -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    from elastic_pm_dyn.ros.qos import LOCKSTEP_COMMAND_QOS
    n = LOCKSTEP_COMMAND_QOS.depth + 500
    plant, pub, stamps, diags = _setup(ros, publisher_depth=2 * n)
    _burst(ros, pub, stamps, n, plant)
    answered = len(stamps) - 2
    overwritten = plant.command_gaps.missed
    assert overwritten > 0
    assert answered + overwritten == n  # nothing silently lost
    ros.wait_until(lambda: diags and _value(diags, "commands_overwritten") == str(overwritten), 30.0,
                   "the count in /diagnostics")
    warned = [d for d in diags if "commands overwritten" in d.status[0].message]
    assert warned and warned[0].status[0].level == DiagnosticStatus.WARN
