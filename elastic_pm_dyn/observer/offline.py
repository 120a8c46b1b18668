"""``elastic-pm-dyn observe``: the observer over a recorded bag, as fast as possible.

Reads the torque commands (``sensor_msgs/JointState`` effort, or
``std_msgs/Float64MultiArray`` in the model's active-joint order), the measured joint
states, optionally an ``sensor_msgs/Imu`` and measured ``elastic_pm_dyn_msgs/BranchForces``
with ``rosbags`` (mcap or sqlite3), feeds them through the same
:class:`~elastic_pm_dyn.observer.stream.ObserverStream` as the live node, and writes

- ``estimates.csv``: ``t``, every tree joint, ``<joint>_vel``, ``F_<branch>``, the standard
  deviation of each (``<column>_std``), ``ee_x``, ``ee_y`` (+ std), the disturbance
  estimates ``d_<joint>`` (+ std) and the NIS of each sensor at that stamp;
- ``estimates/`` (a bag, mcap by default) with ``/joint_states`` (position, velocity,
  effort of every tree joint), ``/branch_forces`` (with ``force_stddev``) and ``/ee_pose``
  for ``elastic-pm-dyn analyze``, plus ``/observer/joint_states_stddev`` (JointState whose
  position/velocity fields hold the standard deviations);
- ``summary.json``: counts, rejections, mean NIS, speed, the observability report.

Message order: by header stamp, ties in bag order (``order="stamp"``, the best offline
estimate), or the bag's own order (``order="arrival"``: what a live node saw, late samples
dropped alike). One estimate row per distinct stamp once the filter runs.

Reading, filtering and writing run at once (``observe_bag(pipeline=True)``, the default; the
compiled filter kernel releases the GIL), with the same results and files as one after the
other; see :func:`observe_bag` for how the stamp order is kept with a bag read in chunks.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import shutil
import struct
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer import cdr, kernels
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.ekf import Estimate, Observer, ObserverFault, UpdateResult
from elastic_pm_dyn.observer.stream import ObserverStream

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
IMU = "sensor_msgs/msg/Imu"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"

RANK = {"joint_state": 0, "branch_forces": 1, "imu": 2, "command": 3}


@dataclass
class Topics:
    torque_command: str = "/torque_command"
    measured_joint_states: str = "/measured_joint_states"
    ee_imu: str = "/ee_imu"
    measured_branch_forces: str = "/measured_branch_forces"

    @classmethod
    def from_config(cls, cfg: ObserverConfig) -> Topics:
        def slash(name: str) -> str:
            return name if name.startswith("/") else "/" + name
        t = cfg.topics
        return cls(slash(t.torque_command), slash(t.measured_joint_states), slash(t.ee_imu),
                   slash(t.measured_branch_forces))


@dataclass
class Event:
    stamp_ns: int
    kind: str
    data: tuple
    index: int = 0


def _fast_decode(msgtype: str, kind: str, t_recv: int, raw: bytes) -> tuple[int, tuple]:
    if msgtype == FLOAT64_ARRAY:  # no header: the bag's receive time
        return int(t_recv), ((), cdr.decode_float64_array(raw))
    if kind == "command":
        ns, names, _, _, effort = cdr.decode_joint_state(raw)
        return ns, (names, effort)
    if kind == "joint_state":
        ns, names, pos, vel, eff = cdr.decode_joint_state(raw)
        return ns, (names, pos, vel, eff)
    if kind == "imu":
        ns, frame, acc = cdr.decode_imu(raw)
        return ns, (acc, frame)
    ns, names, force = cdr.decode_branch_forces(raw)
    return ns, (names, force)


def _slow_decode(reader, conn, t_recv: int, raw: bytes, kind: str) -> tuple[int, tuple]:
    msg = reader.deserialize(raw, conn.msgtype)
    stamp = _stamp(msg, t_recv)
    if kind == "command":
        if conn.msgtype == FLOAT64_ARRAY:
            return stamp, ((), np.asarray(msg.data, dtype=float))
        return stamp, (list(msg.name), np.asarray(msg.effort, dtype=float))
    if kind == "joint_state":
        return stamp, (list(msg.name), np.asarray(msg.position, dtype=float), np.asarray(msg.velocity, dtype=float),
                       np.asarray(msg.effort, dtype=float))
    if kind == "imu":
        a = msg.linear_acceleration
        return stamp, (np.array([a.x, a.y, a.z]), msg.header.frame_id)
    return stamp, (list(msg.name), np.asarray(msg.force, dtype=float))


def _stamp(msg, t_recv: int) -> int:
    header = getattr(msg, "header", None)
    if header is None:
        return int(t_recv)
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def read_events(bag: Path, topics: Topics, cfg: ObserverConfig) -> tuple[list[Event], dict]:
    """Decode the observer's input topics of a bag into events (bag order)."""
    events: list[Event] = []
    counts: dict = {}
    for batch in iter_events(bag, topics, cfg, counts, 1 << 62):
        events.extend(batch)
    return events, counts


