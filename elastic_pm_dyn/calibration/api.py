"""``calibrate``: a model file's physical parameters fitted to recordings, with what the fit knows.

Maximum likelihood through the observer's innovations (the prediction-error method, as ``tune``
but over the model): :mod:`.likelihood` scores a model, :mod:`.fit` searches, first on the
first :data:`COARSE_SECONDS` of every recording (far from the optimum a short recording points the
same way at a fraction of the cost), then on all of it. Why not output error (the model simulated
open loop under the recorded torques, its outputs against the samples): an unknown torque of a
few 0.01 N m moves the free rigid motion away within tenths of a second, and a spring mode a few
percent off drifts out of phase within a few periods, so the output error of a vibrating
machine is many-valleyed in the stiffness; the filter's one-period predictions keep the rigid
motion on the encoders (its disturbance states take the unknown torques) and leave each period's
spring motion to be predicted by the candidate (bench/calibration/README.md measures both).

The result: the values with standard deviations and correlations from the Fisher information,
the parameters the recordings do not excite (left at the file's values), the innovations and
the elastic modes before and after, and the calibrated model file.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from elastic_pm_dyn.calibration.fit import RADIUS_START, FitResult, fit, hessian_at
from elastic_pm_dyn.calibration.identifiability import (
    Identifiability,
    identifiability,
    sandwich,
    score_covariance,
    unexcited,
)
from elastic_pm_dyn.calibration.likelihood import Recording, Score, read_recording, score
from elastic_pm_dyn.calibration.parameters import ModelFile, Parameter, available, dump, select
from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.dynamics.statics import rest_state
from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.observer.cli import DEFAULT_CONFIG
from elastic_pm_dyn.observer.config import ObserverConfig, load_config
from elastic_pm_dyn.output_files import write_text

COARSE_SECONDS = 1.0  # [s] of each recording in the first stage
MAX_PASSES = 120  # filter passes of each stage at most
COARSE_TOL = 5.0  # [nats] the coarse stages stop when a step gains less, or ...
COARSE_REL_TOL = 1e-3  # ... less than this share of the NLL (a stage-1 optimum is not the final one)
FINE_PASSES = 2  # Gauss-Newton iterations at most on the whole recordings after the coarse stages
FINE_RADIUS = 0.005  # [log ratio] the second stage's first trust radius: the first stage is that close


@dataclass
class Calibration:
    params: list[Parameter]
    nominal: np.ndarray  # the file's values
    values: np.ndarray  # the calibrated ones
    ident: Identifiability  # std, correlations, what is not excited
    before: Score  # the filter under the file's model, over all recordings
    after: Score
    modes_before: np.ndarray  # [Hz] elastic modes at the start pose, motors clamped
    modes_after: np.ndarray
    fixed: list[str]  # parameters left at the file's values (not excited)
    stages: list[FitResult] = field(default_factory=list)
    wall_s: float = 0.0
    data: dict = field(default_factory=dict)  # the calibrated model file's data
    source: str = ""

    @property
    def model(self) -> Model:
        from elastic_pm_dyn.calibration.parameters import model_of
        return model_of(self.data, self.source)

    def as_dict(self) -> dict:
        """Everything reported, JSON-ready."""
        return {
            "parameters": [{"name": p.name, "file": float(a), "calibrated": float(b), "std": float(s),
                            "std_relative": float(s / b) if b else math.nan, "std_fisher": float(sf),
                            "fixed": p.name in self.fixed}
                           for p, a, b, s, sf in zip(self.params, self.nominal, self.values, self.ident.std,
                                                     self.ident.std_fisher, strict=True)],
            "covariance": self.ident.covariance,
            "correlations": self.ident.correlation.tolist(),
            "not_excited": self.ident.findings,
            "nll": {"before": self.before.nll, "after": self.after.nll},
            "sensors": {s: {"before": self.before.per_sensor[s], "after": self.after.per_sensor.get(s, {})}
                        for s in self.before.per_sensor},
            "modes_hz": {"before": self.modes_before.tolist(), "after": self.modes_after.tolist()},
            "passes": sum(r.passes for r in self.stages), "wall_s": self.wall_s,
        }


def modes_of(model: Model) -> np.ndarray:
    """The elastic modes [Hz] at the model's start pose, motors clamped (``check``'s)."""
    mech = Mechanism(model)
    if not len(mech.elastic):
        return np.zeros(0)
    return np.sort(elastic_modes(mech, rest_state(mech), clamp_motors=True).natural_hz)


def calibrate(model: str | Path, bags: Sequence[str | Path], out: str | Path | None = None,
              params: Sequence[str] | None = None, config: str | Path | ObserverConfig | None = None,
              sensors: Sequence[str] | None = None, seconds: float | None = None, max_passes: int = MAX_PASSES,
              threads: int = 2, log: Callable[[str], object] = print) -> Calibration:
    """Fit ``params`` (names, groups or patterns of :mod:`.parameters`; None: stiffness, damping,
    payload mass, friction) of the model YAML ``model`` to the recordings ``bags``; write the
    calibrated model YAML to ``out`` if given. ``config``: the observer's parameters (a file or an
    ObserverConfig; tune them first for the best result), ``sensors`` overrides its sensor set."""
    wall = time.perf_counter()
    mf = ModelFile.read(model)
    chosen = select(available(mf), params)
    cfg = _config(config, sensors)
    if not bags:
        raise InputError("calibrate needs at least one recording (--bag)")
    if not 8 <= max_passes <= 100_000:
        raise InputError(f"--max-passes must be 8 to 100000, got {max_passes}")
    recordings = [read_recording(b, cfg, seconds) for b in bags]
    coarse = [_first(r, COARSE_SECONDS) for r in recordings]
    nominal = np.array([p.nominal for p in chosen])

    def evaluator(recs: list[Recording]) -> Callable[[np.ndarray], Score]:
        def evaluate(theta: np.ndarray) -> Score:
            try:
                return score(mf.model(chosen, nominal * np.exp(theta)), cfg, recs)
            except ElasticPmDynError as exc:  # a parameter set the model's checks (or its assembly) refuse
                return Score(np.zeros(0), np.zeros(0), math.inf, {}, str(exc))
        return evaluate

    log(f"calibrating {len(chosen)} parameters ({', '.join(p.name for p in chosen)}) on "
        f"{sum(r.seconds for r in recordings):.3g} s of {len(recordings)} recording(s)")
    fixed = unexcited(evaluator(coarse), len(chosen), threads)
    if fixed:
        log("  not excited, kept at the file's values: " + ", ".join(chosen[i].name for i in fixed))
    stages = []
    theta = np.zeros(len(chosen))
    long = any(r.seconds > 1.5 * COARSE_SECONDS for r in recordings)
    for k, (what, held) in enumerate(coarse_stages(chosen, long), start=1):
        log(f"stage {k}: {what}, on the first {COARSE_SECONDS:g} s of each recording")
        stages.append(fit(evaluator(coarse), len(chosen), theta, max_passes, tol=COARSE_TOL, rel_tol=COARSE_REL_TOL,
                          threads=threads, log=log, fixed=sorted(set(fixed) | set(held))))
        theta = stages[-1].theta
    # the last stage on all the data: a few steps from near the optimum, and the information there
    log(f"stage {len(stages) + 1}: every parameter, the whole recordings")
    n = len(chosen)
    budget = min(max_passes, n + 1 + FINE_PASSES * (n + 3)) if long else max_passes
    stages.append(fit(evaluator(recordings), n, theta, budget, tol=0.5, threads=threads, log=log, fixed=fixed,
                      radius=FINE_RADIUS if long else RADIUS_START))
    final = stages[-1]
    values = nominal * np.exp(final.theta)
    # the standard deviations: the sandwich of the NLL's Hessian and the scores' autocovariance
    # (the filter's noise model is not the data's: identifiability.py, bench/calibration/README.md)
    free = np.array([i for i in range(n) if i not in set(fixed)], dtype=np.int64)
    log(f"standard deviations: the NLL's Hessian ({len(free) * (len(free) + 1) // 2} passes)")
    ev_all = evaluator(recordings)
    with ThreadPoolExecutor(max(1, threads)) as pool:
        A = hessian_at(lambda pts: list(pool.map(ev_all, pts)), final.theta, free, n, final.score, final.scores)
    robust = sandwich(A, score_covariance(final.scores, final.score.segments), free)
    if robust is None:
        log("  the Hessian is not positive definite there: standard deviations from the Fisher information")
    ident = identifiability(final.information, values, [p.name for p in chosen], fixed, robust)
    before = evaluator(recordings)(np.zeros(len(chosen)))
    data = mf.with_values(chosen, values)
    res = Calibration(chosen, nominal, values, ident, before, final.score, modes_of(mf.model(chosen, nominal)),
                      modes_of(mf.model(chosen, values)), [chosen[i].name for i in fixed], stages,
                      time.perf_counter() - wall, data, str(out or "<calibrated>"))
    if out is not None:
        write_model(res, out, mf.path)
    return res


def coarse_stages(chosen: Sequence[Parameter], long: bool) -> list[tuple[str, list[int]]]:
    """The stages on the first second, each as (what, indices held at their current values).

    With its modes off, the filter likes a model that dissipates the vibration it cannot predict:
    from the file's values with everything free, the five-bar's dampers ran away (x6) and its payload
    (x4) before the springs moved, and the Triglide's drive friction (x0.05) kept its modes 7 % off.
    So the springs first, alone (each mode is mostly one spring's), then everything but friction,
    then (on a long recording, whose last stage would otherwise start far) everything."""
    n = len(chosen)
    springs = {i for i, p in enumerate(chosen) if p.group == "stiffness"}
    friction = {i for i, p in enumerate(chosen) if p.group == "friction"}
    out = []
    if springs and len(springs) < n:
        out.append(("the springs alone", sorted(set(range(n)) - springs)))
    if friction and len(friction) < n:
        out.append(("every parameter but friction", sorted(friction)))
    if long or (friction and len(friction) < n):
        out.append(("every parameter", []))
    return out


def write_model(res: Calibration, out: str | Path, source: str) -> Path:
    """The calibrated model YAML: the source file's data with the fitted values, and a header
    saying what was fitted (complete or not at all)."""
    head = [f"# {Path(source).name} calibrated by `elastic-pm-dyn calibrate` (maximum innovation likelihood)"]
    for p, a, b, s in zip(res.params, res.nominal, res.values, res.ident.std, strict=True):
        note = " (not excited: the file's value)" if p.name in res.fixed else f" +- {s:.3g}"
        head.append(f"#   {p.name}: {a:.6g} -> {b:.6g}{note}")
    out = Path(out)
    write_text(out, dump(res.data, "\n".join(head) + "\n"))
    return out


def _first(rec: Recording, seconds: float) -> Recording:
    end = rec.events[0].stamp_ns + round(seconds * 1e9)
    return Recording(rec.label, [e for e in rec.events if e.stamp_ns <= end])


def _config(config: str | Path | ObserverConfig | None, sensors: Sequence[str] | None) -> ObserverConfig:
    """The observer's parameters: ``config`` (default: the package's config/observer.yaml, as ``tune``)."""
    if not isinstance(config, ObserverConfig):
        config = load_config(config if config is not None else DEFAULT_CONFIG if DEFAULT_CONFIG.exists() else None)
    if sensors:
        config = ObserverConfig.from_parameters(dict(config.parameters, sensors=list(sensors)), "<calibrate>")
    return config
