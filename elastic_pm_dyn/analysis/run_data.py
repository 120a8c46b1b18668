"""One run, ready for metrics: model quantities from a bag (or a simulation) on a common clock.

:func:`run_from_bag` turns the topic series of :func:`bags.read_bag` into end-effector
paths (forward kinematics of the joint states by joint name; the reference through the
rigid model, ``Mechanism(model.locked())``), branch forces, the closure gap, motor
torques, the hold phase, stream timing and command age. :func:`run_from_simulation`
does the same for an in-memory :class:`SimulationResult`, so bags and offline runs go
through the same metrics and plots.

Time zero is the first stamp of the reference (else the torque command, else the joint
states): for the feedforward node that is the start of the manoeuvre.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from elastic_pm_dyn.analysis.bags import BagData, TopicSeries
from elastic_pm_dyn.analysis.report_types import BagInfo, StreamStats
from elastic_pm_dyn.analysis.streams import hold_start as find_hold_start
from elastic_pm_dyn.kinematics.mechanism import Mechanism, as_mechanism
from elastic_pm_dyn.model.description import Model

if TYPE_CHECKING:
    from elastic_pm_dyn.sim.result import SimulationResult


@dataclass
class ModelInfo:
    """The elastic model, its rigid twin (elastic joints locked) and its elastic modes."""

    path: Path
    model: Model
    mech: Mechanism
    rigid: Mechanism

    @classmethod
    def load(cls, model: str | Path | Model | Mechanism) -> ModelInfo:
        """From a model file, a loaded :class:`Model` or a :class:`Mechanism`."""
        mech = as_mechanism(model)
        path = Path(model) if isinstance(model, (str, Path)) else Path(mech.model.source)  # the file it came from
        return cls(path, mech.model, mech, Mechanism(mech.model.locked()))

    @property
    def branches(self) -> list[str]:
        return [b.name for b in self.model.branches]

    def natural_hz(self, q: np.ndarray | None = None) -> list[float]:
        """Undamped elastic mode frequencies [Hz] at ``q`` (default: the start pose), motors clamped."""
        from elastic_pm_dyn.dynamics.linear import elastic_modes
        from elastic_pm_dyn.kinematics.assembly import initial_state

        if not len(self.mech.elastic):
            return []
        if q is None or not np.all(np.isfinite(q)):
            q = initial_state(self.mech)
        return [float(f) for f in elastic_modes(self.mech, q).natural_hz]


@dataclass
class RunData:
    """Samples of one run on the clock t - t0 [s]; None where the run has no such data."""

    label: str
    t0: float = 0.0
    t0_source: str = ""
    t: np.ndarray | None = None  # joint-state times
    q: np.ndarray | None = None  # (N, n) tree positions, mech.joint_names order
    qd: np.ndarray | None = None
    ee: np.ndarray | None = None  # (N, k) end effector at t
    ee_source: str = ""
    t_ref: np.ndarray | None = None
    ee_ref: np.ndarray | None = None  # reference end effector at t_ref
    ee_ref_source: str = ""
    t_force: np.ndarray | None = None
    forces: dict[str, np.ndarray] = field(default_factory=dict)  # branch -> F [N] at t_force
    force_source: str = ""
    peak_force: dict[str, float] = field(default_factory=dict)  # over all samples (exact when streamed)
    t_vib: np.ndarray | None = None  # full-rate force samples for fits and spectra
    forces_vib: dict[str, np.ndarray] = field(default_factory=dict)
    t_gap: np.ndarray | None = None
    gap: np.ndarray | None = None
    gap_source: str = ""
    t_torque: np.ndarray | None = None
    torques: dict[str, np.ndarray] = field(default_factory=dict)
    torque_source: str = ""
    t_wrench: np.ndarray | None = None  # the observer's wrench estimate: times, (N, 6) [f; m], std
    wrench: np.ndarray | None = None
    wrench_std: np.ndarray | None = None
    t_wrench_true: np.ndarray | None = None  # the plant's true wrench
    wrench_true: np.ndarray | None = None
    contacts: np.ndarray | None = None  # detection times [s] of the contact events
    hold_start: float | None = None
    hold_source: str = ""
    decimated: bool = False
    streams: dict[str, StreamStats] = field(default_factory=dict)  # by role
    command_age: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    bag: BagInfo | None = None  # None: not from a bag
    notes: list[str] = field(default_factory=list)

    def reference_at(self, t: np.ndarray) -> np.ndarray | None:
        """Reference end effector interpolated at ``t`` (held at its ends), or None."""
        if self.ee_ref is None or self.t_ref is None or len(self.t_ref) == 0:
            return None
        order = np.argsort(self.t_ref, kind="stable")
        tr = self.t_ref[order]
        return np.column_stack([np.interp(t, tr, self.ee_ref[order, k]) for k in range(self.ee_ref.shape[1])])


# ------------------------------------------------------------------------------ bags
def _tree_positions(s: TopicSeries, names: list[str], fld: str = "position") -> np.ndarray | None:
    """(N, len(names)) by joint name, or None if a joint is missing (NaN where a message lacked it)."""
    return s.columns(fld, names)


def _speed(s: TopicSeries) -> np.ndarray:
    """|joint velocity| per sample; from differences of positions if the messages carry none."""
    vel = s.fields["velocity"]
    if vel.size and np.isfinite(vel).any(axis=1).all():
        return np.linalg.norm(np.nan_to_num(vel), axis=1)
    pos = np.nan_to_num(s.fields["position"])
    if len(s.t) < 2:
        return np.zeros(len(s.t))
    dt = np.diff(s.t)
    d = np.linalg.norm(np.diff(pos, axis=0), axis=1) / np.where(dt > 0, dt, np.inf)
    return np.concatenate((d, d[-1:]))


class Timebase:
    """Maps a series' times to the run's clock: seconds since the first stamp of the origin topic.

    Series stamped like the origin topic are shifted; the others (header stamps vs
    receive times, e.g. Float64MultiArray commands against sim-time states) are moved
    across by the origin topic's median receive delay, which aligns them to within the
    transport jitter (and is only approximate when simulated time does not run at wall speed).
    """

    def __init__(self, bag: BagData):
        origin = next((bag.series[r] for r in ("reference", "torque_command", "joint_states", "branch_forces",
                                                "ee_pose") if r in bag.series and len(bag.series[r].t)), None)
        self.crossed: list[str] = []  # topics moved across clocks
        self.source = "bag start" if origin is None else f"first stamp of {origin.topic}"
        self.header = origin is not None and origin.stamp_source == "header"
        if origin is None:
            self.t0, self.delay, self.stamp_s = 0.0, 0.0, bag.start_ns * 1e-9
            return
        self.t0 = float(np.nanmin(origin.t))
        d = origin.t_receive - origin.t
        self.delay = float(np.nanmedian(d)) if self.header and np.isfinite(d).any() else 0.0
        self.stamp_s = (bag.header_origin_ns if self.header else bag.start_ns) * 1e-9 + self.t0

    def __call__(self, s: TopicSeries) -> np.ndarray:
        if (s.stamp_source == "header") == self.header:
            return s.t - self.t0
        self.crossed.append(s.topic)
        if self.header:  # receive times onto the header clock
            return s.t_receive - self.delay - self.t0
        return s.t + np.nanmedian(s.t_receive - s.t) - self.t0  # header stamps onto the receive clock


def _stream_stats(s: TopicSeries) -> StreamStats:
    tm, tr = s.timing, s.timing_receive
    return StreamStats(
        topic=s.topic, type=s.msgtype, messages=s.count, stamps=s.stamp_source, rate_hz=tm.rate,
        period_median_s=tm.period_median, period_p99_s=tm.period_p99, period_max_s=tm.period_max, gaps=tm.gaps,
        longest_gap_s=tm.longest_gap, out_of_order=tm.out_of_order, exact=tm.exact, receive_rate_hz=tr.rate,
        receive_gaps=tr.gaps, receive_period_p99_s=tr.period_p99, decimated_by=s.stride)


def _command_age(cmd: TopicSeries, states: TopicSeries) -> dict:
    """For each joint-state sample: its time minus the newest command time at or before it."""
    both_header = cmd.stamp_source == "header" and states.stamp_source == "header"
    tc = np.sort(cmd.t if both_header else cmd.t_receive)
    ts = states.t if both_header else states.t_receive
    k = np.searchsorted(tc, ts, side="right") - 1
    ok = k >= 0
    if not ok.any():
        return {"clock": "header" if both_header else "receive", "samples": 0,
                "note": "no command before any state"}
    age = ts[ok] - tc[k[ok]]
    return {"clock": "header stamps" if both_header else "receive times", "samples": int(ok.sum()),
            "states_before_first_command": int((~ok).sum()), "max_s": float(age.max()),
            "median_s": float(np.median(age)), "p99_s": float(np.percentile(age, 99))}


def _diagnostics_summary(bag: BagData, t0: float) -> tuple[dict, dict]:
    d = bag.diagnostics
    if d is None:
        return {}, {}
    values = {}
    for key, (t, v) in d.values.items():
        values[key] = {"count": len(v), "min": float(v.min()), "mean": float(v.mean()), "max": float(v.max()),
                       "last": float(v[-1]), "last_at_s": float(t[-1] - t0)}
    summary = {"topic": d.topic, "messages": d.count, "levels": d.levels, "messages_not_ok": d.messages,
               "values": values}
    age = {k: v for k, v in values.items() if k.endswith("command_age_s")}
    return summary, (next(iter(age.values())) if age else {})


def run_from_bag(bag: BagData, info: ModelInfo, label: str, hold_start: float | None = None) -> RunData:
    """Model quantities of a bag (see module doc); ``hold_start`` [s] relative to time zero."""
    mech, rigid = info.mech, info.rigid
    s = bag.series
    rel = Timebase(bag)
    run = RunData(label, t0=rel.stamp_s, t0_source=rel.source, notes=list(bag.notes))
    run.bag = BagInfo(path=str(bag.path), storage=bag.storage, duration_s=(bag.end_ns - bag.start_ns) * 1e-9,
                      topics={k: {"type": ty, "messages": n} for k, (ty, n) in bag.topics.items()}, roles=bag.roles)
    run.streams = {role: _stream_stats(x) for role, x in s.items()}
    run.decimated = any(x.stride > 1 for x in s.values())

    js = s.get("joint_states") or s.get("measured")
    if js is not None and "joint_states" not in s:
        run.notes.append(f"no joint states: using the measured states {js.topic}")
    if js is not None:
        run.t = rel(js)
        q = _tree_positions(js, mech.joint_names)
        if q is None:
            missing = [n for n in mech.joint_names if n not in js.names]
            run.notes.append(f"{js.topic} lacks joints of the model ({', '.join(missing) or 'positions'}): "
                             "no forward kinematics, closure gap or modes from it")
        else:
            run.q = q
            run.qd = _tree_positions(js, mech.joint_names, "velocity")
            run.ee = np.array([mech.end_effector(x) for x in q])
            run.ee_source = f"{js.topic} (forward kinematics of the model)"
            run.t_gap, run.gap = run.t, np.array([mech.gap(x) for x in q])
            run.gap_source = f"{js.topic} (closure residual of the model)"
    if run.ee is None and "ee_pose" in s:  # no usable joint states: the plant's own pose
        pose = s["ee_pose"]
        run.t, run.ee = rel(pose), mech.ee_of(pose.fields["position"])
        run.ee_source = pose.topic

    ref = s.get("reference")
    if ref is not None:
        run.t_ref = rel(ref)
        q_ref = _tree_positions(ref, rigid.joint_names)
        if q_ref is not None:
            run.ee_ref = np.array([rigid.end_effector(x) for x in q_ref])
            run.ee_ref_source = f"{ref.topic} (forward kinematics of the rigid model)"
        elif (q_full := _tree_positions(ref, mech.joint_names)) is not None:
            run.ee_ref = np.array([mech.end_effector(x) for x in q_full])
            run.ee_ref_source = f"{ref.topic} (forward kinematics of the elastic model)"
        else:
            run.notes.append(f"{ref.topic} names neither the rigid model's joints ({', '.join(rigid.joint_names)}) "
                             "nor the elastic model's: no reference path")
        if hold_start is None:
            h = find_hold_start(run.t_ref, _speed(ref)) if ref.stride == 1 else None
            if ref.stride > 1 and bag.hold_start is not None:  # detected while streaming
                h = bag.hold_start - (ref.t[0] - run.t_ref[0])
            if h is not None:
                run.hold_start, run.hold_source = h, f"{ref.topic} comes to rest"
    if hold_start is not None:
        run.hold_start, run.hold_source = float(hold_start), "--hold-start"
    elif run.hold_start is None:
        run.notes.append("hold phase not found (no reference that comes to rest): pass --hold-start "
                         "for the residual-vibration fit")

    _forces_from_bag(run, s, info, rel)
    _torques_from_bag(run, s, mech, rel)
    _wrench_from_bag(run, s, rel)
    if "torque_command" in s and js is not None:
        run.command_age["from_stamps"] = _command_age(s["torque_command"], js)
    run.diagnostics, reported = _diagnostics_summary(bag, rel.t0)
    if reported:
        run.command_age["reported_by_plant"] = reported
    if run.gap is None and run.diagnostics:
        gaps = [k for k in bag.diagnostics.values if k.endswith("closure_gap_m")]
        if gaps:
            t, v = bag.diagnostics.values[gaps[0]]
            run.t_gap, run.gap, run.gap_source = t - rel.t0, v, f"{bag.diagnostics.topic} ({gaps[0]})"
    if rel.crossed:
        run.notes.append(f"{', '.join(rel.crossed)}: stamped on another clock than {rel.source.split()[-1]}; "
                         f"aligned by its median receive delay ({rel.delay * 1e3:.3g} ms)")
    return run


def _wrench_from_bag(run: RunData, s: dict[str, TopicSeries], rel: Timebase) -> None:
    """The wrench estimate (and its standard deviations), the true wrench and the contact events."""
    def six(x: TopicSeries) -> np.ndarray:
        return np.hstack([x.fields["force"], x.fields["torque"]])

    if "wrench" in s:
        run.t_wrench, run.wrench = rel(s["wrench"]), six(s["wrench"])
        if "wrench_stddev" in s and len(s["wrench_stddev"].t) == len(run.t_wrench):
            run.wrench_std = six(s["wrench_stddev"])
    if "wrench_truth" in s:
        run.t_wrench_true, run.wrench_true = rel(s["wrench_truth"]), six(s["wrench_truth"])
    if "contact" in s:
        run.contacts = rel(s["contact"])


def _forces_from_bag(run: RunData, s: dict[str, TopicSeries], info: ModelInfo, rel: Timebase) -> None:
    bf = s.get("branch_forces")
    if bf is not None:
        run.t_force = rel(bf)
        run.forces = {b: bf.column("force", b) for b in bf.names}
        lo, hi = bf.peak_lo["force"], bf.peak_hi["force"]
        run.peak_force = {b: float(max(abs(lo[k]), abs(hi[k]))) for k, b in enumerate(bf.names)}
        run.force_source = bf.topic
        if bf.window is None:  # every sample kept: the fit uses them all
            run.t_vib, run.forces_vib = run.t_force, run.forces
        else:
            run.t_vib = rel(bf.window)
            run.forces_vib = {b: bf.window.column("force", b) for b in bf.window.names}
        return
    if run.q is not None and run.qd is not None and info.branches:
        f = np.array([info.mech.branch_forces(q, qd) for q, qd in zip(run.q, run.qd, strict=True)])
        run.t_force = run.t_vib = run.t
        run.forces = run.forces_vib = {b: f[:, k] for k, b in enumerate(info.branches)}
        run.peak_force = {b: float(np.abs(f[:, k]).max()) for k, b in enumerate(info.branches)}
        run.force_source = "joint states (F = c u + d du/dt of the model)"
        if s["joint_states"].stride > 1:
            run.notes.append("branch forces from decimated joint states: no full-rate window for the fit")


def _torques_from_bag(run: RunData, s: dict[str, TopicSeries], mech: Mechanism, rel: Timebase) -> None:
    cmd = s.get("torque_command")
    if cmd is not None:
        if cmd.msgtype.endswith("Float64MultiArray"):
            data = cmd.fields["data"]
            names = mech.active_names if data.shape[1] == len(mech.active_names) else [f"data[{k}]" for k in
                                                                                        range(data.shape[1])]
            if names is not mech.active_names:
                run.notes.append(f"{cmd.topic}: {data.shape[1]} values for {len(mech.active_names)} motors; "
                                 "columns left unnamed")
            run.torques = {n: data[:, k] for k, n in enumerate(names)}
        else:
            run.torques = {n: cmd.column("effort", n) for n in cmd.names}
        run.t_torque = rel(cmd)
        run.torque_source = cmd.topic
        return
    js = s.get("joint_states")
    if js is not None and (eff := js.columns("effort", mech.active_names)) is not None:
        run.t_torque = rel(js)
        run.torques = {n: eff[:, k] for k, n in enumerate(mech.active_names)}
        run.torque_source = f"{js.topic} (effort of the motors)"


# ------------------------------------------------------------------------ simulation
def run_from_simulation(result: SimulationResult, label: str, reference: np.ndarray | None = None,
                        hold_start: float | None = None, torque_times: np.ndarray | None = None,
                        torques: np.ndarray | None = None) -> RunData:
    """A simulated run: ``reference`` is the desired end effector at ``result.t``."""
    mech = result.mech
    branches = [b.name for b in mech.model.branches]
    run = RunData(label, t=result.t, q=result.q, qd=result.qd, ee=result.ee, ee_source="simulation",
                  t_force=result.t, forces={b: result.branch_forces[:, k] for k, b in enumerate(branches)},
                  force_source="simulation", t_gap=result.t, gap=result.gap, gap_source="simulation",
                  hold_start=hold_start, hold_source="manoeuvre" if hold_start is not None else "")
    run.peak_force = {b: float(np.abs(f).max()) for b, f in run.forces.items()}
    run.t_vib, run.forces_vib = run.t_force, run.forces
    if reference is not None:
        run.t_ref, run.ee_ref, run.ee_ref_source = result.t, np.asarray(reference), "desired path"
    t_tau = result.t if torque_times is None else torque_times
    tau = result.tau if torques is None else torques
    run.t_torque = t_tau
    run.torques = {n: tau[:, k] for k, n in enumerate(mech.active_names)}
    run.torque_source = "feedforward" if torques is not None else "simulation"
    return run