def iter_events(bag: Path, topics: Topics, cfg: ObserverConfig, counts: dict, chunk: int = 2000,
                gate: threading.Event | None = None):
    """:func:`read_events` in batches of ``chunk`` events (bag order); ``counts`` (per kind)
    filled in as they are read; before each message, waits for ``gate`` (if given) to be set."""
    from rosbags.highlevel import AnyReader

    from elastic_pm_dyn.ros.msg_types import BRANCH_FORCES_MSGTYPE, make_typestore
    if not Path(bag).exists():
        raise InputError(f"{bag}: no such bag")
    wanted = {topics.torque_command: "command", topics.measured_joint_states: "joint_state"}
    if "imu" in cfg.sensors:
        wanted[topics.ee_imu] = "imu"
    if "branch_forces" in cfg.sensors and cfg.branch_forces.source == "branch_forces":
        wanted[topics.measured_branch_forces] = "branch_forces"
    events: list[Event] = []
    counts.update({k: 0 for k in wanted.values()})
    try:
        reader = AnyReader([Path(bag)], default_typestore=make_typestore())
        reader.open()
    except Exception as exc:  # rosbags raises several types for unreadable bags
        raise InputError(f"{bag}: cannot read the bag: {exc}") from None
    try:
        conns = [c for c in reader.connections if c.topic in wanted]
        found = {c.topic for c in conns}
        for topic in (topics.torque_command, topics.measured_joint_states):
            if topic not in found:
                have = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
                raise InputError(f"{bag}: no topic {topic} (topics: {have}); see --torque-topic/--joint-topic")
        expected = {"command": (JOINT_STATE, FLOAT64_ARRAY), "joint_state": (JOINT_STATE,), "imu": (IMU,),
                    "branch_forces": (BRANCH_FORCES_MSGTYPE,)}
        for c in conns:
            if c.msgtype not in expected[wanted[c.topic]]:
                raise InputError(f"{bag}: {c.topic} has type {c.msgtype}, expected "
                                 f"{' or '.join(expected[wanted[c.topic]])}")
        for i, (conn, t_recv, raw) in enumerate(reader.messages(connections=conns)):
            if gate is not None and not gate.is_set():
                gate.wait()
            kind = wanted[conn.topic]
            try:  # straight from the CDR bytes; rosbags for anything unexpected
                stamp, data = _fast_decode(conn.msgtype, kind, t_recv, raw)
            except (ValueError, UnicodeDecodeError, struct.error, IndexError):
                stamp, data = _slow_decode(reader, conn, t_recv, raw, kind)
            events.append(Event(stamp, kind, data, i))
            counts[kind] += 1
            if len(events) >= chunk:
                yield events
                events = []
        if events:
            yield events
    finally:
        reader.close()


@dataclass
class Rows:
    """One row per estimate: stamp [ns], ``Observer.estimate_flat`` array, NIS per sensor."""

    obs: Observer | None = None
    t: list = field(default_factory=list)
    flat: list = field(default_factory=list)
    nis: list = field(default_factory=list)

    @property
    def est(self) -> list[Estimate]:
        """The rows as :class:`Estimate` objects (views into the flat arrays)."""
        return [self.obs.unpack_estimate(f, True) for f in self.flat]

    def table(self) -> np.ndarray:
        """The flat estimates stacked (rows x width)."""
        width = self.obs.flat_layout()["P"].stop
        return np.array(self.flat).reshape(len(self.flat), width)


