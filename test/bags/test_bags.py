"""The bag layer: message type names, the fast CDR against rosbags, reading (mcap, sqlite3,
with and without definitions, a single storage file), one-line errors, writing (raw,
message objects, rows of a batch) and what reads it back.

Bags to read are written with a plain ``rosbags`` Writer (bag_factory.py), not with our
writer, so that reader and writer are each checked against rosbags.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bag_factory import run_messages, synthetic_run, write_bag

from elastic_pm_dyn.bags import cdr
from elastic_pm_dyn.bags.decode import Decoder
from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.msgtypes import (
    BRANCH_FORCES,
    HEADER,
    IMU,
    JOINT_STATE,
    POSE_STAMPED,
    QUATERNION,
    TIME,
    VECTOR3,
)
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.series import read_series
from elastic_pm_dyn.bags.typestore import make_typestore, register_msg_text
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.errors import InputError


@pytest.fixture(scope="module")
def run():
    return synthetic_run()


@pytest.fixture(scope="module")
def bag_of(run, tmp_path_factory):
    """``bag_of(storage, definitions)``: the synthetic run as a bag, written once per module."""
    root = tmp_path_factory.mktemp("bags")

    def bag(storage: str = "mcap", definitions: bool = True) -> Path:
        path = root / f"{storage}_{definitions}"
        if not path.exists():
            write_bag(path, run_messages(run, make_typestore()), storage, definitions)
        return path

    return bag


# ------------------------------------------------------------------------- message types
def test_msg_types_does_not_import_rclpy() -> None:
    code = (
        "import sys, elastic_pm_dyn.bags.msgtypes as m; m.BRANCH_FORCES_MSG_TEXT; "
        "sys.exit('rclpy' in sys.modules)"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_msg_types_do_not_import_rosbags() -> None:
    """Nodes import the names and NS: they must not pay for rosbags."""
    code = "import sys, elastic_pm_dyn.bags.msgtypes; sys.exit('rosbags' in sys.modules)"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


# ------------------------------------------------------------------------- fast CDR
def test_fast_cdr_equals_rosbags() -> None:
    """The offline pass's own CDR (de)serialisers agree byte for byte with rosbags."""
    ts = make_typestore()
    T, H = ts.types[TIME], ts.types[HEADER]
    JS, BF = ts.types[JOINT_STATE], ts.types[BRANCH_FORCES]
    V3, Q = ts.types[VECTOR3], ts.types[QUATERNION]
    rng = np.random.default_rng(0)
    for names, frame in ((["a", "bb", "ccc"], ""), (["left_motor", "right_motor"], "x"), ([], "frame")):
        n = len(names)
        pos, vel, eff = rng.standard_normal(n), np.zeros(0), rng.standard_normal(n)
        hdr = H(stamp=T(sec=12, nanosec=345), frame_id=frame)
        ref = bytes(ts.serialize_cdr(JS(header=hdr, name=names, position=pos, velocity=vel, effort=eff),
                                     JOINT_STATE))
        assert cdr.encode_joint_state(12_000_000_345, names, pos, vel, eff, frame) == ref
        ns, nm, p, _, e = cdr.decode_joint_state(ref)
        assert (ns, nm) == (12_000_000_345, names) and np.array_equal(p, pos) and np.array_equal(e, eff)
        ref = bytes(ts.serialize_cdr(BF(header=hdr, name=names, force=pos, deflection=eff, deflection_rate=pos,
                                        force_stddev=vel), BRANCH_FORCES))
        assert cdr.encode_branch_forces(12_000_000_345, names, pos, eff, pos, vel, frame) == ref
        assert cdr.decode_branch_forces(ref)[1] == names
        imu = ts.types[IMU](
            header=hdr, orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.arange(9.0),
            angular_velocity=V3(x=1.0, y=2.0, z=3.0), angular_velocity_covariance=np.arange(9.0),
            linear_acceleration=V3(x=7.0, y=8.0, z=9.0), linear_acceleration_covariance=np.zeros(9))
        ns, f, a = cdr.decode_imu(bytes(ts.serialize_cdr(imu, IMU)))
        assert (ns, f, list(a)) == (12_000_000_345, frame, [7.0, 8.0, 9.0])


