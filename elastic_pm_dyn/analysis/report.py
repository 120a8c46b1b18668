"""Metrics of runs, side by side: summary.json, summary.md and the PNG plots.

:func:`run_metrics` reduces a :class:`RunData` to its typed numbers, a
:class:`~elastic_pm_dyn.analysis.report_types.RunMetrics` (path deviation, final error,
branch-force peaks, residual vibration of the hold phase, closure gap, torques, stream
timing, command age); :func:`compare` gives the differences of two runs (a ``Comparison``);
:func:`write_report` makes the report of one run or several (the first is the baseline of
the differences) from them, with the plots of :mod:`plots`, and writes its ``to_dict()``
(summary.json) and summary.md.
:func:`analyze` is ``elastic-pm-dyn analyze``: bags in, report out (an
:class:`~elastic_pm_dyn.analysis.report_types.AnalysisReport`, summary.json as objects).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from elastic_pm_dyn.analysis import metrics, plots
from elastic_pm_dyn.analysis.report_types import (
    AnalysisReport,
    BranchForces,
    Comparison,
    Gap,
    HoldPhase,
    Note,
    PathMetrics,
    RunMetrics,
    TimeZero,
    Torques,
    VibrationFit,
)
from elastic_pm_dyn.analysis.run_data import ModelInfo, RunData
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.output_files import staged_files, write_text

# Plot file names by figure; paper-figures uses the paper's numbering.
PLOT_NAMES = {"path": "path.png", "branch_forces": "branch_forces.png", "gap": "gap.png",
              "torques": "torques.png", "tracking_error": "tracking_error.png", "spectrum": "spectrum.png",
              "force_difference": "difference_branch_forces.png", "path_difference": "difference_path.png",
              "wrench": "wrench.png"}
ZOOM = (-0.01, 0.04)  # [s] around the hold start: the residual vibration in the branch-force plot


# ----------------------------------------------------------------------------- metrics
def _finite_rows(*arrays: np.ndarray) -> np.ndarray:
    ok = np.ones(len(arrays[0]), dtype=bool)
    for a in arrays:
        ok &= np.isfinite(a).all(axis=1) if a.ndim == 2 else np.isfinite(a)
    return ok


def path_metrics(run: RunData) -> PathMetrics | Note | None:
    """Deviation of the end effector from the reference, on the states inside the reference's span."""
    if run.ee is None or run.t is None:
        return None
    ref = run.reference_at(run.t)
    if ref is None:
        return None
    ok = _finite_rows(run.ee, ref) & (run.t >= run.t_ref.min() - 1e-9) & (run.t <= run.t_ref.max() + 1e-9)
    if ok.sum() < 2:
        return Note("joint states and reference do not overlap in time")
    dev = metrics.path_deviation(run.t[ok], run.ee[ok], ref[ok])
    return PathMetrics(
        max_error_m=dev.max, rms_error_m=dev.rms, t_max_error_s=dev.t_max, max_path_deviation_m=dev.perpendicular_max,
        rms_path_deviation_m=dev.perpendicular_rms, final_position_error_m=dev.final_error,
        final_error_vector_m=dev.final_error_vector.tolist(), samples=int(ok.sum()),
        compared_from_s=float(run.t[ok][0]), compared_to_s=float(run.t[ok][-1]), actual=run.ee_source,
        reference=run.ee_ref_source)


def _f_hint(natural_hz: Sequence[float]) -> float | None:
    # The fit searches +-30 % around the hint, so one value covers modes close together.
    return float(np.median(natural_hz)) if len(natural_hz) else None


def vibration_metrics(run: RunData, natural_hz: Sequence[float]) -> dict[str, VibrationFit | Note]:
    """Damped-sinusoid fit of each branch force in the hold phase (see metrics.residual_vibration), by branch."""
    if run.hold_start is None or run.t_vib is None:
        return {}
    out: dict[str, VibrationFit | Note] = {}
    for b, f in run.forces_vib.items():
        ok = _finite_rows(f) & (run.t_vib >= run.hold_start)
        if ok.sum() < 10:
            out[b] = Note(f"only {int(ok.sum())} samples after the hold start {run.hold_start:.4g} s")
            continue
        if np.ptp(f[ok]) <= 1e-12 * max(1.0, float(np.abs(f[ok]).max())):
            out[b] = Note("constant in the hold phase: no vibration to fit")
            continue
        try:
            v = metrics.residual_vibration(run.t_vib[ok], f[ok], run.hold_start, f_hint=_f_hint(natural_hz))
        except ValueError as err:
            out[b] = Note(str(err))
            continue
        nearest = min(natural_hz, key=lambda fn: abs(fn - v.f_d)) if len(natural_hz) else None
        out[b] = VibrationFit(f_d_hz=v.f_d, f_n_hz=v.f_n, zeta=v.zeta, amplitude_N=v.amplitude, decay_rate_1_s=v.sigma,
                              offset_N=v.offset, f_apparent_hz=v.f_apparent, aliased=v.aliased, sample_rate_hz=v.fs,
                              samples=v.n_samples, residual_rms_N=v.residual_rms, model_f_n_hz=nearest,
                              warnings=v.warnings)
    return out


