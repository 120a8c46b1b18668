"""QoS profiles of the nodes (one place, so publishers and subscribers always match).

- Commands (``torque_command``, ``trajectory``): reliable, keep last 10, volatile. A
  late-joining plant must never act on an old torque, so no history is kept.
- States (``joint_states``, ``branch_forces``, ``ee_pose``, ``reference_joint_states``):
  reliable, keep last 100, transient local. Volatile subscribers (RViz, ros2 topic echo)
  match as usual; transient-local ones (recorder, lockstep controllers) also get the
  latest samples published before they matched, so the lockstep hand-shake cannot be
  lost to discovery order. The depth is the writer history from which reliable delivery
  repairs a reader that falls behind (a recorder on a busy machine): with 10, a lag of
  10 samples lost states; 100 samples are 0.1 s at 1 kHz.
- ``/clock``: reliable, keep last 10, volatile; rclpy's time source subscribes best effort
  depth 1, which a reliable publisher serves.
- Markers and diagnostics: reliable, keep last 1-10, volatile (viewers only need the latest).
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
VIEWER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
