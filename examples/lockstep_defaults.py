"""Drive a lockstep plant with a controller on plain default QoS, as a new ROS 2 user writes it.

``plant_node`` in ``lockstep`` publishes its t = 0 state before this controller subscribes: a default (reliable,
volatile, depth 10) subscriber misses it, so the plant publishes it again (same stamp) until the first command
comes. Answer each new stamp once: a state seen again is not answered twice (that would be an extra period).
Run: ``python examples/lockstep_defaults.py`` (domain: ROS_DOMAIN_ID; plant log in lockstep_defaults_out).
"""
import time
from pathlib import Path

import rclpy
from sensor_msgs.msg import JointState

from elastic_pm_dyn.ros.demos.local_nodes import LocalNodes

PERIODS, START, TIMEOUT = 200, 900.0, 60.0  # control periods of 1 ms; give up after [s] (a cold start compiles)
stamps, repeats = [], []  # the new states' stamps; the stamps seen again


def on_state(msg: JointState) -> None:  # a constant torque here: your control law in its place
    t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
    if stamps and t <= stamps[-1]:
        repeats.append(t)  # the same state again: answered already
    else:
        stamps.append(t)
        if len(stamps) <= PERIODS:  # the last state is only received
            pub.publish(JointState(name=["left_motor", "right_motor"], effort=[0.01, -0.01]))


with LocalNodes(Path("lockstep_defaults_out")) as ros:
    ros.start("plant", ["-p", "sync_mode:=lockstep"])
    node = rclpy.create_node("controller")
    ros.spin_until(node, lambda: node.count_publishers("/joint_states") > 0, START)
    time.sleep(1.0)  # the plant publishes t = 0 before this controller subscribes
    pub = node.create_publisher(JointState, "torque_command", 10)
    node.create_subscription(JointState, "joint_states", on_state, 10)
    ros.spin_until(node, lambda: len(stamps) > PERIODS, TIMEOUT)
print(f"{PERIODS} lockstep periods driven with default QoS; last state at t = {stamps[-1]:.3f} s; "
      f"{len(repeats)} state(s) seen again while the plant waited for the first command")
