"""Tuning the observer from a recording without truth: maximum innovation likelihood.

The prediction-error method: for a candidate configuration theta the filter runs over the
recording and its innovations r_k (covariance S_k, m_k components) give the negative
log-likelihood

    NLL(theta) = sum_k (r_k^T S_k^-1 r_k + log det S_k + m_k log 2 pi) / 2

over every sensor sample (the filter reports NIS and log det S per sample:
``correction.kalman_update_ld``, ``SensorStats.nll``). A Kalman filter whose noise model is the
data's whitens the innovations and minimises it; it needs nothing but the recording. Gating
is off while tuning (``Observer.gating``), so a candidate cannot win by throwing samples away.

What is tuned (:func:`knobs`): the process noise and the disturbance spectrum
(``process.disturbance_stddev``, the ``process.disturbance_bandwidth`` corners,
``process.disturbance_intensity``, ``process.torque_noise_psd``; see :data:`PROCESS_KNOBS`),
and, where the base configuration leaves them at their defaults, the sensor noise levels
(``encoders.position_stddev``, ``imu.stddev``). Every knob in log space within bounds, by a
compass (coordinate) search: each sweep tries every knob one step up and one step down,
the two trials of a knob at once in two threads (the compiled filter kernel releases the
GIL), keeps what lowers the NLL by at least :data:`MIN_GAIN` and halves the step after a
sweep without gain, until the step is small or the budget is spent; first the disturbance
spectrum alone from factors of 10, then every knob from smaller steps (sensor noise and
white torque noise tuned from the start end in worse optima). The compass starts in the basin
a coarse grid finds (:func:`_grid`: the band's top corner over its whole range, the levels a
decade either way, judged on the first second): from the defaults alone it can end in a worse
optimum. ``command_delay`` (the filter is very sensitive to it)
is chosen first by a likelihood scan over 0, 1/2, ..., 2 periods, and checked again at the
end with the tuned noise.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model import yaml12
from elastic_pm_dyn.observer.config import BAND_MODELS, BAND_ORDERS, DEFAULT_PARAMETERS, PREFIX, ObserverConfig, flatten
from elastic_pm_dyn.observer.drivers.bag_input import Event
from elastic_pm_dyn.observer.drivers.event_filter import order_key, run_events
from elastic_pm_dyn.observer.drivers.prepared import PreparedRecording, prepare
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.sim.integrators import METHODS

FAILED_NLL = 1e30  # a candidate whose filter faulted
# A step is kept only if it gains this much log-likelihood [nats]: smaller gains are within
# what chance gives one more free parameter (a likelihood-ratio test at ~5 %), and the
# default stays where the recording does not tell
MIN_GAIN = 2.0
DELAY_STEPS = (0.0, 0.5, 1.0, 1.5, 2.0)  # [periods] of the command-delay scan
CORNER_FACTORS = (1.0, 1.4, 2.0, 2.8, 4.0)  # top corner of another band order, times the fitted one
# The coarse grid that picks the disturbance spectrum's basin before the compass search: the
# top band corner over the whole tunable range, the band order, the stddev a decade either
# side of the base's (the user's guess, else the default). Judged on the first GRID_SECONDS only: the grid
# picks a basin, the compass on the whole recording finds its optimum.
GRID_TOPS = (5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0)  # [Hz]
GRID_LEVELS = (0.1, 1.0, 10.0)  # times the base's disturbance stddev
GRID_SECONDS = 1.0
GRID_FINALISTS = 3  # the grid's likeliest, judged again on the whole recording
# The search's RK4 substep at least this [s] (process.integrator rk4; ETD2 searches at its own
# step); the tuned file keeps process.dt as it was (0: from the model), and the NLL before /
# after are the model's own step's
SEARCH_DT = 1e-4


@dataclass(frozen=True)
class Knob:
    """One tuned parameter in log space: ``index`` picks an entry of a list parameter (the
    bandwidth corners), None a scalar (a list parameter with one value is set to that value)."""

    name: str
    lo: float
    hi: float
    index: int | None = None

    @property
    def label(self) -> str:
        return self.name if self.index is None else f"{self.name}[{self.index}]"

    def get(self, params: Mapping[str, Any]) -> float:
        v = params[self.name]
        if isinstance(v, list):
            return float(v[self.index or 0])
        return float(v)

    def set(self, params: dict[str, Any], value: float) -> None:
        value = float(min(max(value, self.lo), self.hi))
        if self.index is not None:
            v = list(params[self.name])
            v[self.index] = value
            params[self.name] = v
        elif isinstance(DEFAULT_PARAMETERS[self.name], list):
            params[self.name] = [value]
        else:
            params[self.name] = value


# Bounds: wide enough for any machine we know of, narrow enough that the filter stays sane.
# process.elastic_force_psd and process.vibration_noise are not tuned: on the test recordings
# (0.02-0.1 N m disturbances) 100x less of either changes neither the likelihood nor the
# estimates (the disturbance states carry the spring modes' uncertainty).
PROCESS_KNOBS = {
    "process.disturbance_stddev": (1e-4, 2.0),  # [N m]
    "process.disturbance_intensity": (1e-9, 1e2),  # [(N m)^2/s]
    "process.torque_noise_psd": (1e-14, 1e-4),  # [(N m)^2 s]
}
BANDWIDTH_BOUNDS = (0.2, 400.0)  # [Hz]
DISTURBANCE_KNOBS = ("process.disturbance_stddev", "process.disturbance_intensity", "process.disturbance_bandwidth")
SENSOR_KNOBS = {"encoders.position_stddev": ("encoders", (1e-7, 1e-2)), "imu.stddev": ("imu", (1e-4, 5.0))}


def knobs(cfg: ObserverConfig, explicit: set[str]) -> list[Knob]:
    """The parameters tuned for ``cfg`` (module docstring); sensor noise only where not in ``explicit``
    and the sensor is used, the disturbance's only for the disturbance model that has them."""
    out = []
    model = cfg.process.disturbance
    for name, (lo, hi) in PROCESS_KNOBS.items():
        if name == "process.disturbance_stddev" and model not in (*BAND_MODELS, "gauss_markov"):
            continue
        if name == "process.disturbance_intensity" and model not in ("bias_band_limited", "random_walk",
                                                                     "integrated_random_walk"):
            continue
        out.append(Knob(name, lo, hi))
    if model in BAND_MODELS:
        out += [Knob("process.disturbance_bandwidth", *BANDWIDTH_BOUNDS, index=i)
                for i in range(len(cfg.process.disturbance_bandwidth))]
    for name, (sensor, (lo, hi)) in SENSOR_KNOBS.items():
        if sensor in cfg.sensors and name not in explicit and len(cfg.parameters[name]) == 1:
            out.append(Knob(name, lo, hi))
    return out


