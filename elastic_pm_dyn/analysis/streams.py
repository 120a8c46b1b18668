"""Bounded-memory accumulators for message streams: samples, a full-rate window, timing.

A bag can hold hours of 10 kHz messages; nothing here grows without bound.

- :class:`SampleBuffer` keeps every sample until ``cap`` rows are stored, then halves its
  contents (every other row) and from then on keeps every 2nd (4th, 8th, ...) incoming
  row: a uniformly decimated overview of the whole stream, ``cap/2 .. cap`` rows.
  ``stride`` says how much was decimated (1 = all kept, exact).
- :class:`WindowBuffer` keeps ``n`` consecutive rows at full rate: the most recent ones
  (a ring) until it is armed at a time t0, then the first ``n`` rows from t0 on. It gives
  the residual-vibration fit and the spectrum undecimated samples when the overview is
  decimated (decimation would alias the ~550 Hz mode).
- :class:`StreamTimer` gives the statistics of :func:`metrics.stream_stats` exactly while
  it holds at most ``cap`` stamps, then switches to a log-spaced histogram of the periods
  (1 % bins) for median, p99 and gap count; count, mean, std, max and the longest gap
  stay exact.
- :class:`HoldDetector` finds, online, where a reference motion comes to rest.
"""

from __future__ import annotations

import itertools
import math
from array import array

import numpy as np

from elastic_pm_dyn.analysis import metrics

FloatArray = np.ndarray


class SampleBuffer:
    """Rows of ``width`` floats, uniformly decimated to stay within ``cap`` rows (see module doc)."""

    def __init__(self, width: int, cap: int):
        if cap < 2:
            raise ValueError(f"cap must be >= 2, got {cap}")
        self.width = width
        self.cap = cap
        self.stride = 1
        self.seen = 0  # rows offered
        self.n = 0  # rows stored
        self._data = np.empty((min(cap, 1024), width))

    def append(self, row: FloatArray) -> None:
        k = self.seen
        self.seen += 1
        if k % self.stride:
            return
        if self.n == len(self._data):
            if self.n < self.cap:  # grow geometrically up to the cap
                grown = np.empty((min(2 * self.n, self.cap), self.width))
                grown[: self.n] = self._data[: self.n]
                self._data = grown
            else:  # full: keep every other stored row, double the stride
                kept = self._data[: self.n : 2]
                self.n = len(kept)
                self._data[: self.n] = kept
                self.stride *= 2
                if k % self.stride:
                    return
        self._data[self.n] = row
        self.n += 1

    @property
    def rows(self) -> FloatArray:
        return self._data[: self.n]


class WindowBuffer:
    """``n`` consecutive rows at full rate: the latest ones, or the first ones from an armed time."""

    def __init__(self, width: int, n: int, time_column: int = 0):
        self.n = n
        self.col = time_column
        self._data = np.empty((n, width))
        self.count = 0  # rows written since the last reset
        self.start: float | None = None  # armed: collect rows with t >= start

    def arm(self, start: float) -> None:
        """Collect the first ``n`` rows at or after ``start`` (replaces any earlier window)."""
        self.start = start
        self.count = 0

    def append(self, row: FloatArray) -> None:
        if self.start is not None:
            if row[self.col] < self.start or self.count >= self.n:
                return
            self._data[self.count] = row
        else:
            self._data[self.count % self.n] = row
        self.count += 1

    @property
    def rows(self) -> FloatArray:
        if self.start is not None or self.count <= self.n:
            return self._data[: min(self.count, self.n)]
        k = self.count % self.n  # ring: oldest row first
        return np.concatenate((self._data[k:], self._data[:k]))


# Histogram of periods: 1 % wide log bins from 1 ns to ~28 h.
_BINS_PER_DECADE = 230
_LOG_MIN, _LOG_MAX = -9.0, 5.0


