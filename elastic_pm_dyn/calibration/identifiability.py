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
HAC_SECONDS = 0.5  # [s] Bartlett window of the scores' autocovariance (bench/calibration/README.md)


@dataclass
class Identifiability:
    names: list[str]
    std: np.ndarray  # standard deviation of each value (its units)
    std_log: np.ndarray  # ... of its log ratio (relative)
    correlation: np.ndarray  # (n, n)
    findings: list[str]  # one line per parameter or combination the recordings leave open
    std_fisher: np.ndarray  # the Fisher information's (BHHH) alone, for comparison
    covariance: str = "fisher"  # which covariance std is: fisher (B^-1) or sandwich (A^-1 S A^-1)


def identifiability(B: np.ndarray, values: np.ndarray, names: Sequence[str], fixed: Sequence[int] = (),
                    robust: np.ndarray | None = None) -> Identifiability:
    """Standard deviations, correlations and findings of the information ``B`` at ``values``;
    ``robust`` (n, n): a covariance of the log ratios (:func:`sandwich`) that the standard deviations
    and correlations are taken from instead of B^-1 (the findings stay B's)."""
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
    fisher_log = np.sqrt(np.abs(np.diag(cov)))
    kind = "fisher"
    if robust is not None and free and np.all(np.isfinite(robust[np.ix_(free, free)])):
        cov = np.full((n, n), np.nan)
        cov[np.ix_(free, free)] = robust[np.ix_(free, free)]
        kind = "sandwich"
    std_log = np.sqrt(np.abs(np.diag(cov)))
    for i in free:
        if std_log[i] > WEAK_STD:
            findings.append(f"{names[i]}: weakly determined (std {100 * std_log[i]:.3g} %)")
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std_log, std_log)
    return Identifiability(list(names), np.asarray(values) * std_log, std_log, corr, findings,
                           np.asarray(values) * fisher_log, kind)


def time_scores(scores: np.ndarray, segments: Sequence[tuple[int, float, int]]) -> list[np.ndarray]:
    """The per-sample scores summed per time bin, one (bins, n) array per recording: each sensor's
    block (``Score.segments``) spread evenly over its recording, bins at the fastest sensor's rate."""
    return [S for S, _ in _binned(scores, segments)]


def _binned(scores: np.ndarray, segments: Sequence[tuple[int, float, int]]) -> list[tuple[np.ndarray, float]]:
    """:func:`time_scores`' arrays, each with its recording's length [s] (its first block's)."""
    rows: dict[int, list[tuple[float, np.ndarray]]] = {}
    start = 0
    for rec, seconds, count in segments:
        rows.setdefault(rec, []).append((seconds, scores[start:start + count]))
        start += count
    out = []
    for blocks in rows.values():
        bins = max(len(b) for _, b in blocks)
        S = np.zeros((bins, scores.shape[1]))
        for _, b in blocks:
            if len(b):
                np.add.at(S, (np.arange(len(b)) * bins) // len(b), b)
        out.append((S, blocks[0][0]))
    return out


def score_covariance(scores: np.ndarray, segments: Sequence[tuple[int, float, int]],
                     window_s: float = HAC_SECONDS) -> np.ndarray:
    """The covariance of the scores' sum allowing for their correlation in time: Newey-West
    (Bartlett kernel, "A simple, positive semi-definite, heteroskedasticity and autocorrelation
    consistent covariance matrix", Econometrica 1987) over lags up to ``window_s`` within each
    recording, recordings independent. With white innovations it is the outer product B."""
    n = scores.shape[1]
    out = np.zeros((n, n))
    for S, seconds in _binned(scores, segments):
        L = min(len(S) - 1, round(window_s * len(S) / seconds)) if seconds > 0 else 0
        out += S.T @ S
        for lag in range(1, L + 1):
            C = S[lag:].T @ S[:-lag]
            out += (1.0 - lag / (L + 1)) * (C + C.T)
    return out


def sandwich(A: np.ndarray, Sc: np.ndarray, free: Sequence[int]) -> np.ndarray | None:
    """The robust (Huber-White) covariance A^-1 S A^-1 of the log ratios on the ``free`` ones: A the
    NLL's Hessian (:func:`.fit.hessian_at`), S the scores' covariance (:func:`score_covariance`).
    None when A is not positive definite there (not at a minimum, or a failed pass)."""
    n = len(A)
    f = list(free)
    if not f:
        return None
    Af = A[np.ix_(f, f)]
    if not np.all(np.isfinite(Af)):
        return None
    Af = 0.5 * (Af + Af.T)
    w, V = np.linalg.eigh(Af)
    if w.min() <= 0:
        return None
    Ai = (V / w) @ V.T
    cov = np.full((n, n), np.nan)
    cov[np.ix_(f, f)] = Ai @ Sc[np.ix_(f, f)] @ Ai
    return cov


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