def _value_at(t: np.ndarray, x: np.ndarray, at: float) -> float:
    k = int(np.clip(np.searchsorted(t, at), 0, len(t) - 1))
    return float(x[k])


def _gap(run: RunData) -> Gap | None:
    if run.gap is None or not np.isfinite(run.gap).any():
        return None
    g = run.gap
    k = int(np.nanargmax(g))
    return Gap(source=run.gap_source, max_m=float(g[k]), t_max_s=float(run.t_gap[k]), final_m=float(g[-1]),
               at_hold_start_m=None if run.hold_start is None else _value_at(run.t_gap, g, run.hold_start))


def run_metrics(run: RunData, natural_hz: Sequence[float]) -> RunMetrics:
    """All numbers of one run."""
    branch_forces = torques = None
    if run.forces:
        branch_forces = BranchForces(source=run.force_source, peak_N=run.peak_force,
                                     max_N={b: float(np.nanmax(f)) for b, f in run.forces.items()},
                                     min_N={b: float(np.nanmin(f)) for b, f in run.forces.items()})
    vibration = vibration_metrics(run, natural_hz)
    bad_torques = {}
    if run.torques:
        finite = {n: np.asarray(x)[np.isfinite(x)] for n, x in run.torques.items()}
        bad_torques = {n: len(x) - len(finite[n]) for n, x in run.torques.items() if len(x) != len(finite[n])}
        torques = Torques(source=run.torque_source,
                          peak_Nm={n: float(np.max(np.abs(f))) if len(f) else None for n, f in finite.items()})
    warnings = _warnings(run, vibration, natural_hz)
    if bad_torques:  # named, never a silent null
        warnings.append("torques not finite (NaN or Inf): " + ", ".join(
            f"{n} {k} of {len(run.torques[n])} samples" for n, k in bad_torques.items())
            + "; peak_Nm over the finite ones (null: none)")
    return RunMetrics(label=run.label, time_zero=TimeZero(run.t0, run.t0_source),
                      hold_phase=HoldPhase(run.hold_start, run.hold_source or None), path=path_metrics(run),
                      vibration=vibration, command_age=run.command_age, streams=run.streams, warnings=warnings,
                      bag=run.bag, branch_forces=branch_forces, gap=_gap(run), torques=torques,
                      diagnostics=run.diagnostics or None)


def _ms(x: float | None) -> float:
    return (math.nan if x is None else x) * 1e3


def _warnings(run: RunData, vibration: Mapping[str, VibrationFit | Note], natural_hz: Sequence[float]) -> list[str]:
    w = list(run.notes)
    for s in run.streams.values():
        if s.gaps:
            w.append(f"{s.topic}: {s.gaps} gaps in the stream (longest {_ms(s.longest_gap_s):.3g} ms, "
                     f"median period {_ms(s.period_median_s):.3g} ms)")
        if s.out_of_order:
            w.append(f"{s.topic}: {s.out_of_order} stamps earlier than their predecessor")
    fs = _force_rate(run)
    if natural_hz and fs:
        text = metrics.nyquist_warning(max(natural_hz), fs)
        if text:
            w.append(f"branch forces: {text}")
    for b, v in vibration.items():
        if isinstance(v, VibrationFit):
            w.extend(f"vibration fit {b}: {x}" for x in v.warnings if not x.startswith("aliased"))
    return w


def _force_rate(run: RunData) -> float | None:
    if run.t_vib is None or len(run.t_vib) < 2:
        return None
    try:
        return metrics.sample_rate(run.t_vib)
    except ValueError:
        return None


