"""Synthetic runs with known truth, written as rosbag2 bags the way our nodes publish them.

A plain ``rosbags`` Writer stands in for the recorder (mcap or sqlite3); bags "without
definitions" are written like old rosbag2 (sqlite3 without the message_definitions rows)
or with empty mcap schemas, so that readers need a default typestore.

Truth injected into :func:`synthetic_run`:
- the plant's end effector = reference path + ``offset`` (assembled by IK, springs at rest);
- branch forces in the hold phase: a damped oscillation of frequency ``f_d``, damping ratio
  ``zeta`` and amplitude ``amplitude`` on a static level;
- a known closure gap: the right elbow is turned by ``gap_angle`` on [0.10, 0.12) s.
"""

from __future__ import annotations

import functools
import math
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

from elastic_pm_dyn.bags.msgtypes import (
    BRANCH_FORCES,
    DIAGNOSTIC_ARRAY,
    FLOAT64_ARRAY,
    HEADER,
    JOINT_STATE,
    KEY_VALUE,
    POSE_STAMPED,
    QUATERNION,
    TIME,
)
from elastic_pm_dyn.bags.typestore import make_typestore
from elastic_pm_dyn.dynamics.inverse import tree_inverse_dynamics
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import rigid_feedforward
from elastic_pm_dyn.motion.trajectory import QuinticLine

CONFIG = Path(__file__).resolve().parent.parent / "config"
MODEL = CONFIG / "five_bar.yaml"
T0 = 1000.0  # [s] header stamp of the manoeuvre start
LATENCY = 2e-4  # [s] receive time - header stamp
LINE = QuinticLine(np.array([-0.05, 0.35]), np.array([0.05, 0.45]), move=0.2, hold=0.3)


@dataclass
class Run:
    """Sampled topics of a synthetic run; times relative to the manoeuvre start [s]."""

    t_state: np.ndarray
    q: np.ndarray  # (N, 6) elastic tree positions, mech.joint_names order
    qd: np.ndarray
    joint_names: list[str]
    q_ref: np.ndarray  # (N, 4) rigid positions
    qd_ref: np.ndarray
    ref_names: list[str]
    tau: np.ndarray  # (N, 2) motors
    motor_names: list[str]
    ee: np.ndarray  # (N, 2) plant end effector
    ee_ref: np.ndarray  # (N, 2)
    t_force: np.ndarray
    forces: np.ndarray  # (M, 2)
    branch_names: list[str]
    truth: dict = field(default_factory=dict)


@functools.lru_cache(maxsize=4)
def _kinematics(state_rate: float, offset: tuple, gap_angle: float) -> dict:
    """Reference (rigid IK of the line), plant states (elastic IK of line + offset), torques."""
    model = load_model(MODEL)
    mech = Mechanism(model)
    ff = rigid_feedforward(model)
    rigid = ff.mech
    t = np.arange(round(LINE.duration * state_rate) + 1) / state_rate
    q_ref, qd_ref, tau, q = [], [], [], []
    free = np.sort(np.concatenate([mech.active, mech.passive]))
    guess = initial_state(mech)
    for s in t:
        p, pd, pdd = LINE(s)
        qr, qdr, qddr = ff.joint_motion(p, pd, pdd)
        q_ref.append(qr)
        qd_ref.append(qdr)
        tau.append(tree_inverse_dynamics(rigid, qr, qdr, qddr))
        guess = solve_pose(mech, guess, free, p + np.asarray(offset))
        q.append(guess.copy())
    q = np.array(q)
    qd = np.gradient(q, t, axis=0)
    ee = np.array([mech.end_effector(x) for x in q])
    ee_ref = np.array([LINE(s)[0] for s in t])
    bad = (t >= 0.10) & (t < 0.12)
    q[bad, mech.joint_names.index("right_elbow")] += gap_angle
    return {"t": t, "q": q, "qd": qd, "joint_names": list(mech.joint_names), "q_ref": np.array(q_ref),
            "qd_ref": np.array(qd_ref), "ref_names": list(rigid.joint_names), "tau": np.array(tau),
            "motor_names": list(rigid.active_names), "ee": ee, "ee_ref": ee_ref,
            "gap_max": max(mech.gap(x) for x in q[bad]), "branch_names": [b.name for b in model.branches]}


def synthetic_run(state_rate: float = 1000.0, force_rate: float = 5000.0, offset: tuple = (2e-4, -1e-4),
                  f_d: float = 552.0, zeta: float = 0.012, amplitude: float = 2.0, gap_angle: float = 1e-6,
                  noise: float = 1e-3, seed: int = 1) -> Run:
    k = _kinematics(state_rate, offset, gap_angle)
    # Branch forces: smooth during the move, a damped oscillation in the hold.
    rng = np.random.default_rng(seed)
    tf = np.arange(round(LINE.duration * force_rate) + 1) / force_rate
    sigma = zeta * 2 * math.pi * f_d / math.sqrt(1 - zeta**2)
    tau_h = tf - LINE.move
    level = np.array([3.0, -1.0])
    move = np.sin(math.pi * np.clip(tf / LINE.move, 0, 1))[:, None] * np.array([4.0, 1.5])
    vib = np.where(tau_h >= 0, np.exp(-sigma * np.maximum(tau_h, 0)) * np.cos(2 * math.pi * f_d * tau_h + 0.3), 0.0)
    forces = level + move + vib[:, None] * np.array([amplitude, 0.5 * amplitude])
    forces += noise * rng.standard_normal(forces.shape)
    truth = {"offset": np.asarray(offset), "f_d": f_d, "zeta": zeta, "amplitude": amplitude,
             "hold_start": LINE.move, "gap_max": k["gap_max"], "peak_force": np.abs(forces).max(axis=0),
             "peak_torque": np.abs(k["tau"]).max(axis=0)}
    return Run(k["t"], k["q"], k["qd"], k["joint_names"], k["q_ref"], k["qd_ref"], k["ref_names"], k["tau"],
               k["motor_names"], k["ee"], k["ee_ref"], tf, forces, k["branch_names"], truth)


