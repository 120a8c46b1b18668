"""Counting messages lost on the way to a subscriber (no rclpy here: plain bookkeeping).

Two independent witnesses, each exact where it applies:

- **DDS message-lost events** (``SubscriptionEventCallbacks(message_lost=...)``): the
  middleware counts samples a reliable writer gave up on (its keep-last history overwrote
  them before this reader had them) and samples best-effort delivery dropped. Their
  ``total_count_change`` is added up per topic.
- **Publication sequence gaps**: every message a subscription takes carries the writer's
  sequence number (``MessageInfo['publication_sequence_number']``, 1, 2, 3, ... per
  writer). With one publisher on the topic a jump from n to n + k means k - 1 messages never
  reached this callback, whatever dropped them (the writer's history, the reader's own
  keep-last queue while the callback was late). rclpy does not say which writer sent a
  message, so with several publishers the sequences interleave and gaps are not counted
  (:meth:`SequenceGaps.take` is told how many publishers there are).

The two overlap (a sample the writer dropped shows in both), so reports keep them apart
instead of adding them.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class SequenceGaps:
    """Gaps in one topic's publication sequence numbers (one publisher)."""

    last: int | None = None  # the last sequence number taken
    missed: int = 0  # messages skipped over, summed
    restarts: int = 0  # the sequence went back (a publisher restarted, or another one took over)
    exact: bool = False  # two numbers of one publisher compared: missed is the exact count

    def take(self, seq: int | None, publishers: int = 1) -> int:
        """Note one message's sequence number; returns how many messages were skipped before it."""
        if seq is None or seq <= 0:  # the RMW does not give one (0 / unknown): nothing to count
            return 0
        last, self.last = self.last, seq
        if publishers != 1 or last is None:
            return 0
        self.exact = True
        if seq <= last:
            self.restarts += 1
            return 0
        skipped = seq - last - 1
        self.missed += skipped
        return skipped


@dataclass
class TopicLosses:
    """What one subscription knows it did not get."""

    received: int = 0  # messages the callback took
    dds_lost: int = 0  # DDS message-lost events, summed
    gaps: SequenceGaps = field(default_factory=SequenceGaps)

    @property
    def sequence_gaps(self) -> int:
        return self.gaps.missed

    def lost(self) -> int:
        """Messages that never arrived: the sequence gaps where they are exact (one publisher), else
        the DDS events (which may also count samples from before this reader matched)."""
        return self.sequence_gaps if self.gaps.exact else self.dds_lost

    def summary(self) -> str:
        return (f"{self.received} received, {self.dds_lost} lost (DDS events), "
                f"{self.sequence_gaps} skipped (sequence gaps)")
