"""Drive the simulated plant from your own rclpy controller, one control period at a time.

Starts ``plant_node`` (the elastic five-bar simulated in the loop) in ``lockstep`` mode as a
child process on a private, loopback-only ROS domain. A small controller node here
subscribes ``joint_states`` and answers every state with a ``torque_command``
(sensor_msgs/JointState, name + effort): the rigid model's feedforward torques of the
reference line plus a PD loop on the motor angles. In lockstep the plant advances exactly one
period per command: the run is deterministic however slow the controller. After N periods
the tracking error is printed (each command is held over its period, so the machine trails
the reference by about half a period, half a millimetre at the line's top speed). The plant
process is stopped however the run ends.

Run (needs ROS 2 Jazzy's rclpy and the elastic_pm_dyn_msgs package):

    python examples/ros_controller.py [--periods 500] [--kp 40] [--kd 1] [--out DIR] [--domain-id ID]

The plant's log is DIR/logs/plant.log (default DIR: ros_controller_out).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

import elastic_pm_dyn as epd
from elastic_pm_dyn.ros.processes import NodeProcess, private_domain_id, ros_env  # how the package starts nodes

CONFIG = Path(__file__).resolve().parents[1] / "config"
# The plant keeps its states for late joiners (transient local): the state at t = 0, published
# at start-up, reaches this controller even though it subscribes later. Commands keep none.
STATE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=CONFIG / "five_bar.yaml", help="model YAML")
    parser.add_argument("--periods", type=int, default=500, help="control periods to run (1 ms each)")
    parser.add_argument("--kp", type=float, default=40.0, help="motor angle gain [N m/rad]")
    parser.add_argument("--kd", type=float, default=1.0, help="motor rate gain [N m s/rad]")
    parser.add_argument("--out", type=Path, default=Path("ros_controller_out"), help="directory for the logs")
    parser.add_argument("--domain-id", type=int, default=private_domain_id(), help="ROS domain (1-100)")
    parser.add_argument("--timeout", type=float, default=60.0, help="give up after this long [s]")
    args = parser.parse_args(argv)

    model = epd.load_model(args.model)
    mech = epd.Mechanism(model)
    manoeuvre = epd.REFERENCE_MANOEUVRE
    # Rigid motion and torques on the control grid, tabulated once (solves are slow next to 1 ms).
    reference = epd.LineReference(epd.rigid_feedforward(model), manoeuvre.line, manoeuvre.control_rate)
    motors = reference.ff.mech.active_names  # the order of the reference's torques
    in_rigid = [reference.ff.mech.joint_names.index(n) for n in motors]
    in_tree = [mech.joint_names.index(n) for n in motors]

    env = ros_env(args.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]  # read by rcl at init
    rclpy.init(domain_id=args.domain_id)
    node = rclpy.create_node("example_controller")
    # Its own process group: a Ctrl+C here does not reach it, the finally below stops it.
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant_node",
                        ["-p", f"model:={args.model}", "-p", "sync_mode:=lockstep",
                         "-p", f"publish_rate:={manoeuvre.control_rate!r}"], env, args.out / "logs")
    try:
        pub = node.create_publisher(JointState, "torque_command", COMMAND_QOS)
        errors: list[tuple[float, float, float]] = []  # (t, motor angle error, end-effector error)
        waiting: list[JointState] = []

        def answer(state: JointState) -> None:
            t = state.header.stamp.sec + state.header.stamp.nanosec * 1e-9
            order = [state.name.index(n) for n in mech.joint_names]
            q, qd = np.array(state.position)[order], np.array(state.velocity)[order]
            ref = reference.sample(t)
            q_err, qd_err = ref.q[in_rigid] - q[in_tree], ref.qd[in_rigid] - qd[in_tree]
            errors.append((t, np.abs(q_err).max(), np.linalg.norm(mech.end_effector(q) - manoeuvre.line(t)[0])))
            if len(errors) <= args.periods:  # the last state is only measured
                tau = ref.tau + args.kp * q_err + args.kd * qd_err
                pub.publish(JointState(header=state.header, name=motors, effort=tau.tolist()))

        # A command sent before the plant subscribes would be lost, and lockstep would wait forever.
        node.create_subscription(JointState, "joint_states", waiting.append, STATE_QOS)
        deadline = time.monotonic() + args.timeout
        while len(errors) <= args.periods:
            rclpy.spin_once(node, timeout_sec=0.05)
            plant.check_running()
            if time.monotonic() > deadline:
                raise TimeoutError(f"{len(errors)} of {args.periods + 1} states in {args.timeout:g} s")
            while waiting and pub.get_subscription_count():
                answer(waiting.pop(0))
    finally:  # also on an error, a timeout or Ctrl+C: never leave the plant running
        plant.stop()
        node.destroy_node()
        rclpy.try_shutdown()

    t, motor_err, ee_err = np.array(errors).T
    print(f"{args.periods} periods of {1e3 / manoeuvre.control_rate:g} ms in lockstep, kp {args.kp:g}, kd {args.kd:g}")
    print(f"motor angle error: max {motor_err.max() * 1e3:.4f} mrad, final {motor_err[-1] * 1e3:.4f} mrad")
    print(f"end-effector error: max {ee_err.max() * 1e6:.2f} um at t = {t[ee_err.argmax()]:.3f} s, "
          f"final {ee_err[-1] * 1e6:.2f} um")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
