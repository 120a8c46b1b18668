"""Loss bookkeeping and the queued bag writer, without ROS.

The sequence numbers are a writer's 1, 2, 3, ...: what a subscriber did not take shows as a
jump. The queued writer must write every message it was given, in order, from its own
thread, bound its memory and turn a write error into a kept bag plus counted drops.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
import yaml
from ros_harness import require

from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.queued_writer import QueuedWriter
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.ros.losses import SequenceGaps, TopicLosses


def test_sequence_gaps_count_what_was_skipped_by_one_publisher() -> None:
    g = SequenceGaps()
    taken = [5, 6, 7, 10, 11, 20]  # joined late at 5 (not a loss), then 8-9 and 12-19 never came
    skipped = [g.take(s) for s in taken]
    assert skipped == [0, 0, 0, 2, 0, 8]
    assert g.missed == 10


def test_sequence_gaps_restart_and_several_publishers_are_not_losses() -> None:
    g = SequenceGaps()
    for s in (1, 2, 3):
        g.take(s)
    assert g.take(1) == 0 and g.restarts == 1  # the publisher restarted: a new sequence
    assert g.take(2) == 0
    assert g.take(50, publishers=2) == 0  # interleaved writers: no gap can be told
    assert g.take(None) == 0 and g.take(0) == 0  # an RMW without sequence numbers
    assert g.missed == 0


def test_topic_losses_report_the_exact_witness() -> None:
    t = TopicLosses()
    t.dds_lost = 3
    assert t.lost() == 3  # no sequence compared yet: the DDS events are all there is
    for s in (1, 2, 9):
        t.gaps.take(s)
    assert t.sequence_gaps == 6 and t.lost() == 6  # one publisher's numbers: exact
    assert "6 skipped" in t.summary() and "3 lost" in t.summary()


def _conn(w: QueuedWriter, topic: str = "/x"):
    return w.add_connection(topic, "std_msgs/msg/String")


def _string(k: int) -> bytes:
    text = str(k).encode() + b"\0"
    return b"\0\1\0\0" + len(text).to_bytes(4, "little") + text


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_queued_writer_writes_everything_in_order_from_another_thread(storage: str, tmp_path: Path) -> None:
    flushes: list[str] = []
    w = QueuedWriter(lambda: BagWriter(tmp_path / "bag", storage, flush_period=0.05),
                     on_flush=lambda _w: flushes.append(threading.current_thread().name))
    a, b = _conn(w, "/a"), _conn(w, "/b")
    n = 3000
    for k in range(n):
        assert w.put(a if k % 3 else b, 1_000_000 * (k + 1), _string(k))
    w.call(lambda bag: bag.set_custom_data("elastic_pm_dyn.losses", json.dumps({"/a": 0})))
    w.close()
    assert flushes and set(flushes) == {"bag-writer"}
    with open_bag(tmp_path / "bag") as bag:
        assert bag.cut is None
        got = [(c.topic, t) for c, t, _ in bag.messages(bag.connections)]
    assert len(got) == n
    assert [t for _, t in got] == sorted(t for _, t in got)
    assert sum(1 for topic, _ in got if topic == "/b") == (n + 2) // 3
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())
    assert json.loads(meta["rosbag2_bagfile_information"]["custom_data"]["elastic_pm_dyn.losses"]) == {"/a": 0}


def _blocked(w: QueuedWriter) -> threading.Event:
    """Hold the writer thread until the returned event is set (the queue only grows meanwhile)."""
    release, holding = threading.Event(), threading.Event()

    def hold(_w: BagWriter) -> None:
        holding.set()
        release.wait()
    threading.Thread(target=w.call, args=(hold,), daemon=True).start()
    holding.wait()
    return release


def test_queued_writer_bounds_its_queue_and_counts_what_it_drops(tmp_path: Path) -> None:
    w = QueuedWriter(lambda: BagWriter(tmp_path / "bag", "mcap"), max_queued_bytes=0)
    c = _conn(w)
    release = _blocked(w)
    results = [w.put(c, k + 1, _string(k)) for k in range(5)]
    release.set()
    w.close()
    assert results[0] is True and results.count(False) == 4  # over the bound once the first is queued
    assert w.dropped[c.id] == 4 and w.written[c.id] == 1


def test_queued_writer_keeps_the_bag_and_counts_drops_after_a_write_error(tmp_path: Path) -> None:
    w = QueuedWriter(lambda: BagWriter(tmp_path / "bag", "mcap", flush_period=0.0))
    c = _conn(w)
    w.put(c, 1, _string(1))

    def broken(*_args):
        raise BagError("bag: cannot write to the bag: No space left on device")

    def fill_disk(bag: BagWriter) -> None:
        bag.write = broken  # the disk is full from now on
    w.call(fill_disk)
    for k in range(3):
        w.put(c, k + 2, _string(k))
    with pytest.raises(BagError, match="No space left"):
        w.close()
    assert w.written[c.id] == 1 and w.dropped[c.id] == 3
    with open_bag(tmp_path / "bag") as bag:  # what was flushed before stays readable
        assert sum(1 for _ in bag.messages(bag.connections)) == 1


def test_queued_writer_creation_error_is_raised_to_the_caller(tmp_path: Path) -> None:
    (tmp_path / "bag").mkdir()
    with pytest.raises(BagError, match="exists already"):
        QueuedWriter(lambda: BagWriter(tmp_path / "bag", "mcap"))


def test_subscription_depth_covers_the_lag_at_the_rate_and_the_publishers_history() -> None:
    require("rclpy")  # recorder.py imports rclpy
    from elastic_pm_dyn.ros.recorder.node import MAX_DEPTH, subscription_depth
    assert subscription_depth(1000.0, 2.0, []) == 2000  # 2 s behind a 1 kHz topic
    assert subscription_depth(10.0, 0.1, []) == 10  # never below 10
    assert subscription_depth(100.0, 1.0, [100, 5000]) == 5000  # a transient-local history arrives at once
    assert subscription_depth(1e6, 3600.0, []) == MAX_DEPTH

