"""The observer node's inputs merged into stamp order (rclpy-free; :class:`InputOrder`).

Messages of different topics reach a node in any order: the plant publishes the samples of
t_k, a controller answers with the command of t_k, the plant publishes the samples of t_k+1,
but the observer's executor may hand it the accelerometer sample of t_k+1 before the encoder
sample of t_k, or the samples of t_k+1 before the command that moved the plant there (it
travelled another way). Offline ``observe`` takes a recording in stamp order; so does the live
observer when its inputs go through this merge: each topic is first in, first out, so a
message is taken once every other topic has shown that it holds nothing earlier. Keys:

- a sample: (stamp, rank), rank 0 for samples of the state before the command (an
  accelerometer sampling before it, strain gauges), 1 for the primary sample (the encoders:
  it publishes the estimate), 3 for an accelerometer sampling after the command;
- a command: (stamp, 2), after the samples of its stamp. A command stamped 0 (an unset header)
  or further ahead than ``max_future`` (another clock: wall time against simulated time) is
  taken as stamped at the primary sample it answers: the one after the previous command's
  while the controller has answered every period (lockstep, where the plant's next state may
  reach this node before the command that led to it), else the newest received. The command
  topic covers the samples up to the next primary stamp: the samples of t_k+1 wait for a
  command stamped t_k or later. A command stamped before what was already taken is taken at
  once (the observer applies it from its current time).

The wait is bounded: a topic that leaves out sample periods (2 of its latest 20 stamp steps: a
slower sensor, a controller slower than the plant; a lockstep controller answers every period,
and a message lost once, say from a reader queue that overflowed while this node was stalled,
does not count) is not waited for once a message stamped 1.5 sample periods later is waiting,
and no topic that has been silent for ``max_wait`` seconds of wall time once a message has
waited that long, both counted while this node ran (a stall of the node itself, more than
``STALL`` between two polls, restarts the count) (then the topic is not waited for until it
delivers again: a stopped controller, the last state of a run; a topic that delivers is behind,
not gone, e.g. in this node's own queues while it catches up). A sample topic is waited for
only after its first message, the command topic from the start (the samples after the first
stamp need the command that held the machine there). The same sample received twice (a lockstep
plant publishes its first state again until a command comes) is taken once. At most
``max_pending`` messages wait; beyond, the earliest goes.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

BEFORE, PRIMARY, COMMAND, AFTER = 0, 1, 2, 3  # ranks within one stamp
STALL = 0.2  # [s] between two calls of pop_ready (the node polls every ~0.05 s): the node itself did not run
HORIZON = 1.5  # sample periods: a topic with nothing pending is skipped once a message this much later waits
RECENT_STEPS = 20  # a topic skips periods when at least SKIPS_AMONG of its latest RECENT_STEPS stamp steps
SKIPS_AMONG = 2  # left one out (a slower sensor or controller); a message lost now and then is no reason


@dataclass
class _Topic:
    rank: int
    pending: deque[tuple[tuple[int, int], float, Any]] = field(default_factory=deque)  # (key, arrival, item)
    last_ns: int | None = None  # newest stamp received
    covers: tuple[int, int] | None = None  # its next message's key is at least this
    period_ns: int | None = None  # its sample period (the smallest stamp step seen)
    stalled: bool = False  # not waited for until it delivers again
    steps: deque[bool] = field(default_factory=lambda: deque(maxlen=RECENT_STEPS))  # latest steps: a period left out?
    always_skips: bool = False  # a controller found answering less than every period
    last_push: float = float("-inf")  # wall time [s] of its latest message

    @property
    def skips(self) -> bool:
        """It leaves out sample periods (see SKIPS_AMONG): not waited for past HORIZON."""
        return self.always_skips or sum(self.steps) >= SKIPS_AMONG


@dataclass
class OrderStats:
    """Counts for /diagnostics (cumulative) and the queue's depth and lag."""

    taken: int = 0
    repeated: int = 0  # the same sample again: dropped
    restamped: int = 0  # commands stamped 0 or on another clock: taken at the newest primary stamp
    waited_out: int = 0  # releases after max_wait without what they waited for
    forced: int = 0  # releases because more than max_pending waited
    max_depth: int = 0  # deepest queue since the last report


