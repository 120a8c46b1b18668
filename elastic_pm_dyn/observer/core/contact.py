"""Contact detection on the end-effector wrench estimate: a threshold on its normalised value.

The statistic of an estimate row is s = w^T P_w^-1 w: the wrench estimate w (the n_w wrench
states) against its own covariance block P_w. With no wrench acting and a consistent filter,
w is zero-mean Gaussian with covariance P_w, so s is chi-square with n_w degrees of freedom
and P(s > h) = ``probability`` per sample for h = chi2.isf(probability, n_w). A contact is
declared at the first row with s > h (``contact`` event, stamped with that row's stamp) and
released at the first row after it with s < ``release`` h (``release`` event): the hysteresis
keeps a contact that hovers near the threshold one contact.

Why a threshold and not a CUSUM: the wrench states are random walks, so the filter already
sums the evidence of a persistent force over time (a CUSUM on top would sum it twice and
only add delay); a contact with a stiff wall is a fast ramp that the threshold sees as soon as
the estimate has risen, without a drift parameter that would need the contact force's size
in advance. What the threshold gives up, the detection of a force smaller than a few standard
deviations, a CUSUM would not give quickly either.

False alarms: ``probability`` is the chance per sample under the hypotheses above; rows are
correlated (the estimate is filtered), so over N rows the chance of any false alarm is at most
N ``probability`` (the union bound: 6e-3 over 60 s at 1 kHz for the default 1e-7, h = 32.2 for
two components, 5.7 standard deviations). Where the filter overstates its uncertainty (NEES
below its dof, as measured in bench/) the rate is lower still; model errors it does not know
of (an unmodelled payload, friction) raise it: bench/benchmarks/bench_wrench.py measures it on
60 s of normal motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.observer.core.chi_square import chi2_upper_quantile
from elastic_pm_dyn.observer.core.estimate import EstimateLayout

DEFAULT_PROBABILITY = 1e-7  # false-alarm probability per sample
DEFAULT_RELEASE = 0.25  # released below this fraction of the threshold


@dataclass(frozen=True)
class ContactEvent:
    """A detected contact (``kind`` "contact") or its end ("release") at ``t`` [s, filter time]."""

    kind: str
    t: float
    statistic: float  # s = w^T P_w^-1 w of the row
    threshold: float
    wrench: np.ndarray  # the estimate (n_w, the layout's wrench components)


class ContactDetector:
    """The threshold test of the module docstring over estimate rows of ``layout``."""

    def __init__(self, layout: EstimateLayout, probability: float = DEFAULT_PROBABILITY,
                 release: float = DEFAULT_RELEASE):
        nw = len(layout.wrench_names or ())
        if nw == 0:
            raise ValueError("contact detection needs the wrench states (process.wrench: random_walk)")
        if not (0.0 < probability < 0.5 and 0.0 < release < 1.0):
            raise ValueError(f"probability in (0, 0.5) and release in (0, 1), got {probability!r}, {release!r}")
        self.layout = layout
        self.threshold = float(chi2_upper_quantile(probability, nw))
        self.release = release
        self.states = np.arange(layout.nx - nw, layout.nx)  # the wrench states: the last n_w of x
        self.in_contact = False
        self.events: list[ContactEvent] = []

    def block(self, P: np.ndarray) -> np.ndarray:
        """The wrench states' block of a filter covariance (nx x nx)."""
        return P[np.ix_(self.states, self.states)]

    def statistic(self, row: np.ndarray) -> float:
        """s = w^T P_w^-1 w of an estimate row (inf if P_w is not positive definite)."""
        nx = self.layout.nx
        return normalised(row[self.layout["wrench"]], self.block(row[self.layout["P"]].reshape(nx, nx)))

    def update(self, row: np.ndarray) -> ContactEvent | None:
        """The event this row makes (None: no change)."""
        nx = self.layout.nx
        return self.update_values(float(row[0]), row[self.layout["wrench"]],
                                  self.block(row[self.layout["P"]].reshape(nx, nx)))

    def update_values(self, t: float, w: np.ndarray, P_w: np.ndarray) -> ContactEvent | None:
        """The event of an estimate ``w`` with covariance ``P_w`` at ``t`` (what :meth:`update` reads
        from a row; the live node passes an Estimate's fields)."""
        s = normalised(w, P_w)
        event = None
        if not self.in_contact and s > self.threshold:
            event = ContactEvent("contact", t, s, self.threshold, np.array(w, dtype=float))
        elif self.in_contact and s < self.release * self.threshold:
            event = ContactEvent("release", t, s, self.threshold, np.array(w, dtype=float))
        if event is not None:
            self.in_contact = event.kind == "contact"
            self.events.append(event)
        return event


def normalised(w: np.ndarray, P_w: np.ndarray) -> float:
    """w^T P_w^-1 w (inf if P_w is not positive definite)."""
    try:
        L = np.linalg.cholesky(P_w)
    except np.linalg.LinAlgError:
        return float("inf")
    y = np.linalg.solve(L, w)
    return float(y @ y)


def detect(layout: EstimateLayout, rows: np.ndarray, probability: float = DEFAULT_PROBABILITY,
           release: float = DEFAULT_RELEASE) -> list[ContactEvent]:
    """Every event over estimate ``rows`` (one per line), in order."""
    det = ContactDetector(layout, probability, release)
    for row in rows:
        det.update(row)
    return det.events
