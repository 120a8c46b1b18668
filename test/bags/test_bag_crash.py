"""A real recorder process killed with SIGKILL mid-recording (mcap and sqlite3).

A publisher sends numbered joint states at ~1 kHz for ~3 s to a recorder node in its own
process (private domain, loopback; as ``elastic-pm-dyn ros-demo`` starts it), which is
then killed with SIGKILL. Every message published more than 1 s before the kill must be
read back, the bag must say that it was cut off, ``bag-repair`` must give a bag that
rosbags' own Reader opens with every recovered message, and the recorder's "recording
<topic>" line must come only once a message of the topic can be read from the bag.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.bags.msgtypes import JOINT_STATE
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.repair import repair_bag

RATE = 1000.0  # [Hz]
PUBLISH = 3.0  # [s]
SAFE_AGE = 1.0  # [s] messages at least this old when the recorder dies must survive


def _positions(bag: Path) -> list[int]:
    """The sequence numbers (position[0]) of the /joint_states messages in the bag."""
    with open_bag(bag) as b:
        dec = b.decoder()
        conns = [c for c in b.connections if c.topic == "/joint_states"]
        return [int(dec.joint_state(raw)[2][0]) for _, _, raw in b.messages(conns)]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_sigkilled_recorder_keeps_all_but_the_last_second(storage: str, tmp_path: Path) -> None:
    require("rclpy")
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosbags.rosbag2 import Reader
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env

    domain = domain_id(5)
    bag = tmp_path / "bag"
    recorder = NodeProcess("recorder", "elastic_pm_dyn.ros.recorder.node",
                           ["-p", f"output:={bag}", "-p", f"storage:={storage}", "-p", "topics:=[/joint_states]"],
                           ros_env(domain), tmp_path / "logs")
    h = RosHarness(domain)
    sent: list[float] = []  # monotonic time of each publication, by sequence number
    readable_when_logged: list[int] | None = None
    try:
        node = h.node("numbered_states")
        pub = node.create_publisher(JointState, "/joint_states",
                                    QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))

        def subscribed() -> bool:
            recorder.check_running()
            return pub.get_subscription_count() >= 1

        h.wait_until(subscribed, 60.0, "the recorder's subscription")
        h.spin_for(0.3)  # the match seen from the recorder's side too
        t0 = next_log_check = time.monotonic()
        while (now := time.monotonic()) - t0 < PUBLISH:
            while len(sent) < (now - t0) * RATE:
                k = len(sent)
                msg = JointState(name=["left_motor", "right_motor"], position=[float(k), 0.0])
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 1_000_000, 10**9)
                pub.publish(msg)
                sent.append(time.monotonic())
            if readable_when_logged is None and now >= next_log_check:
                next_log_check = now + 0.05
                if "recording /joint_states" in recorder.log.read_text(errors="replace"):
                    readable_when_logged = _positions(bag)
            time.sleep(0.0003)
        t_kill = time.monotonic()
        recorder.proc.send_signal(signal.SIGKILL)
        assert recorder.proc.wait(10.0) == -signal.SIGKILL
    finally:
        h.close()
        if recorder.proc.poll() is None:
            recorder.proc.kill()
            recorder.proc.wait(10.0)

    log = recorder.log.read_text(errors="replace")
    assert readable_when_logged, f"'recording /joint_states' logged before a message was readable:\n{log}"

    got = _positions(bag)
    old = [k for k, t in enumerate(sent) if t < t_kill - SAFE_AGE]
    assert len(old) > 1000
    missing = sorted(set(old) - set(got))
    assert not missing, f"{len(missing)} messages older than {SAFE_AGE} s lost (first {missing[:5]}) of {len(got)} read"
    assert got == sorted(got)  # in order, no duplicates
    with open_bag(bag) as b:
        assert b.cut is not None and "cut off" in b.cut and f"{len(got)} messages" in b.cut

    report = repair_bag(bag, tmp_path / "repaired")
    assert report.messages == {"/joint_states": len(got)}
    with Reader(tmp_path / "repaired") as reader:  # rosbags' own reader, metadata.yaml and all
        assert reader.message_count == len(got)
        assert [(c.topic, c.msgtype) for c in reader.connections] == [("/joint_states", JOINT_STATE)]
        raws = [raw for _, _, raw in reader.messages()]
    assert len(raws) == len(got)
    assert _positions(tmp_path / "repaired") == got