@dataclass
class Evaluation:
    """One filter pass over the recording."""

    nll: float
    per_sensor: dict[str, dict]  # sensor -> {samples, nll, mean_nis_per_dof, gated}
    fault: str
    wall_s: float


def evaluate(mech: Mechanism, params: Mapping[str, Any], events: list[Event], gating: bool = False,
             prepared: PreparedRecording | None = None) -> Evaluation:
    """The filter with flat ``params`` over ``events`` (in stamp order, :func:`select`): the NLL of every sensor
    sample (gating off unless ``gating``), per sensor its share, mean NIS / dof and gated count. ``prepared``:
    the fixed observer model and the fast path's input of these events (:func:`~.prepared.prepare`), made
    here if None; ``tune`` makes it once for all its passes."""
    wall = time.perf_counter()
    cfg = ObserverConfig.from_parameters(params, "<tuning>")
    prep = prepare(mech, cfg, events) if prepared is None else prepared
    obs = Observer(prep.model, cfg, t0=0.0)
    obs.gating = gating
    _, _, fault = run_events(obs, events, "arrival", origin_ns=prep.origin_ns, runs=prep.runs)
    per, total = {}, 0.0
    for s in cfg.sensors:
        st = obs.stats[s]
        n = st.accepted + st.rejected
        dof = sum(d for _, d in st.window) / len(st.window) if st.window else float("nan")
        per[s] = {"samples": n, "nll": st.nll, "gated": st.rejected,
                  "mean_nis_per_dof": st.nis_sum / st.accepted / dof if st.accepted else float("nan")}
        total += st.nll
    if fault or not math.isfinite(total):
        total = FAILED_NLL
    return Evaluation(total, per, fault, time.perf_counter() - wall)


