"""What a goal's ``header.stamp`` means to the feedforward node: one rule for every goal.

0 is now: the goal starts when its reference is ready, from its first point. Any other stamp
is its start on the node's clock (the clock that stamps the node's commands: wall time,
simulated time with ``use_sim_time``, or with ``trigger: state`` the plant states' stamps),
accepted within a window around now: at most :data:`STAMP_PAST` seconds before it (a goal
stamped with the sender's now, late by its transport) and at most :data:`STAMP_FUTURE` seconds
after it (a goal the node holds its first pose for until then). A stamp outside is refused
in one line that gives the stamp and the clock, with a hint where one of them is wall time
and the other simulated time (a node on simulated time sent a wall-clock stamp, or the
reverse). A start that has passed (a stamp in the past, or one that passed while the goal was
computed) is not cut short: the goal starts now, whole, with a warning (:func:`late_start`):
cutting its beginning would jump the machine to a later pose of the goal.
"""

from __future__ import annotations

from elastic_pm_dyn.errors import InputError

NS = 1_000_000_000
STAMP_PAST = 5.0  # [s] a goal stamped up to this long before the node's now starts now (whole); older: refused
STAMP_FUTURE = 60.0  # [s] a goal stamped further ahead is refused (the node would hold its first pose that long)
WALL_EPOCH = 1e9  # [s] stamps from 2001 on are wall time; simulated time starts near 0


def goal_start(stamp_ns: int, now_ns: int, clock: str) -> int | None:
    """The start [ns] on the node's clock of a goal stamped ``stamp_ns`` when the clock (named
    ``clock`` in messages) reads ``now_ns``: None for now (stamp 0), else the stamp; InputError
    (one line) outside the window (module doc)."""
    if stamp_ns == 0:
        return None
    ahead = (stamp_ns - now_ns) / NS
    if -STAMP_PAST <= ahead <= STAMP_FUTURE:
        return stamp_ns
    hint = ""
    if stamp_ns >= WALL_EPOCH * NS > now_ns:
        hint = ("; the stamp looks like wall time and the node's clock like simulated time: stamp goals with the "
                "node's clock, or 0")
    elif now_ns >= WALL_EPOCH * NS > stamp_ns:
        hint = "; the stamp looks like simulated time and the node's clock is wall time: set use_sim_time, or stamp 0"
    when = "before" if ahead < 0 else "after"
    raise InputError(f"stamp {stamp_ns / NS:.9f} s is {abs(ahead):.6g} s {when} the node's clock ({clock}: "
                     f"{now_ns / NS:.9f} s); a goal starts at its stamp on that clock, at most {STAMP_PAST:g} s "
                     f"before it or {STAMP_FUTURE:g} s after it, or at once with stamp 0{hint}")


def late_start(start_ns: int | None, now_ns: int, period: float) -> float:
    """How late [s] a goal's start is when its reference is ready at ``now_ns``: 0 when it is
    not (a start to come, now, or less than one control ``period`` ago: the next command is its
    first); else the goal starts now, whole, and the node warns with this lateness."""
    if start_ns is None:
        return 0.0
    late = (now_ns - start_ns) / NS
    return late if late > period else 0.0
