"""A node's high-rate inputs taken in one executor turn: what is queued on them is taken directly.

rclpy's executor spends 100-270 us on each message it hands to a callback (it rebuilds its wait
set over every entity of the node: parameter services, timers, events, for each message), while
taking a message from a subscription directly costs 3-12 us (raw bytes) to 14-50 us (a message
object; quiet and loaded machine, ``bench/benchmarks/bench_take.py``). At the loop's rate that is
the difference between a node that keeps up and one that falls behind: the observer reads three messages a period, the
recorder a dozen. So the executor only wakes the node for the first message; the callback then
takes whatever else is queued on the node's drained subscriptions itself, one message per
subscription per round (as a wait set yields each ready subscription once: arrival order across
topics is kept as the executor would keep it), at most ``max_per_turn`` before it lets the
executor serve timers and services again.

Only the subscriptions of one node, spun by one thread, go into one :class:`Drain`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.subscription import Subscription

MAX_PER_TURN = 300  # messages taken in one executor turn: timers and services wait at most this long

Handler = Callable[[Any, dict[str, Any]], None]  # (message or its bytes, message info)


class Drain:
    """The subscriptions whose queues a callback empties (see module doc)."""

    def __init__(self, max_per_turn: int = MAX_PER_TURN):
        self.max_per_turn = max_per_turn
        self._inputs: list[tuple[Subscription, Handler]] = []
        self._draining = False
        self.turns = 0  # executor turns that took messages
        self.taken = 0  # messages taken directly (beyond the one the executor handed over)

    def subscribe(self, node: Node, msg_type: Any, topic: str, handler: Handler, qos: Any,
                  **kwargs: Any) -> Subscription:
        """``node.create_subscription`` (``kwargs``: raw, event_callbacks, ...) whose messages go to
        ``handler``: the one the executor hands over, then every queued message of this drain's
        subscriptions."""

        def on_message(msg: Any, info: dict[str, Any]) -> None:
            handler(msg, info)
            self.drain()
        subscription = node.create_subscription(msg_type, topic, on_message, qos, **kwargs)
        self._inputs.append((subscription, handler))
        return subscription

    def remove(self, subscription: Subscription) -> None:
        self._inputs = [(s, h) for s, h in self._inputs if s is not subscription]

    def drain(self) -> int:
        """Take and handle the queued messages, round by round; returns how many."""
        if self._draining:  # a handler that spins (it must not): no second drain inside the first
            return 0
        self._draining = True
        taken = 0
        try:
            more = True
            while more and taken < self.max_per_turn:
                more = False
                for sub, handler in list(self._inputs):
                    got = _take(sub)
                    if got is not None:
                        more = True
                        taken += 1
                        handler(*got)
        finally:
            self._draining = False
        self.turns += 1
        self.taken += taken
        return taken


def _take(sub: Subscription) -> tuple[Any, dict[str, Any]] | None:
    """The next queued message of ``sub`` with its info, or None (also for a destroyed subscription)."""
    try:
        with sub.handle:
            return sub.handle.take_message(sub.msg_type, sub.raw)
    except InvalidHandle:  # destroyed meanwhile (a node resubscribing): nothing to take
        return None