class StreamTimer:
    """Timing statistics of a stream of stamps [s], exact up to ``cap`` stamps (see module doc)."""

    def __init__(self, cap: int):
        self.cap = cap
        self._stamps: array | None = array("d")  # 8 bytes per stamp
        self.count = 0
        self.first = self.last = math.nan
        self.lo = math.inf
        self.hi = -math.inf
        self.out_of_order = 0
        self._hist: np.ndarray | None = None
        self._sum = self._sum2 = 0.0
        self._n_dt = 0
        self._max_dt = -math.inf
        self._max_dt_at = math.nan

    def add(self, t: float) -> None:
        if self.count == 0:
            self.first = t
        elif t < self.last:
            self.out_of_order += 1
        self.count += 1
        self.lo, self.hi = min(self.lo, t), max(self.hi, t)
        if self._stamps is not None:
            self._stamps.append(t)
            if len(self._stamps) > self.cap:
                self._to_histogram()
        elif t >= self.last:
            self._add_period(t - self.last, self.last)
        self.last = t

    def _to_histogram(self) -> None:
        stamps, self._stamps = self._stamps, None
        self._hist = np.zeros(int((_LOG_MAX - _LOG_MIN) * _BINS_PER_DECADE) + 2, dtype=np.int64)
        self._hist_sum = np.zeros(len(self._hist))  # sum of the periods per bin: their mean is exact
        for a, b in itertools.pairwise(stamps):
            if b >= a:
                self._add_period(b - a, a)

    def _add_period(self, dt: float, at: float) -> None:
        self._n_dt += 1
        self._sum += dt
        self._sum2 += dt * dt
        if dt > self._max_dt:
            self._max_dt, self._max_dt_at = dt, at
        k = 0 if dt <= 0.0 else int((math.log10(dt) - _LOG_MIN) * _BINS_PER_DECADE) + 1
        k = min(max(k, 0), len(self._hist) - 1)
        self._hist[k] += 1
        self._hist_sum[k] += dt

    @staticmethod
    def _edges_above(limit: float) -> np.ndarray:
        """Bins whose periods all exceed ``limit`` (bin k >= 1 holds [10^(lo+(k-1)/n), 10^(lo+k/n)))."""
        k = np.arange(int((_LOG_MAX - _LOG_MIN) * _BINS_PER_DECADE) + 2)
        lower = 10.0 ** (_LOG_MIN + (k - 1) / _BINS_PER_DECADE)
        return (k >= 1) & (lower > limit)

    @property
    def exact(self) -> bool:
        return self._stamps is not None

    def stats(self) -> metrics.StreamTiming:
        """As :func:`metrics.stream_stats`, with ``exact`` False when from the histogram (estimates)."""
        if self._stamps is not None:
            return metrics.stream_stats(np.frombuffer(self._stamps, dtype=float))
        hist = self._hist
        # Quantiles: the mean period of the bin they fall in (exact for a periodic stream).
        centres = self._hist_sum / np.maximum(hist, 1)
        cum = np.cumsum(hist)
        n = max(int(cum[-1]), 1)
        med = float(centres[np.searchsorted(cum, 0.5 * n)])
        mean = self._sum / n
        return metrics.StreamTiming(
            count=self.count,
            duration=self.hi - self.lo,
            rate=1.0 / med if med > 0.0 else math.inf,
            period_median=med,
            period_mean=mean,
            period_std=math.sqrt(max(self._sum2 / n - mean * mean, 0.0)),
            period_p99=float(centres[np.searchsorted(cum, 0.99 * n)]),
            period_max=self._max_dt,
            gaps=int(hist[self._edges_above(2.0 * med)].sum()),
            longest_gap=self._max_dt,
            longest_gap_at=self._max_dt_at,
            out_of_order=self.out_of_order,
            exact=False,
        )


class HoldDetector:
    """Online: the time where a motion comes to rest (speed falls to ~0 after moving).

    ``still`` is a fraction of the largest speed seen so far: a reference from the
    feedforward node holds its end pose with exactly zero velocity, so the default
    (1e-6) only trims the last microseconds of a smooth stop. ``on_hold(t)`` is called
    at every move-to-rest transition; ``hold_start`` is the latest one.
    """

    def __init__(self, still: float = 1e-6, floor: float = 1e-12):
        self.still = still
        self.floor = floor
        self.peak = 0.0
        self.moving = False
        self.hold_start: float | None = None
        self.listeners: list = []

    def add(self, t: float, speed: float) -> None:
        if not math.isfinite(speed):
            return
        self.peak = max(self.peak, speed)
        threshold = max(self.still * self.peak, self.floor)
        if speed > threshold:
            self.moving = True
        elif self.moving:
            self.moving = False
            self.hold_start = t
            for listener in self.listeners:
                listener(t)


def hold_start(t: FloatArray, speed: FloatArray, still: float = 1e-6, floor: float = 1e-12) -> float | None:
    """Offline twin of :class:`HoldDetector`: the start of the last rest after a motion, or None."""
    speed = np.asarray(speed, dtype=float)
    ok = np.isfinite(speed)
    if not ok.any():
        return None
    t, speed = np.asarray(t, dtype=float)[ok], speed[ok]
    moving = np.flatnonzero(speed > max(still * float(speed.max()), floor))
    if moving.size == 0 or moving[-1] + 1 >= len(t):
        return None
    return float(t[moving[-1] + 1])
