"""The observer's input bag: its topics and message types, read and decoded into events.

Reads the torque commands (``sensor_msgs/JointState`` effort, or
``std_msgs/Float64MultiArray`` in the model's active-joint order), the measured joint
states, optionally an ``sensor_msgs/Imu`` and measured ``elastic_pm_dyn_msgs/BranchForces``
through :mod:`elastic_pm_dyn.bags` (mcap or sqlite3) into :class:`Event` s in bag order,
each with its header stamp (a ``Float64MultiArray`` has none: the bag's receive time).
Messages are decoded straight from their CDR bytes, rosbags' deserialiser taking anything
unexpected (:class:`~elastic_pm_dyn.bags.decode.Decoder`). :func:`recording_to_bag`
writes such a bag from a simulated recording.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from elastic_pm_dyn.bags.decode import Decoder
from elastic_pm_dyn.bags.msgtypes import (
    BRANCH_FORCES,
    FLOAT64_ARRAY,
    HEADER,
    IMU,
    JOINT_STATE,
    NS,
    QUATERNION,
    TIME,
    VECTOR3,
)
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer.config import ObserverConfig

# Accepted message types of each kind of input.
EXPECTED = {"command": (JOINT_STATE, FLOAT64_ARRAY), "applied": (JOINT_STATE,), "joint_state": (JOINT_STATE,),
            "imu": (IMU,), "branch_forces": (BRANCH_FORCES,)}


@dataclass
class Topics:
    torque_command: str = "/torque_command"
    measured_joint_states: str = "/measured_joint_states"
    ee_imu: str = "/ee_imu"
    measured_branch_forces: str = "/measured_branch_forces"
    applied_torque: str = "/applied_torque"  # "": never

    @classmethod
    def from_config(cls, cfg: ObserverConfig) -> Topics:
        def slash(name: str) -> str:
            return name if name.startswith("/") else "/" + name
        t = cfg.topics
        return cls(slash(t.torque_command), slash(t.measured_joint_states), slash(t.ee_imu),
                   slash(t.measured_branch_forces), slash(t.applied_torque) if t.applied_torque else "")


@dataclass
class Event:
    stamp_ns: int
    kind: str
    data: tuple
    index: int = 0


def _decode(dec: Decoder, msgtype: str, kind: str, t_recv: int, raw: bytes) -> tuple[int, tuple]:
    """(stamp [ns], the event's data) of one message."""
    if msgtype == FLOAT64_ARRAY:  # no header: the bag's receive time
        return int(t_recv), ((), dec.float64_array(raw))
    if kind == "command":
        ns, names, _, _, effort = dec.joint_state(raw)
        return ns, (names, effort)
    if kind == "joint_state":
        ns, names, pos, vel, eff = dec.joint_state(raw)
        return ns, (names, pos, vel, eff)
    if kind == "imu":
        ns, frame, acc = dec.imu(raw)
        return ns, (acc, frame)
    ns, names, force = dec.branch_forces(raw)
    return ns, (names, force)


BACKWARD_LIMIT = 10  # stamps of one topic that go back in time, and ...
BACKWARD_SHARE = 0.01  # ... this share of its messages so far: its stamps are not the samples' times


class StampOrder:
    """Each topic's header stamps must run forward in the order the bag recorded them (one
    publisher stamps its samples in order, the recorder keeps that order): a topic whose stamps go
    back more than BACKWARD_LIMIT times, and in more than BACKWARD_SHARE of its messages, has
    stamps that are not its samples' times (shuffled, two publishers, a clock that jumped). The
    filter would take each sample for another time and diverge; the bag is refused in one line
    instead. A few late messages (a recorder's reordering) stay below both."""

    def __init__(self, bag: Path):
        self.bag = bag
        self.seen: dict[str, list[int]] = {}  # topic -> [messages, backward steps, latest stamp]

    def check(self, topic: str, stamp: int) -> None:
        counts = self.seen.setdefault(topic, [0, 0, stamp])
        counts[0] += 1
        if stamp < counts[2]:
            counts[1] += 1
            if counts[1] > BACKWARD_LIMIT and counts[1] > BACKWARD_SHARE * counts[0]:
                raise InputError(f"{self.bag}: {topic}: header stamps go back in time at {counts[1]} of its first "
                                 f"{counts[0]} messages (now {stamp / NS:.9f} s after {counts[2] / NS:.9f} s): they "
                                 "are not the times of its samples (shuffled, two publishers, a clock that jumped?); "
                                 "the observer needs each topic stamped in the order it was recorded")
        else:
            counts[2] = stamp


def read_events(bag: Path, topics: Topics, cfg: ObserverConfig) -> tuple[list[Event], dict]:
    """Decode the observer's input topics of a bag into events (bag order)."""
    events: list[Event] = []
    counts: dict = {}
    for batch in iter_events(bag, topics, cfg, counts, 1 << 62):
        events.extend(batch)
    return events, counts


def iter_events(bag: Path, topics: Topics, cfg: ObserverConfig, counts: dict, chunk: int = 2000,
                gate: threading.Event | None = None) -> Iterator[list[Event]]:
    """:func:`read_events` in batches of ``chunk`` events (bag order); ``counts`` (per kind)
    filled in as they are read; before each message, waits for ``gate`` (if given) to be set."""
    wanted = {topics.torque_command: "command", topics.measured_joint_states: "joint_state"}
    if topics.applied_torque:
        wanted[topics.applied_torque] = "applied"
    if "imu" in cfg.sensors:
        wanted[topics.ee_imu] = "imu"
    if "branch_forces" in cfg.sensors and cfg.branch_forces.source == "branch_forces":
        wanted[topics.measured_branch_forces] = "branch_forces"
    events: list[Event] = []
    counts.update({k: 0 for k in wanted.values() if k != "applied"})  # applied: counted only if present
    with open_bag(bag) as reader:
        reader.require_messages()
        conns = [c for c in reader.connections if c.topic in wanted]
        found = {c.topic for c in conns}
        has_applied = topics.applied_torque in found
        for topic in (topics.applied_torque if has_applied else topics.torque_command, topics.measured_joint_states):
            if topic not in found:
                have = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
                raise InputError(f"{bag}: no topic {topic} (topics: {have}); see --torque-topic/--joint-topic")
        for c in conns:
            if c.msgtype not in EXPECTED[wanted[c.topic]]:
                raise InputError(f"{bag}: {c.topic} has type {c.msgtype}, expected "
                                 f"{' or '.join(EXPECTED[wanted[c.topic]])}")
        dec = reader.decoder()
        order = StampOrder(bag)
        switched = False
        for i, (conn, t_recv, raw) in enumerate(reader.messages(conns)):
            if gate is not None and not gate.is_set():
                gate.wait()
            kind = wanted[conn.topic]
            if kind == "applied":  # the torque that acted: the torque input from its first message on, as
                counts["applied"] = counts.get("applied", 0) + 1  # the live node takes it (no command after it)
                kind, switched = "command", True
            elif kind == "command" and switched:
                counts["superseded"] = counts.get("superseded", 0) + 1
                continue
            stamp, data = _decode(dec, conn.msgtype, kind, t_recv, raw)
            order.check(conn.topic, stamp)
            events.append(Event(stamp, kind, data, i))
            counts[kind] += 1
            if len(events) >= chunk:
                yield events
                events = []
        if events:
            yield events


def recording_to_bag(rec, path: str | Path, use: tuple[str, ...] = ("encoders", "imu", "branch_forces"),
                     storage: str = "mcap", topics: Topics | None = None, imu_frame: str = "ee_imu",
                     receive_ns: dict[str, np.ndarray] | None = None, commands: np.ndarray | None = None,
                     applied: bool = False) -> None:
    """Write a simulated :class:`~elastic_pm_dyn.observer.testing.scenarios.Recording` as the bag a
    robot would give: per sample the measurements stamped ``rec.stamp_ns[k]``, then the
    command of t_k. ``receive_ns``: the receive time [ns] per sample of each kind
    ("encoders", "imu", "branch_forces", "command"); a kind not given: its stamps. ``commands``:
    the torque_command values written (default ``rec.tau_cmd``); ``applied``: also the torque
    that acted over each period (``rec.acting``) on ``topics.applied_torque``, stamped at the
    period's start and received just before the next sample, as the plant node publishes it."""
    topics = topics or Topics()
    stamps = np.asarray(rec.stamp_ns, dtype=np.int64)
    recv = {kind: np.asarray((receive_ns or {}).get(kind, stamps), dtype=np.int64)
            for kind in ("encoders", "imu", "branch_forces", "command")}
    names = list(rec.active_names)
    zero9 = np.zeros(9)
    unknown = np.full(9, -1.0)  # covariance[0] = -1: not provided (sensor_msgs/Imu convention)
    with BagWriter(path, storage) as w:
        types = w.typestore.types
        T, H, JS, BF, Imu = types[TIME], types[HEADER], types[JOINT_STATE], types[BRANCH_FORCES], types[IMU]
        V3, Q = types[VECTOR3], types[QUATERNION]
        c_cmd = w.add_connection(topics.torque_command, JOINT_STATE)
        c_applied = w.add_connection(topics.applied_torque, JOINT_STATE) if applied else None
        tau = rec.tau_cmd if commands is None else np.asarray(commands, dtype=float)
        c_js = w.add_connection(topics.measured_joint_states, JOINT_STATE)
        c_imu = w.add_connection(topics.ee_imu, IMU) if "imu" in use else None
        c_bf = w.add_connection(topics.measured_branch_forces, BRANCH_FORCES) if "branch_forces" in use else None
        for k, ns in enumerate(rec.stamp_ns):
            sec, nsec = divmod(int(ns), NS)
            hdr = H(stamp=T(sec=sec, nanosec=nsec), frame_id="")
            w.write_message(c_js, int(recv["encoders"][k]), JS(header=hdr, name=names, position=rec.encoder[k],
                                                               velocity=np.zeros(0), effort=np.zeros(0)))
            if c_imu is not None:
                a = rec.accel[k]
                w.write_message(c_imu, int(recv["imu"][k]), Imu(
                    header=H(stamp=T(sec=sec, nanosec=nsec), frame_id=imu_frame),
                    orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=unknown,
                    angular_velocity=V3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=unknown,
                    linear_acceleration=V3(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                    linear_acceleration_covariance=zero9))
            if c_bf is not None:
                w.write_message(c_bf, int(recv["branch_forces"][k]), BF(
                    header=hdr, name=list(rec.branch_names), force=rec.branch[k], deflection=np.zeros(0),
                    deflection_rate=np.zeros(0), force_stddev=np.zeros(0)))
            w.write_message(c_cmd, int(recv["command"][k]), JS(header=hdr, name=names, position=np.zeros(0),
                                                               velocity=np.zeros(0), effort=tau[k]))
            if c_applied is not None:
                step = int(stamps[-1] - stamps[-2]) if len(stamps) > 1 else 2
                nxt = int(recv["encoders"][k + 1]) if k + 1 < len(stamps) else int(recv["encoders"][k]) + step
                w.write_message(c_applied, nxt - 1, JS(
                    header=hdr, name=names, position=np.zeros(0), velocity=np.zeros(0), effort=rec.acting[k]))
