"""Numerical metrics of a run: path deviation, residual vibration, spectra, timing.

All inputs are plain numpy arrays in SI units (s, m, N, Hz); nothing here knows
about ROS, bags or the model. Functions return floats, arrays or typed results
(:class:`PathDeviation`, :class:`DampedSinusoid`, :class:`StreamTiming`) whose fields say
what each number is.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import hilbert
from scipy.signal.windows import hann
from scipy.spatial import cKDTree

FloatArray = NDArray[np.float64]

# Relative tolerance on the sample spacing for data to count as uniformly sampled.
UNIFORM_TOL = 0.01


def rms(x: ArrayLike, axis: int | None = None) -> float | FloatArray:
    """Root mean square of ``x`` (over all elements, or along ``axis``)."""
    a = np.asarray(x, dtype=float)
    r = np.sqrt(np.mean(a * a, axis=axis))
    return float(r) if axis is None else r


def sample_rate(t: ArrayLike) -> float:
    """Sample rate [Hz] from the median sample spacing of time stamps ``t`` [s]."""
    dt = np.diff(np.asarray(t, dtype=float))
    if dt.size == 0:
        raise ValueError("need at least two time stamps to get a sample rate")
    med = float(np.median(dt))
    if med <= 0.0:
        raise ValueError("time stamps must be increasing")
    return 1.0 / med


def is_uniform(t: ArrayLike, tol: float = UNIFORM_TOL) -> bool:
    """True if every sample spacing of ``t`` is within ``tol`` (relative) of the median."""
    dt = np.diff(np.asarray(t, dtype=float))
    med = float(np.median(dt))
    return bool(med > 0.0 and np.all(np.abs(dt - med) <= tol * med))


def _as_points(p: ArrayLike, name: str) -> FloatArray:
    a = np.asarray(p, dtype=float)
    if a.ndim != 2 or a.shape[1] not in (2, 3):
        raise ValueError(f"{name} must have shape (N, 2) or (N, 3), got {a.shape}")
    return a


def straight_line_deviation(p: ArrayLike, a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Distance of each point of ``p`` (N x 2 or N x 3) from the segment ``a``-``b``.

    The foot of the perpendicular is clipped to the segment, so points beyond an
    end are measured to that end point. A degenerate segment (a == b) gives the
    distance to ``a``.
    """
    pts = _as_points(p, "p")
    a = np.asarray(a, dtype=float)
    d = np.asarray(b, dtype=float) - a
    dd = float(d @ d)
    u = np.zeros(len(pts)) if dd == 0.0 else np.clip((pts - a) @ d / dd, 0.0, 1.0)
    return np.linalg.norm(pts - (a + u[:, None] * d), axis=1)


