"""The sensors' statistics: what became of each sample, and what that says of the filter's health.

Every measurement ends as an :class:`UpdateResult` (accepted, gated, late, ...) and is counted
in its sensor's :class:`SensorStats` (:func:`record`; :func:`record_accepted` for a run of
accepted ones from the offline fast path, the same sums in the same order). From the counts and
the windowed NIS: :func:`health` (one level and line for /diagnostics), :func:`nis_band` and
:func:`diagnostics` (the key/value pairs); :mod:`.consistency` names a far-off sensor's likely
cause.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from elastic_pm_dyn.observer.core.chi_square import chi2_quantile
from elastic_pm_dyn.observer.schedule import consistency
from elastic_pm_dyn.observer.schedule.sample_timing import TIMING_SWITCH_EVIDENCE

OK, WARN, ERROR = 0, 1, 2  # diagnostic levels (as diagnostic_msgs/DiagnosticStatus)
SENSOR_NAMES = ("encoders", "imu", "branch_forces", "command")  # Observer.stats' keys
LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass
class UpdateResult:
    """What became of one measurement."""

    sensor: str
    t: float
    accepted: bool
    nis: float = float("nan")
    dof: int = 0
    reason: str = ""  # "" (accepted) | gate | nan | late | future | frame | uninitialised | empty
    dropped: list[str] = field(default_factory=list)
    logdet: float = float("nan")  # log det S of the innovation covariance (with nis: the log-likelihood)


@dataclass
class SensorStats:
    accepted: int = 0
    rejected: int = 0  # gated out
    late: int = 0
    future: int = 0  # stamped more than timing.max_future ahead of the filter
    nan: int = 0  # NaN entries dropped
    other: int = 0  # wrong frame, before initialisation
    consecutive_rejections: int = 0
    last_nis: float = float("nan")
    last_reason: str = ""
    window: deque = field(default_factory=deque)  # (nis, dof) of recent accepted samples
    # Prediction-error negative log-likelihood of the samples weighed (accepted and gated; a
    # gated one counted at the gate): sum of (NIS + log det S + dof log 2 pi) / 2
    nll: float = 0.0
    nis_sum: float = 0.0  # NIS of the accepted samples, summed
    recoveries: int = 0  # re-initialisations from this sensor after a run of gated samples (schedule.recovery)
    # each weighed sample's (NIS, NLL term) in order, when a list (calibration's per-sample scores); None: not kept
    terms: list[tuple[float, float]] | None = None


def fresh_stats(keep_terms: bool = False) -> dict[str, SensorStats]:
    """New statistics; ``keep_terms``: each keeps its samples' NLL terms (``SensorStats.terms``)."""
    return {s: SensorStats(terms=[] if keep_terms else None) for s in SENSOR_NAMES}


def nll_term(nis: float, logdet: float, dof: int) -> float:
    """One sample's negative Gaussian log-likelihood (NIS + log det S + dof log 2 pi) / 2."""
    return 0.5 * (nis + logdet + dof * LOG_2PI)


def record(st: SensorStats, sensor: str, t: float, nis: float, gated: bool, dof: int, gate: float,
           dropped: list[str], logdet: float, window: int) -> UpdateResult:
    """Count a corrected sample (``gated``: its NIS beyond ``gate``, not used; ``window``: the
    NIS window's length) and say what became of it."""
    st.last_nis = nis
    if gated:
        st.rejected += 1
        st.consecutive_rejections += 1
        st.nll += nll_term(min(nis, gate), logdet, dof)
        if st.terms is not None:
            st.terms.append((min(nis, gate), nll_term(min(nis, gate), logdet, dof)))
        st.last_reason = f"gated out at t = {t:.6f} s: NIS {nis:.3g} > {gate:.3g} ({dof} dof)"
        return UpdateResult(sensor, t, False, nis, dof, "gate", dropped, logdet)
    st.accepted += 1
    st.consecutive_rejections = 0
    st.nll += nll_term(nis, logdet, dof)
    st.nis_sum += nis
    if st.terms is not None:
        st.terms.append((nis, nll_term(nis, logdet, dof)))
    st.window.append((nis, dof))
    if len(st.window) > window:
        st.window.popleft()
    return UpdateResult(sensor, t, True, nis, dof, "", dropped, logdet)