def test_batch_encoders_equal_rosbags() -> None:
    """Each row of a batch is the message rosbags serialises (stamps across a second boundary)."""
    ts = make_typestore()
    T, H, P = ts.types[TIME], ts.types[HEADER], ts.types
    ns = np.array([999_999_999, 1_000_000_000, 7_000_000_123])
    rng = np.random.default_rng(1)
    q, qd, eff = rng.standard_normal((3, 3)), rng.standard_normal((3, 3)), np.zeros((3, 0))
    xyz = rng.standard_normal((3, 3))
    js = cdr.encode_joint_state_batch(ns, ["a", "b", "c"], q, qd, eff)
    pose = cdr.encode_pose_stamped_batch(ns, xyz, "world")
    for k, t in enumerate(ns.tolist()):
        hdr = H(stamp=T(sec=t // 10**9, nanosec=t % 10**9), frame_id="")
        ref = ts.serialize_cdr(P[JOINT_STATE](header=hdr, name=["a", "b", "c"], position=q[k], velocity=qd[k],
                                              effort=eff[k]), JOINT_STATE)
        assert js[k].tobytes() == bytes(ref)
        hdr = H(stamp=T(sec=t // 10**9, nanosec=t % 10**9), frame_id="world")
        point = P["geometry_msgs/msg/Point"](x=xyz[k, 0], y=xyz[k, 1], z=xyz[k, 2])
        ref = ts.serialize_cdr(P[POSE_STAMPED](header=hdr, pose=P["geometry_msgs/msg/Pose"](
            position=point, orientation=P[QUATERNION](x=0.0, y=0.0, z=0.0, w=1.0))), POSE_STAMPED)
        assert pose[k].tobytes() == bytes(ref)


def test_decoder_falls_back_to_rosbags_with_the_same_values() -> None:
    """Big-endian CDR (legal, never written by ROS 2 on x86) is not the fast decoders': rosbags takes it."""
    ts = make_typestore()
    T, H = ts.types[TIME], ts.types[HEADER]
    hdr = H(stamp=T(sec=3, nanosec=4), frame_id="ee")
    msgs = {JOINT_STATE: ts.types[JOINT_STATE](header=hdr, name=["a", "b"], position=np.array([1.0, 2.0]),
                                               velocity=np.zeros(0), effort=np.array([-1.0, 0.5])),
            BRANCH_FORCES: ts.types[BRANCH_FORCES](header=hdr, name=["l"], force=np.array([9.0]),
                                                   deflection=np.zeros(1), deflection_rate=np.zeros(1),
                                                   force_stddev=np.zeros(0)),
            IMU: ts.types[IMU](header=hdr, orientation=ts.types[QUATERNION](x=0.0, y=0.0, z=0.0, w=1.0),
                               orientation_covariance=np.zeros(9),
                               angular_velocity=ts.types[VECTOR3](x=0.0, y=0.0, z=0.0),
                               angular_velocity_covariance=np.zeros(9),
                               linear_acceleration=ts.types[VECTOR3](x=1.0, y=2.0, z=3.0),
                               linear_acceleration_covariance=np.zeros(9))}
    slow = []
    dec = Decoder(lambda raw, msgtype: slow.append(msgtype) or ts.deserialize_cdr(raw, msgtype))
    decode = {JOINT_STATE: dec.joint_state, BRANCH_FORCES: dec.branch_forces, IMU: dec.imu}
    for msgtype, msg in msgs.items():
        fast = decode[msgtype](bytes(ts.serialize_cdr(msg, msgtype, little_endian=True)))
        assert slow == []
        fallback = decode[msgtype](bytes(ts.serialize_cdr(msg, msgtype, little_endian=False)))
        assert slow == [msgtype]
        slow.clear()
        assert len(fast) == len(fallback)
        for a, b in zip(fast, fallback, strict=True):
            assert (np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b), msgtype


# ------------------------------------------------------------------------- reading
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("definitions", [True, False])
def test_reads_every_storage_with_and_without_definitions(run, bag_of, storage, definitions):
    path = bag_of(storage, definitions)
    with open_bag(path) as bag:
        assert bag.storage == storage
        assert bag.topics()["/branch_forces"] == (BRANCH_FORCES, len(run.t_force))
        assert all(bag.can_decode(c.msgtype) for c in bag.connections)
    series = read_series(path)
    bf = series["/branch_forces"]
    assert bf.names == run.branch_names
    np.testing.assert_array_equal(bf.values["force"], run.forces)  # exact, through CDR
    np.testing.assert_allclose(bf.t - bf.t[0], run.t_force, atol=1e-9)
    js = series["/joint_states"]
    np.testing.assert_array_equal(np.column_stack([js.column("position", n) for n in run.joint_names]), run.q)
    assert series["/ee_pose"].names == ["x", "y", "z"]


def test_a_single_storage_file_reads_like_its_directory(bag_of):
    path = bag_of()
    whole, single = read_series(path), read_series(next(path.glob("*.mcap")))
    assert sorted(whole) == sorted(single)
    for topic, s in whole.items():
        np.testing.assert_array_equal(s.t, single[topic].t)


def test_corrupt_truncated_and_missing_bags_give_one_line_errors(bag_of, tmp_path):
    good = {s: bag_of(s) for s in ("mcap", "sqlite3")}
    cases = {}
    for storage, src in good.items():
        for kind in ("truncated", "overwritten"):
            dst = tmp_path / f"{storage}_{kind}"
            dst.mkdir()
            for f in src.iterdir():
                dst.joinpath(f.name).write_bytes(f.read_bytes())
            data = next(dst.glob("*.mcap" if storage == "mcap" else "*.db3"))
            size = data.stat().st_size
            if kind == "truncated":
                os.truncate(data, size // 2)
            else:
                with data.open("r+b") as fh:
                    fh.seek(size // 2)
                    fh.write(b"\xff" * 5000)
            cases[dst] = "truncated or corrupt"
    no_meta = tmp_path / "no_metadata"
    no_meta.mkdir()
    cases[no_meta] = "not a rosbag2 bag"
    cases[tmp_path / "missing"] = "no such bag"
    bad_yaml = tmp_path / "bad_yaml"
    bad_yaml.mkdir()
    (bad_yaml / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    cases[bad_yaml] = "cannot open the bag"
    for path, text in cases.items():
        with pytest.raises(BagError, match=text) as err:
            read_series(path)
        assert isinstance(err.value, InputError) and "\n" not in str(err.value) and str(path) in str(err.value)


# ------------------------------------------------------------------------- writing
def _rows(n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    rng = np.random.default_rng(2)
    ns = 5 * 10**9 + np.arange(n, dtype=np.int64) * 1_000_000
    names = ["left_motor", "left_spring", "right_motor"]
    return ns, [cdr.encode_joint_state_batch(ns, names, *rng.standard_normal((3, n, 3))),
                cdr.encode_branch_forces_batch(ns, ["left", "right"], *rng.standard_normal((3, n, 2)),
                                               np.zeros((n, 0))),
                cdr.encode_pose_stamped_batch(ns, rng.standard_normal((n, 3)))]


def _files(path: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(path.iterdir())}


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_rows_of_a_batch_give_the_bag_of_one_message_after_another(tmp_path, storage):
    """Over several mcap chunks (> 1 MiB) and in two calls: byte for byte what write() gives."""
    ns, msgs = _rows(6000)
    types = (JOINT_STATE, BRANCH_FORCES, POSE_STAMPED)
    with BagWriter(tmp_path / "rows" / "bag", storage) as w:
        conns = [w.add_connection(f"/t{k}", ty) for k, ty in enumerate(types)]
        w.write_rows(conns, ns[:2500], [m[:2500] for m in msgs])
        w.write_rows(conns, ns[2500:], [m[2500:] for m in msgs])
        assert [w.count(c) for c in conns] == [6000] * 3
    with BagWriter(tmp_path / "one" / "bag", storage) as w:
        conns = [w.add_connection(f"/t{k}", ty) for k, ty in enumerate(types)]
        for k, t in enumerate(ns.tolist()):
            for c, m in zip(conns, msgs, strict=True):
                w.write(c, t, m[k].tobytes())
    if storage == "mcap":
        assert _files(tmp_path / "rows" / "bag") == _files(tmp_path / "one" / "bag")
    series = read_series(tmp_path / "rows" / "bag")
    np.testing.assert_allclose(series["/t0"].t, ns * 1e-9, rtol=0, atol=1e-12)
    with open_bag(tmp_path / "rows" / "bag") as bag:
        raw = [r for _, _, r in bag.messages([c for c in bag.connections if c.topic == "/t1"])]
    assert [bytes(r) for r in raw] == [m.tobytes() for m in msgs[1]]


def test_writer_never_overwrites_and_names_what_it_cannot_record(tmp_path):
    with BagWriter(tmp_path / "bag", "sqlite3") as w:
        c = w.add_connection("/js", JOINT_STATE)
        ts = w.typestore
        hdr = ts.types[HEADER](stamp=ts.types[TIME](sec=1, nanosec=2), frame_id="")
        w.write_message(c, 5, ts.types[JOINT_STATE](header=hdr, name=["a"], position=np.ones(1),
                                                    velocity=np.zeros(0), effort=np.zeros(0)))
        with pytest.raises(BagError, match="cannot record /x \\[my_msgs/msg/Thing\\]"):
            w.add_connection("/x", "my_msgs/msg/Thing")
        register_msg_text(w.typestore, "my_msgs/msg/Thing", "float64 value\n")
        w.add_connection("/x", "my_msgs/msg/Thing")
        with pytest.raises(BagError, match="cannot use the definition of my_msgs/msg/Bad"):
            register_msg_text(w.typestore, "my_msgs/msg/Bad", "float64[ x\n")
    assert read_series(tmp_path / "bag")["/js"].values["position"].tolist() == [[1.0]]
    with pytest.raises(BagError, match="exists already"):
        BagWriter(tmp_path / "bag")
    (tmp_path / "file").write_text("")
    with pytest.raises(BagError, match="cannot create the bag"):
        BagWriter(tmp_path / "file" / "bag")
