"""QoS profiles of the nodes (one place, so publishers and subscribers always match).

- Commands (``torque_command``, ``trajectory``): readers reliable, keep last 10, volatile: a
  late-joining plant must never act on an old torque. Our controllers' writers
  (:data:`COMMAND_OUT_QOS`) are transient local, for the recorder's sake only.
- States (``joint_states``, ``branch_forces``, ``ee_pose``, ``reference_joint_states``):
  reliable, keep last 100, transient local. Volatile subscribers (RViz, ros2 topic echo)
  match as usual; transient-local ones (recorder, lockstep controllers) also get the
  latest samples published before they matched. A volatile lockstep controller that
  matched after the t = 0 state gets it too: the plant publishes it again while it waits
  for the first command (docs/ros.md). Best-effort readers (SensorDataQoS) match as well.
  The depth is the writer history from which reliable delivery repairs a reader that
  falls behind (a recorder on a busy machine): with 10, a lag of
  10 samples lost states; 100 samples are 0.1 s at 1 kHz, and a loaded machine's recorder
  still lost samples the 100 had overwritten, so the plant's own writers keep 1000
  (:data:`STATE_OUT_QOS`, 1 s; a transient-local reader gets at most its own depth of it).
- Lockstep commands (plant in ``sync_mode: lockstep``): the reader keeps the last 1000
  (:data:`LOCKSTEP_COMMAND_QOS`, compatible with any COMMAND_QOS writer). Each command must
  be answered, and a controller that publishes a burst without waiting for the states (or a
  plant late on a loaded machine) would see commands overwritten in a 10-deep queue. Those
  still lost are counted from the publication sequence numbers (``commands_overwritten`` in
  the plant's /diagnostics, a warning each second while it grows).
- ``clock`` (relative: ``<namespace>/clock``, ``/clock`` without one): reliable, keep last
  10, volatile; rclpy's time source subscribes best effort depth 1, which a reliable
  publisher serves.
- Markers and diagnostics: reliable, keep last 1-10, volatile (viewers only need the latest).
- Observer inputs (plant node in ``mode: observer``: ``torque_command``,
  ``measured_joint_states``, ``ee_imu``, ``measured_branch_forces``): reliable, keep last
  1000, volatile. Reliable and deep (1 s at 1 kHz of reader history) because every lost
  sample changes the estimates, and then the live node no longer equals the offline pass
  over a recording of the same messages; volatile because an observer that starts late
  must start from fresh samples, not from a publisher's history. A driver that publishes
  best effort (sensor-data QoS, common for IMUs) does not match a reliable reader: these
  subscriptions accept ``qos_overrides.<topic>.subscription.reliability|history|depth``
  parameters (a lost sample then just lengthens one prediction).
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
# A controller's publisher: the reader side as COMMAND_QOS, a deeper writer history so that reliable
# delivery repairs a recorder that lags up to 1 s at 1 kHz (with 10, a loaded machine's recorder
# lost 8 of 2000 lockstep commands, and the bag no longer held what the observer had used).
# Transient local: only for transient-local readers (the recorder), which get the commands sent
# before their side of the match completed (a fast run lost its first 31 of 142 commands that way:
# the writer saw the recorder matched and sent, the recorder's reader had not matched the writer
# yet). 1000 deep (1 s at 1 kHz, as the plant's state writers): a loaded CI machine's recorder matched
# the writer 215 lockstep commands after the writer had matched it, and a 100-deep history had lost them.
# The plant's and the observer's readers are volatile: they never see an old command.
COMMAND_OUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
LOCKSTEP_COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.VOLATILE)
STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The plant's state writers: as STATE_QOS, with 1 s of history at 1 kHz from which reliable delivery
# repairs a reader that lags (a recorder on a loaded machine lost samples the 100-deep history had
# overwritten: DDS message-lost events). Transient-local readers still get at most their own depth.
STATE_OUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
VIEWER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
# The observer's inputs: 1 s at 1 kHz waits in its reader when it falls behind (a loaded machine,
# its start-up), so a late estimate is still made instead of a sample being overwritten.
OBSERVER_INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.VOLATILE)
