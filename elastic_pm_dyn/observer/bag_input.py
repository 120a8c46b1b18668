"""The observer's input bag: its topics and message types, read and decoded into events.

Reads the torque commands (``sensor_msgs/JointState`` effort, or
``std_msgs/Float64MultiArray`` in the model's active-joint order), the measured joint
states, optionally an ``sensor_msgs/Imu`` and measured ``elastic_pm_dyn_msgs/BranchForces``
with ``rosbags`` (mcap or sqlite3) into :class:`Event` s in bag order, each with its header
stamp (a ``Float64MultiArray`` has none: the bag's receive time). Messages are decoded
straight from their CDR bytes (:mod:`~elastic_pm_dyn.observer.cdr`), with rosbags'
deserialiser for anything unexpected. :func:`recording_to_bag` writes such a bag from a
simulated recording.
"""

from __future__ import annotations

import struct
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import cdr
from elastic_pm_dyn.observer.config import ObserverConfig

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
IMU = "sensor_msgs/msg/Imu"



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