# ------------------------------------------------------------------------------ messages
class Messages:
    def __init__(self, ts):
        self.ts = ts
        self.T = ts.types

    def header(self, t: float):
        ns = round((T0 + t) * 1e9)
        stamp = self.T[TIME](sec=ns // 10**9, nanosec=ns % 10**9)
        return self.T[HEADER](stamp=stamp, frame_id="world")

    def joint_state(self, t, names, position, velocity=(), effort=()):
        return self.T[JOINT_STATE](
            header=self.header(t), name=list(names), position=np.asarray(position, dtype=float),
            velocity=np.asarray(velocity, dtype=float), effort=np.asarray(effort, dtype=float))

    def branch_forces(self, t, names, force):
        empty = np.zeros(0)
        return self.T[BRANCH_FORCES](header=self.header(t), name=list(names),
                                             force=np.asarray(force, dtype=float), deflection=force / 5.464e6,
                                             deflection_rate=np.zeros(len(names)), force_stddev=empty)

    def pose(self, t, xy):
        T = self.T
        pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=xy[0], y=xy[1], z=0.0),
                                           orientation=T[QUATERNION](x=0.0, y=0.0, z=0.0, w=1.0))
        return T[POSE_STAMPED](header=self.header(t), pose=pose)

    def float_array(self, values):
        T = self.T
        layout = T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
        return T[FLOAT64_ARRAY](layout=layout, data=np.asarray(values, dtype=float))

    def diagnostics(self, t, values: dict[str, str], level: int = 0, message: str = "running"):
        T = self.T
        kvs = [T[KEY_VALUE](key=k, value=v) for k, v in values.items()]
        status = T["diagnostic_msgs/msg/DiagnosticStatus"](level=level, name="plant: plant", message=message,
                                                           hardware_id="five_bar", values=kvs)
        return T[DIAGNOSTIC_ARRAY](header=self.header(t), status=[status])


def run_messages(run: Run, ts, command: str = "joint_state", topics: set[str] | None = None,
                 shuffle: bool = True) -> list[tuple[str, str, int, object]]:
    """(topic, msgtype, receive time [ns], message) in receive-time order."""
    m = Messages(ts)
    out = []
    order = [3, 0, 5, 1, 4, 2] if shuffle else list(range(len(run.joint_names)))  # names out of model order
    names = [run.joint_names[k] for k in order]
    js_effort = np.zeros((len(run.t_state), len(run.joint_names)))
    for k, n in enumerate(run.motor_names):
        js_effort[:, run.joint_names.index(n)] = run.tau[:, k]

    def add(topic, msgtype, t, msg):
        if topics is None or topic in topics:
            out.append((topic, msgtype, round((T0 + t + LATENCY) * 1e9), msg))

    for k, t in enumerate(run.t_state):
        add("/joint_states", JOINT_STATE, t,
            m.joint_state(t, names, run.q[k, order], run.qd[k, order], js_effort[k, order]))
        add("/reference_joint_states", JOINT_STATE, t,
            m.joint_state(t, run.ref_names, run.q_ref[k], run.qd_ref[k]))
        if command == "joint_state":
            add("/torque_command", JOINT_STATE, t,
                m.joint_state(t, run.motor_names, [], [], run.tau[k]))
        else:
            add("/torque_command", FLOAT64_ARRAY, t, m.float_array(run.tau[k]))
        add("/ee_pose", POSE_STAMPED, t, m.pose(t, run.ee[k]))
        if k % 100 == 0:
            add("/diagnostics", DIAGNOSTIC_ARRAY, t,
                m.diagnostics(t, {"sync_mode": "lockstep", "command_age_s": "0.001", "real_time_factor": "1.5",
                                  "closure_gap_m": "1e-16"}))
    for k, t in enumerate(run.t_force):
        add("/branch_forces", BRANCH_FORCES, t, m.branch_forces(t, run.branch_names, run.forces[k]))
    out.sort(key=lambda x: x[2])
    return out


def write_bag(path: Path, messages: list, storage: str = "mcap", definitions: bool = True) -> Path:
    """Write ``messages`` (see :func:`run_messages`) with a plain rosbags Writer."""
    ts = make_typestore()
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    writer = Writer(path, version=9, storage_plugin=plugin)
    writer.open()
    if not definitions and storage == "mcap":
        _empty_mcap_schemas(writer)
    conns = {}
    for topic, msgtype, t_ns, msg in messages:
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
        writer.write(conns[topic], t_ns, ts.serialize_cdr(msg, msgtype))
    writer.close()
    if not definitions and storage == "sqlite3":
        db = next(path.glob("*.db3"))
        with sqlite3.connect(db) as con:  # like a bag of rosbag2 before Jazzy: no definitions
            con.execute("DELETE FROM message_definitions")
        con.close()
    return path


def _empty_mcap_schemas(writer: Writer) -> None:
    from rosbags.rosbag2.storage_mcap import Schema, write_schema

    storage = writer.storage

    def add_msgtype(connection) -> None:
        storage.schemas.append(Schema(len(storage.schemas) + 1, connection.msgtype, "", ""))
        write_schema(storage.chunk.bio, storage.schemas[-1])

    storage.add_msgtype = add_msgtype
