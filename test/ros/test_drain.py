"""ros/drain.py: what is queued on a node's drained inputs is taken in the executor turn of the first.

Two publishers fill two topics before the reader spins; one executor turn then hands every
message to its handler, in each topic's own order, alternating between the topics as a wait set
would; a turn takes at most ``max_per_turn``; a subscription destroyed meanwhile is skipped.
"""

from __future__ import annotations

from typing import Any

import pytest
from ros_harness import RosHarness, domain_id, require

N = 40  # messages per topic


@pytest.fixture()
def harness() -> Any:
    require("rclpy")
    h = RosHarness(domain_id(9))
    yield h
    h.close()


def _wire(h: RosHarness, max_per_turn: int) -> tuple[Any, dict[str, list[int]], list[str], Any]:
    """Two drained topics with N messages each queued in the reader (acknowledged: in its history),
    nothing taken yet; (drain, messages by topic, topic order of the handler calls, the reader node)."""
    from rclpy.duration import Duration
    from std_msgs.msg import Int64

    from elastic_pm_dyn.ros.drain import Drain
    from elastic_pm_dyn.ros.qos import OBSERVER_INPUT_QOS
    writer, reader = h.node("writer"), h.node("reader")
    drain = Drain(max_per_turn)
    got: dict[str, list[int]] = {"a": [], "b": []}
    order: list[str] = []
    for topic in ("a", "b"):
        def handler(msg: Any, info: dict[str, Any], topic: str = topic) -> None:
            got[topic].append(msg.data)
            order.append(topic)
            assert info["publication_sequence_number"] >= 1  # the message info travels with a direct take
        drain.subscribe(reader, Int64, topic, handler, OBSERVER_INPUT_QOS)
    pubs = [writer.create_publisher(Int64, t, OBSERVER_INPUT_QOS) for t in ("a", "b")]
    h.wait_until(lambda: all(p.get_subscription_count() == 1 for p in pubs), 600.0, "the readers to match")
    for k in range(N):
        for p in pubs:
            p.publish(Int64(data=k))
    for p in pubs:  # reliable: acknowledged once in the reader's queue (no executor turn needed)
        assert p.wait_for_all_acked(Duration(seconds=600))
    return drain, got, order, reader


def test_one_turn_takes_every_queued_message_in_order(harness: RosHarness) -> None:
    drain, got, order, _ = _wire(harness, max_per_turn=1000)
    harness.executor.spin_once(timeout_sec=5.0)
    assert got == {"a": list(range(N)), "b": list(range(N))}  # all of them, each topic in its order, in one turn
    assert drain.turns == 1 and drain.taken == 2 * N - 1  # the executor handed over the first
    # round by round: never two of one topic while the other still has messages waiting
    assert all(order[i] != order[i + 1] for i in range(1, 2 * N - 2))


def test_a_turn_takes_at_most_max_per_turn(harness: RosHarness) -> None:
    _, got, _, _ = _wire(harness, max_per_turn=10)
    harness.executor.spin_once(timeout_sec=5.0)
    assert len(got["a"]) + len(got["b"]) == 11  # the executor's one, then ten taken directly
    harness.wait_until(lambda: len(got["a"]) + len(got["b"]) == 2 * N, 600.0, "the rest, in later turns")
    assert got == {"a": list(range(N)), "b": list(range(N))}


def test_a_destroyed_subscription_is_skipped(harness: RosHarness) -> None:
    _, got, _, reader = _wire(harness, max_per_turn=1000)
    reader.destroy_subscription(list(reader.subscriptions)[1])  # behind the drain's back
    harness.executor.spin_once(timeout_sec=5.0)
    assert got["a"] == list(range(N)) and got["b"] == []
