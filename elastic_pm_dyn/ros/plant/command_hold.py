"""What torque the plant applies over its next period, from the commands it got (rclpy-free).

- lockstep: every command is one period, in order (:attr:`CommandHold.queue`); a rejected one
  holds the last valid command for its period, so every command is answered;
- realtime and fast: the last valid command, held until a newer one comes, or zero once it is
  older than ``timeout`` on the plant's clock (:meth:`CommandHold.held`);
- the unknown disturbance torque received on its input topic is held the same way, zero when
  older than ``disturbance_timeout`` (:meth:`CommandHold.held_disturbance`).

The clock is the caller's (simulated time, or the wall clock when the stamps are the wall
clock): every method that needs "now" takes it.
"""

from __future__ import annotations

import collections

import numpy as np


class CommandHold:
    """The plant's commands and the torque they give each period (see module doc)."""

    def __init__(self, n_motors: int, lockstep: bool, timeout: float, disturbance_input: bool,
                 disturbance_timeout: float):
        self.n = n_motors
        self.lockstep = lockstep
        self.timeout = timeout  # [s] realtime/fast: an older command means zero torque
        self.disturbance_input = disturbance_input
        self.disturbance_timeout = disturbance_timeout
        self.command: np.ndarray | None = None  # the last valid command
        self.command_time = 0.0  # when it arrived, on the caller's clock
        self.arrival: float | None = None  # monotonic [s] of a command no period has used yet
        # lockstep: (torque, arrival [monotonic s]) per command, in order
        self.queue: collections.deque[tuple[np.ndarray, float]] = collections.deque()
        self.awaiting_first = True  # lockstep: no command since start, reset or set_state
        self.disturbance: np.ndarray | None = None  # the last valid disturbance torque
        self.disturbance_time = 0.0  # when it arrived, on the caller's clock

    # ------------------------------------------------------------------ inputs
    def take(self, tau: np.ndarray, arrival: float, now: float) -> bool:
        """A valid command (``now``: the caller's clock); True if it is the first since start or a restart."""
        first = self.command is None
        self.command = tau
        if self.lockstep:
            self._queue(tau, arrival)
        else:
            self.command_time = now
            self.arrival = arrival
        return first

    def take_rejected(self, arrival: float) -> None:
        """Lockstep answers a rejected command all the same: the last valid one holds for its period."""
        if self.lockstep:
            self._queue(self.last_or_zero(), arrival)

    def take_disturbance(self, d: np.ndarray, now: float) -> None:
        self.disturbance = d
        self.disturbance_time = now

    def _queue(self, tau: np.ndarray, arrival: float) -> None:
        self.awaiting_first = False
        self.queue.append((tau, arrival))

    # ----------------------------------------------------------------- outputs
    def last_or_zero(self) -> np.ndarray:
        return self.command if self.command is not None else np.zeros(self.n)

    def held(self, now: float) -> tuple[np.ndarray, float | None]:
        """Realtime/fast: the torque of the next period and, when it is zero because the command is
        stale, its age [s] (None otherwise, also when there never was one)."""
        if self.command is not None:
            age = now - self.command_time
            if age <= self.timeout:
                return self.command, None
            return np.zeros(self.n), age
        return np.zeros(self.n), None

    def held_disturbance(self, now: float) -> np.ndarray | None:
        """The disturbance torque of the next period: the last valid one, zero when stale; None
        without the input (the plant then integrates the command alone)."""
        if not self.disturbance_input:
            return None
        if self.disturbance is not None and now - self.disturbance_time <= self.disturbance_timeout:
            return self.disturbance
        return np.zeros(self.n)

    def take_arrival(self) -> float | None:
        """Arrival time of a command no period has used yet (it is used now), else None."""
        arrival, self.arrival = self.arrival, None
        return arrival

    def next_queued(self) -> tuple[np.ndarray, float | None]:
        """Lockstep ``~/step``: the next queued command and its arrival, else the last valid one
        (zero if none) and None."""
        if self.queue:
            return self.queue.popleft()
        return self.last_or_zero(), None

    def age(self, now: float) -> float | None:
        """Realtime/fast: how old the last command is (None without one)."""
        return None if self.command is None or self.lockstep else now - self.command_time

    def restart(self) -> None:
        """After reset/set_state: the old commands are forgotten."""
        self.command = None
        self.arrival = None
        self.queue.clear()
        self.awaiting_first = True
