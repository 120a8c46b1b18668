"""The accelerometer's sample timing (``imu.sample_timing``): which side of a command jump a sample was taken.

The accelerometer reads J qdd + Jdot qd, and qdd jumps where the torque jumps, so a sample
taken at the instant a command starts to act depends on which side of it it was taken:

- ``before_command``: a(t_k-), under the torque of the interval that ended at t_k (a
  controller that reads its sensors, then applies the next command);
- ``after_command``: a(t_k+), under the torque acting from t_k on (a logged feedforward run
  that applies the command, then samples). With no delay that is the command of t_k itself:
  an accelerometer sample waits (is held, :attr:`SampleTiming.held`) until the command of its
  stamp, or any message stamped later, arrives, then is corrected at t_k with the torque acting
  then. So a live node and the offline pass give the same estimates whichever arrives first;
- ``auto``: both hypotheses are weighed on every sample at the same (prior) state (two
  predicted accelerations, one innovation covariance S; ``correction.imu_innovations``) into
  :attr:`SampleTiming.evidence`. Over the first :data:`TIMING_TRIAL` seconds after
  (re)initialisation each sample is corrected with the likelier so far (this sample not
  counted); then the likelier is chosen (:class:`TimingDecision`, with both log-likelihoods,
  in :attr:`SampleTiming.decisions`). Under ``before_command`` a sample is corrected at once and
  weighed when the command of its stamp arrives (:attr:`SampleTiming.deferred`: so a live
  node's estimate at the joint state of t_k holds the accelerometer of t_k); under
  ``after_command`` it waits, as above. Every :data:`TIMING_RECHECK` seconds the evidence
  since the last check is weighed again, and the choice switches only if the other is likelier
  by :data:`TIMING_SWITCH_EVIDENCE` (logged likewise). Where no command starts to act at a
  sample (a delay that is not a whole number of periods, a repeated command), the hypotheses
  agree and the sample is no evidence.

Other corrections at one stamp and the command at that stamp commute (they do not depend
on the command), so a live node and the offline pass give the same estimates whichever
message arrives first. Strain gauges have no feed-through in this model: a branch force
F = c (u - u_rest) + d du/dt is a function of the state, continuous where the torque jumps.

:class:`SampleTiming` holds the hypotheses, the evidence, the choices and the samples that
wait; the scheduler (:class:`~elastic_pm_dyn.observer.schedule.observer.Observer`) corrects and
weighs them with the filter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

BEFORE, AFTER, AUTO = 0, 1, 2  # the modes (period.run_periods' codes)
TIMING_MODES = {"before_command": BEFORE, "after_command": AFTER, "auto": AUTO}
TIMING_TRIAL = 0.1  # [s] auto: samples weighed before the first choice (about 100 at 1 kHz)
TIMING_MIN_SAMPLES = 20  # auto: the first choice waits for at least this many accelerometer samples
TIMING_RECHECK = 1.0  # [s] auto: evidence window of each later check
TIMING_SWITCH_EVIDENCE = 20.0  # auto: log-likelihood margin (nats) the other hypothesis needs to take over


@dataclass
class TimingDecision:
    """A choice of ``imu.sample_timing: auto``: at time t, over ``samples`` accelerometer
    samples, the Gaussian log-likelihoods of their innovations under each hypothesis."""

    t: float
    samples: int
    loglik_before: float
    loglik_after: float
    choice: str  # before_command | after_command
    switched: bool  # a later check that changed the choice

    def text(self) -> str:
        what = "switched to" if self.switched else "chose"
        return (f"accelerometer sample timing: {what} {self.choice} at t = {self.t:.6f} s (log-likelihood of "
                f"{self.samples} samples: before_command {self.loglik_before:.6g}, after_command "
                f"{self.loglik_after:.6g})")


class HeldSample(NamedTuple):
    """An accelerometer sample waiting for the command of its stamp (``after_command``)."""

    t: float
    acc: np.ndarray  # x, y, z


class DeferredSample(NamedTuple):
    """An accelerometer sample corrected under ``before_command`` and to be weighed (``auto``)
    when the command of its stamp comes."""

    t: float
    meas: np.ndarray  # its used axes
    prior: tuple  # the filter's state before its correction (a kernels.State)
    tau_before: np.ndarray  # the tree forces before it
    a_before: np.ndarray  # the point's acceleration at the prior under them (not evaluated again)


class SampleTiming:
    """The sample-timing hypotheses of one accelerometer (none: ``before_command``, nothing waits)."""

    def __init__(self, mode: str, has_imu: bool, no_delay: bool, tol: float):
        self.mode = TIMING_MODES[mode] if has_imu else BEFORE
        self.after = self.mode == AFTER  # the hypothesis in use (auto: the choice so far)
        self.trial = self.mode == AUTO  # auto before the first choice
        # no delay: the command that starts to act at a sample is the one of its own stamp
        self.no_delay = no_delay
        self.tol = tol
        self.evidence = np.zeros(4)  # correction.imu_innovations', since the last choice or check
        self.decisions: list[TimingDecision] = []  # the first choice and every switch
        self.last: TimingDecision | None = None  # the latest choice or check
        self.held: HeldSample | None = None
        self.deferred: DeferredSample | None = None
        self.t_decide = np.inf  # auto: the next choice or check is due at this stamp

    def reset(self, t: float) -> None:
        """A (re)started filter at time t: nothing waits, no evidence yet (the choice so far stays)."""
        self.held = self.deferred = None
        self.evidence[:] = 0.0
        self.restart(t)

    def restart(self, t: float) -> None:
        """The filter's clock starts at t: the next check counts from there."""
        if self.mode != AUTO:
            self.t_decide = np.inf
        else:
            self.t_decide = t + (TIMING_TRIAL if self.trial else TIMING_RECHECK)

    def use_after(self) -> bool:
        """The hypothesis in use: ``auto``'s likelier so far before its first choice."""
        return bool(self.evidence[1] < self.evidence[0]) if self.trial else self.after

    def waits_for_command(self, t: float, newest: float, delay: float) -> bool:
        """With no delay the command that starts to act at sample stamp t may still come (the
        command of t): ``newest``, when the newest accepted command acts from, is before it."""
        return self.mode != BEFORE and self.no_delay and newest < t + delay - self.tol

    def waiting_since(self) -> float:
        """Stamp of a sample that waits for its command (held, or to be weighed), else inf."""
        if self.held is not None:
            return self.held.t
        return self.deferred.t if self.deferred is not None else np.inf

    def due(self, t: float) -> bool:
        """``auto``: a choice or check is due at stamp t (what waits is to be settled first)."""
        return t >= self.t_decide - self.tol

    def decide(self, t: float) -> None:
        """``auto`` at a stamp when :meth:`due`: choose (first) or check the choice on the evidence so far."""
        nis_b, nis_a, logdet, n = self.evidence
        if self.trial and n < TIMING_MIN_SAMPLES:
            self.t_decide = t + TIMING_TRIAL  # too few samples yet: weigh on
            return
        self.t_decide = t + TIMING_RECHECK
        if n == 0:
            return
        ll_b, ll_a = -0.5 * (nis_b + logdet), -0.5 * (nis_a + logdet)
        if self.trial:
            after, switched = bool(ll_a > ll_b), False
        else:
            gain = ll_b - ll_a if self.after else ll_a - ll_b
            switched = bool(gain > TIMING_SWITCH_EVIDENCE)
            after = self.after != switched
        decision = TimingDecision(t, int(n), float(ll_b), float(ll_a), "after_command" if after else "before_command",
                                  switched)
        if self.trial or switched:
            self.decisions.append(decision)
        self.last = decision
        self.after, self.trial = after, False
        self.evidence[:] = 0.0

    def in_use(self) -> str:
        """before_command | after_command (auto: ``auto (trial)`` until the first choice)."""
        if self.trial:
            return "auto (trial)"
        return "after_command" if self.after else "before_command"

    def summary(self, setting: str, delay: float) -> dict:
        """The timing settings (``setting``: ``imu.sample_timing``; ``delay``: the command delay)
        and, for ``auto``, its choices (for summary.json)."""
        return {"imu_sample_timing": setting, "in_use": self.in_use(), "command_delay_s": delay,
                "decisions": [vars(d) | {"text": d.text()} for d in self.decisions],
                "last_check": None if self.last is None else vars(self.last)}
