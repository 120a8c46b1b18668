"""Read the plant's topics back from a rosbag2 (mcap or sqlite3) with ``rosbags`` (no rclpy).

Times are the messages' header stamps [s] (for a lockstep or fast plant: simulated time),
not the bag's receive times; messages without a header (Float64MultiArray) use the
receive time.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.msg_types import BRANCH_FORCES_MSGTYPE, make_typestore

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"


@dataclass
class Series:
    """Samples of one topic: ``t`` (N,), ``names`` of the columns, ``values[field]`` (N, n)."""

    t: np.ndarray
    names: list[str]
    values: dict[str, np.ndarray]

    def column(self, field: str, name: str) -> np.ndarray:
        return self.values[field][:, self.names.index(name)]


def read_bag(path: str | Path) -> dict[str, Series]:
    """Every JointState, BranchForces, PoseStamped and Float64MultiArray topic, by topic name.

    Messages of one topic must name the same columns in the same order (as our nodes do).
    """
    path = Path(path)
    if not path.is_dir():
        raise InputError(f"{path}: no such bag directory")
    fields = {JOINT_STATE: ("position", "velocity", "effort"),
              BRANCH_FORCES_MSGTYPE: ("force", "deflection", "deflection_rate"),
              POSE_STAMPED: ("position",), FLOAT64_ARRAY: ("data",)}
    rows: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    names: dict[str, list[str]] = {}
    with AnyReader([path], default_typestore=make_typestore()) as reader:
        conns = [c for c in reader.connections if c.msgtype in fields]
        for conn, t_recv, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            r = rows[conn.topic]
            header = getattr(msg, "header", None)
            r["t"].append(header.stamp.sec + header.stamp.nanosec * 1e-9 if header else t_recv * 1e-9)
            if conn.msgtype == POSE_STAMPED:
                p = msg.pose.position
                names[conn.topic] = ["x", "y", "z"]
                r["position"].append([p.x, p.y, p.z])
                continue
            cols = list(getattr(msg, "name", [])) or [str(k) for k in range(len(msg.data))]
            if names.setdefault(conn.topic, cols) != cols:
                raise InputError(f"{path}: {conn.topic} changes its names from {names[conn.topic]} to {cols}")
            for f in fields[conn.msgtype]:
                r[f].append(np.asarray(getattr(msg, f), dtype=float))
    return {topic: Series(np.array(r.pop("t")), names[topic], {f: _stack(v) for f, v in r.items()})
            for topic, r in rows.items()}


def _stack(rows: list) -> np.ndarray:
    # An empty field (e.g. JointState without efforts) stacks to an (N, 0) array.
    return np.array([np.asarray(x, dtype=float) for x in rows]).reshape(len(rows), -1)
