"""Maximum likelihood over physical parameters: a Gauss-Newton search on the filter's innovations.

theta are log ratios to the file's values. At theta, n + 1 filter passes (the point and one
forward step per parameter, two at once in threads: the compiled filter releases the GIL) give
every sample's score g_k = d l_k / d theta (:mod:`.likelihood`); the gradient is sum_k g_k.

The step: Gauss-Newton on the whitened innovations' lengths e_k = sqrt(NIS_k) (l_k = e_k^2 / 2 +
log det S_k / 2 + const, so de_k = g_k / e_k), curvature H = sum_k g_k g_k^T / NIS_k, damped
(Levenberg-Marquardt, mu) and tried at two lengths at once: along its direction at the trust
radius, and its own length (at most a quarter of the radius); the likelier is kept. The radius
grows threefold while the long trial wins (far from the optimum H's steps are too short) and
shrinks after a miss. It stops when two steps in a row gain less than ``tol`` nats, or at the
budget. (The plain BHHH curvature sum_k g_k g_k^T, the usual choice, weighs each sample by its
misfit NIS_k: at the file's values of a machine 15 % off it is thousands of times too large and
its steps stall; measured in bench/calibration/README.md.)

At the optimum the Fisher information is estimated by the outer product of the scores,
B = sum_k g_k g_k^T (Berndt-Hall-Hall-Hausman: the NLL's expected Hessian at the true parameters,
positive semi-definite, free once the scores are there): cov = B^-1 in log ratios gives standard
deviations and correlations (:mod:`.identifiability`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from elastic_pm_dyn.calibration.likelihood import Score
from elastic_pm_dyn.errors import InputError

FD_STEP = 1e-4  # log-ratio step of the forward differences (0.01 %): the NLL is smooth and noise-free there
MAX_STEP = 0.4  # the longest step in log ratio (a factor 1.5) per iteration: far off, B's model is poor
MU_START, MU_MIN, MU_MAX = 1e-3, 1e-9, 1e6
RADIUS_START = 0.05  # [log ratio] the first trust radius: 5 %
MIN_RADIUS = 1e-6
MAX_MISSES = 3  # steps in a row that gain nothing, each at an 8x smaller radius: stop
FAILED = 1e30


@dataclass
class FitResult:
    theta: np.ndarray  # log ratios at the optimum
    score: Score  # the filter's pass there
    scores: np.ndarray  # (samples, n) per-sample scores there
    information: np.ndarray  # (n, n) B
    iterations: int
    passes: int
    wall_s: float
    history: list[tuple[int, float]] = field(default_factory=list)  # (pass count, NLL) of each accepted point
    stopped: str = ""


def fit(evaluate: Callable[[np.ndarray], Score], n: int, theta0: np.ndarray | None = None, max_passes: int = 120,
        tol: float = 0.5, threads: int = 2, log: Callable[[str], object] = print,
        fixed: Sequence[int] = (), radius: float = RADIUS_START, rel_tol: float = 0.0) -> FitResult:
    """Minimise the NLL of ``evaluate(theta)`` over the n log ratios (module docstring).
    ``fixed``: indices kept at theta0 (parameters the recording does not excite); ``radius``: the
    first trust radius (small when theta0 is near the optimum already); a step gaining less than
    max(``tol``, ``rel_tol`` |NLL|) nats counts as small."""
    wall = time.perf_counter()
    theta = np.zeros(n) if theta0 is None else np.asarray(theta0, dtype=float).copy()
    free = np.array([i for i in range(n) if i not in set(fixed)], dtype=np.int64)
    pool = ThreadPoolExecutor(max(1, threads))
    passes = [0]

    def run(points: list[np.ndarray]) -> list[Score]:
        passes[0] += len(points)
        return list(pool.map(evaluate, points))

    def nll(s: Score) -> float:
        return s.nll if s.ok else FAILED

    try:
        here, scores = scores_at(run, theta, free, n)
        if not here.ok:
            raise InputError(f"the observer fails on the model it starts from ({here.fault or 'no likelihood'}): "
                             "check the recording's topics, --sensors and --config")
        history = [(passes[0], here.nll)]
        mu, it, stopped, small, misses = MU_START, 0, "budget", 0, 0
        while passes[0] + len(free) + 3 <= max_passes:
            it += 1
            g = scores.sum(axis=0)
            # Gauss-Newton on the whitened innovations' lengths e_k = sqrt(NIS_k): de_k = g_k / e_k, so
            # the curvature is sum g_k g_k^T / NIS_k (BHHH weighted down by each sample's misfit, which
            # far off is thousands of times the noise and makes B thousands of times too cautious)
            w = 1.0 / np.sqrt(np.maximum(here.nis, 1.0))
            H = (scores * w[:, None]).T @ (scores * w[:, None])
            step = _step(H, g, mu, free)
            length = float(np.abs(step).max())
            if length == 0.0:
                stopped = "converged"
                break
            # far off, B (built of large scores) is too cautious: the step along its direction at the
            # trust radius; near the optimum its own length is right: both tried, two passes at once
            trials = [step * (radius / length), step * min(1.0, 0.25 * radius / length)]
            results = run([theta + t for t in trials])
            k = int(np.argmin([nll(r) for r in results]))
            gain = here.nll - nll(results[k])
            small_gain = max(tol, rel_tol * abs(here.nll))
            taken = float(np.abs(trials[k]).max())
            log(f"  iteration {it}: NLL {here.nll:.7g} -> {nll(results[k]):.7g} (step {taken:.3g} in log ratio)")
            whole = length <= 0.25 * radius  # the second trial was the Gauss-Newton step itself
            if gain > 0:
                misses = 0
                theta = theta + trials[k]
                radius = min(radius * 3.0, MAX_STEP) if k == 0 else max(2.0 * taken, MIN_RADIUS)
                mu = max(mu / 10.0, MU_MIN)
                here, scores = scores_at(run, theta, free, n, results[k])
                history.append((passes[0], here.nll))
                # converged: the Gauss-Newton step itself gains little, or two steps in a row do
                small = small + 1 if gain < small_gain else 0
                if small >= 2 or (gain < small_gain and k == 1 and whole):
                    stopped = "converged"
                    break
            else:
                # two misses in a row, the Gauss-Newton step among them, or MAX_MISSES at shrinking
                # radii: at the optimum within what the forward differences resolve
                misses += 1
                if (misses >= 2 and whole) or misses >= MAX_MISSES:
                    stopped = "converged (no step gains)"
                    break
                radius = max(radius / 8.0, MIN_RADIUS)
                mu *= 10.0
                if mu > MU_MAX:
                    stopped = "no step gains"
                    break
    finally:
        pool.shutdown()
    B = scores.T @ scores
    return FitResult(theta, here, scores, B, it, passes[0], time.perf_counter() - wall, history, stopped)


def scores_at(run, theta: np.ndarray, free: np.ndarray, n: int, here: Score | None = None) -> tuple[Score, np.ndarray]:
    """The pass at theta (``here`` if known) and the per-sample scores by forward differences
    (columns of fixed parameters zero)."""
    points = [] if here is not None else [theta]
    for i in free:
        t = theta.copy()
        t[i] += FD_STEP
        points.append(t)
    results = run(points)
    if here is None:
        here, results = results[0], results[1:]
    G = np.zeros((here.terms.size, n))
    for i, r in zip(free, results, strict=True):
        if r.ok and r.terms.shape == here.terms.shape:
            G[:, i] = (r.terms - here.terms) / FD_STEP
    return here, G


def _step(B: np.ndarray, g: np.ndarray, mu: float, free: np.ndarray) -> np.ndarray:
    """The damped BHHH step on the free parameters."""
    out = np.zeros(len(g))
    if not len(free):
        return out
    Bf = B[np.ix_(free, free)]
    d = np.diag(Bf).copy()
    d[d <= 0] = 1.0
    step = -np.linalg.solve(Bf + mu * np.diag(d) + 1e-12 * d.max() * np.eye(len(free)), g[free])
    out[free] = step
    return out


def hessian_at(run: Callable[[list[np.ndarray]], list[Score]], theta: np.ndarray, free: np.ndarray, n: int,
               here: Score, scores: np.ndarray, h: float = FD_STEP) -> np.ndarray:
    """The NLL's Hessian at theta by second forward differences: A_ij = (f(theta + h e_i + h e_j)
    - f(theta + h e_i) - f(theta + h e_j) + f(theta)) / h^2, the single steps' values taken from
    the scores (their column sums are (f(theta + h e_i) - f(theta)) / h): n (n + 1) / 2 more passes.
    The observed information, which the outer product of the scores (BHHH) equals only when the
    filter's noise model is the data's (Huber 1967; White 1982, "Maximum likelihood estimation of
    misspecified models"). Rows and columns of fixed parameters are zero; NaN where a pass failed."""
    pairs = [(int(i), int(j)) for a, i in enumerate(free) for j in free[a:]]
    points = []
    for i, j in pairs:
        t = theta.copy()
        t[i] += h
        t[j] += h
        points.append(t)
    g = scores.sum(axis=0)
    A = np.zeros((n, n))
    for (i, j), r in zip(pairs, run(points), strict=True):
        v = (r.nll - here.nll - h * (g[i] + g[j])) / h ** 2 if r.ok else np.nan
        A[i, j] = A[j, i] = v
    return A
