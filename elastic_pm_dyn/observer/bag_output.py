"""The observer's estimates written out: ``estimates.csv`` and a bag of estimates.

- ``estimates.csv`` (:func:`csv_header`, :func:`csv_table`): ``t``, every tree joint,
  ``<joint>_vel``, ``F_<branch>``, the standard deviation of each (``<column>_std``),
  ``ee_x``, ``ee_y`` (``ee_z`` if spatial; + std), the disturbance estimates ``d_<joint>`` (+ std) and the NIS of
  each sensor at that stamp;
- ``estimates/`` (:func:`write_bag`, a bag, mcap by default) with ``/joint_states``
  (position, velocity, effort of every tree joint), ``/branch_forces`` (with
  ``force_stddev``) and ``/ee_pose`` for ``elastic-pm-dyn analyze``, plus
  ``/observer/joint_states_stddev`` (JointState whose position/velocity fields hold the
  standard deviations).

Both can be written a chunk of rows after another (:class:`_BagOut` for the bag), giving the
same files as all rows at once.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import cdr
from elastic_pm_dyn.observer.bag_input import JOINT_STATE
from elastic_pm_dyn.observer.ekf import Observer

if TYPE_CHECKING:
    from elastic_pm_dyn.observer.offline import Rows

POSE_STAMPED = "geometry_msgs/msg/PoseStamped"


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


def write_outputs(out: Path, obs: Observer, rows: Rows, write_estimates_bag: bool, storage: str) -> None:
    """``estimates.csv`` and (optionally) the ``estimates/`` bag of all rows into ``out`` (nothing if no rows)."""
    if not rows.t:
        return
    np.savetxt(out / "estimates.csv", csv_table(rows), delimiter=",", header=",".join(csv_header(obs)),
               comments="", fmt="%.12g")
    if write_estimates_bag:
        bag_out = out / "estimates"
        if bag_out.exists():
            raise InputError(f"{bag_out} exists already (rosbag2 will not overwrite it)")
        write_bag(bag_out, obs, rows, storage)


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

