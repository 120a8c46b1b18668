"""Your own controller in the loop: a PD on the plant's encoders plus the holding torque, on default QoS. Start
`elastic-pm-dyn plant --params-file config/plant_sensors.yaml`, `elastic-pm-dyn observer --params-file
config/observer_five_bar.yaml` (other machines: -p model:=M on both, config/observer_<machine>.yaml), then
``python examples/own_controller.py [MODEL] [PERIODS] [LISTENERS]``; answer each new stamp once (docs/ros.md)."""
import sys

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState

import elastic_pm_dyn as epd
from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state
from elastic_pm_dyn.ros.demos.loop_demo import default_gains  # kp = m w^2, kd = 2 zeta m w at 2 Hz

MODEL, PERIODS, LISTENERS = (sys.argv[1:] + ["config/five_bar.yaml", "1000", "2"][len(sys.argv) - 1:])[:3]
mech = epd.Mechanism(epd.load_model(MODEL))
rest = rest_state(mech)  # the plant's `start: static` pose: hold it
target, hold, (kp, kd), motors = rest[mech.active], holding_torques(mech, rest), default_gains(mech), mech.active_names
last = {"ns": -1, "q": None, "left": int(PERIODS)}  # commands to send, then stop

def on_encoders(msg: JointState) -> None:
    ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    if ns <= last["ns"] or last["left"] <= 0:
        return  # seen already (the plant repeats its first state until a command comes)
    q = np.array([msg.position[msg.name.index(n)] for n in motors])
    qd = np.zeros_like(q) if last["q"] is None else (q - last["q"]) / ((ns - last["ns"]) * 1e-9)
    last.update(ns=ns, q=q, left=last["left"] - 1)
    command.publish(JointState(header=msg.header, name=motors, effort=list(hold + kp * (target - q) - kd * qd)))

rclpy.init()
node, executor = rclpy.create_node("my_controller"), SingleThreadedExecutor()
executor.add_node(node)  # one executor for the run: rclpy.spin_once(node) adds and removes the node on every call
command = node.create_publisher(JointState, "torque_command", 10)
while command.get_subscription_count() < int(LISTENERS):  # plant, observer: discovery takes a moment, and a
    executor.spin_once(timeout_sec=0.1)  # command sent before a reader matched is lost to it
node.create_subscription(JointState, "measured_joint_states", on_encoders, 10)
while last["left"] > 0 and rclpy.ok():
    executor.spin_once(timeout_sec=0.1)
print(f"{MODEL}: commands sent up to t = {last['ns'] * 1e-9:.3f} s")
