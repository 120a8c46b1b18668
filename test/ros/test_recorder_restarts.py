"""Recorders killed and restarted against a running plant must each record (issue #29).

A recorder started on the domain of one that was just SIGKILLed takes the dead process's
Fast DDS participant id, and with it its shared-memory port: the plant could keep writing
into the dead port and the new recorder, matched, received nothing. Each restarted recorder
here (mcap and sqlite3, both orders) must get messages of every topic into its bag.
``ELASTIC_PM_DYN_RESTART_CYCLES=N`` runs N cycles of two recorders (default 2: 4 recorders).

Also: a topic that is matched but silent is reported (log and /diagnostics), not left as an
empty bag without a word.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.bags.reader import open_bag

TOPICS = ["/joint_states", "/branch_forces", "/ee_pose"]
CYCLES = int(os.environ.get("ELASTIC_PM_DYN_RESTART_CYCLES", "2"))
HANG_GUARD = 300.0  # [s] only against a hang: a cold numba cache compiles the plant first


def _wait_for(proc, text: str | list[str], guard: float = HANG_GUARD) -> None:
    texts = [text] if isinstance(text, str) else text
    end = time.monotonic() + guard
    while not all(t in proc.log.read_text(errors="replace") for t in texts):
        proc.check_running()
        if time.monotonic() > end:
            raise AssertionError(f"{proc.name}: no {texts} within {guard:g} s:\n{proc.log.read_text()}")
        time.sleep(0.05)


def _counts(bag: Path) -> dict[str, int]:
    with open_bag(bag) as b:
        return {c.topic: sum(1 for _ in b.messages([c])) for c in b.connections}


def test_every_restarted_recorder_records(tmp_path: Path) -> None:
    require("rclpy")
    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env

    env = ros_env(domain_id(44))
    topics = "topics:=[" + ",".join(TOPICS) + "]"
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", ["-p", "sync_mode:=realtime"], env, tmp_path / "logs")
    recorders = []
    try:
        _wait_for(plant, "robot_description")
        k = 0
        for cycle in range(CYCLES):
            for storage in ("mcap", "sqlite3") if cycle % 2 == 0 else ("sqlite3", "mcap"):
                k += 1
                bag = tmp_path / f"bag{k}"
                rec = NodeProcess(f"recorder{k}", "elastic_pm_dyn.ros.recorder.node",
                                  ["-p", f"output:={bag}", "-p", f"storage:={storage}", "-p", topics],
                                  env, tmp_path / "logs")
                recorders.append(rec)
                # Killed as soon as every topic is in the file (a recorder that never gets there
                # fails here, its log quoted), while the plant keeps publishing.
                _wait_for(rec, [f"recording {t}" for t in TOPICS])
                rec.proc.send_signal(signal.SIGKILL)
                rec.proc.wait(30.0)
                counts = _counts(bag)
                assert all(counts.get(t, 0) > 0 for t in TOPICS), f"{rec.name} ({storage}): {counts}"
    finally:
        for rec in recorders:
            if rec.proc.poll() is None:
                rec.proc.kill()
                rec.proc.wait(30.0)
        plant.stop()
    assert k == 2 * CYCLES


def test_a_matched_but_silent_topic_is_reported(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    require("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.parameter import Parameter
    from std_msgs.msg import String

    import elastic_pm_dyn.ros.recorder.node as recorder_module
    from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS

    monkeypatch.setattr(recorder_module, "SILENT_AFTER", 0.5)
    monkeypatch.setattr(recorder_module, "REPORT_PERIOD", 0.2)
    h = RosHarness(domain_id(47))
    try:
        node = h.node("quiet_publisher")
        pub = node.create_publisher(String, "/quiet", 10)
        diags: list = []
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, DIAGNOSTICS_QOS)
        rec = h.add(recorder_module.RecorderNode(context=h.context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "bag")), Parameter("topics", value=["/quiet"])]))
        warnings: list[str] = []
        logger = rec.get_logger()
        monkeypatch.setattr(rec, "get_logger", lambda: _Spy(logger, warnings))

        def reported() -> bool:
            return any(d.status[0].level == DiagnosticStatus.WARN and "/quiet silent" in d.status[0].message
                       for d in diags)
        h.wait_until(reported, 60.0, "the silent topic in /diagnostics")
        assert any("/quiet" in w and "no message" in w for w in warnings), warnings
        assert rec.losses()["/quiet"]["resubscribed"] >= 1 and rec.participants

        # The publisher was only silent (as the observer is before its loop starts). A reader made
        # now in yet another participant cannot have matched when these go out: the older readers,
        # kept, take them, once each (the readers destroyed, all five were lost).
        rec._resubscribe("/quiet", rec.topics["/quiet"])
        for k in range(5):
            pub.publish(String(data=str(k)))
        h.wait_until(lambda: rec.losses()["/quiet"]["received"] >= 5, 60.0, "the five messages")
        h.wait_until(lambda: diags[-1].status[0].level == DiagnosticStatus.OK
                     and "/quiet received" in {kv.key for kv in diags[-1].status[0].values}
                     and {kv.key: kv.value for kv in diags[-1].status[0].values}["/quiet received"] != "0",
                     60.0, "OK again, with the message counted")
        rec.close()
    finally:
        h.close()
    from elastic_pm_dyn.bags.reader import open_bag
    with open_bag(tmp_path / "bag") as bag:
        data = [bag.deserialize(raw, c.msgtype).data for c, _, raw in bag.messages(bag.connections)]
    assert data == ["0", "1", "2", "3", "4"]  # none lost to the resubscription, none twice


def test_a_topic_subscribed_anew_records_through_a_second_participant(tmp_path: Path) -> None:
    """The remedy for a reader that is never served: the new subscription lives in a DDS
    participant of its own, and what it takes goes into the same bag as before. Here the old
    reader is served too: both deliver, and the bag has each message once, in order."""
    require("rclpy")
    from rclpy.parameter import Parameter
    from std_msgs.msg import String

    import elastic_pm_dyn.ros.recorder.node as recorder_module
    from elastic_pm_dyn.bags.reader import open_bag

    h = RosHarness(domain_id(50))
    try:
        node = h.node("numbered_publisher")
        pub = node.create_publisher(String, "/numbered", 1000)
        sent = [0]

        def send() -> None:
            sent[0] += 1
            pub.publish(String(data=str(sent[0])))
        node.create_timer(0.005, send)
        rec = h.add(recorder_module.RecorderNode(context=h.context, parameter_overrides=[
            Parameter("output", value=str(tmp_path / "bag")), Parameter("topics", value=["/numbered"])]))
        h.wait_until(lambda: rec.count("/numbered") >= 20, 60.0, "messages through the first participant")
        state = rec.topics["/numbered"]
        rec._resubscribe("/numbered", state)
        assert state.node is rec.participants[0].node and state.node is not rec
        assert state.node.context is not rec.context  # a participant of its own
        before = state.losses.received
        h.wait_until(lambda: state.losses.received >= before + 20, 60.0, "messages through the second participant")
        rec.close()
        assert not rec.participants[0].context.ok()
    finally:
        h.close()
    with open_bag(tmp_path / "bag") as bag:
        numbers = [int(bag.deserialize(raw, c.msgtype).data) for c, _, raw in bag.messages(bag.connections)]
    assert numbers == sorted(set(numbers))  # in order, none twice
    assert len(numbers) >= before + 20  # the second participant's messages are in the bag too


class _Spy:
    """A logger that also keeps the warnings."""

    def __init__(self, logger, warnings: list[str]):
        self.logger, self.warnings = logger, warnings

    def warning(self, text: str) -> None:
        self.warnings.append(text)
        self.logger.warning(text)

    def __getattr__(self, name: str):
        return getattr(self.logger, name)