def project_to_polyline(p: ArrayLike, poly: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Closest point of the polyline ``poly`` to each point of ``p``.

    Returns ``(distance, s)``: the perpendicular distance (clipped to the
    segments) and the arc length along ``poly`` of the closest point. Exact, and
    O(N log M) rather than O(N M): only segments that can possibly be closer than
    the nearest vertex are examined.
    """
    pts = _as_points(p, "p")
    poly = _as_points(poly, "poly")
    # Zero-length segments (e.g. a reference holding still) add nothing but cost.
    keep = np.concatenate(([True], np.any(np.diff(poly, axis=0) != 0.0, axis=1)))
    poly = poly[keep]
    if len(poly) == 1:
        return np.linalg.norm(pts - poly[0], axis=1), np.zeros(len(pts))
    seg = np.diff(poly, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    s_vertex = np.concatenate(([0.0], np.cumsum(seg_len)))

    tree = cKDTree(poly)
    d_vertex, _ = tree.query(pts)
    # A segment whose closest point is nearer than the nearest vertex has an end
    # point within d_vertex + (segment length)/2 of the query point.
    radius = d_vertex + 0.5 * seg_len.max() * (1.0 + 1e-9) + 1e-300
    hits = tree.query_ball_point(pts, radius)
    counts = np.fromiter((len(h) for h in hits), dtype=np.intp, count=len(hits))
    vert = np.fromiter(
        itertools.chain.from_iterable(hits), dtype=np.intp, count=int(counts.sum())
    )
    owner = np.repeat(np.arange(len(pts)), counts)
    # Each vertex j touches segments j-1 and j.
    cand_seg = np.concatenate((vert - 1, vert))
    cand_pt = np.concatenate((owner, owner))
    ok = (cand_seg >= 0) & (cand_seg < len(seg))
    cand_seg, cand_pt = cand_seg[ok], cand_pt[ok]

    d = seg[cand_seg]
    rel = pts[cand_pt] - poly[cand_seg]
    u = np.clip(np.einsum("ij,ij->i", rel, d) / seg_len[cand_seg] ** 2, 0.0, 1.0)
    dist = np.linalg.norm(rel - u[:, None] * d, axis=1)

    order = np.lexsort((dist, cand_pt))
    first = order[np.unique(cand_pt[order], return_index=True)[1]]
    s = s_vertex[cand_seg[first]] + u[first] * seg_len[cand_seg[first]]
    return dist[first], s


@dataclass(frozen=True)
class PathDeviation:
    """Deviation of an end-effector path from a reference [m] (:func:`path_deviation`)."""

    euclidean: FloatArray  # |p(t_k) - p_ref(t_k)| per sample (time-matched: contains lag along the path)
    perpendicular: FloatArray  # distance of p(t_k) from the reference path as a curve, per sample
    max: float  # of euclidean
    rms: float
    t_max: float  # [s] where euclidean is largest
    perpendicular_max: float
    perpendicular_rms: float
    final_error: float  # euclidean at the last sample
    final_error_vector: FloatArray  # p - p_ref at the last sample


def path_deviation(t: ArrayLike, p: ArrayLike, p_ref: ArrayLike) -> PathDeviation:
    """Deviation of an end-effector path ``p`` from a reference ``p_ref`` [m].

    ``p`` and ``p_ref`` are N x 2 or N x 3, sampled at the same times ``t`` [s].
    Two measures are given:

    - Euclidean (time-matched): ``|p(t_k) - p_ref(t_k)|``; contains lag along the path.
    - perpendicular: distance of ``p(t_k)`` from the reference path as a curve
      (polyline through ``p_ref``, clipped to its segments); lag along the path
      does not count, only leaving the path does.

    Returns a :class:`PathDeviation`: both time series, ``max``, ``rms``, ``t_max``
    (Euclidean), ``perpendicular_max``, ``perpendicular_rms``, ``final_error`` (Euclidean
    at the last sample) and ``final_error_vector`` (p - p_ref at the last sample).
    """
    t = np.asarray(t, dtype=float)
    pts = _as_points(p, "p")
    ref = _as_points(p_ref, "p_ref")
    if pts.shape != ref.shape or len(t) != len(pts):
        raise ValueError(
            f"t, p and p_ref must describe the same samples: got {t.shape}, {pts.shape}, {ref.shape}"
        )
    err = pts - ref
    eucl = np.linalg.norm(err, axis=1)
    perp, _ = project_to_polyline(pts, ref)
    k = int(np.argmax(eucl))
    return PathDeviation(euclidean=eucl, perpendicular=perp, max=float(eucl[k]), rms=rms(eucl), t_max=float(t[k]),
                         perpendicular_max=float(perp.max()), perpendicular_rms=rms(perp),
                         final_error=float(eucl[-1]), final_error_vector=err[-1].copy())


def alias_frequency(f: float, fs: float) -> float:
    """Apparent frequency [Hz] of a sinusoid at ``f`` [Hz] sampled at ``fs`` [Hz].

    Folds ``f`` into [0, fs/2], e.g. 552 Hz sampled at 1 kHz appears at 448 Hz.
    """
    if fs <= 0.0:
        raise ValueError(f"sample rate must be positive, got {fs}")
    return float(abs(f - fs * round(f / fs)))


def nyquist_warning(f_model: float, fs: float) -> str | None:
    """A warning text if ``f_model`` [Hz] is at or above the Nyquist frequency of ``fs``, else None."""
    nyq = 0.5 * fs
    if f_model < nyq:
        return None
    return (
        f"model frequency {f_model:.1f} Hz is at or above the Nyquist frequency {nyq:.1f} Hz "
        f"of {fs:.1f} Hz sampling: it appears aliased at {alias_frequency(f_model, fs):.1f} Hz; "
        f"sample faster than {2.0 * f_model:.0f} Hz to see it"
    )


def _hann_amplitude(
    x: FloatArray, fs: float, n_fft: int
) -> tuple[FloatArray, FloatArray]:
    """One-sided, Hann-windowed amplitude spectrum; a sinusoid on a bin reads its amplitude."""
    w = hann(len(x), sym=False)  # periodic window: the one meant for spectral analysis
    amp = np.abs(np.fft.rfft(x * w, n_fft)) * (2.0 / w.sum())
    amp[0] *= 0.5  # DC (and Nyquist, for even n_fft) have no mirror image to fold in
    if n_fft % 2 == 0:
        amp[-1] *= 0.5
    return np.fft.rfftfreq(n_fft, 1.0 / fs), amp


def spectrum(
    t: ArrayLike, x: ArrayLike, detrend: bool = True, n_fft: int | None = None
) -> tuple[FloatArray, FloatArray]:
    """One-sided amplitude spectrum of uniformly sampled data, Hann window.

    Returns ``(freqs [Hz], amplitude [unit of x])``, amplitude-corrected so that a
    sinusoid of amplitude A centred on a frequency bin shows a peak of height A.
    ``detrend`` removes the mean first; ``n_fft`` > len(x) zero-pads for a
    finer-looking (not finer-resolved) spectrum.

    Raises ValueError if any sample spacing differs from the median by more than
    1 %: the data is not resampled here, because interpolation would silently
    low-pass the very vibration one is looking for. Resample on purpose, or fit
    with :func:`residual_vibration`, which works on the raw samples.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.shape != x.shape or t.ndim != 1 or len(t) < 2:
        raise ValueError(
            f"t and x must be 1-D of equal length >= 2, got {t.shape} and {x.shape}"
        )
    if not is_uniform(t):
        dt = np.diff(t)
        raise ValueError(
            "spectrum needs uniformly sampled data: sample spacing ranges "
            f"{dt.min():.3g} .. {dt.max():.3g} s around a median of {np.median(dt):.3g} s "
            f"(tolerance {UNIFORM_TOL:.0%}); resample first"
        )
    if detrend:
        x = x - x.mean()
    n_fft = len(x) if n_fft is None else max(int(n_fft), len(x))
    return _hann_amplitude(x, sample_rate(t), n_fft)


def _fft_peak(x: FloatArray, fs: float, band: tuple[float, float] | None) -> float:
    """Frequency of the largest spectral peak, zero-padded and parabolically interpolated.

    The window is the falling half of a Hann window: a free decay has its energy
    at the start of the record, which a full Hann window would fade out (leaving
    noise peaks to win), while the taper to zero at the end still suppresses the
    leakage from cutting the record off.
    """
    n = len(x)
    n_fft = min(16 * 2 ** math.ceil(math.log2(n)), 2**22)
    w = np.cos(0.5 * np.pi * np.arange(n) / n) ** 2
    amp = np.abs(np.fft.rfft(x * w, n_fft))
    freqs = np.fft.rfftfreq(n_fft, 1.0 / fs)
    # Skip the leakage of whatever DC is left (main lobe about 2 native bins wide).
    allowed = freqs > 2.0 * fs / n
    if band is not None:
        in_band = allowed & (freqs >= band[0]) & (freqs <= band[1])
        if in_band.any():
            allowed = in_band
    k = int(np.flatnonzero(allowed)[np.argmax(amp[allowed])])
    if 0 < k < len(amp) - 1:
        y0, y1, y2 = np.log(amp[k - 1 : k + 2] + 1e-300)
        den = y0 - 2.0 * y1 + y2
        if den < 0.0:
            return float(freqs[k] + 0.5 * (y0 - y2) / den * (freqs[1] - freqs[0]))
    return float(freqs[k])


def _envelope_decay(tau: FloatArray, z: FloatArray, fs: float, f: float) -> float:
    """Decay rate sigma [1/s] from a straight-line fit to the log of the Hilbert envelope."""
    env = np.abs(hilbert(z))
    # Hilbert envelopes ring at the record ends; drop about one period at each.
    trim = max(2, round(fs / max(f, 1e-9)))
    if len(env) <= 2 * trim + 3:
        return 0.0
    env, tt = env[trim:-trim], tau[trim:-trim]
    # Use the head of the decay, until the envelope first falls below 10 % of its
    # peak: later samples are mostly noise and would bias the slope towards zero.
    start = int(np.argmax(env))
    below = np.flatnonzero(env[start:] < 0.1 * env[start])
    stop = start + (int(below[0]) if below.size else len(env) - start)
    if stop - start < 3:
        return 0.0
    slope = np.polyfit(tt[start:stop], np.log(env[start:stop]), 1, w=env[start:stop])[0]
    return float(-slope)


def _damped_cos_design(tau: FloatArray, f: float, sigma: float) -> FloatArray:
    e = np.exp(-sigma * tau)
    w = 2.0 * np.pi * f * tau
    return np.column_stack((e * np.cos(w), e * np.sin(w), np.ones_like(tau)))


def _unfold(f_apparent: float, fs: float, f_hint: float) -> float:
    """The frequency k fs +- f_apparent that is closest to ``f_hint``."""
    k_max = math.ceil(f_hint / fs) + 1
    cands = [
        abs(k * fs + sgn * f_apparent) for k in range(k_max + 1) for sgn in (-1.0, 1.0)
    ]
    return float(min(cands, key=lambda c: abs(c - f_hint)))


@dataclass(frozen=True)
class DampedSinusoid:
    """A fitted residual vibration ``x = A exp(-sigma tau) cos(2 pi f_d tau + phi) + c``
    (:func:`residual_vibration`); :meth:`as_dict` gives the same fields for JSON."""

    f_d: float  # damped frequency [Hz] (unfolded if aliased)
    f_apparent: float  # the frequency the samples show [Hz]
    f_alias: float | None  # = f_apparent when aliased, else None
    f_n: float  # natural frequency sqrt(f_d^2 + (sigma / 2 pi)^2) [Hz]
    zeta: float  # damping ratio sigma / (2 pi f_n)
    sigma: float  # decay rate [1/s]
    amplitude: float  # A at t_start
    phase: float  # phi [rad]
    offset: float  # c, the static part
    residual_rms: float  # of the fit
    fs: float  # sample rate [Hz]
    nyquist: float  # [Hz]
    aliased: bool
    n_samples: int
    seed: dict  # the initial estimates: f, sigma, amplitude, offset
    success: bool  # the least-squares fit converged
    warnings: list[str]

    def as_dict(self) -> dict:
        return asdict(self)


def residual_vibration(
    t: ArrayLike,
    x: ArrayLike,
    t_start: float,
    f_hint: float | None = None,
    t_end: float | None = None,
) -> DampedSinusoid:
    """Fit a single damped sinusoid to ``x`` in the hold phase from ``t_start`` [s].

    Model: ``x = A exp(-sigma tau) cos(2 pi f tau + phi) + c`` with
    ``tau = t - t_start``, so ``A`` is the amplitude at ``t_start`` and ``c`` the
    static part. Fitted by nonlinear least squares (Levenberg-Marquardt, analytic
    Jacobian) on the raw samples, seeded with the peak of a zero-padded Hann
    spectrum (frequency), the slope of the log Hilbert envelope (decay rate) and
    a linear least-squares fit for amplitude, phase and offset.

    ``f_hint`` [Hz] is the expected frequency, e.g. the model's natural
    frequency. It narrows the spectral peak search to +-30 % around where that
    frequency appears after sampling and, if it lies at or above the Nyquist
    frequency, flags the record as aliased and unfolds the fitted frequency to
    the candidate ``k fs +- f_apparent`` nearest the hint. Without a hint,
    aliasing cannot be detected from the samples alone; a warning is given
    when the apparent frequency is within 20 % of Nyquist.

    Returns a :class:`DampedSinusoid` (its fields say what each number is).
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.shape != x.shape or t.ndim != 1:
        raise ValueError(
            f"t and x must be 1-D of equal length, got {t.shape} and {x.shape}"
        )
    sel = t >= t_start
    if t_end is not None:
        sel &= t <= t_end
    tau, y = t[sel] - t_start, x[sel]
    if len(tau) < 10:
        raise ValueError(
            f"need at least 10 samples after t_start={t_start}, got {len(tau)}"
        )

    warnings: list[str] = []
    fs = sample_rate(tau)
    nyq = 0.5 * fs
    tail = y[-max(len(y) // 4, 1) :]
    c0 = float(tail.mean())
    z = y - c0
    if is_uniform(tau):
        zu = z
    else:
        warnings.append(
            "non-uniform sampling: spectral seed taken from linearly resampled data"
        )
        zu = np.interp(np.arange(tau[0], tau[-1], 1.0 / fs), tau, z)

    aliased = f_hint is not None and f_hint >= nyq
    band = None
    if f_hint is not None:
        f_expect = alias_frequency(f_hint, fs)
        band = (0.7 * f_expect, min(1.3 * f_expect, nyq))
    f0 = _fft_peak(zu, fs, band)
    sigma0 = _envelope_decay(tau, z, fs, f0)
    if sigma0 <= 0.0:
        sigma0 = (
            0.01 * 2.0 * np.pi * f0
        )  # nothing usable in the envelope: assume light damping
    a, b, c_lin = np.linalg.lstsq(_damped_cos_design(tau, f0, sigma0), y, rcond=None)[0]
    seed = {
        "f": f0,
        "sigma": sigma0,
        "amplitude": float(math.hypot(a, b)),
        "offset": float(c_lin),
    }
    p0 = np.array([math.hypot(a, b), sigma0, f0, math.atan2(-b, a), c_lin])

    def resid(p: FloatArray) -> FloatArray:
        amp, sig, f, ph, c = p
        return amp * np.exp(-sig * tau) * np.cos(2.0 * np.pi * f * tau + ph) + c - y

    def jac(p: FloatArray) -> FloatArray:
        amp, sig, f, ph, _ = p
        e = np.exp(-sig * tau)
        arg = 2.0 * np.pi * f * tau + ph
        ec, es = e * np.cos(arg), e * np.sin(arg)
        return np.column_stack(
            (
                ec,
                -amp * tau * ec,
                -2.0 * np.pi * amp * tau * es,
                -amp * es,
                np.ones_like(tau),
            )
        )

    from scipy.optimize import least_squares  # here: scipy.optimize costs every start-up ~0.1-0.3 s
    fit = least_squares(resid, p0, jac=jac, method="lm", x_scale="jac")
    amp, sigma, f, phase, offset = (float(v) for v in fit.x)
    # Same curve, canonical form: positive amplitude and frequency.
    if amp < 0.0:
        amp, phase = -amp, phase + np.pi
    if f < 0.0:
        f, phase = -f, -phase
    phase = float((phase + np.pi) % (2.0 * np.pi) - np.pi)
    f_apparent = alias_frequency(f, fs)

    if aliased:
        f_d = _unfold(f_apparent, fs, f_hint)
        warnings.append(
            f"aliased: expected {f_hint:.1f} Hz is above the Nyquist frequency {nyq:.1f} Hz; "
            f"the samples show {f_apparent:.2f} Hz, unfolded to {f_d:.2f} Hz using the hint"
        )
    else:
        f_d = f_apparent
        if f_hint is None and f_apparent > 0.8 * nyq:
            warnings.append(
                f"apparent frequency {f_apparent:.1f} Hz is close to the Nyquist frequency "
                f"{nyq:.1f} Hz: it may be an alias; pass f_hint to check"
            )
    f_n = math.hypot(f_d, sigma / (2.0 * np.pi))
    zeta = sigma / (2.0 * np.pi * f_n) if f_n > 0.0 else float("nan")
    res_rms = rms(fit.fun)
    if not fit.success:
        warnings.append(f"least squares did not converge: {fit.message}")
    if sigma < 0.0:
        warnings.append("negative decay rate: the oscillation grows in this window")
    if res_rms > 0.2 * amp:
        warnings.append(
            f"fit residual RMS {res_rms:.3g} exceeds 20 % of the amplitude {amp:.3g}: "
            "not a single damped sinusoid (several modes, a transient, or mostly noise)"
        )
    return DampedSinusoid(
        f_d=f_d, f_apparent=f_apparent, f_alias=f_apparent if aliased else None, f_n=f_n, zeta=zeta,
        sigma=sigma, amplitude=amp, phase=phase, offset=offset, residual_rms=float(res_rms), fs=float(fs),
        nyquist=float(nyq), aliased=bool(aliased), n_samples=len(tau), seed=seed, success=bool(fit.success),
        warnings=warnings)


@dataclass(frozen=True)
class StreamTiming:
    """Timing statistics of a message stream [s, Hz] (:func:`stream_stats`, ``StreamTimer.stats``)."""

    count: int  # stamps
    duration: float  # last - first (NaN without stamps)
    rate: float  # 1 / median period (NaN with fewer than two stamps)
    period_median: float
    period_mean: float
    period_std: float
    period_p99: float
    period_max: float
    gaps: int  # inter-arrival times above twice the median period
    longest_gap: float  # = period_max
    longest_gap_at: float  # stamp where it starts
    out_of_order: int  # stamps earlier than their predecessor
    exact: bool = True  # False: median, p99 and gaps from a histogram of the periods (long streams)


def stream_stats(stamps: ArrayLike) -> StreamTiming:
    """Timing statistics of a message stream from its time stamps [s].

    Returns a :class:`StreamTiming`: ``count``, ``duration`` [s], ``rate`` [Hz] (1 / median period),
    ``period_median``, ``period_mean``, ``period_std``, ``period_p99``,
    ``period_max`` [s], ``gaps`` (number of inter-arrival times above twice the
    median period), ``longest_gap`` [s] (= period_max), ``longest_gap_at`` (stamp where it
    starts) and ``out_of_order`` (stamps earlier than their predecessor; the
    statistics use the sorted stamps). With fewer than two stamps the timing
    values are NaN and ``gaps`` is 0.
    """
    s = np.asarray(stamps, dtype=float).ravel()
    out_of_order = int(np.count_nonzero(np.diff(s) < 0.0))
    s = np.sort(s)
    nan = float("nan")
    duration = float(s[-1] - s[0]) if len(s) else nan
    if len(s) < 2:
        return StreamTiming(count=len(s), duration=duration, rate=nan, period_median=nan, period_mean=nan,
                            period_std=nan, period_p99=nan, period_max=nan, gaps=0, longest_gap=nan,
                            longest_gap_at=nan, out_of_order=out_of_order)
    dt = np.diff(s)
    med = float(np.median(dt))
    k = int(np.argmax(dt))
    return StreamTiming(count=len(s), duration=duration, rate=1.0 / med if med > 0.0 else float("inf"),
                        period_median=med, period_mean=float(dt.mean()), period_std=float(dt.std()),
                        period_p99=float(np.percentile(dt, 99)), period_max=float(dt[k]),
                        gaps=int(np.count_nonzero(dt > 2.0 * med)), longest_gap=float(dt[k]),
                        longest_gap_at=float(s[k]), out_of_order=out_of_order)