class InputOrder:
    """Merge of the observer's input topics into stamp order (see module doc)."""

    def __init__(self, ranks: dict[str, int], primary: str, max_wait: float, max_future_ns: int,
                 max_pending: int = 1000):
        self.topics = {kind: _Topic(rank) for kind, rank in ranks.items()}
        if "command" in self.topics:  # waited for from the start: the first samples after t_0 need the
            self.topics["command"].covers = (-1, COMMAND)  # command of t_0 (a holding torque, say)
        self.primary = primary
        self.max_wait = max_wait
        self.last_poll = float("-inf")  # wall time [s] of the latest pop_ready
        self.awake_since = float("-inf")  # since then the node has run without a stall: silence counts from here
        self.max_future_ns = max_future_ns
        self.max_pending = max_pending
        self.period_ns: int | None = None  # the primary topic's sample period, from its stamps
        self.released_primary: int | None = None  # newest primary stamp taken
        self.newest_ns: int | None = None  # newest stamp received on any sample topic
        self.stats = OrderStats()
        self._flushed: list[tuple[str, int, Any]] = []  # taken before a backward stamp, not handed out yet
        self.primaries: deque[int] = deque(maxlen=max_pending)  # recent primary stamps received

    # ------------------------------------------------------------------ input
    def push(self, kind: str, ns: int, item: Any, now: float) -> int:
        """Queue one message; returns the stamp it is taken at (a command's may change)."""
        topic = self.topics[kind]
        if kind == "command":
            ns = self._command_stamp(ns)
            topic.covers = (ns, COMMAND)
        else:
            if topic.last_ns is not None and ns == topic.last_ns:
                self.stats.repeated += 1
                return ns
            if topic.last_ns is not None and ns < topic.last_ns:
                self._restart()
            if kind == self.primary and topic.last_ns is not None and ns > topic.last_ns:
                gap = ns - topic.last_ns
                self.period_ns = gap if self.period_ns is None else min(self.period_ns, gap)
            if kind == self.primary:
                self.primaries.append(ns)
            if topic.last_ns is not None and ns > topic.last_ns:
                gap = ns - topic.last_ns
                topic.period_ns = gap if topic.period_ns is None else min(topic.period_ns, gap)
            # its next message: a period later (periodic samples), at least a later stamp
            topic.covers = (ns + topic.period_ns, topic.rank) if topic.period_ns else (ns, AFTER + 1)
            self.newest_ns = ns if self.newest_ns is None else max(self.newest_ns, ns)
        if topic.last_ns is not None and self.period_ns is not None and ns > topic.last_ns:
            # a slower sensor or controller (a lockstep one answers every period); not a message lost
            # once (a reader queue that overflowed while this node was stalled)
            topic.steps.append(ns - topic.last_ns >= HORIZON * self.period_ns)
        topic.last_ns = ns
        topic.last_push = now
        topic.stalled = False
        topic.pending.append(((ns, topic.rank), now, item))
        depth = self.depth()
        self.stats.max_depth = max(self.stats.max_depth, depth)
        return ns

    def _command_stamp(self, ns: int) -> int:
        """An unset stamp (0) or one on another clock: the primary stamp the command answers. That is
        the newest one received, unless the controller has so far answered every period (lockstep):
        then the one after its previous command's, since the plant's next state may have come first."""
        newest = self.topics[self.primary].last_ns
        if newest is None or not (ns == 0 or ns - newest > self.max_future_ns):
            return ns
        self.stats.restamped += 1
        command = self.topics["command"]
        if command.skips or not self.primaries:
            return newest
        previous = command.last_ns
        if previous is None:
            return self.primaries[0]
        after = [s for s in self.primaries if s > previous]
        if len(after) > 3:  # more states than a lockstep plant makes ahead of a command on its way here
            command.always_skips = True
            return newest
        if after:
            return after[0]
        # it overtook the state it answers on the way here: that state is the next one
        return previous + self.period_ns if self.period_ns is not None else newest

    # ----------------------------------------------------------------- output
    def pop_ready(self, now: float) -> list[tuple[str, int, Any]]:
        """The messages that may be taken now, in stamp order: (kind, stamp, item)."""
        out, self._flushed = self._flushed, []
        if now - self.last_poll > STALL:
            self.awake_since = now
        self.last_poll = now
        while True:
            head = self._earliest()
            if head is None:
                return out
            kind, (key, arrival, _) = head
            blockers = self._blockers(kind, key)
            if blockers:
                # only a topic silent for max_wait is given up on: one that delivers is behind, not gone
                # (this node's own queues hold its messages while it catches up)
                # and only silence while this node ran: after a stall (descheduled, a long update) the
                # messages of that time still wait in its reader queues, delivered one callback at a time
                since = self.awake_since
                silent = [b for b in blockers if now - max(self.topics[b].last_push, since) > self.max_wait]
                if now - max(arrival, since) > self.max_wait and silent:
                    self.stats.waited_out += 1
                    for b in silent:
                        self.topics[b].stalled = True
                    continue  # the others may still block
                if self.depth() > self.max_pending:
                    self.stats.forced += 1
                else:
                    return out
            out.append(self._take(kind))

    def discard(self, kind: str) -> int:
        """Drop what ``kind`` holds (another source replaces it); returns how many."""
        topic = self.topics[kind]
        n = len(topic.pending)
        self.topics[kind] = _Topic(topic.rank, covers=topic.covers)  # the new source starts afresh
        return n

    def flush(self) -> list[tuple[str, int, Any]]:
        """Everything waiting, in stamp order (shutdown, reset)."""
        out = []
        while (head := self._earliest()) is not None:
            out.append(self._take(head[0]))
        return out

    def _restart(self) -> None:
        """A topic went back in time (a reset clock): what waits goes first, in its order, and
        the merge starts afresh from the new stamps (no order across the jump)."""
        self._flushed += self.flush()
        for topic in self.topics.values():
            topic.last_ns = topic.covers = None
        self.released_primary = self.newest_ns = None
        self.primaries.clear()

    def depth(self) -> int:
        return sum(len(t.pending) for t in self.topics.values())

    def lag_ns(self) -> int:
        """Newest sample stamp received minus the newest primary stamp taken (0 when none waits)."""
        if self.newest_ns is None or self.released_primary is None:
            return 0
        return max(0, self.newest_ns - self.released_primary)

    def _earliest(self) -> tuple[str, tuple[tuple[int, int], float, Any]] | None:
        best = None
        for kind, topic in self.topics.items():
            if topic.pending and (best is None or topic.pending[0][0] < best[1][0]):
                best = (kind, topic.pending[0])
        return best

    def _blockers(self, kind: str, key: tuple[int, int]) -> list[str]:
        """Topics that may still deliver something earlier than ``key``."""
        skip = self.period_ns is not None and self.newest_ns is not None and \
            self.newest_ns - key[0] >= HORIZON * self.period_ns
        blockers = []
        for other, topic in self.topics.items():
            if other == kind or topic.pending or topic.covers is None or topic.stalled or (skip and topic.skips):
                continue
            if other == "command":
                # a command covers the samples up to the next primary stamp after it
                before = self._primary_before(key[0])
                if before is not None and topic.covers[0] < before:
                    blockers.append(other)
            elif topic.covers < key:
                blockers.append(other)
        return blockers

    def _primary_before(self, ns: int) -> int | None:
        """The primary stamp before ``ns`` (the state the command that leads to ``ns`` answers)."""
        if self.period_ns is None:
            return self.released_primary if self.released_primary is not None and self.released_primary < ns else None
        return ns - self.period_ns if ns - self.period_ns >= 0 else None

    def _take(self, kind: str) -> tuple[str, int, Any]:
        key, _, item = self.topics[kind].pending.popleft()
        if kind == self.primary:
            self.released_primary = key[0] if self.released_primary is None else max(self.released_primary, key[0])
        self.stats.taken += 1
        return kind, key[0], item
