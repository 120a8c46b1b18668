"""The observer node's stamp-order merge (ros/observer/input_order.py) on arrival orders a live loop produces.

A lockstep loop's messages reach the observer in many orders: each topic first in, first out, but
a command may come after the samples it led to, the encoders of t_k before the accelerometer of
t_k. Whatever the order, the merge hands them on as offline ``observe`` takes a recording: by
stamp, the samples of a stamp before its command. Arrival orders are drawn from seeds; the
checks are the order itself, nothing lost, and the bounds (a silent topic, the last state).
"""

from __future__ import annotations

import random

import numpy as np
import pytest

from elastic_pm_dyn.ros.observer.input_order import BEFORE, COMMAND, PRIMARY, InputOrder

P = 1_000_000  # [ns] 1 kHz
RANK = {"imu": BEFORE, "joint_state": PRIMARY, "command": COMMAND}


def lockstep_arrivals(periods: int, seed: int, stamp: str) -> list[tuple[str, int]]:
    """(kind, stamp) in the order they reach the observer: the plant publishes the samples of t_k,
    the controller answers the encoders with a command (stamped t_k, or 0: an unset header), which
    reaches the plant and the observer with independent delays; the plant then publishes t_k+1."""
    rnd = random.Random(seed)
    events = []
    t = 0.0
    for k in range(periods):
        ns = k * P
        events += [(t + rnd.random() * 0.5, "imu", ns), (t + rnd.random() * 0.5, "joint_state", ns)]
        answered = t + 0.2 + rnd.random()
        events.append((answered + rnd.random() * 0.5, "command", ns if stamp == "copy" else 0))
        t = answered + 0.1
    arrivals, last = [], {}
    for when, kind, ns in events:  # each topic in order: a later message never arrives first
        last[kind] = max(last.get(kind, -1.0), when)
        arrivals.append((last[kind], kind, ns))
    return [(kind, ns) for _, kind, ns in sorted(arrivals)]


def poll(order: InputOrder, start: float, end: float) -> list[tuple[str, int, object]]:
    """What the node's timer takes between ``start`` and ``end`` (it polls every 0.05 s)."""
    taken = []
    for now in np.arange(start, end + 1e-9, 0.05):
        taken += order.pop_ready(float(now))
    return taken


def run(order: InputOrder, arrivals: list[tuple[str, int]]) -> list[tuple[str, int]]:
    taken = []
    for i, (kind, ns) in enumerate(arrivals):
        order.push(kind, ns, None, now=i * 1e-3)
        taken += [(k, s) for k, s, _ in order.pop_ready(now=i * 1e-3)]
    end = len(arrivals) * 1e-3
    return taken + [(k, s) for k, s, _ in poll(order, end, end + 1.0)]


@pytest.mark.parametrize("seed", [3, 11, 29])
@pytest.mark.parametrize("stamp", ["copy", "zero"])
def test_lockstep_arrivals_come_out_in_stamp_order(seed: int, stamp: str) -> None:
    arrivals = lockstep_arrivals(300, seed, stamp)
    order = InputOrder(dict(RANK), "joint_state", 0.5, 10**9)
    taken = run(order, arrivals)
    assert len(taken) == len(arrivals)  # nothing lost
    # from the second period on (before its first message the accelerometer is not waited for)
    keys = [(ns, RANK[kind]) for kind, ns in taken if ns >= P]
    assert keys == sorted(keys)
    commands = [ns for kind, ns in taken if kind == "command"]
    assert commands == [k * P for k in range(300)]  # an unset stamp: the state each answers


def test_arrival_order_without_the_merge_is_not_stamp_order() -> None:
    """The draw above does mix the topics (else the test could not fail)."""
    arrivals = lockstep_arrivals(300, 3, "copy")
    keys = [(ns, RANK[kind]) for kind, ns in arrivals]
    assert keys != sorted(keys)


def test_a_sample_repeated_is_taken_once_and_a_silent_topic_is_waited_for_boundedly() -> None:
    order = InputOrder(dict(RANK), "joint_state", max_wait=0.5, max_future_ns=10**9)
    for _ in range(3):  # the plant's first state, published again while it waits for a command
        order.push("imu", 0, None, 0.0)
        order.push("joint_state", 0, None, 0.0)
    assert [k for k, _, _ in order.pop_ready(0.0)] == ["imu", "joint_state"]
    assert order.stats.repeated == 4
    order.push("command", 0, None, 0.1)
    order.push("imu", P, None, 0.1)
    order.push("joint_state", P, None, 0.1)
    assert len(order.pop_ready(0.1)) == 3
    # the controller stops: the next state waits for its command, then goes after max_wait
    order.push("imu", 2 * P, None, 0.2)
    order.push("joint_state", 2 * P, None, 0.2)
    assert order.pop_ready(0.3) == []
    assert [k for k, _, _ in poll(order, 0.35, 0.8)] == ["imu", "joint_state"]
    assert order.stats.waited_out == 1
    # not waited for again until it speaks
    order.push("imu", 3 * P, None, 0.9)
    order.push("joint_state", 3 * P, None, 0.9)
    assert len(order.pop_ready(0.9)) == 2