# --------------------------------------------------------------------------- comparison
def _leaves(d: Mapping, prefix: str = "", nan: frozenset[str] = frozenset()) -> dict[str, float]:
    """Every number of ``d`` by its dotted key path; the paths in ``nan`` (null: not finite) as NaN."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_leaves(v, key + ".", nan))
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[key] = float(v)
        elif v is None and key in nan:
            out[key] = math.nan
    return out


COMPARED = ("path", "branch_forces", "vibration", "gap", "torques", "command_age")


def _compared(m: RunMetrics) -> dict[str, float]:
    content = m.to_dict()
    return _leaves({k: content.get(k) or {} for k in COMPARED}, nan=frozenset(m.non_finite))


def compare(base: RunData, other: RunData, m_base: RunMetrics, m_other: RunMetrics) -> Comparison:
    """``other`` - ``base``: every scalar metric both have, plus differences of the time series."""
    a, b = _compared(m_base), _compared(m_other)
    series = {}
    for br in base.forces:
        if br in other.forces and base.t_force is not None and other.t_force is not None:
            d = _on_base(base.t_force, base.forces[br], other.t_force, other.forces[br])
            if d is not None:
                series[f"branch_force_{br}_max_abs_N"] = float(np.nanmax(np.abs(d)))
                series[f"branch_force_{br}_rms_N"] = float(np.sqrt(np.nanmean(d * d)))
    if base.ee is not None and other.ee is not None:
        d = _ee_difference(base, other)
        if d is not None:
            series["end_effector_max_distance_m"] = float(np.nanmax(d))
            series["end_effector_rms_distance_m"] = float(np.sqrt(np.nanmean(d * d)))
    return Comparison(baseline=base.label, other=other.label, metric_difference={k: b[k] - a[k] for k in a if k in b},
                      series_difference=series)


def _on_base(t_a: np.ndarray, x_a: np.ndarray, t_b: np.ndarray, x_b: np.ndarray) -> np.ndarray | None:
    """x_b - x_a on the times of a that lie within b's span (linear interpolation), NaN outside."""
    ok = np.isfinite(x_b)
    if ok.sum() < 2:
        return None
    tb, xb = t_b[ok], x_b[ok]
    order = np.argsort(tb, kind="stable")
    y = np.interp(t_a, tb[order], xb[order])
    y[(t_a < tb.min()) | (t_a > tb.max())] = np.nan
    return y - x_a


def _ee_difference(base: RunData, other: RunData) -> np.ndarray | None:
    cols = [_on_base(base.t, base.ee[:, k], other.t, other.ee[:, k]) for k in range(base.ee.shape[1])]
    if any(c is None for c in cols):
        return None
    return np.linalg.norm(np.column_stack(cols), axis=1)


# ------------------------------------------------------------------------------- plots
def _zoom(runs: Sequence[RunData]) -> tuple[float, float] | None:
    h = next((r.hold_start for r in runs if r.hold_start is not None), None)
    return None if h is None else (h + ZOOM[0], h + ZOOM[1])


def _spectra(runs: Sequence[RunData]) -> tuple[dict, float | None, list[tuple[str, str]]]:
    """Branch-force spectra of the hold phase (whole record without one), per run and branch."""
    spectra, notes, fs = {}, [], None
    for r in runs:
        if r.t_vib is None:
            continue
        for b, f in r.forces_vib.items():
            sel = _finite_rows(f) & (r.t_vib >= (r.hold_start if r.hold_start is not None else -np.inf))
            t, x = r.t_vib[sel], f[sel]
            if len(t) < 8:
                continue
            try:
                freq, amp = metrics.spectrum(t, x)
            except ValueError:  # jittery stamps: resample on purpose, and say so
                rate = metrics.sample_rate(t)
                grid = np.arange(t[0], t[-1], 1.0 / rate)
                freq, amp = metrics.spectrum(grid, np.interp(grid, t, x))
                notes.append((r.label, f"spectrum {b}: non-uniform stamps, computed from linearly resampled data"))
            fs = fs or metrics.sample_rate(t)
            spectra[f"{r.label}: {b}" if len(runs) > 1 else b] = (freq, amp)
    return spectra, fs, notes


