"""Message definitions of elastic_pm_dyn_msgs for code that does not use rclpy.

rclpy users import ``elastic_pm_dyn_msgs.msg.BranchForces`` (built from ``msg_defs/``).
Bag tools built on ``rosbags`` need the definition text instead; an installed
``elastic_pm_dyn`` does not ship ``msg_defs/``, so the text is embedded here and a test
checks it equals ``msg_defs/msg/BranchForces.msg``.
No rclpy import here, and rosbags is imported only when a typestore is made.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

BRANCH_FORCES_MSGTYPE = "elastic_pm_dyn_msgs/msg/BranchForces"

# Verbatim copy of msg_defs/msg/BranchForces.msg (test/test_ros_msgs.py checks it).
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

# Custom message types of this project: rosbags type name -> .msg text.
MSG_TEXTS: dict[str, str] = {BRANCH_FORCES_MSGTYPE: BRANCH_FORCES_MSG_TEXT}


def make_typestore() -> Typestore:
    """Return a rosbags typestore for ROS 2 Jazzy with this project's messages registered.

    A fresh store each call: rosbags typestores are mutable, so sharing one would let a
    caller's registrations leak into another's.
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    for msgtype, text in MSG_TEXTS.items():
        store.register(get_types_from_msg(text, msgtype))
    return store