def record_accepted(st: SensorStats, nis: list[float], dof: int, logdet: list[float], window: int) -> None:
    """:func:`record` of consecutive accepted samples (the offline fast path; the same sums in the same order)."""
    if not nis:
        return
    st.last_nis = nis[-1]
    nll, nis_sum = st.nll, st.nis_sum
    for v, ld in zip(nis, logdet, strict=True):
        nll += nll_term(v, ld, dof)
        nis_sum += v
    st.nll, st.nis_sum = nll, nis_sum
    if st.terms is not None:
        st.terms.extend((v, nll_term(v, ld, dof)) for v, ld in zip(nis, logdet, strict=True))
    st.accepted += len(nis)
    st.consecutive_rejections = 0
    w = st.window
    w.extend((v, dof) for v in nis[-window - 1:])
    while len(w) > window:
        w.popleft()


def nis_findings(obs: Any) -> dict[str, str]:
    """Sensors whose windowed NIS is far off (or that are mostly gated out), each with one line
    naming its likely cause (:mod:`~elastic_pm_dyn.observer.schedule.consistency`)."""
    return consistency.findings(obs, TIMING_SWITCH_EVIDENCE)


def health(obs: Any) -> tuple[int, str]:
    """(level OK/WARN/ERROR, one line) of an Observer, for /diagnostics."""
    if obs.fault is not None:
        return ERROR, f"fault: {obs.fault}; reset needed"
    if not obs.initialised:
        return WARN, "waiting for a joint state with every motor position"
    findings = list(nis_findings(obs).values())  # a sensor far off, with its likely cause
    limit = obs.cfg.gating.max_consecutive_rejections
    for name, st in obs.stats.items():
        if st.consecutive_rejections >= limit:
            return ERROR, "; ".join([f"{name}: {st.consecutive_rejections} consecutive samples gated out "
                                     f"(last: {st.last_reason}); the estimate has diverged, reset needed",
                                     *findings])
    if findings:
        return WARN, "; ".join(findings)
    return OK, "tracking"


def nis_band(st: SensorStats, p: float = 0.95) -> tuple[float, float, float]:
    """Two-sided p band of a sensor's windowed mean NIS and its value (NaN if no samples)."""
    w = st.window
    if len(w) < 10:
        return float("nan"), float("nan"), float("nan")
    total = sum(n for n, _ in w)
    dof = sum(d for _, d in w)
    lo, hi = chi2_quantile((1 - p) / 2, dof) / len(w), chi2_quantile((1 + p) / 2, dof) / len(w)
    return float(lo), float(hi), float(total / len(w))


def diagnostics(obs: Any) -> dict[str, str]:
    """Key/value pairs of an Observer for diagnostic_msgs/KeyValue: counts and NIS statistics per sensor."""
    out = {"time": f"{obs.t:.6f}"}
    for name, st in obs.stats.items():
        out[f"{name}.accepted"] = str(st.accepted)
        out[f"{name}.rejected"] = str(st.rejected)
        out[f"{name}.late"] = str(st.late)
        out[f"{name}.future"] = str(st.future)
        out[f"{name}.nan_entries"] = str(st.nan)
        if st.recoveries:
            out[f"{name}.recoveries"] = str(st.recoveries)
        if st.window:
            lo, hi, mean = obs.nis_band(name)
            out[f"{name}.nis_last"] = f"{st.last_nis:.4g}"
            out[f"{name}.nis_mean"] = f"{mean:.4g}"
            out[f"{name}.nis_band95"] = f"[{lo:.4g}, {hi:.4g}]"
        if st.last_reason:
            out[f"{name}.last_rejection"] = st.last_reason
    for name, text in obs.nis_findings().items():
        out[f"{name}.nis_diagnosis"] = text
    if obs.imu is not None:
        out["imu.sample_timing"] = obs.sample_timing()
        d = obs.timing_last
        if d is not None:
            out["imu.sample_timing_check"] = d.text()
    if obs.recoveries:
        out["recovery_last"] = obs.recoveries[-1].text()
    out["command_delay"] = f"{obs.delay:g}"
    out["process.dt_in_use"] = f"{obs.dt:g}"
    return out