def write_plots(out: Path, runs: Sequence[RunData], natural_hz: Sequence[float],
                names: Mapping[str, str] = PLOT_NAMES) -> tuple[dict[str, str], list[tuple[str, str]]]:
    """The PNG figures of ``runs`` (all in one figure each); returns name -> file and (run, note)s."""
    files: dict[str, Path] = {}
    notes: list[tuple[str, str]] = []
    with_ee = [r for r in runs if r.ee is not None]
    ref_run = next((r for r in runs if r.ee_ref is not None), None)
    if with_ee:
        files["path"] = plots.plot_path(out / names["path"], {r.label: r.ee for r in with_ee},
                                        None if ref_run is None else ref_run.ee_ref)
    with_f = [r for r in runs if r.forces]
    if with_f:
        t_by, f_by = {}, {}
        for r in with_f:
            t_by[r.label], f_by[r.label] = r.t_force, r.forces
            if r.t_vib is not r.t_force and r.t_vib is not None:  # decimated: show the full-rate window too
                label = f"{r.label} (full rate)"
                t_by[label], f_by[label] = r.t_vib, r.forces_vib
        files["branch_forces"] = plots.plot_branch_forces(out / names["branch_forces"], t_by, f_by, zoom=_zoom(runs))
    with_gap = [r for r in runs if r.gap is not None]
    if with_gap:
        files["gap"] = plots.plot_gap(out / names["gap"], {r.label: r.t_gap for r in with_gap},
                                      {r.label: r.gap for r in with_gap})
    with_tau = [r for r in runs if r.torques]
    if with_tau:
        t_by, tau = {}, {}
        for r in with_tau:
            for n, x in r.torques.items():
                key = f"{r.label}: {n}" if len(runs) > 1 else n
                t_by[key], tau[key] = r.t_torque, x
        files["torques"] = plots.plot_torques(out / names["torques"], t_by, tau)
    with_w = next((r for r in runs if r.wrench is not None or r.wrench_true is not None), None)
    if with_w is not None:  # the first run that has one (an estimate or a plant's truth)
        files["wrench"] = plots.plot_wrench(
            out / names["wrench"], with_w.t_wrench if with_w.wrench is not None else with_w.t_wrench_true,
            with_w.wrench if with_w.wrench is not None else with_w.wrench_true, with_w.wrench_std,
            with_w.t_wrench_true if with_w.wrench is not None else None,
            with_w.wrench_true if with_w.wrench is not None else None, with_w.contacts)
    errs = {r.label: (r.t, r.ee - r.reference_at(r.t)) for r in with_ee if r.ee_ref is not None}
    if errs:
        files["tracking_error"] = plots.plot_tracking_error(
            out / names["tracking_error"], {k: v[0] for k, v in errs.items()}, {k: v[1] for k, v in errs.items()})
    spectra, fs, spec_notes = _spectra(runs)
    notes += spec_notes
    if spectra:
        where = "hold phase" if any(r.hold_start is not None for r in runs) else "whole record"
        files["spectrum"] = plots.plot_spectrum(out / names["spectrum"], spectra, f_model=list(natural_hz) or None,
                                                fs=fs, title=f"Branch forces, {where}: amplitude spectrum")
    if len(runs) > 1:
        files.update(_difference_plots(out, runs, names))
    return {k: v.name for k, v in files.items()}, notes


def _difference_plots(out: Path, runs: Sequence[RunData], names: Mapping[str, str]) -> dict[str, Path]:
    base, files = runs[0], {}
    t_by, d_by = {}, {}
    for r in runs[1:]:
        for b in base.forces:
            if b in r.forces and (d := _on_base(base.t_force, base.forces[b], r.t_force, r.forces[b])) is not None:
                key = f"{r.label} - {base.label}: {b}"
                t_by[key], d_by[key] = base.t_force, d
    if d_by:
        files["force_difference"] = plots.plot_tracking_error(
            out / names["force_difference"], t_by, d_by, quantity="branch force difference", unit="N",
            title="Difference between runs: branch forces")
    t_by, d_by = {}, {}
    for r in runs[1:]:
        if base.ee is not None and r.ee is not None and (d := _ee_difference(base, r)) is not None:
            key = f"|{r.label} - {base.label}|"
            t_by[key], d_by[key] = base.t, d
    if d_by:
        files["path_difference"] = plots.plot_tracking_error(
            out / names["path_difference"], t_by, d_by, quantity="end-effector distance between runs",
            title="Difference between runs: end-effector position")
    return files


