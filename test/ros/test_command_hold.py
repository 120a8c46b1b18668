"""The plant's command holding (ros/plant/command_hold.py), without a node: what torque each period gets."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.ros.plant.command_hold import CommandHold


def test_lockstep_answers_every_command_in_order_and_a_rejected_one_holds_the_last() -> None:
    hold = CommandHold(2, lockstep=True, timeout=0.1, disturbance_input=False, disturbance_timeout=0.1)
    assert hold.awaiting_first
    hold.take_rejected(1.0)  # before any valid one: zero torque for its period
    hold.take(np.array([1.0, 2.0]), 2.0, 0.0)
    hold.take_rejected(3.0)
    hold.take(np.array([3.0, 4.0]), 4.0, 0.0)
    got = [hold.next_queued() for _ in range(5)]
    assert [a for _, a in got] == [1.0, 2.0, 3.0, 4.0, None]
    assert [t.tolist() for t, _ in got] == [[0, 0], [1, 2], [1, 2], [3, 4], [3, 4]]
    assert not hold.awaiting_first
    hold.restart()
    assert hold.awaiting_first and hold.command is None and not hold.queue


def test_realtime_holds_the_last_command_until_it_is_stale() -> None:
    hold = CommandHold(2, lockstep=False, timeout=0.1, disturbance_input=False, disturbance_timeout=0.1)
    assert hold.held(5.0)[1] is None and not hold.held(5.0)[0].any()  # never had one: zero, not stale
    hold.take(np.array([1.0, -1.0]), arrival=7.0, now=5.0)
    assert hold.held(5.1)[0].tolist() == [1.0, -1.0] and hold.held(5.1)[1] is None
    tau, age = hold.held(5.25)
    assert not tau.any() and abs(age - 0.25) < 1e-12
    assert hold.take_arrival() == 7.0 and hold.take_arrival() is None  # one period counts it as fresh
    assert abs(hold.age(5.3) - 0.3) < 1e-12


def test_the_disturbance_input_is_held_until_its_own_timeout() -> None:
    off = CommandHold(2, lockstep=False, timeout=0.1, disturbance_input=False, disturbance_timeout=0.1)
    assert off.held_disturbance(0.0) is None
    hold = CommandHold(2, lockstep=False, timeout=0.1, disturbance_input=True, disturbance_timeout=0.5)
    assert not hold.held_disturbance(0.0).any()
    hold.take_disturbance(np.array([0.2, 0.3]), 1.0)
    assert hold.held_disturbance(1.4).tolist() == [0.2, 0.3]
    assert not hold.held_disturbance(1.6).any()
