"""Input shaping of a path: ZV, ZVD and EI shapers built from the machine's elastic modes.

A shaper is a train of impulses (A_i, t_i), sum A_i = 1; the shaped path is
y_s(t) = sum_i A_i y(t - t_i): the same end point, reached later by the shaper's length. For
one mode of natural frequency f and damping ratio zeta (damped period T_d = 1 / (f sqrt(1 -
zeta^2)), K = exp(-zeta pi / sqrt(1 - zeta^2))):

- ZV: A = [1, K] / (1 + K) at [0, T_d / 2]: no residual vibration at exactly that mode;
- ZVD: A = [1, 2K, K^2] / (1 + K)^2 at [0, T_d / 2, T_d]: also zero slope in frequency
  (robust to a few percent of error in f);
- EI (tolerance V = 5 %): A = [(1 + V) / 4, (1 - V) / 2, (1 + V) / 4] at [0, T_d / 2, T_d]
  (the undamped design; wider insensitivity than ZVD at the same length).

Several modes: the shapers convolved. The modes are those ``check`` reports' kind (the
linearisation of :mod:`elastic_pm_dyn.dynamics.linear`), taken at the path's start and end
poses with the motors free (the feedforward drives torques, so the free-motor modes ring),
merged where they lie within 3 % of each other, the lowest ``MAX_MODES`` kept.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.errors import InputError

SHAPERS = ("zv", "zvd", "ei")
EI_TOLERANCE = 0.05
MERGE = 0.03  # relative frequency within which two modes get one shaper
MAX_MODES = 4  # shapers convolved at most (3^4 = 81 impulses)


@dataclass(frozen=True)
class Shaper:
    amplitudes: np.ndarray
    times: np.ndarray  # [s], first 0

    @property
    def length(self) -> float:
        return float(self.times[-1])

    def __mul__(self, other: Shaper) -> Shaper:
        """Convolution: both shapers in series."""
        t = (self.times[:, None] + other.times[None, :]).ravel()
        a = (self.amplitudes[:, None] * other.amplitudes[None, :]).ravel()
        order = np.argsort(t, kind="stable")
        return Shaper(a[order], t[order])


def single_mode(kind: str, frequency: float, damping: float = 0.0) -> Shaper:
    """The ``kind`` shaper (zv, zvd, ei) of one mode [Hz]."""
    if kind not in SHAPERS:
        raise InputError(f"unknown shaper {kind!r} (expected one of {', '.join(SHAPERS)})")
    if not (np.isfinite(frequency) and frequency > 0 and 0 <= damping < 1):
        raise InputError(f"a shaper needs a frequency > 0 and a damping ratio in [0, 1), got {frequency}, {damping}")
    root = np.sqrt(1.0 - damping**2)
    half = 0.5 / (frequency * root)
    k = np.exp(-damping * np.pi / root)
    if kind == "zv":
        return Shaper(np.array([1.0, k]) / (1 + k), np.array([0.0, half]))
    if kind == "zvd":
        return Shaper(np.array([1.0, 2 * k, k * k]) / (1 + k) ** 2, np.array([0.0, half, 2 * half]))
    v = EI_TOLERANCE
    return Shaper(np.array([(1 + v) / 4, (1 - v) / 2, (1 + v) / 4]), np.array([0.0, half, 2 * half]))


def for_modes(kind: str, frequencies: np.ndarray, damping: np.ndarray) -> Shaper:
    """One shaper for several modes: merged within MERGE, the lowest MAX_MODES, convolved."""
    order = np.argsort(frequencies)
    kept: list[tuple[float, float]] = []
    for f, z in zip(np.asarray(frequencies)[order], np.asarray(damping)[order], strict=True):
        if not (np.isfinite(f) and f > 0):
            continue
        if kept and f <= kept[-1][0] * (1 + MERGE):
            continue
        kept.append((float(f), float(z) if np.isfinite(z) else 0.0))
    if not kept:
        raise InputError("no elastic mode to shape for")
    shaper = Shaper(np.array([1.0]), np.array([0.0]))
    for f, z in kept[:MAX_MODES]:
        shaper = shaper * single_mode(kind, f, z)
    return shaper


class ShapedPath:
    """y_s(t) = sum_i A_i y(t - t_i): a path (its rates and accelerations) through a shaper."""

    def __init__(self, path, shaper: Shaper):
        self.path = path
        self.shaper = shaper
        self.move = path.move + shaper.length
        self.hold = max(path.duration - path.move - shaper.length, 0.0)
        self.start = getattr(path, "start", None)
        self.end = getattr(path, "end", None)

    @property
    def duration(self) -> float:
        return self.move + self.hold

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        parts = [self.path(t - ti) for ti in self.shaper.times]
        a = self.shaper.amplitudes
        return tuple(sum(ai * p[m] for ai, p in zip(a, parts, strict=True)) for m in range(3))