# ----------------------------------------------------------------------------- output
def write_report(out: Path, runs: Sequence[RunData], info: ModelInfo, plots_on: bool = True,
                 names: Mapping[str, str] = PLOT_NAMES, extra: Mapping | None = None) -> AnalysisReport:
    """summary.json, summary.md and (``plots_on``) the plots of ``runs`` in ``out``; ``extra``: more
    top-level keys of summary.json (the report's ``extra``). Returns what summary.json holds."""
    out.mkdir(parents=True, exist_ok=True)
    q_hold = _hold_pose(runs[0])
    natural = info.natural_hz(q_hold)
    by_label = {r.label: run_metrics(r, natural) for r in runs}
    base = runs[0]
    comparison = [compare(base, r, by_label[base.label], by_label[r.label]) for r in runs[1:]] or None
    files = None
    if plots_on:
        files, notes = write_plots(out, runs, natural, names)
        for label, note in notes:
            by_label[label].warnings.append(note)
    for m in by_label.values():  # a null in summary.json is named, never silent
        m.warn_non_finite()
    report = AnalysisReport(model=str(info.path), model_natural_hz=natural,
                            natural_hz_at="hold pose of the first run" if q_hold is not None else "start pose",
                            runs=by_label, comparison=comparison, plots=files, extra=dict(extra or {}))
    content = report.to_dict()
    write_text(out / "summary.json", json.dumps(content, indent=2))
    write_text(out / "summary.md", markdown(content))
    return report


def _hold_pose(run: RunData) -> np.ndarray | None:
    if run.q is None or run.t is None or not len(run.t):
        return None
    at = run.hold_start if run.hold_start is not None else run.t[-1]
    k = int(np.clip(np.searchsorted(run.t, at), 0, len(run.t) - 1))
    return run.q[k] if np.all(np.isfinite(run.q[k])) else None