@dataclass
class TuneResult:
    params: dict[str, Any]  # the tuned flat parameters (without the prefix)
    base: dict[str, Any]
    before: Evaluation
    after: Evaluation
    gated_before: Evaluation  # the passes with the gate on, as observe runs
    gated_after: Evaluation
    changed: dict[str, tuple[Any, Any]]  # name -> (base, tuned)
    evaluations: int
    wall_s: float
    history: list[tuple[str, float]] = field(default_factory=list)  # (what, NLL) of each kept step


def period_of(events: list[Event]) -> float:
    """The median step between joint-state stamps [s] (the command period)."""
    ns = np.array([e.stamp_ns for e in events if e.kind == "joint_state"], dtype=np.int64)
    if len(ns) < 2:
        raise InputError("tuning needs at least two joint states")
    return float(np.median(np.diff(ns))) * 1e-9


def select(events: list[Event], seconds: float | None) -> list[Event]:
    """The events in stamp order, only the first ``seconds`` if given."""
    ev = sorted(events, key=order_key)
    if seconds is not None and ev:
        end = ev[0].stamp_ns + round(seconds * 1e9)
        ev = [e for e in ev if e.stamp_ns <= end]
    return ev


def tune(mech: Mechanism, base: ObserverConfig, events: list[Event], explicit: set[str] | None = None,
         delay: bool = True, max_evaluations: int = 160, min_step: float = 0.1, threads: int = 2,
         log: Callable[[str], object] = print, grid: bool = True) -> TuneResult:
    """Maximum-likelihood tuning of ``base`` on ``events`` (module docstring). ``explicit``: flat
    names the user set (their sensor noise is kept); ``delay``: scan ``command_delay``;
    ``min_step``: the smallest log step (0.1: about 10 %); ``max_evaluations``: filter passes in all
    (the grid's short passes not counted); ``grid``: start from the grid's basin (:func:`_grid`)."""
    wall0 = time.perf_counter()
    explicit = set(explicit or ())
    if not events:
        raise InputError("no messages on the observer's topics")
    base_params = dict(base.parameters)
    theta = dict(base_params)
    count = [0]
    prepared = prepare(mech, base, events)  # the tuned knobs leave the observer model as it is
    pool = ThreadPoolExecutor(max(1, threads))

    # The search ranks noise models at a substep of at least SEARCH_DT; the result is judged at
    # the model's own (process.dt: 0 halves it for fast spring modes, which doubles every pass).
    # ETD2's own step is set by the springs' coupling, not their stability: searched as it is.
    integrator = METHODS[base.process.integrator]
    fine_dt = prepared.model.mean_step(integrator, base.process.dt, base.process.max_interval)
    search = {"process.dt": SEARCH_DT} if (not integrator.exponential and fine_dt < SEARCH_DT
                                           and "process.dt" not in explicit) else {}

    def passes(params_list: list[dict], evs: list[Event] = events,
               prep: PreparedRecording = prepared) -> list[Evaluation]:
        """Filter passes over ``evs`` at the search's substep, two at once."""
        return list(pool.map(lambda p: evaluate(mech, dict(p, **search), evs, prepared=prep), params_list))

    def run(params_list: list[dict]) -> list[Evaluation]:
        count[0] += len(params_list)
        return passes(params_list)

    try:
        before = run([theta])[0]  # alone: compiles and caches the kernels once
        log(f"base: NLL {before.nll:.6g} ({before.wall_s:.2f} s per pass"
            + (f"; the search at a {SEARCH_DT:g} s substep, the result at {fine_dt:g} s)" if search else ")"))
        best = before
        history = [("base", before.nll)]
        if delay:
            best, theta = _scan_delay(run, theta, events, best, history, log)
        ks = knobs(base, explicit)
        first = [k for k in ks if k.name in DISTURBANCE_KNOBS]
        band = base.process.disturbance in BAND_MODELS
        orders = BAND_ORDERS if band and "process.disturbance_band_order" not in explicit else ()
        if band and grid:
            short = select(events, GRID_SECONDS)
            best, theta = _grid(run, lambda ps: passes(ps, short, prepare(mech, base, short)), theta, best, first,
                                orders, history, log)
        # passes kept for the end: the delay checked again, the two with the gate on (and two at the fine step)
        budget = max_evaluations - (len(DELAY_STEPS) - 1 if delay else 0) - (4 if search else 2)
        # First the disturbance spectrum alone, from factors of 10, then every knob from a factor
        # of ~1.8: tried together from the start, the sensor noise and the white torque noise
        # take what the disturbance band should explain and the search ends in a worse optimum.
        best, theta = _compass(run, count, theta, best, first, math.log(10.0), 2 * min_step,
                               min(budget, count[0] + (2 * budget) // 3), history, log)
        if first and orders:
            best, theta = _band_order(run, theta, best, history, log)
        best, theta = _compass(run, count, theta, best, ks, math.log(10.0) / 4, min_step, budget, history, log)
        if delay:
            best, theta = _scan_delay(run, theta, events, best, history, log)
        # the gate on, as observe runs: what the tuning does to the gated counts; and, if the
        # search ran at a coarser substep, the likelihoods at the model's own
        final = [(base_params, True), (theta, True)] + ([(base_params, False), (theta, False)] if search else [])
        judged = list(pool.map(lambda pg: evaluate(mech, pg[0], events, gating=pg[1], prepared=prepared), final))
        g_before, g_after = judged[:2]
        if search:
            before, best = judged[2:]
        count[0] += len(final)
    finally:
        pool.shutdown()
    changed = {name: (base_params[name], theta[name]) for name in theta if theta[name] != base_params[name]}
    return TuneResult(theta, base_params, before, best, g_before, g_after, changed, count[0],
                      time.perf_counter() - wall0, history)


def _grid(run, run_short, theta: dict, best: Evaluation, first: list[Knob], orders: tuple[int, ...],
          history: list, log) -> tuple[Evaluation, dict]:
    """Start the search in the likeliest basin: the band's top corner (:data:`GRID_TOPS`, the other
    corners scaled with it), the disturbance stddev (:data:`GRID_LEVELS`) and the band ``orders``
    on a coarse grid, each point judged on the first :data:`GRID_SECONDS` of the recording
    (``run_short``), the :data:`GRID_FINALISTS` likeliest on all of it (``run``); one is kept if it
    gains :data:`MIN_GAIN` over ``best``. Without it the compass, started from the defaults, can
    walk into a worse optimum (a random walk of large intensity explaining tones at 20-100 Hz
    through a band that ends at 5 Hz, 200 nats less likely than the tones' band; a second-order
    band where a fourth-order one at another corner is 100 nats likelier)."""
    def top_corner(p: dict, top: float) -> None:  # the other corners keep their ratios to it
        corners = theta["process.disturbance_bandwidth"]
        lo, hi = BANDWIDTH_BOUNDS
        p["process.disturbance_bandwidth"] = [float(min(max(c * top / max(corners), lo), hi)) for c in corners]

    def order(p: dict, value: int) -> None:
        p["process.disturbance_band_order"] = value

    axes = [[(order, o) for o in orders]] if orders else []
    for k in first:
        if k.name == "process.disturbance_bandwidth" and k.index == int(np.argmax(theta[k.name])):
            axes.append([(top_corner, top) for top in GRID_TOPS])
        elif k.name == "process.disturbance_stddev":
            axes.append([(k.set, k.get(theta) * f) for f in GRID_LEVELS])
    trials = []
    for point in itertools.product(*axes):
        p = dict(theta)
        for set_value, value in point:
            set_value(p, value)
        if _valid(p) and p not in trials:
            trials.append(p)
    coarse = [r.nll for r in run_short(trials)]
    finalists = [trials[i] for i in np.argsort(coarse)[:GRID_FINALISTS]]
    results = run(finalists)
    log(f"  grid of {len(trials)} spectra on the first {GRID_SECONDS:g} s; finalists: "
        + ", ".join(f"order {p['process.disturbance_band_order']} to {max(p['process.disturbance_bandwidth']):.4g} Hz"
                    f" stddev {p.get('process.disturbance_stddev', float('nan')):.3g}: NLL {r.nll:.6g}"
                    for p, r in zip(finalists, results, strict=True)) + f" (now {best.nll:.6g})")
    return _likeliest(finalists, results, best, theta, history, "process.disturbance_bandwidth")


def _compass(run, count: list, theta: dict, best: Evaluation, ks: list[Knob], step: float, min_step: float,
             budget: int, history: list, log) -> tuple[Evaluation, dict]:
    """Compass search: each sweep tries every knob ``step`` up and down in log space (the two
    trials at once), keeps a trial that gains :data:`MIN_GAIN`, halves the step after a sweep
    without gain; until the step is below ``min_step`` or ``budget`` passes are done."""
    while ks and step >= min_step and count[0] + 2 <= budget:
        improved = False
        for k in ks:
            if count[0] + 2 > budget:
                break
            x = math.log(k.get(theta))
            trials = []
            for sgn in (1.0, -1.0):
                value = math.exp(x + sgn * step)
                if not k.lo <= value <= k.hi and not (k.lo < k.get(theta) < k.hi):
                    continue  # at a bound already
                p = dict(theta)
                k.set(p, value)
                if _valid(p):
                    trials.append(p)
            if not trials:
                continue
            results = run(trials)
            i = int(np.argmin([r.nll for r in results]))
            if results[i].nll < best.nll - MIN_GAIN:
                best, theta, improved = results[i], trials[i], True
                history.append((f"{k.label} = {k.get(theta):.4g}", best.nll))
                log(f"  {k.label} -> {k.get(theta):.4g}: NLL {best.nll:.6g}")
        if not improved:
            step /= 2.0
    return best, theta


def _band_order(run, theta: dict, best: Evaluation, history: list, log) -> tuple[Evaluation, dict]:
    """The bands' Butterworth order (:data:`~.config.BAND_ORDERS`) by likelihood at the fitted
    spectrum: another order, with the top corner at :data:`CORNER_FACTORS` times the fitted one (a
    steeper band needs a higher corner to pass the same frequencies), is kept if it gains :data:`MIN_GAIN`."""
    corners = list(theta["process.disturbance_bandwidth"])
    top = int(np.argmax(corners))
    trials = []
    for order in BAND_ORDERS:
        if order == theta["process.disturbance_band_order"]:
            continue
        for factor in CORNER_FACTORS:
            c = list(corners)
            c[top] = float(min(c[top] * factor, BANDWIDTH_BOUNDS[1]))
            p = dict(theta, **{"process.disturbance_band_order": order, "process.disturbance_bandwidth": c})
            if _valid(p) and p not in trials:
                trials.append(p)
    results = run(trials)
    log("  band order: " + ", ".join(f"{p['process.disturbance_band_order']} to "
                                     f"{max(p['process.disturbance_bandwidth']):.4g} Hz: NLL {r.nll:.6g}"
                                     for p, r in zip(trials, results, strict=True))
        + f" (now {theta['process.disturbance_band_order']}: {best.nll:.6g})")
    return _likeliest(trials, results, best, theta, history, "process.disturbance_band_order")


def _likeliest(trials: list[dict], results: list[Evaluation], best: Evaluation, theta: dict, history: list,
               name: str) -> tuple[Evaluation, dict]:
    """The likeliest trial if it gains :data:`MIN_GAIN` over ``best`` (recorded in ``history`` by
    the value of ``name``), else ``best`` and ``theta`` as they were."""
    i = int(np.argmin([r.nll for r in results]))
    if results[i].nll < best.nll - MIN_GAIN:
        best, theta = results[i], trials[i]
        history.append((f"{name} = {_text(theta[name])}", best.nll))
    return best, theta


def _valid(params: Mapping[str, Any]) -> bool:
    """Bandwidth corners must stay distinct."""
    b = params.get("process.disturbance_bandwidth", [])
    return len(set(round(x, 9) for x in b)) == len(b)


def _scan_delay(run, theta: dict, events: list[Event], best: Evaluation, history: list, log) -> tuple:
    """``command_delay`` by likelihood over :data:`DELAY_STEPS` periods (the current value kept
    unless another is likelier)."""
    period = period_of(events)
    current = theta["command_delay"]
    trials = []
    for k in DELAY_STEPS:
        d = k * period
        if abs(d - current) > 1e-9:
            trials.append(dict(theta, command_delay=float(d)))
    results = run(trials)
    log("  command_delay scan: " + ", ".join(f"{p['command_delay'] * 1e3:.3g} ms {r.nll:.6g}"
                                            for p, r in zip(trials, results, strict=True))
        + f" (now {current * 1e3:.3g} ms {best.nll:.6g})")
    return _likeliest(trials, results, best, theta, history, "command_delay")


# ---------------------------------------------------------------------- parameter files
def explicit_names(path: str | Path | None) -> set[str]:
    """Flat observer names (without the prefix) a parameter file sets."""
    if path is None:
        return set()
    data = yaml12.load_file(path)
    names = set()
    if isinstance(data, dict):
        for body in data.values():
            if isinstance(body, dict) and isinstance(body.get("ros__parameters"), dict):
                names |= {k[len(PREFIX):] for k in flatten(body["ros__parameters"]) if k.startswith(PREFIX)}
        if "observer" in data and isinstance(data["observer"], dict):
            names |= {k[len(PREFIX):] for k in flatten(data) if k.startswith(PREFIX)}
    return names


def nest(flat: Mapping[str, Any]) -> dict:
    """Dotted names -> nested maps (what :func:`~elastic_pm_dyn.observer.config.flatten` undoes)."""
    out: dict = {}
    for name, value in flat.items():
        node = out
        *head, last = name.split(".")
        for part in head:
            node = node.setdefault(part, {})
        node[last] = value
    return out


class _QuotingDumper(yaml.SafeDumper):
    """Strings YAML 1.1 would read as something else quoted: ROS reads a bare y (an imu axis) as true."""


_YAML11_WORDS = {"y", "n", "yes", "no", "on", "off", "true", "false", "null", "~"}
_QuotingDumper.add_representer(str, lambda d, v: d.represent_scalar(
    "tag:yaml.org,2002:str", v, style='"' if v.lower() in _YAML11_WORDS else None))
# as the shipped files: nested maps in block style, lists in flow style ([a, b])
_QuotingDumper.add_representer(dict, lambda d, v: d.represent_mapping("tag:yaml.org,2002:map", v, flow_style=False))
_QuotingDumper.add_representer(list, lambda d, v: d.represent_sequence("tag:yaml.org,2002:seq", v, flow_style=True))


def write_parameters(params: Mapping[str, Any], out: str | Path, base_path: str | Path | None = None) -> Path:
    """A ``ros__parameters`` YAML file with every observer parameter of ``params`` (floats as
    floats); the base file's other sections and keys kept (its observer block replaced)."""
    data: dict = {}
    if base_path is not None:
        loaded = yaml12.load_file(base_path)
        data = loaded if isinstance(loaded, dict) else {}
    section = None
    for body in data.values():
        if isinstance(body, dict) and isinstance(body.get("ros__parameters"), dict) and \
                any(k == "observer" or k.startswith(PREFIX) for k in body["ros__parameters"]):
            section = body["ros__parameters"]
            break
    if section is None:
        data.setdefault("/**", {}).setdefault("ros__parameters", {})
        section = data["/**"]["ros__parameters"]
    for k in [k for k in section if k.startswith(PREFIX)]:
        del section[k]
    typed = {k: (float(v) if isinstance(DEFAULT_PARAMETERS[k], float) else
                 [float(x) for x in v] if isinstance(DEFAULT_PARAMETERS[k], list)
                 and isinstance(DEFAULT_PARAMETERS[k][0], float) else v)
             for k, v in params.items()}
    section["observer"] = nest(typed)
    text = ("# Observer parameters tuned by `elastic-pm-dyn tune` (maximum innovation likelihood)\n"
            + yaml.dump(data, Dumper=_QuotingDumper, sort_keys=False))
    out = Path(out)
    out.write_text(text)
    return out


def report(res: TuneResult) -> str:
    """What :func:`tune` found, and the NLL, mean NIS / dof and gated counts before and after."""
    lines = [f"tuned in {res.wall_s:.1f} s ({res.evaluations} filter passes)"]
    for name, (a, b) in res.changed.items():
        lines.append(f"  {PREFIX}{name}: {_text(a)} -> {_text(b)}")
    if not res.changed:
        lines.append("  (the base configuration is the likeliest found)")
    lines.append(f"NLL (gate off): {res.before.nll:.6g} -> {res.after.nll:.6g}")
    for s, b in res.before.per_sensor.items():
        a = res.after.per_sensor[s]
        gb, ga = res.gated_before.per_sensor[s]["gated"], res.gated_after.per_sensor[s]["gated"]
        lines.append(f"  {s}: {b['samples']} samples, NLL {b['nll']:.6g} -> {a['nll']:.6g}, mean NIS / dof "
                     f"{b['mean_nis_per_dof']:.3g} -> {a['mean_nis_per_dof']:.3g}, gated (gate on) {gb} -> {ga}")
    for name, ev in (("base", res.before), ("tuned", res.after)):
        if ev.fault:
            lines.append(f"  the {name} filter faulted: {ev.fault}")
    return "\n".join(lines)


def _text(v: Any) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_text(x) for x in v) + "]"
    return f"{v:.4g}" if isinstance(v, float) else str(v)
