"""Drive the simulated plant from your own rclpy controller, one control period at a time.

``plant_node`` (the elastic five-bar) in ``lockstep`` advances one period per command: deterministic however slow
the controller (here feedforward + PD). Run: ``python examples/ros_controller.py``; domain: ROS_DOMAIN_ID.
"""
from pathlib import Path

import numpy as np
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState

import elastic_pm_dyn as epd
from elastic_pm_dyn.ros.demos.local_nodes import LocalNodes

MODEL = Path(__file__).resolve().parents[1] / "config" / "five_bar.yaml"
PERIODS, KP, KD, START, TIMEOUT = 500, 40.0, 1.0, 900.0, 60.0  # 1 ms each, [N m/rad], [N m s/rad], give up [s]
STATE_QOS = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL)  # t = 0 came before us: still arrives
mech, line, errors = epd.Mechanism(epd.load_model(MODEL)), epd.REFERENCE_MANOEUVRE.line, []
reference = epd.LineReference(epd.rigid_feedforward(mech.model), line, 1000.0)  # solved at once: 1 ms is short
motors = reference.ff.mech.active_names
in_ref, in_tree = ([m.joint_names.index(n) for n in motors] for m in (reference.ff.mech, mech))

def answer(state: JointState) -> None:  # your control law: feedforward + PD
    ref = reference.sample(t := state.header.stamp.sec + state.header.stamp.nanosec * 1e-9)
    q, qd = (np.array(v)[[state.name.index(n) for n in mech.joint_names]] for v in (state.position, state.velocity))
    q_err, qd_err = ref.q[in_ref] - q[in_tree], ref.qd[in_ref] - qd[in_tree]
    errors.append((t, np.abs(q_err).max(), np.linalg.norm(mech.end_effector(q) - line(t)[0])))
    if len(errors) <= PERIODS:  # the last state is only measured
        pub.publish(JointState(header=state.header, name=motors, effort=list(ref.tau + KP * q_err + KD * qd_err)))

with LocalNodes(Path("ros_controller_out")) as ros:
    ros.start("plant", ["-p", f"model:={MODEL}", "-p", "sync_mode:=lockstep", "-p", "publish_rate:=1000.0"])
    pub = (node := rclpy.create_node("example_controller")).create_publisher(JointState, "torque_command", 10)
    ros.spin_until(node, lambda: pub.get_subscription_count() > 0, START)  # a cold start compiles (minutes)
    node.create_subscription(JointState, "joint_states", answer, STATE_QOS)
    ros.spin_until(node, lambda: len(errors) > PERIODS, TIMEOUT)
t, motor, ee = np.array(errors).T  # each command is held over its period: about half a period behind the line
print(f"{PERIODS} periods of 1 ms in lockstep; motor angle error: max {motor.max() * 1e3:.4f} mrad")
print(f"end-effector error: max {ee.max() * 1e6:.2f} um at t = {t[ee.argmax()]:.3f} s, final {ee[-1] * 1e6:.2f} um")