class _Run:
    """Consecutive ordinary stamp groups with one encoder plan (the offline fast path's input)."""

    def __init__(self, g0: int, plan: tuple, has_imu: bool):
        self.g0, self.g1, self.plan, self.has_imu = g0, g0, plan, has_imu
        self.ns: list[int] = []
        self.enc: list = []
        self.imu: list = []
        self.tau: list = []
        self.flat: np.ndarray | None = None
        self.nis: np.ndarray | None = None

    def close(self) -> None:
        self.ts = np.array([int(ns) * 1e-9 for ns in self.ns])
        self.enc = np.array(self.enc, dtype=float).reshape(len(self.ns), len(self.plan[0]))
        self.imu = np.array(self.imu, dtype=float).reshape(len(self.ns), -1 if self.imu else 0)
        self.tau = np.array(self.tau, dtype=float).reshape(len(self.ns), -1)


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
    ``kernels.run_periods`` with any period that turns out unusual)."""
    enc, imu = obs.encoders, obs.imu
    run_of: list = [None] * len(groups)
    if enc is None:
        return run_of
    branch_effort = obs.branch is not None and obs.branch.source == "joint_state_effort"
    axes = imu.axes if imu is not None else None
    cur: _Run | None = None
    last_names, last_plan = None, None
    for gi, (i0, i1) in enumerate(groups):
        spec = None
        size = i1 - i0
        if size == 2 or (size == 3 and imu is not None):
            ej, ec = events[i0], events[i1 - 1]
            ei = events[i0 + 1] if size == 3 else None
            if ej.kind == "joint_state" and ec.kind == "command" and (ei is None or ei.kind == "imu"):
                names, pos, vel, eff = ej.data
                if names is not last_names and names != last_names:  # decoded messages repeat them
                    last_names, last_plan = names, enc.fast_plan(names, obs.nx)
                plan = last_plan if len(pos) == len(names) else None
                if plan is not None and not (plan[5] and len(vel)) and not (branch_effort and len(eff)):
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
                cur.close()
                cur = None
            continue
        has_imu = ei is not None
        if cur is None or cur.plan is not spec or cur.has_imu != has_imu:
            if cur is not None:
                cur.close()
            cur = _Run(gi, spec, has_imu)
        cur.g1 = gi + 1
        cur.ns.append(ej.stamp_ns)
        cur.enc.append(np.asarray(pos, dtype=float)[spec[0]])
        if has_imu:
            cur.imu.append(np.asarray(acc, dtype=float)[axes])
        cur.tau.append(tau)
        run_of[gi] = cur
    if cur is not None:
        cur.close()
    return run_of


SENSORS = ("encoders", "imu", "branch_forces")


class _Filter:
    """:func:`run_events`' loop, fed one chunk of events after another: a chunk holds whole
    stamp groups (all events of its stamps, none split across chunks) in the final order, so
    that feeding the chunks one by one gives what feeding their concatenation gives."""

    def __init__(self, obs: Observer, fast: bool = True, gate: threading.Event | None = None):
        self.obs, self.fast = obs, fast
        self.gate = gate  # cleared while this runs Python (other threads wait), set otherwise
        self.stream = ObserverStream(obs)
        self.rows = Rows(obs)
        self.nis = dict.fromkeys(SENSORS, np.nan)
        self.fault = ""
        self.last_row_ns = None
        self.fixed = None

    def feed(self, events: list[Event]) -> None:
        if self.fault:
            return
        if self.gate is None:
            self._feed(events, None)
            return
        self.gate.clear()
        try:
            self._feed(events, self.gate)
        finally:
            self.gate.set()

    def _feed(self, events: list[Event], gate: threading.Event | None) -> None:
        obs, stream, rows, sensors = self.obs, self.stream, self.rows, SENSORS
        nis, fault, last_row_ns, fixed = self.nis, self.fault, self.last_row_ns, self.fixed
        groups = _groups(events)
        run_of = _fast_runs(obs, stream, events, groups) if self.fast else [None] * len(groups)
        skip = -1  # a group the fast path stopped at: the per-message API's

        def record(ns: int) -> None:
            rows.t.append(ns)
            rows.flat.append(obs.estimate_flat())
            rows.nis.append([nis[s] for s in sensors])

        gi = 0
        while gi < len(groups):
            run = run_of[gi]
            if run is not None and gi != skip and obs.initialised and obs.fault is None \
                    and run.ns[gi - run.g0] != last_row_ns:
                if fixed is None:
                    obs.flat_layout()
                    imu, p = obs.imu, obs.cfg.process
                    fixed = (obs.mech.arrays, obs.dist_idx, obs.dist_col, obs.Lz, obs.Fz, obs.psd_ae, obs.rel_ae,
                             obs.psd_z, obs.eps_q, obs.eps_v, obs.point, obs.with_point, obs._active_idx,
                             np.array([p.max_interval, p.dt, obs.cfg.timing.stamp_tolerance, p.relinearize_every,
                                       obs.cfg.timing.command_timeout]),
                             imu.S if imu is not None else np.zeros((0, 3)), imu.g if imu is not None else np.zeros(3),
                             imu.var if imu is not None else np.zeros(0),
                             obs.gate(len(imu.axes)) if imu is not None else np.inf)
                (ma, dist_idx, dist_col, Lz, Fz, psd_ae, rel_ae, psd_z, eps_q, eps_v, point, with_point, active_idx,
                 timing, S, g, imu_R, imu_gate) = fixed
                idx, H, var, js, wrap, _ = run.plan
                a, b = gi - run.g0, run.g1 - run.g0
                hold, last = obs.tau_hold.copy(), obs.tau_last.copy()
                ctl = np.array([obs.t, float(obs._lin_age), obs._lin_T, obs.t_command])
                if run.flat is None:  # the run's rows (views of it become rows.flat)
                    run.flat, run.nis = np.empty((b, obs._flat_width)), np.empty((b, 2))
                if gate is not None:  # the compiled call leaves the GIL to the other threads
                    gate.set()
                done = kernels.run_periods(
                    ma, obs.q, obs.qd, obs.z, obs.P, obs.Phi, obs.Qd, obs.Hpt, obs.info, dist_idx, dist_col, Lz,
                    Fz, psd_ae, rel_ae, psd_z, eps_q, eps_v, point, with_point, active_idx, hold, last, ctl, timing,
                    H, var, js, wrap, obs.gate(len(idx)), run.enc, run.has_imu, S, g, imu_R, imu_gate, run.imu, run.ts,
                    run.tau, obs._ee_point, obs._ee, obs._branch_joint, obs._stiff, obs._damp, obs._rest, a, b,
                    run.flat, run.nis)
                if gate is not None:
                    gate.clear()
                if done:
                    obs.t, obs._lin_age, obs._lin_T, obs.t_command = float(ctl[0]), int(ctl[1]), float(ctl[2]), \
                        float(ctl[3])
                    obs.tau_hold, obs.tau_last = hold, last
                    ns = run.ns[a:a + done]
                    enc_nis = run.nis[a:a + done, 0].tolist()
                    obs._accepted_many("encoders", enc_nis, len(idx))
                    obs.stats["command"].accepted += done
                    first = dict(nis, encoders=enc_nis[0])
                    if run.has_imu:
                        imu_nis = run.nis[a:a + done, 1].tolist()
                        obs._accepted_many("imu", imu_nis, run.imu.shape[1])
                        first["imu"] = imu_nis[0]
                        stream.results = [UpdateResult("imu", ns[-1] * 1e-9, True, imu_nis[-1], run.imu.shape[1])]
                        tail = [[e, i, np.nan] for e, i in zip(enc_nis[1:], imu_nis[1:], strict=True)]
                    else:
                        stream.results = [UpdateResult("encoders", ns[-1] * 1e-9, True, enc_nis[-1], len(idx))]
                        tail = [[e, np.nan, np.nan] for e in enc_nis[1:]]
                    rows.t.extend(ns)
                    rows.flat.extend(run.flat[a:a + done])
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
                    elif ev.kind == "joint_state":
                        results = stream.on_joint_state(ev.stamp_ns, *ev.data)
                    elif ev.kind == "imu":
                        results = stream.on_imu(ev.stamp_ns, ev.data[0], ev.data[1])
                    else:
                        results = stream.on_branch_forces(ev.stamp_ns, *ev.data)
                except ObserverFault as err:
                    fault = str(err)
                    break
                if ev.kind != "command":
                    for r in results:
                        if r.accepted and r.dof:
                            nis[r.sensor] = r.nis
                nxt = events[i + 1].stamp_ns if i + 1 < len(events) else None
                if nxt != ev.stamp_ns and obs.initialised and ev.stamp_ns != last_row_ns \
                        and abs(obs.t - ev.stamp_ns * 1e-9) <= obs.cfg.timing.stamp_tolerance:
                    record(ev.stamp_ns)
                    last_row_ns = ev.stamp_ns
                    nis = dict.fromkeys(sensors, np.nan)
            if fault:
                break
            gi += 1
        self.nis, self.fault, self.last_row_ns, self.fixed = nis, fault, last_row_ns, fixed


def run_events(obs: Observer, events: list[Event], order: str = "stamp", fast: bool = True
               ) -> tuple[Rows, ObserverStream, str]:
    """Feed events through a stream; one estimate per distinct stamp. Returns (rows, stream, fault).

    ``fast``: ordinary stamp groups (a joint state, an accelerometer sample, the command)
    go through ``kernels.run_periods``, many in one compiled call, with the same numbers,
    statistics and rows as the per-message API (``fast=False``) that takes all the others.
    """
    if order == "stamp":
        events = sorted(events, key=_order_key)
    elif order != "arrival":
        raise InputError(f"unknown message order {order!r} (expected stamp or arrival)")
    f = _Filter(obs, fast)
    f.feed(events)
    return f.rows, f.stream, f.fault


def _order_key(e: Event) -> tuple[int, int]:
    return e.stamp_ns, e.index


def csv_header(obs: Observer) -> list[str]:
    mech = obs.mech
    names = mech.joint_names
    vel = [f"{n}_vel" for n in names]
    F = [f"F_{b}" for b in obs.branch_names]
    ee = ["ee_x", "ee_y", "ee_z"][:len(mech.ee_components)]
    d = [f"d_{mech.joint_names[j]}" for j in obs.dist_idx]
    cols = ["t", *names, *vel, *F]
    cols += [f"{c}_std" for c in (*names, *vel, *F)]
    cols += [*ee, *[f"{c}_std" for c in ee], *d, *[f"{c}_std" for c in d]]
    return [*cols, "nis_encoders", "nis_imu", "nis_branch_forces"]


def csv_table(rows: Rows) -> np.ndarray:
    lay = rows.obs.flat_layout()
    cols = np.r_[lay["q"], lay["qd"], lay["branch_force"], lay["q_std"], lay["qd_std"], lay["branch_force_std"],
                 lay["ee"], lay["ee_std"], lay["disturbance"], lay["disturbance_std"]]
    t = np.array(rows.t, dtype=np.int64) * 1e-9
    return np.column_stack([t, rows.table()[:, cols], np.array(rows.nis, dtype=float).reshape(len(rows.t), 3)])


def write_bag(path: Path, obs: Observer, rows: Rows, storage: str = "mcap") -> None:
    """Estimates as a rosbag2: /joint_states, /branch_forces, /ee_pose, /observer/joint_states_stddev."""
    out = _BagOut(path, obs, storage)
    try:
        out.write(rows)
    finally:
        out.close()


class _BagOut:
    """:func:`write_bag` a chunk of rows after another (the same file as all rows at once)."""

    def __init__(self, path: Path, obs: Observer, storage: str = "mcap"):
        from rosbags.rosbag2 import StoragePlugin, Writer

        from elastic_pm_dyn.ros.msg_types import BRANCH_FORCES_MSGTYPE, make_typestore
        ts = make_typestore()
        plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
        self.obs = obs
        self.names = list(obs.mech.joint_names)
        self.comps = [int(c) for c in obs.mech.ee_components]
        self.lay = obs.flat_layout()
        self.w = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        self.w.open()
        try:
            self.conns = [self.w.add_connection("/joint_states", JOINT_STATE, typestore=ts),
                          self.w.add_connection("/branch_forces", BRANCH_FORCES_MSGTYPE, typestore=ts),
                          self.w.add_connection("/ee_pose", POSE_STAMPED, typestore=ts),
                          self.w.add_connection("/observer/joint_states_stddev", JOINT_STATE, typestore=ts)]
        except BaseException:
            self.w.close()
            raise

    def write(self, rows: Rows) -> None:
        obs, names, lay, w, conns = self.obs, self.names, self.lay, self.w, self.conns
        table = rows.table()
        ns = np.array(rows.t, dtype=np.int64)
        xyz = np.zeros((len(ns), 3))
        xyz[:, self.comps] = table[:, lay["ee"]]
        # Every message encoded at once (one layout per topic), then written row by row.
        msgs = [cdr.encode_joint_state_batch(ns, names, table[:, lay["q"]], table[:, lay["qd"]],
                                             table[:, lay["effort"]]),
                cdr.encode_branch_forces_batch(ns, obs.branch_names, *(table[:, lay[k]] for k in (
                    "branch_force", "deflection", "deflection_rate", "branch_force_std"))),
                cdr.encode_pose_stamped_batch(ns, xyz, "world"),
                cdr.encode_joint_state_batch(ns, names, table[:, lay["q_std"]], table[:, lay["qd_std"]],
                                             np.zeros((len(ns), 0)))]
        blobs = [(m.tobytes(), m.shape[1]) for m in msgs]
        if not _write_rows_mcap(w, conns, ns, msgs):
            write = w.write
            for k, t in enumerate(ns.tolist()):
                for c, (blob, size) in zip(conns, blobs, strict=True):
                    write(c, t, blob[k * size:(k + 1) * size])

    def close(self) -> None:
        self.w.close()


def _write_rows_mcap(w, conns, ns: np.ndarray, msgs: list[np.ndarray]) -> bool:
    """Write row k's message of every connection, row after row, as ``Writer.write`` would,
    but with the mcap message records built at once with numpy (rosbags spends ~10 us per
    message on them). Only for rosbags' uncompressed ``McapWriter`` as we know it (False
    otherwise: the caller writes message by message); the file is byte for byte the same."""
    from collections import defaultdict
    from io import BytesIO

    from rosbags.rosbag2.enums import CompressionMode
    try:
        from rosbags.rosbag2.storage_mcap import McapWriter
    except ImportError:  # pragma: no cover - older or newer rosbags
        return False
    st = w.storage
    chunk = getattr(st, "chunk", None)
    if (type(st) is not McapWriter or w.compression_mode != CompressionMode.NONE or st.compression != ""
            or not isinstance(getattr(chunk, "bio", None), BytesIO) or not isinstance(chunk.msgs, defaultdict)
            or not all(c.id in st.channel_stats for c in conns)):
        return False
    n = len(ns)
    # Record: op 0x05, u64 length, u16 channel id, u32 sequence 0, u64 log time, u64 publish time, data.
    parts, sizes = [], []
    stamp = ns.astype("<u8").view(np.uint8).reshape(n, 8)
    for c, m in zip(conns, msgs, strict=True):
        rec = np.zeros((n, 31 + m.shape[1]), dtype=np.uint8)
        rec[:, 0] = 0x05
        rec[:, 1:9] = np.frombuffer(int(22 + m.shape[1]).to_bytes(8, "little"), dtype=np.uint8)
        rec[:, 9:11] = np.frombuffer(int(c.id).to_bytes(2, "little"), dtype=np.uint8)
        rec[:, 15:23] = stamp
        rec[:, 23:31] = stamp
        rec[:, 31:] = m
        parts.append(rec)
        sizes.append(rec.shape[1])
    blob = np.hstack(parts).tobytes() if n else b""
    t = ns.tolist()
    ids = [c.id for c in conns]
    counts = dict.fromkeys(ids, 0)
    limit = 2**20  # McapWriter closes a chunk after the message that takes it past 1 MiB
    chunk = st.chunk
    pos = chunk.bio.tell()
    seg, first = 0, 0  # blob offset and row where the pending segment starts
    end = 0

    def flush(last_row: int) -> None:
        chunk.bio.write(blob[seg:end])
        lo, hi = min(t[first:last_row + 1]), max(t[first:last_row + 1])
        chunk.message_start_time = min(lo, chunk.message_start_time)
        chunk.message_end_time = max(hi, chunk.message_end_time)
        st.message_start_time = min(lo, st.message_start_time)
        st.message_end_time = max(hi, st.message_end_time)
        w.min_timestamp = min(lo, w.min_timestamp)
        w.max_timestamp = max(hi, w.max_timestamp)

    for r in range(n):
        tr = t[r]
        for cid, size in zip(ids, sizes, strict=True):
            chunk.msgs[cid].append((tr, pos))
            counts[cid] += 1
            pos += size
            end += size
            if pos > limit:
                flush(r)
                st.close_chunk()
                chunk = st.chunk
                pos = chunk.bio.tell()
                seg, first = end, r
    if end > seg:
        flush(n - 1)
    for cid, cnt in counts.items():
        st.channel_stats[cid] += cnt
        w.counts[cid] += cnt
    return True


@dataclass
class OfflineResult:
    rows: Rows
    summary: dict
    observer: Observer


def observe_bag(mech: Mechanism, cfg: ObserverConfig, bag: str | Path, out: str | Path | None = None,
                topics: Topics | None = None, order: str = "stamp", storage: str = "mcap",
                write_estimates_bag: bool = True, log=print, pipeline: bool = True) -> OfflineResult:
    """Run the observer over ``bag``; write CSV, bag and summary into ``out`` (if given).

    ``pipeline``: read, filter and write at once (a reading thread, a writing thread, the filter
    here; the compiled filter kernel releases the GIL), with the same results, files and
    summary keys as one after the other (``pipeline=False``). The filter takes the events in
    chunks of whole stamp groups. ``order="stamp"``: events are released to it once the bag
    has reached stamps :data:`STAMP_LAG_NS` later; an event stamped before what has been
    released already (a bag not stamp-ordered within that lag) makes the filter start over,
    one after the other, on all events. ``order="arrival"``: released in bag order, less the
    last stamp's events; an event stamped before the first released ones (the observer's
    start time) makes it start over alike. In the summary, ``wall_read_s`` is then the time
    until the bag is read, ``wall_filter_s`` and ``wall_write_s`` the time spent filtering
    and writing (they overlap). Python's thread switch interval is :data:`SWITCH_INTERVAL_S`
    meanwhile."""
    topics = topics or Topics.from_config(cfg)
    wall0 = time.perf_counter()
    if pipeline and order in ("stamp", "arrival"):
        with _short_switch_interval():
            return _observe_pipelined(mech, cfg, Path(bag), out, topics, order, storage, write_estimates_bag, log,
                                      wall0)
    events, counts = read_events(Path(bag), topics, cfg)
    if not events:
        raise InputError(f"{bag}: no messages on the observer's topics")
    wall_read = time.perf_counter() - wall0
    obs = Observer(mech, cfg, t0=min(e.stamp_ns for e in events) * 1e-9)
    report = obs.observability()
    log(report.text())
    wall1 = time.perf_counter()
    rows, stream, fault = run_events(obs, events, order)
    wall_filter = time.perf_counter() - wall1
    summary = _summary(bag, topics, counts, order, events, rows, obs, stream, fault, report, wall_read, wall_filter)
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        wall2 = time.perf_counter()
        if rows.t:
            np.savetxt(out / "estimates.csv", csv_table(rows), delimiter=",", header=",".join(csv_header(obs)),
                       comments="", fmt="%.12g")
            if write_estimates_bag:
                bag_out = out / "estimates"
                if bag_out.exists():
                    raise InputError(f"{bag_out} exists already (rosbag2 will not overwrite it)")
                write_bag(bag_out, obs, rows, storage)
        summary["wall_write_s"] = time.perf_counter() - wall2
    return _finish(summary, out, wall0, rows, obs)


def _summary(bag, topics, counts, order, events, rows, obs, stream, fault, report, wall_read, wall_filter) -> dict:
    stamps = [e.stamp_ns for e in events]
    duration = (max(stamps) - min(stamps)) * 1e-9
    return {
        "bag": str(bag), "topics": topics.__dict__, "messages": counts, "order": order,
        "rows": len(rows.t), "fault": fault, "health": list(obs.health()),
        "bad_commands": stream.bad_commands,
        "sensors": {s: {"accepted": st.accepted, "rejected": st.rejected, "late": st.late, "nan_entries": st.nan,
                        "mean_nis": obs.nis_band(s)[2], "last_rejection": st.last_reason}
                    for s, st in obs.stats.items()},
        "duration_s": duration,
        "wall_read_s": wall_read, "wall_filter_s": wall_filter,
        "observability": report.text(),
    }


def _finish(summary: dict, out, wall0: float, rows: Rows, obs: Observer) -> OfflineResult:
    summary["wall_total_s"] = time.perf_counter() - wall0
    duration = summary["duration_s"]
    summary["speed_factor"] = duration / summary["wall_total_s"] if summary["wall_total_s"] > 0 else float("inf")
    if out is not None:
        (Path(out) / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    return OfflineResult(rows, summary, obs)


STAMP_LAG_NS = 500_000_000
"""``observe_bag(pipeline=True, order="stamp")``: how far (header stamps) the bag must have
gone past an event before the filter takes it; later events stamped earlier than that make
the filter start over on all events, one stage after the other."""

CHUNK_EVENTS = 1000
"""``observe_bag(pipeline=True)``: events per batch from the reading thread."""

_STAGE = ".observe-partial"
_WRITE_ROWS = 64

SWITCH_INTERVAL_S = 0.001
"""``observe_bag(pipeline=True)``: Python's thread switch interval while it runs (restored
after). The filter thread leaves the GIL for every compiled call and must get it back from a
reading or writing thread busy in Python: with the default 5 ms, that wait doubled the time
filtering took; 1 ms makes it small."""

_switch_lock = threading.Lock()
_switch = {"depth": 0, "saved": 0.0}


@contextlib.contextmanager
def _short_switch_interval():
    with _switch_lock:
        if _switch["depth"] == 0:
            _switch["saved"] = sys.getswitchinterval()
            sys.setswitchinterval(min(SWITCH_INTERVAL_S, _switch["saved"]))
        _switch["depth"] += 1
    try:
        yield
    finally:
        with _switch_lock:
            _switch["depth"] -= 1
            if _switch["depth"] == 0:
                sys.setswitchinterval(_switch["saved"])


def _read_worker(bag: Path, topics: Topics, cfg: ObserverConfig, counts: dict, q: queue.Queue,
                 stop: threading.Event, gate: threading.Event) -> None:
    """Reading thread: ("batch", events)..., then ("done", time) or ("error", exception)."""
    def put(item) -> bool:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.05)
                return True
            except queue.Full:
                continue
        return False

    gen = iter_events(bag, topics, cfg, counts, CHUNK_EVENTS, gate)
    try:
        for batch in gen:
            if not put(("batch", batch)):
                return
        put(("done", time.perf_counter()))
    except BaseException as exc:  # re-raised by the filtering thread
        put(("error", exc))
    finally:
        gen.close()


def _pieces(events: list[Event], size: int):
    """``events`` in consecutive pieces of about ``size`` events, none splitting a stamp group."""
    a, n = 0, len(events)
    while a < n:
        b = min(a + max(size, 1), n)
        while b < n and events[b].stamp_ns == events[b - 1].stamp_ns:
            b += 1
        yield events[a:b]
        a = b


class _WriteWorker(threading.Thread):
    """Writing thread: CSV (and bag) of the finished rows lo..hi-1 put into ``q``, into ``stage``."""

    def __init__(self, stage: Path, obs: Observer, rows: Rows, storage: str, with_bag: bool, gate: threading.Event):
        super().__init__(name="observe-write", daemon=True)
        self.stage, self.obs, self.rows, self.storage, self.with_bag = stage, obs, rows, storage, with_bag
        self.gate = gate
        self.header = ",".join(csv_header(obs))
        obs.flat_layout()
        self.q: queue.Queue = queue.Queue()
        self.error: BaseException | None = None
        self.busy = 0.0

    def run(self) -> None:
        fh = bag = None
        try:
            while True:
                item = self.q.get()
                if item is None:
                    break
                lo, hi = item
                for a in range(lo, hi, _WRITE_ROWS):  # in pieces: waits for the gate between them
                    b = min(a + _WRITE_ROWS, hi)
                    self.gate.wait()
                    t = time.perf_counter()
                    rows = Rows(self.obs, self.rows.t[a:b], self.rows.flat[a:b], self.rows.nis[a:b])
                    header = ""
                    if fh is None:
                        fh = open(self.stage / "estimates.csv", "w")  # noqa: SIM115 - closed below
                        header = self.header
                        if self.with_bag:
                            bag = _BagOut(self.stage / "estimates", self.obs, self.storage)
                    np.savetxt(fh, csv_table(rows), delimiter=",", header=header, comments="", fmt="%.12g")
                    if bag is not None:
                        bag.write(rows)
                    self.busy += time.perf_counter() - t
        except BaseException as exc:
            self.error = exc
        finally:
            for f in (fh, bag):
                if f is not None:
                    try:
                        f.close()
                    except BaseException as exc:
                        self.error = self.error or exc

    def finish(self) -> None:
        self.q.put(None)
        self.join()
        if self.error is not None:
            raise self.error


def _observe_pipelined(mech: Mechanism, cfg: ObserverConfig, bag: Path, out, topics: Topics, order: str,
                       storage: str, write_estimates_bag: bool, log, wall0: float) -> OfflineResult:
    counts: dict = {}
    q: queue.Queue = queue.Queue(maxsize=8)
    stop = threading.Event()
    gate = threading.Event()  # cleared while the filter runs Python: reading and writing wait then
    gate.set()
    reader = threading.Thread(target=_read_worker, args=(bag, topics, cfg, counts, q, stop, gate),
                              name="observe-read", daemon=True)
    out = Path(out) if out is not None else None
    overlap_write = out is not None and not (write_estimates_bag and (out / "estimates").exists())
    made: list[Path] = []  # directories this call created (removed again on an error)
    stage = out / _STAGE if out is not None else None
    events: list[Event] = []
    pending: list[Event] = []
    state = {"filter": None, "writer": None, "wall": 0.0, "t0": None}
    fallback = False
    released = None  # order="stamp": every event released so far is stamped before this
    top = None

    def release(chunk: list[Event]) -> None:
        filt = state["filter"]
        if filt is None:
            state["t0"] = min(e.stamp_ns for e in events)
            obs = Observer(mech, cfg, t0=state["t0"] * 1e-9)
            filt = state["filter"] = _Filter(obs, gate=gate)
            state["report"] = obs.observability()
            if overlap_write:
                for d in (out, *out.parents):
                    if d.exists():
                        break
                    made.append(d)
                out.mkdir(parents=True, exist_ok=True)
                if stage.exists():
                    shutil.rmtree(stage)
                stage.mkdir()
                state["writer"] = _WriteWorker(stage, obs, filt.rows, storage, write_estimates_bag, gate)
                state["writer"].start()
        t = time.perf_counter()
        n0 = len(filt.rows.t)
        filt.feed(chunk)
        state["wall"] += time.perf_counter() - t
        if state["writer"] is not None and len(filt.rows.t) > n0:
            state["writer"].q.put((n0, len(filt.rows.t)))

    reader.start()
    try:
        try:
            while True:
                what, item = q.get()
                if what == "error":
                    raise item
                if what == "done":
                    wall_read = item - wall0
                    break
                events.extend(item)
                if fallback:
                    continue
                lo = min(e.stamp_ns for e in item)
                if order == "stamp":
                    if released is not None and lo < released:
                        fallback = True
                        continue
                    pending.extend(item)
                    hi = max(e.stamp_ns for e in item)
                    top = hi if top is None else max(top, hi)
                    cut = top - STAMP_LAG_NS
                    if released is None or cut > released:
                        chunk = [e for e in pending if e.stamp_ns < cut]
                        if chunk:
                            pending = [e for e in pending if e.stamp_ns >= cut]
                            chunk.sort(key=_order_key)
                            released = cut
                            release(chunk)
                else:
                    if state["t0"] is not None and lo < state["t0"]:
                        fallback = True
                        continue
                    pending.extend(item)
                    k, last = len(pending), pending[-1].stamp_ns
                    while k > 0 and pending[k - 1].stamp_ns == last:
                        k -= 1
                    if k:
                        chunk, pending = pending[:k], pending[k:]
                        release(chunk)
        finally:
            stop.set()
            reader.join()
        if not events:
            raise InputError(f"{bag}: no messages on the observer's topics")
        if not fallback and pending:
            if order == "stamp":
                pending.sort(key=_order_key)
            for piece in _pieces(pending, CHUNK_EVENTS // 2):  # the rows written while the next is filtered
                release(piece)
        writer = state["writer"]
        if fallback:  # start over, one stage after the other
            if writer is not None:
                writer.finish()
                state["writer"] = writer = None
                shutil.rmtree(stage, ignore_errors=True)
            obs = Observer(mech, cfg, t0=min(e.stamp_ns for e in events) * 1e-9)
            report = obs.observability()
            log(report.text())
            wall1 = time.perf_counter()
            rows, stream, fault = run_events(obs, events, order)
            wall_filter = time.perf_counter() - wall1
        else:
            filt = state["filter"]
            obs, rows, stream, fault, report = filt.obs, filt.rows, filt.stream, filt.fault, state["report"]
            log(report.text())
            wall_filter = state["wall"]
        summary = _summary(bag, topics, counts, order, events, rows, obs, stream, fault, report, wall_read,
                           wall_filter)
        if out is not None:
            wall2 = time.perf_counter()
            if writer is not None:
                writer.finish()
                state["writer"] = None
                if rows.t:
                    os.replace(stage / "estimates.csv", out / "estimates.csv")
                    if write_estimates_bag:
                        os.rename(stage / "estimates", out / "estimates")
                shutil.rmtree(stage)
                summary["wall_write_s"] = writer.busy + time.perf_counter() - wall2
            else:
                out.mkdir(parents=True, exist_ok=True)
                if rows.t:
                    np.savetxt(out / "estimates.csv", csv_table(rows), delimiter=",",
                               header=",".join(csv_header(obs)), comments="", fmt="%.12g")
                    if write_estimates_bag:
                        bag_out = out / "estimates"
                        if bag_out.exists():
                            raise InputError(f"{bag_out} exists already (rosbag2 will not overwrite it)")
                        write_bag(bag_out, obs, rows, storage)
                summary["wall_write_s"] = time.perf_counter() - wall2
    except BaseException:
        writer = state["writer"]
        if writer is not None:
            with contextlib.suppress(BaseException):  # the first error is the one to report
                writer.finish()
            shutil.rmtree(stage, ignore_errors=True)
            for d in made:
                try:
                    d.rmdir()
                except OSError:
                    break
        raise
    return _finish(summary, out, wall0, rows, obs)


def recording_to_bag(rec, path: str | Path, use: tuple[str, ...] = ("encoders", "imu", "branch_forces"),
                     storage: str = "mcap", topics: Topics | None = None, imu_frame: str = "ee_imu") -> None:
    """Write a simulated :class:`~elastic_pm_dyn.observer.scenarios.Recording` as the bag a
    robot would give: per sample the measurements stamped t_k, then the command of t_k."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from elastic_pm_dyn.ros.msg_types import BRANCH_FORCES_MSGTYPE, make_typestore
    topics = topics or Topics()
    ts = make_typestore()
    T = ts.types["builtin_interfaces/msg/Time"]
    H = ts.types["std_msgs/msg/Header"]
    JS = ts.types[JOINT_STATE]
    BF = ts.types[BRANCH_FORCES_MSGTYPE]
    Imu = ts.types[IMU]
    V3 = ts.types["geometry_msgs/msg/Vector3"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    names = list(rec.active_names)
    zero9 = np.zeros(9)
    unknown = np.full(9, -1.0)  # covariance[0] = -1: not provided (sensor_msgs/Imu convention)
    with Writer(Path(path), version=Writer.VERSION_LATEST, storage_plugin=plugin) as w:
        c_cmd = w.add_connection(topics.torque_command, JOINT_STATE, typestore=ts)
        c_js = w.add_connection(topics.measured_joint_states, JOINT_STATE, typestore=ts)
        c_imu = w.add_connection(topics.ee_imu, IMU, typestore=ts) if "imu" in use else None
        c_bf = w.add_connection(topics.measured_branch_forces, BRANCH_FORCES_MSGTYPE, typestore=ts) \
            if "branch_forces" in use else None
        for k, ns in enumerate(rec.stamp_ns):
            ns = int(ns)
            sec, nsec = divmod(ns, 1_000_000_000)
            hdr = H(stamp=T(sec=sec, nanosec=nsec), frame_id="")
            w.write(c_js, ns, ts.serialize_cdr(JS(header=hdr, name=names, position=rec.encoder[k],
                                                  velocity=np.zeros(0), effort=np.zeros(0)), JOINT_STATE))
            if c_imu is not None:
                a = rec.accel[k]
                msg = Imu(header=H(stamp=T(sec=sec, nanosec=nsec), frame_id=imu_frame),
                          orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=unknown,
                          angular_velocity=V3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=unknown,
                          linear_acceleration=V3(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                          linear_acceleration_covariance=zero9)
                w.write(c_imu, ns, ts.serialize_cdr(msg, IMU))
            if c_bf is not None:
                w.write(c_bf, ns, ts.serialize_cdr(BF(header=hdr, name=list(rec.branch_names), force=rec.branch[k],
                                                      deflection=np.zeros(0), deflection_rate=np.zeros(0),
                                                      force_stddev=np.zeros(0)), BRANCH_FORCES_MSGTYPE))
            w.write(c_cmd, ns, ts.serialize_cdr(JS(header=hdr, name=names, position=np.zeros(0),
                                                   velocity=np.zeros(0), effort=rec.tau_cmd[k]), JOINT_STATE))


def estimates_equal(a: list[Estimate], b: list[Estimate]) -> float:
    """Largest difference of states and covariances between two estimate sequences (inf if lengths differ)."""
    if len(a) != len(b):
        return float("inf")
    worst = 0.0
    for x, y in zip(a, b, strict=True):
        worst = max(worst, float(np.max(np.abs(x.x - y.x))), float(np.max(np.abs(x.P - y.P))), abs(x.t - y.t))
    return worst
