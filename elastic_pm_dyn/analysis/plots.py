"""PNG figures of a run: path, branch forces, closure gap, torques, errors, spectra.

Each function draws one figure, writes it as a PNG (creating the folder) and
returns the path. Inputs are arrays in SI units; plots convert to readable units
(mm, µm, ...) where stated.

Figures are built with :class:`matplotlib.figure.Figure` directly instead of
through pyplot: saving to PNG then goes through the Agg renderer without a
display, nothing is registered in pyplot's global figure list (so nothing has to
be closed or can leak), and importing this module does not switch the matplotlib
backend of a caller such as a notebook or a GUI.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import ArrayLike

from elastic_pm_dyn.analysis.metrics import alias_frequency, project_to_polyline
from elastic_pm_dyn.output_files import atomic_file

DPI = 100
# Smallest value drawn on the log-scale gap plot; exact zeros are clipped to it.
GAP_FLOOR = 1e-18

_PREFIXES = [
    (1e9, "G"),
    (1e6, "M"),
    (1e3, "k"),
    (1.0, ""),
    (1e-3, "m"),
    (1e-6, "µ"),
    (1e-9, "n"),
    (1e-12, "p"),
    (1e-15, "f"),
]


def _si_scale(max_abs: float, unit: str) -> tuple[float, str]:
    """Factor and unit label (with SI prefix) that bring ``max_abs`` into [1, 1000)."""
    if not math.isfinite(max_abs) or max_abs <= 0.0:
        return 1.0, unit
    for value, prefix in _PREFIXES:
        if max_abs >= value:
            return 1.0 / value, prefix + unit
    value, prefix = _PREFIXES[-1]
    return 1.0 / value, prefix + unit


def _new_figure(width: float = 9.0, height: float = 5.5) -> Figure:
    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


def _save(fig: Figure, path_png: str | Path) -> Path:
    path = Path(path_png)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as tmp:  # a full disk leaves no cut PNG
        fig.savefig(tmp, dpi=DPI, format="png")
    return path


def _time_of(t: ArrayLike | Mapping[str, ArrayLike], run: str) -> np.ndarray:
    """Time axis of ``run``: one array shared by all runs, or a dict of arrays per run."""
    return np.asarray(t[run] if isinstance(t, Mapping) else t, dtype=float)


def _magnitude(v: ArrayLike) -> np.ndarray:
    """A 1-D series as is; an N x k series of vectors as its Euclidean norm per sample."""
    a = np.asarray(v, dtype=float)
    return np.linalg.norm(a, axis=1) if a.ndim == 2 else a


def _colors(names: list[str]) -> dict[str, str]:
    # Fixed colour per run across all axes of a figure.
    return {name: f"C{i % 10}" for i, name in enumerate(names)}


def plot_path(
    path_png: str | Path,
    runs: Mapping[str, ArrayLike],
    reference: ArrayLike | None = None,
) -> Path:
    """End-effector path in the x-y plane, one line per run (paper Fig. 2).

    ``runs`` maps a run name to its path, N x 2 or N x 3 [m] (x and y are drawn,
    in mm, on equal axes); ``reference`` is drawn in black. With a reference, a
    second panel shows each run's perpendicular distance from the reference path
    against the arc length along it, because deviations of micrometres are
    invisible at the scale of the whole path.
    """
    fig = _new_figure(12.0 if reference is not None else 7.0, 5.5)
    axes = fig.subplots(1, 2 if reference is not None else 1, squeeze=False)[0]
    ax = axes[0]
    colors = _colors(list(runs))
    for name, p in runs.items():
        p = np.asarray(p, dtype=float)
        ax.plot(1e3 * p[:, 0], 1e3 * p[:, 1], color=colors[name], lw=1.5, label=name)
    if reference is not None:
        ref = np.asarray(reference, dtype=float)
        ax.plot(1e3 * ref[:, 0], 1e3 * ref[:, 1], "k--", lw=1.0, label="reference")
        ax.plot(1e3 * ref[0, 0], 1e3 * ref[0, 1], "ko", ms=5, label="start")
        ax.plot(1e3 * ref[-1, 0], 1e3 * ref[-1, 1], "ks", ms=5, label="end")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title("End-effector path")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")

    if reference is not None:
        ax = axes[1]
        # NaN or infinite samples (a joint state that was) are left out of the distances, as the
        # metrics leave them out; the path panel shows them as gaps
        ref_xy = ref[np.all(np.isfinite(ref[:, :2]), axis=1), :2]
        dev = {}
        for name, p in runs.items():
            xy = np.asarray(p, dtype=float)[:, :2]
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            if len(xy) and len(ref_xy):
                dev[name] = project_to_polyline(xy, ref_xy)
        max_dev = max((float(d.max()) for d, _ in dev.values()), default=0.0)
        scale, unit = _si_scale(max_dev, "m")
        for name, (d, s) in dev.items():
            ax.plot(1e3 * s, scale * d, ".", ms=2, color=colors[name], label=name)
        ax.set_xlabel("arc length along the reference path [mm]")
        ax.set_ylabel(f"distance from reference path [{unit}]")
        ax.set_title("Deviation from the reference path")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small", markerscale=4)
    return _save(fig, path_png)


def _zoom_ylim(
    ax: Axes, series: list[tuple[np.ndarray, np.ndarray]], t0: float, t1: float
) -> None:
    # Autoscaling would use the whole record; fit the y range to the window only.
    vals = [y[(t >= t0) & (t <= t1)] for t, y in series]
    vals = [v for v in vals if v.size]
    if not vals:
        return
    lo = min(float(v.min()) for v in vals)
    hi = max(float(v.max()) for v in vals)
    pad = 0.05 * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 1e-3
    ax.set_ylim(lo - pad, hi + pad)


def plot_branch_forces(
    path_png: str | Path,
    t: ArrayLike | Mapping[str, ArrayLike],
    forces: Mapping[str, Mapping[str, ArrayLike]],
    zoom: tuple[float, float] | None = None,
) -> Path:
    """Branch (active rod) forces, one axis per branch, one line per run (paper Fig. 3).

    ``forces[run][branch]`` is the force [N] (tension positive) sampled at ``t``
    [s]; ``t`` is shared by all runs or a dict ``run -> t``. ``zoom = (t0, t1)``
    adds a second row showing only that window (e.g. the residual vibration in
    the hold phase), shaded in the first row.
    """
    runs = list(forces)
    branches = list(dict.fromkeys(b for run in runs for b in forces[run]))
    nrows = 2 if zoom is not None else 1
    fig = _new_figure(5.0 * len(branches) + 1.0, 3.6 * nrows + 0.6)
    axes = fig.subplots(nrows, len(branches), squeeze=False)
    colors = _colors(runs)
    for j, branch in enumerate(branches):
        series = []
        for run in runs:
            if branch not in forces[run]:
                continue
            tt, f = _time_of(t, run), np.asarray(forces[run][branch], dtype=float)
            series.append((tt, f))
            for i in range(nrows):
                axes[i, j].plot(tt, f, color=colors[run], lw=1.0, label=run)
        ax = axes[0, j]
        ax.set_title(f"branch '{branch}'")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"F_{branch} [N]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
        if zoom is not None:
            ax.axvspan(zoom[0], zoom[1], color="0.85", zorder=0, label="_zoom window")
            zax = axes[1, j]
            zax.set_xlim(zoom)
            _zoom_ylim(zax, series, *zoom)
            zax.set_title(f"branch '{branch}', zoom {zoom[0]:g} - {zoom[1]:g} s")
            zax.set_xlabel("time [s]")
            zax.set_ylabel(f"F_{branch} [N]")
            zax.grid(True, alpha=0.3)
    fig.suptitle("Branch forces (tension positive)")
    return _save(fig, path_png)


def plot_gap(
    path_png: str | Path,
    t_by_run: Mapping[str, ArrayLike],
    gap_by_run: Mapping[str, ArrayLike],
) -> Path:
    """Closure gap |P_L - P_R| [m] over time on a log scale, one line per run (paper Fig. 4).

    A gap series may be the norm (N) or the gap vector (N x k, its norm is
    drawn). Values below 1e-18 m, in particular exact zeros, cannot be shown on a
    log axis; they are drawn at 1e-18 m and the axis label says so.
    """
    fig = _new_figure(9.0, 5.0)
    ax = fig.subplots()
    colors = _colors(list(gap_by_run))
    clipped = False
    for run, gap in gap_by_run.items():
        g = _magnitude(gap)
        clipped |= bool(np.any(g < GAP_FLOOR))
        ax.semilogy(
            _time_of(t_by_run, run),
            np.maximum(g, GAP_FLOOR),
            color=colors[run],
            lw=1.0,
            label=run,
        )
    label = "closure gap |P_L - P_R| [m]"
    if clipped:
        label += (
            f"\n(values < {GAP_FLOOR:.0e}, incl. exact zeros, drawn at {GAP_FLOOR:.0e})"
        )
    ax.set_ylabel(label)
    ax.set_xlabel("time [s]")
    ax.set_title("Loop-closure gap")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return _save(fig, path_png)


def plot_torques(
    path_png: str | Path,
    t: ArrayLike | Mapping[str, ArrayLike],
    torques: Mapping[str, ArrayLike],
    steps: bool = True,
) -> Path:
    """Motor torques [N m] over time, one line per entry of ``torques`` (joint or run).

    ``steps`` draws each sample held until the next one (zero-order hold), which
    is how a digital controller's torque table acts on the plant.
    """
    fig = _new_figure(9.0, 5.0)
    ax = fig.subplots()
    colors = _colors(list(torques))
    for name, tau in torques.items():
        ax.plot(
            _time_of(t, name),
            np.asarray(tau, dtype=float),
            color=colors[name],
            lw=1.0,
            drawstyle="steps-post" if steps else "default",
            label=name,
        )
    ax.set_xlabel("time [s]")
    ax.set_ylabel("torque [N m]")
    ax.set_title("Motor torques" + (" (zero-order hold)" if steps else ""))
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return _save(fig, path_png)


def plot_wrench(
    path_png: str | Path,
    t: np.ndarray,
    wrench: np.ndarray,
    std: np.ndarray | None = None,
    t_true: np.ndarray | None = None,
    true: np.ndarray | None = None,
    contacts: np.ndarray | None = None,
) -> Path:
    """The end-effector wrench estimate (rows [fx, fy, fz, mx, my, mz]) with its +-2 sigma band,
    the true wrench (dashed) where a plant recorded it, and the contact detections (vertical
    lines): forces above, couples below where there are any."""
    wrench = np.asarray(wrench, dtype=float)
    couples = bool(np.any(wrench[:, 3:] != 0)) or (true is not None and bool(np.any(np.asarray(true)[:, 3:] != 0)))
    fig = _new_figure(9.0, 6.5 if couples else 4.5)
    axes = fig.subplots(2 if couples else 1, 1, sharex=True, squeeze=False)[:, 0]
    colors = {"x": "tab:blue", "y": "tab:orange", "z": "tab:green"}
    for ax, first, unit, name in zip(axes, (0, 3), ("N", "N m"), ("force", "couple"), strict=False):
        for c, axis in enumerate("xyz"):
            k = first + c
            if not np.any(wrench[:, k] != 0) and (true is None or not np.any(np.asarray(true)[:, k] != 0)):
                continue
            ax.plot(t, wrench[:, k], color=colors[axis], lw=1.0, label=f"{name} {axis} (estimate)")
            if std is not None:
                ax.fill_between(t, wrench[:, k] - 2 * std[:, k], wrench[:, k] + 2 * std[:, k], color=colors[axis],
                                alpha=0.15, lw=0)
            if true is not None:
                ax.plot(t_true, np.asarray(true)[:, k], color=colors[axis], lw=1.0, ls="--",
                        label=f"{name} {axis} (true)")
        for tc in contacts if contacts is not None else ():
            ax.axvline(tc, color="tab:red", lw=0.8, ls=":")
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title("End-effector wrench (band: +-2 sigma; red: contact detected)")
    return _save(fig, path_png)


def plot_tracking_error(
    path_png: str | Path,
    t: ArrayLike | Mapping[str, ArrayLike],
    err_by_run: Mapping[str, ArrayLike],
    quantity: str = "end-effector position error",
    unit: str = "m",
    log_scale: bool = False,
    title: str | None = None,
) -> Path:
    """Tracking error over time, one line per run, in an SI-prefixed unit (e.g. µm).

    An error series may be a magnitude (N) or error vectors (N x k, whose norm is
    drawn). ``quantity`` and ``unit`` name what is plotted (e.g. "joint error", "rad").
    ``log_scale`` puts runs whose errors differ by orders of magnitude (rigid vs
    elastic) on one readable axis; exact zeros are then left out. ``title`` replaces
    the default "Tracking: <quantity>" (e.g. for differences between runs).
    """
    fig = _new_figure(9.0, 5.0)
    ax = fig.subplots()
    colors = _colors(list(err_by_run))
    errs = {run: _magnitude(e) for run, e in err_by_run.items()}
    max_abs = max(
        (float(np.nanmax(np.abs(e))) for e in errs.values() if e.size), default=0.0
    )
    scale, label_unit = _si_scale(max_abs, unit)
    for run, e in errs.items():
        ax.plot(_time_of(t, run), scale * e, color=colors[run], lw=1.0, label=run)
    if log_scale:
        ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{quantity} [{label_unit}]")
    ax.set_title(title or f"Tracking: {quantity}")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return _save(fig, path_png)


def plot_spectrum(
    path_png: str | Path,
    freqs_amps_by_run: Mapping[str, tuple[ArrayLike, ArrayLike]],
    f_model: float | Sequence[float] | None = None,
    fs: float | None = None,
    unit: str = "N",
    title: str = "Amplitude spectrum",
) -> Path:
    """Amplitude spectra (e.g. from :func:`metrics.spectrum`), one line per run, log scale.

    ``f_model`` [Hz], the model's natural frequency (or several: one line each), is
    marked by a vertical line, the Nyquist frequency ``fs / 2`` by another. If a model
    frequency is at or above Nyquist, the frequency where it appears after sampling is
    marked too, the unobservable band is shaded and the title warns.
    """
    fig = _new_figure(9.0, 5.0)
    ax = fig.subplots()
    colors = _colors(list(freqs_amps_by_run))
    peak, floor, f_max = 0.0, math.inf, 0.0
    for run, (f, a) in freqs_amps_by_run.items():
        f, a = np.asarray(f, dtype=float), np.asarray(a, dtype=float)
        ax.plot(f, a, color=colors[run], lw=1.0, label=run)
        positive = a[a > 0.0]
        if positive.size:
            peak = max(peak, float(positive.max()))
            floor = min(floor, float(np.percentile(positive, 1)))
        f_max = max(f_max, float(f.max()) if f.size else 0.0)
    ax.set_yscale("log")
    if peak > 0.0:
        # Down to the noise floor, but no deeper than 1e-7 of the peak: round-off
        # floors of clean simulations would otherwise squash the peaks.
        ax.set_ylim(bottom=max(0.5 * floor, peak * 1e-7))

    nyq = None if fs is None else 0.5 * fs
    if nyq is not None:
        ax.axvline(nyq, color="0.3", ls=":", lw=1.5, label=f"Nyquist {nyq:.0f} Hz")
    f_models = [] if f_model is None else [float(f_model)] if np.ndim(f_model) == 0 else [float(x) for x in f_model]
    aliased = [f for f in f_models if nyq is not None and f >= nyq]
    for f in f_models:
        ax.axvline(f, color="r", ls="--", lw=1.5, label=f"model f_n {f:.0f} Hz")
        if f in aliased:
            f_alias = alias_frequency(f, fs)
            ax.axvline(f_alias, color="r", ls=":", lw=1.5, label=f"alias of f_n {f_alias:.0f} Hz")
    if aliased:
        top = max(aliased)
        ax.axvspan(nyq, max(1.1 * top, f_max), color="0.9", zorder=0, label=f"above Nyquist of {fs:g} Hz sampling")
        seen = ", ".join(f"{alias_frequency(f, fs):.0f}" for f in aliased)
        title = (f"ALIASED: model mode {', '.join(f'{f:.0f}' for f in aliased)} Hz > Nyquist {nyq:.0f} Hz, "
                 f"seen at {seen} Hz")
    if f_models:
        ax.set_xlim(0.0, max(1.1 * max(f_models), f_max))
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"amplitude [{unit}]" if unit else "amplitude")
    ax.set_title(title, color="r" if title.startswith("ALIASED") else "k")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return _save(fig, path_png)
