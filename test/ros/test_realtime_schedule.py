"""The realtime plant's schedule (elastic_pm_dyn.ros.plant.realtime_schedule) with made-up wall times:
on time, a hiccup caught up, an overrun that slows the clock (slow) or jumps the stamps (skip)."""

from __future__ import annotations

import pytest

from elastic_pm_dyn.ros.plant.realtime_schedule import RealtimeSchedule, Tick

T = 0.25  # [s] the period (exact in binary: the wall times below are exact)


def run(schedule: RealtimeSchedule, ticks: list[float], k: int = 0) -> tuple[list[Tick], int]:
    """Tick at the given wall times, stepping what is due each time; the ticks and the final k."""
    out = []
    for now in ticks:
        tick = schedule.tick(now, k)
        k += tick.due
        out.append(tick)
    return out, k


@pytest.mark.parametrize("overrun", ["slow", "skip"])
def test_on_time_one_period_per_tick(overrun: str) -> None:
    s = RealtimeSchedule(T, 5, overrun)
    s.start(10.0, 7)
    ticks, k = run(s, [10.0 + n * T for n in range(1, 9)], 7)
    assert k == 15 and all(t == Tick(due=1, lateness=0.0) for t in ticks)
    assert s.origin == 10.0
    # a tick a little early (under half a period) still steps its period; one too early steps none
    assert s.tick(10.0 + 9 * T - 0.4 * T, k).due == 1
    assert s.tick(10.0 + 10 * T - 0.6 * T, k + 1) == Tick()


@pytest.mark.parametrize("overrun", ["slow", "skip"])
def test_a_hiccup_within_max_catch_up_is_caught_up_without_slowing(overrun: str) -> None:
    s = RealtimeSchedule(T, 5, overrun)
    s.start(0.0, 0)
    tick = s.tick(4 * T, 0)  # periods 1-4 due at once: 1, 2, 3 later than half a period
    assert tick == Tick(due=4, late=3, lateness=3 * T)
    assert s.origin == 0.0
    assert s.tick(5 * T, 4) == Tick(due=1, lateness=0.0)  # back on the schedule


def test_slow_moves_the_origin_and_steps_every_period() -> None:
    s = RealtimeSchedule(T, 5, "slow")
    s.start(0.0, 0)
    tick = s.tick(20 * T, 0)  # 20 due, 5 stepped: the clock falls 15 periods behind
    assert tick.due == 5 and tick.slowed == 15 and tick.skipped == 0
    assert s.origin == 15 * T
    assert s.tick(21 * T, 5) == Tick(due=1, lateness=0.0)  # the new origin: on time again


def test_skip_moves_the_origin_and_the_stamps_jump() -> None:
    s = RealtimeSchedule(T, 5, "skip")
    s.start(0.0, 0)
    tick = s.tick(20 * T, 0)
    assert tick.due == 5 and tick.skipped == 15 and tick.slowed == 0
    assert s.origin == 15 * T
    assert s.tick(21 * T, 5) == Tick(due=1, lateness=0.0)


def test_a_plant_three_times_too_slow_runs_at_a_third_of_real_time() -> None:
    """Each period costs three periods of wall time: every period is stepped (consecutive k), at
    most max_catch_up a tick, and the clock falls behind by what was not stepped."""
    s = RealtimeSchedule(T, 2, "slow")
    s.start(0.0, 0)
    now, k, slowed = 0.0, 0, 0
    for _ in range(300):
        now += T / 8  # the next tick, then the periods due take 3 T each
        tick = s.tick(now, k)
        assert tick.due <= 2 and tick.skipped == 0
        k += tick.due
        slowed += tick.slowed
        # at the tick: wall time = simulated time (after its periods) + the time the clock fell behind
        assert abs(now - (k + slowed) * T) <= T / 2
        now += 3 * T * tick.due
    assert abs(k * T / now - 1 / 3) < 0.01  # the real-time factor


def test_stop_start_is_a_new_schedule_and_bad_arguments_are_refused() -> None:
    s = RealtimeSchedule(T, 5)
    assert s.overrun == "slow" and not s.started
    with pytest.raises(RuntimeError):
        s.tick(0.0, 0)
    s.start(0.0, 0)
    s.tick(T, 0)
    s.stop()
    assert not s.started
    s.start(100.0, 1)  # after a pause: due from the new origin, nothing late
    assert s.tick(100.0 + T, 1) == Tick(due=1, lateness=0.0)
    with pytest.raises(ValueError, match="overrun"):
        RealtimeSchedule(T, 5, "drop")
    with pytest.raises(ValueError, match="max_catch_up"):
        RealtimeSchedule(T, 0)
