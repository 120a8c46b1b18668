"""Message type names, ``NS`` and the text of our own message: written once for the package.

rclpy users import ``elastic_pm_dyn_msgs.msg.BranchForces`` (built from ``msg_defs/``).
Bag tools built on ``rosbags`` need the definition text instead; an installed
``elastic_pm_dyn`` does not ship ``msg_defs/``, so the text is embedded here and a test
checks it equals ``msg_defs/msg/BranchForces.msg``. Nothing here imports rosbags or rclpy.
"""

from __future__ import annotations

from typing import Any

NS = 1_000_000_000  # nanoseconds per second: stamps travel as integer ns

# rosbags' names ('pkg/msg/Type') of the message types read, written or flattened.
JOINT_STATE = "sensor_msgs/msg/JointState"
IMU = "sensor_msgs/msg/Imu"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
BRANCH_FORCES = "elastic_pm_dyn_msgs/msg/BranchForces"
# Their parts, where messages are built or flattened field by field.
HEADER = "std_msgs/msg/Header"
TIME = "builtin_interfaces/msg/Time"
DURATION = "builtin_interfaces/msg/Duration"
VECTOR3 = "geometry_msgs/msg/Vector3"
QUATERNION = "geometry_msgs/msg/Quaternion"
KEY_VALUE = "diagnostic_msgs/msg/KeyValue"

# Verbatim copy of msg_defs/msg/BranchForces.msg (test/ros/test_ros_msgs.py checks it).
BRANCH_FORCES_MSG_TEXT = """\
# Axial forces in the elastic branches (legs) of a parallel manipulator.
# All arrays are indexed alike: entry i of every array belongs to name[i].
# Force law per branch: F = c * u + d * du/dt (c stiffness [N/m], d damping [N*s/m]).

# Stamp = time the values refer to; frame_id is unused (axial quantities have no frame).
std_msgs/Header header

# Branch names [-], e.g. "leg_1".
string[] name

# Axial force F [N]; tension positive, compression negative.
float64[] force

# Axial deflection u [m]; elongation positive.
float64[] deflection

# Axial deflection rate du/dt [m/s].
float64[] deflection_rate

# Standard deviation of the force estimate [N]; empty when force is not an estimate
# (e.g. simulated or measured), else the same length as force.
float64[] force_stddev
"""

# Custom message types of this project: type name -> .msg text.
MSG_TEXTS: dict[str, str] = {BRANCH_FORCES: BRANCH_FORCES_MSG_TEXT}


def stamp_ns(stamp: Any) -> int:
    """A ``builtin_interfaces/Time`` (rclpy's or rosbags') as integer nanoseconds."""
    return int(stamp.sec) * NS + int(stamp.nanosec)
