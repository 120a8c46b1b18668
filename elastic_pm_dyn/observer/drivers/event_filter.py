"""The filter over a bag's events: :func:`run_events`, and :class:`EventFilter` fed chunk by chunk.

Events go through the same :class:`~elastic_pm_dyn.observer.drivers.stream.ObserverStream` as the
live node, ordinary periods many at once in one compiled call (``period.run_periods``);
one estimate row per distinct stamp once the filter runs. Message order: by header stamp,
ties in bag order (``order="stamp"``, the best offline estimate), or the bag's own order
(``order="arrival"``: what a live node saw, late samples dropped alike). Times are seconds
since the stream's integer-ns origin (:mod:`~elastic_pm_dyn.observer.drivers.stream`); the rows
keep the exact stamps.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.core import period
from elastic_pm_dyn.observer.core.ekf import ObserverFault
from elastic_pm_dyn.observer.drivers.bag_input import Event
from elastic_pm_dyn.observer.drivers.results import FilterPass
from elastic_pm_dyn.observer.drivers.rows import SENSORS, Rows
from elastic_pm_dyn.observer.drivers.stream import ObserverStream
from elastic_pm_dyn.observer.schedule import sensor_stats
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.observer.schedule.sensor_stats import UpdateResult


class _Run:
    """Consecutive ordinary stamp groups with one encoder plan (the offline fast path's input;
    read only once closed, so that filters of other noise levels can share it: the plan's H and
    variances are looked up by ``names`` in each filter's encoders)."""

    def __init__(self, g0: int, names: tuple, plan: tuple, has_imu: bool):
        self.g0, self.g1, self.names, self.plan, self.has_imu = g0, g0, names, plan, has_imu
        self.ns: list[int] = []
        self.enc: list = []
        self.imu: list = []
        self.tau: list = []

    def close(self, origin_ns: int) -> None:
        self.ts = np.array([(int(ns) - origin_ns) * 1e-9 for ns in self.ns])  # as ObserverStream.seconds
        self.enc = np.array(self.enc, dtype=float).reshape(len(self.ns), len(self.plan.idx))
        self.imu = np.array(self.imu, dtype=float).reshape(len(self.ns), -1 if self.imu else 0)
        self.tau = np.array(self.tau, dtype=float).reshape(len(self.ns), -1)
        # period.run_periods' inputs: (ts, taus, enc_meas, has_imu, imu_meas)
        self.inputs = (self.ts, self.tau, self.enc, self.has_imu, self.imu)


class FastRuns:
    """The stamp groups of a list of events and the :class:`_Run` of each (None: the per-message
    API's), for one observer model, ``timing.max_future`` and time origin: made once
    (:func:`fast_runs`), fed to many filters over the same events (``EventFilter.feed``)."""

    def __init__(self, groups: list[tuple[int, int]], run_of: list):
        self.groups, self.run_of = groups, run_of


def fast_runs(obs: Observer, events: list[Event], origin_ns: int) -> FastRuns:
    """The :class:`FastRuns` of ``events`` (in the order they will be fed) for observers with
    ``obs``'s model and ``timing.max_future``, time origin ``origin_ns``."""
    groups = _groups(events)
    return FastRuns(groups, _fast_runs(obs, ObserverStream(obs, origin_ns=origin_ns), events, groups))


def _groups(events: list[Event]) -> list[tuple[int, int]]:
    out, i, n = [], 0, len(events)
    while i < n:
        ns, j = events[i].stamp_ns, i + 1
        while j < n and events[j].stamp_ns == ns:
            j += 1
        out.append((i, j))
        i = j
    return out


def _fast_runs(obs: Observer, stream: ObserverStream, events: list[Event], groups: list[tuple[int, int]]) -> list:
    """Per stamp group, the :class:`_Run` it belongs to, or None: groups of exactly a joint state
    with positions of state joints only, an optional accelerometer sample, then a well-formed
    torque command (:func:`run_events` gives the others to the per-message API, and so does
    ``period.run_periods`` with any period that turns out unusual). A run ends before a stamp
    more than ``timing.max_future`` after the one before (the per-message API rejects it)."""
    enc, imu = obs.encoders, obs.imu
    run_of: list = [None] * len(groups)
    if enc is None:
        return run_of
    origin, max_future = stream.origin_ns, obs.cfg.timing.max_future
    branch_effort = obs.branch is not None and obs.branch.source == "joint_state_effort"
    axes = imu.axes if imu is not None else None
    cur: _Run | None = None
    last_names, last_key, last_plan = None, None, None
    for gi, (i0, i1) in enumerate(groups):
        spec = None
        size = i1 - i0
        if size == 2 or (size == 3 and imu is not None):
            ej, ec = events[i0], events[i1 - 1]
            ei = events[i0 + 1] if size == 3 else None
            if ej.kind == "joint_state" and ec.kind == "command" and (ei is None or ei.kind == "imu"):
                names, pos, vel, eff = ej.data
                if names is not last_names and names != last_names:  # decoded messages repeat them
                    last_names, last_key = names, tuple(names)
                    last_plan = None if stream.name_problem(names)[0] else enc.fast_plan(last_key, obs.nx)
                plan = last_plan if len(pos) == len(names) else None
                if plan is not None and not (plan.with_rates and len(vel)) and not (branch_effort and len(eff)):
                    spec = plan
                if spec is not None and ei is not None:
                    acc, frame = ei.data
                    if (imu.frame_id and frame and frame != imu.frame_id) or len(acc) != 3:
                        spec = None
                if spec is not None:
                    try:
                        tau = stream.command_tau(*ec.data)
                    except InputError:
                        spec = None
        if spec is None:
            if cur is not None:
                cur.close(origin)
                cur = None
            continue
        has_imu = ei is not None
        if cur is None or cur.plan is not spec or cur.has_imu != has_imu or \
                (ej.stamp_ns - origin) * 1e-9 - (cur.ns[-1] - origin) * 1e-9 > max_future:
            if cur is not None:
                cur.close(origin)
            cur = _Run(gi, last_key, spec, has_imu)
        cur.g1 = gi + 1
        cur.ns.append(ej.stamp_ns)
        cur.enc.append(np.asarray(pos, dtype=float)[spec.idx])
        if has_imu:
            cur.imu.append(np.asarray(acc, dtype=float)[axes])
        cur.tau.append(tau)
        run_of[gi] = cur
    if cur is not None:
        cur.close(origin)
    return run_of


class EventFilter:
    """:func:`run_events`' loop, fed one chunk of events after another: a chunk holds whole
    stamp groups (all events of its stamps, none split across chunks) in the final order, so
    that feeding the chunks one by one gives what feeding their concatenation gives.
    ``origin_ns``: the stream's time origin (default: the first stamp fed)."""

    def __init__(self, obs: Observer, fast: bool = True, gate: threading.Event | None = None,
                 origin_ns: int | None = None):
        self.obs, self.fast = obs, fast
        self.gate = gate  # cleared while this runs Python (other threads wait), set otherwise
        self.stream = ObserverStream(obs, origin_ns=origin_ns)
        self.rows = Rows(obs.layout)
        self.nis = dict.fromkeys(SENSORS, np.nan)
        self.fault = ""
        self.last_row_ns = None
        self.fixed = None

    def feed(self, events: list[Event]) -> None:
        self.feed_runs(events, None)

    def feed_runs(self, events: list[Event], runs: FastRuns | None) -> None:
        """:meth:`feed` with ``runs``, the :class:`FastRuns` of exactly these events (:func:`fast_runs`
        with this observer's model, ``timing.max_future`` and the stream's origin; None: made here)."""
        if self.fault:
            return
        if self.gate is None:
            self._feed(events, None, runs)
            return
        self.gate.clear()
        try:
            self._feed(events, self.gate, runs)
        finally:
            self.gate.set()

    def _feed(self, events: list[Event], gate: threading.Event | None, runs: FastRuns | None) -> None:
        obs, stream, rows, sensors = self.obs, self.stream, self.rows, SENSORS
        nis, fault, last_row_ns, fixed = self.nis, self.fault, self.last_row_ns, self.fixed
        if events and stream.origin_ns is None:
            stream.seconds(events[0].stamp_ns)  # sets the origin
        rows.origin_ns = stream.origin_ns or 0
        seconds, max_future, window = stream.seconds, obs.cfg.timing.max_future, obs.cfg.gating.nis_window
        if runs is None:
            groups = _groups(events)
            run_of = _fast_runs(obs, stream, events, groups) if self.fast else [None] * len(groups)
        else:
            groups, run_of = runs.groups, runs.run_of if self.fast else [None] * len(runs.groups)
        skip = -1  # a group the fast path stopped at: the per-message API's
        outs: dict[_Run, tuple[np.ndarray, np.ndarray]] = {}  # a run's rows and NIS (this pass's)

        def record(ns: int) -> None:
            rows.t.append(ns)
            rows.flat.append(obs.estimate_flat())
            rows.nis.append([nis[s] for s in sensors])

        gi = 0
        while gi < len(groups):
            run = run_of[gi]
            if run is not None and gi != skip and obs.initialised and obs.fault is None \
                    and not obs.time_pending and run.ns[gi - run.g0] != last_row_ns \
                    and not run.ts[gi - run.g0] - obs.t > max_future:
                if fixed is None:
                    imu = obs.imu
                    # the steps' timing array, the accelerometer's bundle (kernels.ImuModel; a
                    # placeholder without one) and its gate: the Observer's own
                    fixed = (obs._timing, obs._imu_bundle, obs.imu_gate(len(imu.axes)) if imu is not None else np.inf)
                timing, imu_model, imu_gate = fixed
                plan = obs.encoders.fast_plan(run.names, obs.nx)
                a, b = gi - run.g0, run.g1 - run.g0
                cmd, ctl = obs.fast_state(b - a)
                out = outs.get(run)
                if out is None:  # the run's rows (views of it become rows.flat) and, per sensor
                    # (encoders, imu), NIS and log det S: period.run_periods'
                    out = outs[run] = (np.empty((b, obs.layout.width)), np.empty((b, 4)))
                run_flat, run_nis = out
                if gate is not None:  # the compiled call leaves the GIL to the other threads
                    gate.set()
                done = period.run_periods(
                    obs.mech.arrays, obs.model.fixed, obs._proc, obs._state(), cmd, ctl,
                    timing, obs.evidence, plan.bundle, obs.gate(len(plan.idx)), imu_model, imu_gate, run.inputs, a,
                    b, run_flat, run_nis)
                if gate is not None:
                    gate.clear()
                if done:
                    obs._take_control(cmd, ctl)
                    ns = run.ns[a:a + done]
                    enc_nis = run_nis[a:a + done, 0].tolist()
                    sensor_stats.record_accepted(obs.stats["encoders"], enc_nis, len(plan.idx),
                                                 run_nis[a:a + done, 2].tolist(), window)
                    obs.stats["command"].accepted += done
                    obs.stats["command"].consecutive_rejections = 0
                    first = dict(nis, encoders=enc_nis[0])
                    if run.has_imu:
                        imu_nis = run_nis[a:a + done, 1].tolist()
                        sensor_stats.record_accepted(obs.stats["imu"], imu_nis, run.imu.shape[1],
                                                     run_nis[a:a + done, 3].tolist(), window)
                        first["imu"] = imu_nis[0]
                        stream.results = [UpdateResult("imu", seconds(ns[-1]), True, imu_nis[-1], run.imu.shape[1],
                                                       logdet=float(run_nis[a + done - 1, 3]))]
                        tail = [[e, i, np.nan] for e, i in zip(enc_nis[1:], imu_nis[1:], strict=True)]
                    else:
                        stream.results = [UpdateResult("encoders", seconds(ns[-1]), True, enc_nis[-1], len(plan.idx),
                                                       logdet=float(run_nis[a + done - 1, 2]))]
                        tail = [[e, np.nan, np.nan] for e in enc_nis[1:]]
                    rows.t.extend(ns)
                    rows.flat.extend(run_flat[a:a + done])
                    rows.nis.append([first[s] for s in sensors])
                    rows.nis.extend(tail)
                    nis = dict.fromkeys(sensors, np.nan)
                    last_row_ns = ns[-1]
                    gi += done
                    if done < b - a:
                        skip = gi
                    continue
            skip = -1
            i0, i1 = groups[gi]
            for i in range(i0, i1):
                ev = events[i]
                try:
                    if ev.kind == "command":
                        stream.on_torque_command(ev.stamp_ns, *ev.data)
                        results = obs.released  # accelerometer samples that waited for it
                    elif ev.kind == "joint_state":
                        results = stream.on_joint_state(ev.stamp_ns, *ev.data)
                    elif ev.kind == "imu":
                        results = stream.on_imu(ev.stamp_ns, ev.data[0], ev.data[1])
                    else:
                        results = stream.on_branch_forces(ev.stamp_ns, *ev.data)
                except ObserverFault as err:
                    fault = str(err)
                    break
                for r in results:
                    if r.accepted and r.dof:
                        nis[r.sensor] = r.nis
                nxt = events[i + 1].stamp_ns if i + 1 < len(events) else None
                if nxt != ev.stamp_ns and obs.initialised and ev.stamp_ns != last_row_ns \
                        and abs(obs.t - seconds(ev.stamp_ns)) <= obs.cfg.timing.stamp_tolerance:
                    record(ev.stamp_ns)
                    last_row_ns = ev.stamp_ns
                    nis = dict.fromkeys(sensors, np.nan)
            if fault:
                break
            gi += 1
        self.nis, self.fault, self.last_row_ns, self.fixed = nis, fault, last_row_ns, fixed
        rows.stats = obs.stats  # (a reset makes new ones)


def run_events(obs: Observer, events: list[Event], order: str = "stamp", fast: bool = True,
               origin_ns: int | None = None, runs: FastRuns | None = None) -> tuple[Rows, ObserverStream, str]:
    """Feed events through a stream; one estimate per distinct stamp. Returns (rows, stream, fault).

    ``origin_ns``: the stream's time origin (default: the first stamp, at the observer's time).
    ``runs``: the :class:`FastRuns` of the events in the order fed (:func:`fast_runs`), made
    here if None.

    ``fast``: ordinary stamp groups (a joint state, an accelerometer sample, the command)
    go through ``period.run_periods``, many in one compiled call, with the same numbers,
    statistics and rows as the per-message API (``fast=False``) that takes all the others.
    """
    if order == "stamp":
        events = sorted(events, key=order_key)
    elif order != "arrival":
        raise InputError(f"unknown message order {order!r} (expected stamp or arrival)")
    f = EventFilter(obs, fast, origin_ns=origin_ns)
    if runs is None:
        f.feed(events)
    else:
        f.feed_runs(events, runs)
    return f.rows, f.stream, f.fault


def order_key(e: Event) -> tuple[int, int]:
    return e.stamp_ns, e.index


def filter_all(mech: Mechanism, cfg: ObserverConfig, events: list[Event], order: str,
               log: Callable[[str], object]) -> FilterPass:
    """An observer started at the first stamp (the time origin: t = 0 there; its observability
    report logged), then every event through :func:`run_events` at once (the accelerometer
    sample timing's decisions logged)."""
    obs = Observer(mech, cfg, t0=0.0)
    report = obs.observability()
    log(report.text())
    wall = time.perf_counter()
    rows, stream, fault = run_events(obs, events, order, origin_ns=min(e.stamp_ns for e in events))
    for decision in obs.timing_decisions:  # imu.sample_timing auto: what it chose (and any switch)
        log(decision.text())
    for recovery in obs.recoveries:  # fall-backs after runs of gated encoder samples
        log(recovery.text())
    return FilterPass(obs, report, rows, stream, fault, time.perf_counter() - wall)
