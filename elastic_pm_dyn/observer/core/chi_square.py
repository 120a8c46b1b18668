"""Quantiles of the chi-square distribution, for the gates, consistency bands and contact test.

``scipy.stats.chi2.ppf`` computes ``2 * gammaincinv(dof / 2, p)`` (``isf``: ``gammainccinv``); these are
those expressions
through ``scipy.special`` alone: importing ``scipy.stats`` cost ~0.4 s of every observer's
start-up on a quiet machine (1.3 s loaded), ``scipy.special`` a fraction of it, for the same
numbers bit for bit."""

from __future__ import annotations

import numpy as np
from scipy.special import gammainccinv, gammaincinv


def chi2_quantile(p: float | np.ndarray, dof: float | np.ndarray) -> float | np.ndarray:
    """The value below which a chi-square variable with ``dof`` degrees of freedom lies with
    probability ``p`` (0 < p < 1): ``scipy.stats.chi2.ppf(p, dof)``."""
    return 2.0 * gammaincinv(np.asarray(dof) / 2.0, p)


def chi2_upper_quantile(p: float | np.ndarray, dof: float | np.ndarray) -> float | np.ndarray:
    """The value a chi-square variable with ``dof`` degrees of freedom exceeds with probability
    ``p``: ``scipy.stats.chi2.isf(p, dof)`` (exact where 1 - p would round)."""
    return 2.0 * gammainccinv(np.asarray(dof) / 2.0, p)