# ----------------------------------------------------------------------------- markdown
def _fmt(v: object, scale: float = 1.0, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        return f"{v * scale:.{digits}g}"
    return str(v)


def _get(m: Mapping, path: str) -> object:
    for key in path.split("/"):
        if not isinstance(m, Mapping) or key not in m:
            return None
        m = m[key]
    return m


def _metric_rows(runs: Mapping[str, dict]) -> list[tuple[str, list[object], float]]:
    """(row label, value per run, display scale) in a fixed order."""
    rows: list[tuple[str, str, float]] = [
        ("max end-effector error [µm]", "path/max_error_m", 1e6),
        ("RMS end-effector error [µm]", "path/rms_error_m", 1e6),
        ("max deviation from the path [µm]", "path/max_path_deviation_m", 1e6),
        ("RMS deviation from the path [µm]", "path/rms_path_deviation_m", 1e6),
        ("final position error [µm]", "path/final_position_error_m", 1e6),
    ]
    branches = list(dict.fromkeys(b for m in runs.values() for b in (_get(m, "branch_forces/peak_N") or {})))
    rows += [(f"peak branch force {b} [N]", f"branch_forces/peak_N/{b}", 1.0) for b in branches]
    vib = list(dict.fromkeys(b for m in runs.values() for b in (m.get("vibration") or {})))
    for b in vib:
        rows += [(f"residual vibration {b}: frequency [Hz]", f"vibration/{b}/f_d_hz", 1.0),
                 (f"residual vibration {b}: amplitude [N]", f"vibration/{b}/amplitude_N", 1.0),
                 (f"residual vibration {b}: damping ratio [-]", f"vibration/{b}/zeta", 1.0)]
    rows += [("max closure gap [m]", "gap/max_m", 1.0), ("final closure gap [m]", "gap/final_m", 1.0)]
    motors = list(dict.fromkeys(n for m in runs.values() for n in (_get(m, "torques/peak_Nm") or {})))
    rows += [(f"peak torque {n} [N m]", f"torques/peak_Nm/{n}", 1.0) for n in motors]
    rows += [("command age, max [ms]", "command_age/from_stamps/max_s", 1e3),
             ("command age reported by the plant, max [ms]", "command_age/reported_by_plant/max", 1e3),
             ("hold phase starts at [s]", "hold_phase/start_s", 1.0)]
    return [(label, [_get(m, path) for m in runs.values()], scale) for label, path, scale in rows
            if any(_get(m, path) is not None for m in runs.values())]


def markdown(summary: Mapping) -> str:
    runs: Mapping[str, dict] = summary["runs"]
    labels = list(runs)
    lines = ["# Run analysis", "", f"Model: `{summary['model']}`; elastic modes "
             + (", ".join(f"{f:.1f} Hz" for f in summary.get("model_natural_hz") or []) or "none")
             + f" (at the {summary.get('natural_hz_at', 'start pose')}).", ""]
    for label, m in runs.items():
        bag = m.get("bag")
        if bag:
            lines.append(f"- **{label}**: `{bag['path']}` ({bag['storage']}, {_fmt(bag['duration_s'])} s); "
                         f"time zero = {m['time_zero']['from']}; hold phase from "
                         f"{_fmt(m['hold_phase']['start_s'])} s ({m['hold_phase']['from'] or 'not found'})")
    lines += ["", "## Metrics", ""]
    two = len(labels) == 2
    head = ["metric", *labels] + ([f"{labels[1]} - {labels[0]}"] if two else [])
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, values, scale in _metric_rows(runs):
        cells = [_fmt(v, scale) for v in values]
        if two:
            a, b = values
            cells.append(_fmt(b - a, scale) if isinstance(a, (int, float)) and isinstance(b, (int, float))
                         and not isinstance(a, bool) else "-")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "End-effector error: distance to the reference at the same time (includes lag along the path, "
              "e.g. the half-sample delay of a zero-order-held feedforward); deviation from the path: distance "
              "to the reference path as a curve. Vibration: damped sinusoid fitted to the hold phase."]
    for comp in summary.get("comparison", []):
        if comp["series_difference"]:
            lines += ["", f"Time-series differences {comp['other']} - {comp['baseline']}: "
                      + ", ".join(f"{k} {_fmt(v)}" for k, v in comp["series_difference"].items())]
    lines += ["", "## Message streams", "",
              "| run | role | topic | messages | rate [Hz] | gaps | longest gap [ms] | p99 period [ms] | stamps |",
              "|---|---|---|---|---|---|---|---|---|"]
    for label, m in runs.items():
        for role, s in (m.get("streams") or {}).items():
            lines.append(f"| {label} | {role} | `{s['topic']}` | {s['messages']} | {_fmt(s['rate_hz'])} | "
                         f"{_fmt(s['gaps'])} | {_fmt(s['longest_gap_s'], 1e3)} | {_fmt(s['period_p99_s'], 1e3)} | "
                         f"{s['stamps']}{'' if s.get('exact', True) else ' (histogram)'} |")
    warnings = [(label, w) for label, m in runs.items() for w in m.get("warnings", [])]
    if warnings:
        lines += ["", "## Warnings", ""] + [f"- {label}: {w}" for label, w in warnings]
    if summary.get("plots"):
        lines += ["", "## Plots", ""] + [f"![{k}]({v})" for k, v in summary["plots"].items()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ analyze
def analyze(model: str | Path | Model | Mechanism, bags: str | Path | Sequence[str | Path], out: str | Path,
            topics: Mapping[str, str | None] | None = None, hold_start: float | None = None,
            labels: Sequence[str] | None = None, plots_on: bool = True, max_samples: int | None = None,
            window_samples: int | None = None) -> AnalysisReport:
    """``elastic-pm-dyn analyze``: one or more bags -> plots, summary.json, summary.md in ``out``.

    ``model`` first, as ``epd.simulate`` and ``epd.observe`` take it: a model file, a loaded Model
    or a Mechanism; ``bags``: one bag folder or a list of them (compared in one report).
    Returns the :class:`~elastic_pm_dyn.analysis.report_types.AnalysisReport` (summary.json as objects)."""
    from elastic_pm_dyn.analysis import bags as bagmod
    from elastic_pm_dyn.analysis.run_data import run_from_bag

    if isinstance(model, list | tuple):  # the order before the model came first: refused, never reinterpreted
        raise InputError("analyze takes the model first: analyze(model, bags, out) (a list of bags was given as "
                         "the model; or name them: analyze(bags=..., model=..., out=...))")
    bags = [bags] if isinstance(bags, str | Path) else list(bags)
    info = ModelInfo.load(model)
    labels = list(labels) if labels else _labels(bags)
    kw = {k: v for k, v in (("max_samples", max_samples), ("window_samples", window_samples)) if v}
    runs = []
    for bag, label in zip(bags, labels, strict=True):
        data = bagmod.read_bag(bag, topics, hold_start=hold_start, **kw)
        runs.append(run_from_bag(data, info, label, hold_start))
    with staged_files(out) as stage:  # every file, or none (and no folder made for them)
        return write_report(stage, runs, info, plots_on)


def _labels(bags: Sequence[str | Path]) -> list[str]:
    names = [Path(b).resolve().name for b in bags]
    if len(set(names)) < len(names):
        names = [f"{chr(65 + k)}: {n}" for k, n in enumerate(names)]
    return names
