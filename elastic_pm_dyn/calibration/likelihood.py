"""The likelihood of recordings under a model: the observer's innovations, sample by sample.

For a candidate model the EKF (built on that model, so its prediction is the candidate's SCDD
dynamics, eqs 33-41) runs over each recording with the gate off, and every sensor sample's
negative log-likelihood term l_k = (r_k^T S_k^-1 r_k + log det S_k + m_k log 2 pi) / 2 is kept
(``SensorStats.terms``): the prediction-error criterion ``tune`` minimises over the noise
model, here over the physics. Kept per sample, not summed, because the fit's Fisher information
is the outer product of the per-sample scores (:mod:`.fit`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.drivers.bag_input import Event, Topics, read_events
from elastic_pm_dyn.observer.drivers.event_filter import order_key, run_events
from elastic_pm_dyn.observer.drivers.prepared import prepare
from elastic_pm_dyn.observer.schedule.observer import Observer

MIN_SECONDS = 0.1  # [s] of a recording: fewer periods fit nothing


@dataclass(frozen=True)
class Recording:
    """One bag's observer input, in stamp order."""

    label: str
    events: list[Event]

    @property
    def seconds(self) -> float:
        return (self.events[-1].stamp_ns - self.events[0].stamp_ns) * 1e-9 if self.events else 0.0


def read_recording(bag: str | Path, cfg: ObserverConfig, seconds: float | None = None) -> Recording:
    """The events of ``bag`` on the observer's topics (the first ``seconds`` if given)."""
    events, _ = read_events(Path(bag), Topics.from_config(cfg), cfg)
    events = sorted(events, key=order_key)
    if seconds is not None and events:
        end = events[0].stamp_ns + round(seconds * 1e9)
        events = [e for e in events if e.stamp_ns <= end]
    rec = Recording(str(bag), events)
    if rec.seconds < MIN_SECONDS:
        raise InputError(f"{bag}: {rec.seconds:g} s of observer input; calibration needs at least {MIN_SECONDS:g} s")
    return rec


@dataclass
class Score:
    """One pass of the filter over every recording under one model."""

    terms: np.ndarray  # per-sample NLL terms, recordings and sensors in a fixed order
    nis: np.ndarray  # per-sample NIS r^T S^-1 r, in the same order
    nll: float
    per_sensor: dict[str, dict]  # sensor -> {samples, nll, mean_nis_per_dof}
    fault: str
    # (recording, its duration [s], terms) of each consecutive block of ``terms``: one sensor of
    # one recording, its samples evenly spread over the recording (the robust covariance's time axis)
    segments: list[tuple[int, float, int]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.fault and math.isfinite(self.nll)


def score(model: Model, cfg: ObserverConfig, recordings: Sequence[Recording]) -> Score:
    """The filter of ``cfg`` on ``model`` over ``recordings`` (module docstring)."""
    mech = Mechanism(model)
    parts, per, faults, segments = [], {}, [], []
    for ri, rec in enumerate(recordings):
        prep = prepare(mech, cfg, rec.events)
        obs = Observer(prep.model, cfg, t0=0.0)
        obs.gating = False  # a candidate must not win by throwing samples away
        obs.keep_terms = True
        for s in cfg.sensors:
            obs.stats[s].terms = []
        try:
            _, _, fault = run_events(obs, rec.events, "arrival", origin_ns=prep.origin_ns, runs=prep.runs)
        except (FloatingPointError, np.linalg.LinAlgError, ValueError) as exc:  # a model the filter cannot run
            fault = f"{type(exc).__name__}: {exc}"
        if fault:
            faults.append(f"{rec.label}: {fault}")
        for s in cfg.sensors:
            st = obs.stats[s]
            parts.append(np.asarray(st.terms, dtype=float).reshape(-1, 2))
            segments.append((ri, rec.seconds, len(parts[-1])))
            d = per.setdefault(s, {"samples": 0, "nll": 0.0, "nis": 0.0, "dof": 0.0})
            d["samples"] += st.accepted
            d["nll"] += st.nll
            d["nis"] += st.nis_sum
            d["dof"] += sum(x for _, x in st.window) / len(st.window) * st.accepted if st.window else 0.0
    for d in per.values():
        d["mean_nis_per_dof"] = d["nis"] / d["dof"] if d["dof"] else float("nan")
    both = np.concatenate(parts) if parts else np.zeros((0, 2))
    nll = float(both[:, 1].sum()) if len(both) else float("nan")
    return Score(both[:, 1].copy(), both[:, 0].copy(), nll, per, "; ".join(faults), segments)
