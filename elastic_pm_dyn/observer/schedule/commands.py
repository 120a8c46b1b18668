"""The torque commands the filter predicts with: the one held, the delayed ones waiting, the timeout.

The command stamped t_k acts on [t_k + delay, t_k+1 + delay) (``command_delay``, the actuation
latency: the zero-order hold shifted). A delayed command waits in :attr:`CommandQueue.pending`
until its time comes; then it is held (:attr:`CommandQueue.tau_hold`, acting since
:attr:`CommandQueue.t_command`) and the prediction starts a new piece there. A held command
older than ``timing.command_timeout`` (counted from where it starts to act) gives zero torque.
The compiled steps keep the same queue in arrays (``period``'s ``cmd`` bundle): :meth:`CommandQueue.bundle`
and :meth:`CommandQueue.take_bundle` hand it over and back.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.config import ObserverConfig

MAX_PENDING_COMMANDS = 10_000  # delayed commands kept before the filter runs (the oldest then act)


class CommandQueue:
    """The held command, the delayed ones (each (time it acts from, torque), oldest first) and
    the timeout, for one mechanism's motors."""

    def __init__(self, mech: Mechanism, cfg: ObserverConfig):
        self.active_names = list(mech.active_names)
        self.delay = cfg.command_delay
        self.tol = cfg.timing.stamp_tolerance
        self.timeout = cfg.timing.command_timeout
        self.tau_hold = np.zeros(len(self.active_names))  # active joint order
        self.t_command = -np.inf  # the held command acts from here
        self.pending: deque = deque()  # (time it acts from, torque) of delayed commands

    def checked(self, tau, stats) -> np.ndarray:
        """A copy of ``tau`` as a command (InputError if it is not one finite value per motor;
        ``stats``: the commands' statistics, whose ``nan`` counts the non-finite ones)."""
        tau = np.asarray(tau, dtype=float).reshape(-1)
        if tau.shape != (len(self.active_names),):
            raise InputError(f"torque command needs {len(self.active_names)} values (active joints "
                             f"{', '.join(self.active_names)}), got {tau.size}")
        if not np.all(np.isfinite(tau)):
            stats.nan += 1
            raise InputError("torque command with NaN or Inf")
        return tau.copy()

    def torque_at(self, t: float) -> np.ndarray:
        """The held torque at time t (zero once it has timed out)."""
        if self.timeout > 0 and t - self.t_command >= self.timeout - 1e-12:
            return np.zeros_like(self.tau_hold)
        return self.tau_hold

    def newest(self) -> float:
        """When the newest accepted command acts from (-inf if none)."""
        return self.pending[-1][0] if self.pending else self.t_command

    def add(self, t_act: float, tau: np.ndarray) -> None:
        """A command acting from ``t_act`` joins the queue (past :data:`MAX_PENDING_COMMANDS`: the oldest acts)."""
        self.pending.append((t_act, tau))
        if len(self.pending) > MAX_PENDING_COMMANDS:
            self.t_command, self.tau_hold = self.pending.popleft()

    def activate_due(self, now: float) -> None:
        """Delayed commands whose time has come by ``now``: the newest is held."""
        while self.pending and self.pending[0][0] <= now + self.tol:
            self.t_command, self.tau_hold = self.pending.popleft()

    def restart_clock(self, t: float) -> None:
        """The filter's clock restarts at t (a reset without a time): a held command acts from there."""
        if self.t_command > -np.inf:
            self.t_command = t

    def restart_at(self, t: float) -> None:
        """The filter restarts at t from a measured state: the delayed commands of the old time are
        not replayed, and a command stamped after t does not hold the new filter's back."""
        if self.t_command > t + self.tol:
            self.t_command = -np.inf
        self.pending.clear()

    def bundle(self, room: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The compiled steps' copy: held torque, and the delayed commands' times and torques with
        room for ``room`` more."""
        n = len(self.pending)
        pend_t = np.empty(n + room)
        pend_tau = np.empty((n + room, len(self.active_names)))
        for i, (ta, tau) in enumerate(self.pending):
            pend_t[i], pend_tau[i] = ta, tau
        return self.tau_hold.copy(), pend_t, pend_tau

    def take_bundle(self, tau_hold: np.ndarray, t_command: float, pend_t: np.ndarray, pend_tau: np.ndarray,
                    head: int, tail: int) -> None:
        """Take back what a compiled step made of :meth:`bundle` (the queue is its entries head..tail-1)."""
        self.tau_hold, self.t_command = tau_hold, t_command
        if tail > head or self.pending:
            self.pending = deque((float(pend_t[i]), pend_tau[i].copy()) for i in range(head, tail))
