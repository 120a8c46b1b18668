"""Drive a lockstep plant with a controller that uses plain default QoS, as a new ROS 2 user writes it.

Starts ``plant_node`` in ``lockstep`` as a child process on a private, loopback-only domain,
and only then creates a controller node with ``create_subscription(JointState,
"joint_states", cb, 10)`` and ``create_publisher(JointState, "torque_command", 10)``: default
reliable, volatile QoS, no transient local. The plant's t = 0 state was published before this
subscriber existed; the plant publishes it again (same stamp) until the first command
arrives, so the loop starts. The controller answers each new stamp once (a state seen again
is not answered twice) with a constant torque, for N periods.

Run (needs ROS 2 Jazzy's rclpy and the elastic_pm_dyn_msgs package):

    python examples/lockstep_defaults.py [--periods 200] [--out DIR] [--domain-id ID]

The plant's log is DIR/logs/plant.log (default DIR: lockstep_defaults_out).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState

from elastic_pm_dyn.ros.processes import NodeProcess, private_domain_id, ros_env


class Controller(Node):
    """Plain defaults: depth 10, reliable, volatile; one command per new state stamp."""

    def __init__(self, periods: int):
        super().__init__("controller")
        self.periods = periods
        self.pub = self.create_publisher(JointState, "torque_command", 10)
        self.create_subscription(JointState, "joint_states", self.on_state, 10)
        self.stamps: list[float] = []
        self.repeats = 0  # states seen again (re-published while the plant waited)

    def on_state(self, msg: JointState) -> None:
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if self.stamps and t <= self.stamps[-1]:
            self.repeats += 1
            return  # the same state again: answered already
        self.stamps.append(t)
        if len(self.stamps) <= self.periods:  # the last state is only received
            self.pub.publish(JointState(name=["left_motor", "right_motor"], effort=[0.01, -0.01]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=200, help="control periods to run (1 ms each)")
    parser.add_argument("--out", type=Path, default=Path("lockstep_defaults_out"), help="directory for the logs")
    parser.add_argument("--domain-id", type=int, default=private_domain_id(), help="ROS domain (1-100)")
    parser.add_argument("--timeout", type=float, default=60.0, help="give up after this long [s]")
    args = parser.parse_args(argv)

    env = ros_env(args.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]  # read by rcl at init
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant_node", ["-p", "sync_mode:=lockstep"], env,
                        args.out / "logs")
    rclpy.init(domain_id=args.domain_id)
    node = None
    try:
        time.sleep(1.0)  # the plant publishes t = 0 before this controller exists
        node = Controller(args.periods)
        deadline = time.monotonic() + args.timeout
        while len(node.stamps) <= args.periods:
            rclpy.spin_once(node, timeout_sec=0.05)
            plant.check_running()
            if time.monotonic() > deadline:
                raise TimeoutError(f"{len(node.stamps)} of {args.periods + 1} states in {args.timeout:g} s")
    finally:  # also on an error, a timeout or Ctrl+C: never leave the plant running
        plant.stop()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    print(f"{args.periods} lockstep periods driven with default QoS; last state at t = {node.stamps[-1]:.3f} s; "
          f"{node.repeats} state(s) seen again while the plant waited for the first command")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
