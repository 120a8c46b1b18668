"""What the recordings determine: standard deviations, correlations, and what they do not excite.

From the Fisher information B of the log ratios (:mod:`.fit`): cov = B^-1, so a parameter's
standard deviation is its value times sqrt(cov_ii) and the correlations are
cov_ij / sqrt(cov_ii cov_jj). Two ways a recording leaves a parameter undetermined, both named:
- near-zero sensitivity: the parameter's own information alone gives a log standard deviation
  above :data:`NOT_EXCITED_STD` (the samples hardly change with it): found before the fit
  (:func:`unexcited`), the parameter stays at the file's value;
- rank deficiency: parameters that move the samples only together (a payload and a spring that
  set one mode and nothing else): an eigenvalue of the correlation-scaled information below
  :data:`RANK_TOL` of the largest, named with the combination of log ratios it leaves free.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.calibration.fit import scores_at
from elastic_pm_dyn.calibration.likelihood import Score

NOT_EXCITED_STD = 0.5  # [log ratio] a factor 1.6 either way: the recording says nothing useful
RANK_TOL = 1e-8  # eigenvalue ratio of the scaled information below which a combination is free
WEAK_STD = 0.05  # [relative] named as weakly determined beyond this (5 %)


@dataclass
class Identifiability:
    names: list[str]
    std: np.ndarray  # standard deviation of each value (its units)
    std_log: np.ndarray  # ... of its log ratio (relative)
    correlation: np.ndarray  # (n, n)
    findings: list[str]  # one line per parameter or combination the recordings leave open


def identifiability(B: np.ndarray, values: np.ndarray, names: Sequence[str], fixed: Sequence[int] = ()
                    ) -> Identifiability:
    """Standard deviations, correlations and findings of the information ``B`` at ``values``."""
    n = len(names)
    free = [i for i in range(n) if i not in set(fixed)]
    cov = np.full((n, n), np.nan)
    findings = [f"{names[i]}: not excited (near-zero sensitivity), kept at the file's value" for i in fixed]
    if free:
        Bf = B[np.ix_(free, free)]
        d = np.sqrt(np.maximum(np.diag(Bf), 1e-300))
        scaled = Bf / np.outer(d, d)
        w, V = np.linalg.eigh(scaled)
        for k in np.flatnonzero(w < RANK_TOL * w.max()):
            v = V[:, k] / np.abs(V[:, k]).max()
            combo = " ".join(f"{v[j]:+.2f} log {names[free[j]]}" for j in np.argsort(-np.abs(v)) if abs(v[j]) > 0.1)
            findings.append(f"rank-deficient: {combo} is not determined by the recordings")
        cf = np.linalg.pinv(scaled) / np.outer(d, d)
        cov[np.ix_(free, free)] = cf
    std_log = np.sqrt(np.abs(np.diag(cov)))
    for i in free:
        if std_log[i] > WEAK_STD:
            findings.append(f"{names[i]}: weakly determined (std {100 * std_log[i]:.3g} %)")
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std_log, std_log)
    return Identifiability(list(names), np.asarray(values) * std_log, std_log, corr, findings)


def unexcited(evaluate: Callable[[np.ndarray], Score], n: int, threads: int = 2) -> list[int]:
    """Parameters whose own information at the file's values (the Gauss-Newton curvature of
    :mod:`.fit`, each sample weighed by its misfit) gives a log std above :data:`NOT_EXCITED_STD`."""
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(max(1, threads)) as pool:
        here, G = scores_at(lambda pts: list(pool.map(evaluate, pts)), np.zeros(n), np.arange(n), n)
    if not here.ok:
        return []
    w = 1.0 / np.maximum(here.nis, 1.0)
    info = (G * G * w[:, None]).sum(axis=0)
    return [i for i in range(n) if info[i] * NOT_EXCITED_STD ** 2 < 1.0]
