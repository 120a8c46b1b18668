"""The realtime plant's schedule: which periods are due at a wall-clock moment, and what
happens when the plant falls behind (parameter ``realtime.overrun``).

Period n of a schedule (counted from its start) is due at ``origin + n T``. A tick steps
every period due by now, at most ``max_catch_up`` of them: a brief hiccup is caught up
(the periods stepped more than half a period after their due time are counted as late).
More than ``max_catch_up`` due, the rest is given up and the origin moves later by as many
periods; what that means for the stamps (``stamp = stamp_base + k T``) is the overrun mode:

- ``slow`` (default): the stamps stay on the simulated-time grid (consecutive k, no gap);
  the plant's clock (its first period's wall time + simulated time) runs slower than the
  wall clock for as long as the plant cannot keep up, as Gazebo does. Every period is
  simulated and stamped; ``slowed`` counts the periods the clock fell behind.
- ``skip``: the stamps follow the wall clock; the given-up periods are jumped over
  (``stamp_base`` moves by ``skipped`` periods): a stamp gap, no period simulated in it.

Pure logic, no ROS: the plant node calls :meth:`RealtimeSchedule.tick` with ``time.monotonic()``.
"""

from __future__ import annotations

import dataclasses

OVERRUNS = ("slow", "skip")


@dataclasses.dataclass(frozen=True)
class Tick:
    """What one tick does: step ``due`` periods now."""

    due: int = 0
    late: int = 0  # of them, stepped more than half a period after their due time
    lateness: float = 0.0  # [s] how late the first of them is
    slowed: int = 0  # slow: periods the origin moved later (the plant's clock fell behind)
    skipped: int = 0  # skip: periods the stamps jump over


class RealtimeSchedule:
    """The wall-clock schedule of the realtime plant (see module doc)."""

    def __init__(self, period: float, max_catch_up: int, overrun: str = "slow"):
        if overrun not in OVERRUNS:
            raise ValueError(f"overrun must be one of {', '.join(OVERRUNS)}, got {overrun!r}")
        if max_catch_up < 1:
            raise ValueError(f"max_catch_up must be >= 1, got {max_catch_up}")
        self.period = period
        self.max_catch_up = max_catch_up
        self.overrun = overrun
        self.origin: float | None = None  # [s] wall time (monotonic) when period 0 of the schedule was due
        self.k_start = 0  # the plant's period count at the origin

    @property
    def started(self) -> bool:
        return self.origin is not None

    def start(self, now: float, k: int) -> None:
        """A new schedule: the state of period ``k`` is the one of ``now``."""
        self.origin, self.k_start = now, k

    def stop(self) -> None:
        """The next :meth:`start` begins a new schedule (after a pause, a reset, a new state)."""
        self.origin = None

    def tick(self, now: float, k: int) -> Tick:
        """Periods due at ``now`` when the plant has done ``k`` (the origin moves when it is too far behind)."""
        if self.origin is None:
            raise RuntimeError("tick before start")
        period = self.period
        done = k - self.k_start
        # Periods due by now; the half period tolerates ticks that come a little early.
        due = int((now - self.origin) / period + 0.5) - done
        behind = 0
        if due > self.max_catch_up:  # too far behind: the origin moves later
            behind = due - self.max_catch_up
            self.origin += behind * period
            due = self.max_catch_up
        if due <= 0:
            return Tick()
        # Period n was due at origin + n period; one stepped more than half a period after that was late.
        lateness = now - (self.origin + (done + 1) * period)
        late = sum(1 for i in range(due) if lateness - i * period > 0.5 * period)
        slow = self.overrun == "slow"
        return Tick(due=due, late=late, lateness=lateness, slowed=behind if slow else 0,
                    skipped=0 if slow else behind)