def test_a_controller_slower_than_the_plant_delays_a_state_by_two_periods_at_most() -> None:
    """Until it has left out periods twice it is waited for (a lockstep controller answers every one; a
    message lost once is no reason to stop waiting)."""
    order = InputOrder(dict(RANK), "joint_state", max_wait=1e9, max_future_ns=10**9)
    taken = []
    for k in range(50):
        order.push("joint_state", k * P, None, 0.0)
        if k % 10 == 0:
            order.push("command", k * P, None, 0.0)
        taken += [ns for kind, ns, _ in order.pop_ready(0.0) if kind == "joint_state"]
        if k > 20:  # once the controller has shown that it leaves out periods
            assert taken[-1] >= (k - 2) * P
    assert taken == [k * P for k in range(len(taken))]


def test_commands_on_another_clock_are_taken_at_the_newest_state() -> None:
    order = InputOrder(dict(RANK), "joint_state", 0.5, max_future_ns=10**9)
    order.push("joint_state", 5 * P, None, 0.0)
    epoch = 1_700_000_000 * 10**9  # a controller stamping wall time against a simulated clock
    assert order.push("command", epoch, None, 0.0) == 5 * P
    assert order.stats.restamped == 1


def test_an_unset_stamp_of_a_controller_slower_than_the_plant_is_the_newest_state() -> None:
    order = InputOrder(dict(RANK), "joint_state", 0.5, max_future_ns=10**9)
    for k in range(30):
        order.push("joint_state", k * P, None, 0.0)
        if k in (0, 10, 20):
            order.push("command", 0, None, 0.0)
    assert order.topics["command"].last_ns == 20 * P  # it left out periods: not a lockstep answer


def test_a_topic_that_delivers_is_behind_not_gone() -> None:
    """The wall-time bound gives up only on a silent topic: commands that keep coming, late (this
    node's own queues hold them while it catches up), are waited for however long that takes."""
    order = InputOrder(dict(RANK), "joint_state", max_wait=0.5, max_future_ns=10**9)
    order.push("joint_state", 0, None, 0.0)
    assert len(order.pop_ready(0.0)) == 1
    for k in range(1, 30):
        order.push("joint_state", k * P, None, 0.0)  # the plant ran ahead
    for i in range(20):  # commands of the early periods trickle in, one every 0.1 s
        order.push("command", i * P, None, 0.1 * (i + 1))
        taken = order.pop_ready(0.1 * (i + 1))
        assert all(ns <= (i + 1) * P for _, ns, _ in taken)  # never a state ahead of its command
    assert order.stats.waited_out == 0
    assert [ns for kind, ns, _ in poll(order, 2.05, 10.0) if kind == "joint_state"][:1] == [21 * P]  # silent now


def test_a_sample_lost_once_does_not_stop_the_wait_for_its_topic() -> None:
    """A reader queue that overflowed while the node was stalled loses a run of samples: one gap in
    the stamps. The topic is still waited for afterwards, so its later samples keep their order."""
    order = InputOrder(dict(RANK), "joint_state", max_wait=1e9, max_future_ns=10**9)
    taken = []
    for k in range(40):
        if not 10 <= k < 15:  # five accelerometer samples lost
            order.push("imu", k * P, None, 0.0)
        order.push("joint_state", k * P, None, 0.0)
        order.push("command", k * P, None, 0.0)
        taken += order.pop_ready(0.0)
    for k in range(40, 45):  # the encoders run ahead of the accelerometer for a while
        order.push("joint_state", k * P, None, 0.0)
        order.push("command", k * P, None, 0.0)
        taken += order.pop_ready(0.0)
    assert not [ns for kind, ns, _ in taken if kind == "joint_state" and ns >= 40 * P]  # they wait for the imu
    for k in range(40, 45):
        order.push("imu", k * P, None, 0.0)
        taken += order.pop_ready(0.0)
    keys = [(ns, RANK[kind]) for kind, ns, _ in taken]
    assert keys == sorted(keys)


def test_a_stall_of_the_node_itself_is_no_silence_of_its_inputs() -> None:
    """Descheduled for 2 s, the node's timer may poll before its subscriptions hand over what arrived
    meanwhile: the command topic is not given up on then (its commands wait in the reader queue)."""
    order = InputOrder(dict(RANK), "joint_state", max_wait=0.5, max_future_ns=10**9)
    order.push("command", 0, None, 0.0)
    order.push("joint_state", 0, None, 0.0)
    order.push("joint_state", P, None, 0.0)
    order.push("joint_state", 2 * P, None, 0.0)
    assert [ns for _, ns, _ in order.pop_ready(0.0)] == [0, 0, P]  # the state of 2P waits for the command of P
    assert order.pop_ready(2.0) == []  # the first poll after the stall: not silence
    order.push("command", P, None, 2.01)  # the reader queue hands it over
    assert [ns for _, ns, _ in order.pop_ready(2.01)] == [P, 2 * P]
    assert order.stats.waited_out == 0
    # a command topic silent while the node runs is given up on as before
    order.push("joint_state", 3 * P, None, 2.02)
    order.push("joint_state", 4 * P, None, 2.02)
    assert [ns for _, ns, _ in poll(order, 2.05, 2.6)] == [3 * P, 4 * P]
    assert order.stats.waited_out == 1
