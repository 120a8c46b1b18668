"""The numeric topics of a bag as arrays: every sample of every topic, read at once.

For a small bag (a demo run, a test, the observer's estimates) where all samples fit in
memory; ``analysis`` streams long bags with bounded memory over the same :data:`FIELDS`.
Times are the messages' header stamps [s] (for a lockstep or fast plant: simulated time),
not the bag's receive times; messages without a header (Float64MultiArray) use the
receive time.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES, FLOAT64_ARRAY, JOINT_STATE, POSE_STAMPED, WRENCH_STAMPED
from elastic_pm_dyn.bags.reader import open_bag

# Numeric fields per message type (a PoseStamped's: its position, columns x, y, z).
FIELDS: dict[str, tuple[str, ...]] = {
    JOINT_STATE: ("position", "velocity", "effort"),
    BRANCH_FORCES: ("force", "deflection", "deflection_rate"),
    FLOAT64_ARRAY: ("data",),
    POSE_STAMPED: ("position",),
    WRENCH_STAMPED: ("force", "torque"),  # columns x, y, z each
}


def numeric_values(msg: Any, msgtype: str) -> tuple[list[str] | None, list[np.ndarray]]:
    """Column names (None: the message names none) and one array per field of :data:`FIELDS`."""
    if msgtype == POSE_STAMPED:
        p = msg.pose.position
        return ["x", "y", "z"], [np.array([p.x, p.y, p.z])]
    if msgtype == WRENCH_STAMPED:
        f, m = msg.wrench.force, msg.wrench.torque
        return ["x", "y", "z"], [np.array([f.x, f.y, f.z]), np.array([m.x, m.y, m.z])]
    names = list(msg.name) if hasattr(msg, "name") else None
    return names, [np.asarray(getattr(msg, f), dtype=float) for f in FIELDS[msgtype]]


@dataclass
class Series:
    """Samples of one topic: ``t`` (N,), ``names`` of the columns, ``values[field]`` (N, n)."""

    t: np.ndarray
    names: list[str]
    values: dict[str, np.ndarray]

    def column(self, field: str, name: str) -> np.ndarray:
        return self.values[field][:, self.names.index(name)]


def read_series(path: str | Path) -> dict[str, Series]:
    """Every JointState, BranchForces, PoseStamped and Float64MultiArray topic, by topic name.

    Messages of one topic must name the same columns in the same order (as our nodes do).
    """
    rows: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    names: dict[str, list[str]] = {}
    with open_bag(path) as bag:
        conns = [c for c in bag.connections if c.msgtype in FIELDS]
        for conn, t_recv, msg in bag.decoded(conns):
            r = rows[conn.topic]
            header = getattr(msg, "header", None)
            r["t"].append(header.stamp.sec + header.stamp.nanosec * 1e-9 if header else t_recv * 1e-9)
            cols, arrays = numeric_values(msg, conn.msgtype)
            cols = cols or [str(k) for k in range(len(arrays[0]))]
            if names.setdefault(conn.topic, cols) != cols:
                raise BagError(f"{path}: {conn.topic} changes its names from {names[conn.topic]} to {cols}")
            for f, a in zip(FIELDS[conn.msgtype], arrays, strict=True):
                r[f].append(a)
    return {topic: Series(np.array(r.pop("t")), names[topic], {f: _stack(v) for f, v in r.items()})
            for topic, r in rows.items()}


def _stack(rows: list) -> np.ndarray:
    # An empty field (e.g. JointState without efforts) stacks to an (N, 0) array.
    return np.array([np.asarray(x, dtype=float) for x in rows]).reshape(len(rows), -1)
