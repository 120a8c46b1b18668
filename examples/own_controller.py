"""Your own controller in the loop: a PD on the plant's encoders plus the holding torque, on default QoS.

Start the plant and the observer (any order, before or after this script), e.g. in two shells:
  elastic-pm-dyn plant --params-file config/plant_sensors.yaml
  elastic-pm-dyn observer --params-file config/observer_five_bar.yaml
(another machine: --model on both, and its own observer file, e.g. config/observer_hexa.yaml;
config/observer_node.yaml for a machine without one)
then ``python examples/own_controller.py [MODEL] [PERIODS]`` (domain: ROS_DOMAIN_ID). In lockstep every command
advances the plant one period: answer each new encoder stamp once, with that stamp (the observer's estimates of
the springs and branch forces appear on observer/joint_states and observer/branch_forces).
"""
import sys

import numpy as np
import rclpy
from sensor_msgs.msg import JointState

import elastic_pm_dyn as epd
from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state
from elastic_pm_dyn.ros.loop_demo import default_gains  # kp = m w^2, kd = 2 zeta m w at 2 Hz

MODEL = sys.argv[1] if len(sys.argv) > 1 else "config/five_bar.yaml"
PERIODS = int(sys.argv[2]) if len(sys.argv) > 2 else 1000  # commands to send, then stop
mech = epd.Mechanism(epd.load_model(MODEL))
rest = rest_state(mech)  # the plant's `start: static` pose
target, hold, (kp, kd) = rest[mech.active], holding_torques(mech, rest), default_gains(mech)
last = {"ns": -1, "q": None}


def on_encoders(msg: JointState) -> None:
    ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    if ns <= last["ns"] or PERIODS <= 0:
        return  # a state seen again (the plant repeats its first until a command comes)
    q = np.array([msg.position[msg.name.index(n)] for n in mech.active_names])
    qd = np.zeros_like(q) if last["q"] is None else (q - last["q"]) / max((ns - last["ns"]) * 1e-9, 1e-6)
    last.update(ns=ns, q=q)
    tau = hold + kp * (target - q) - kd * qd
    command.publish(JointState(header=msg.header, name=mech.active_names, effort=tau.tolist()))
    globals()["PERIODS"] -= 1


rclpy.init()
node = rclpy.create_node("my_controller")
command = node.create_publisher(JointState, "torque_command", 10)
node.create_subscription(JointState, "measured_joint_states", on_encoders, 10)
while PERIODS > 0 and rclpy.ok():
    rclpy.spin_once(node, timeout_sec=0.1)
print(f"{MODEL}: commands sent up to t = {last['ns'] * 1e-9:.3f} s")
