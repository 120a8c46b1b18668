"""Fast CDR (little-endian XCDR1, as rosbag2 stores ROS 2 messages) for the few message types
read and written in bulk.

rosbags' generic (de)serialisers build message objects field by field (~12 us per
JointState); these functions go straight between bytes and numpy arrays (~2-4 us; both
measured 2026-11-22 on the 2-core dev machine), which is what lets ``observe`` run several
times faster than real time. They decode
``sensor_msgs/JointState``, ``sensor_msgs/Imu`` (header + linear acceleration),
``std_msgs/Float64MultiArray`` (data) and ``elastic_pm_dyn_msgs/BranchForces``, and encode
JointState, BranchForces and ``geometry_msgs/PoseStamped`` (batches); the tests compare
them byte for byte with rosbags. Any decoding surprise raises ``ValueError`` (or another of
:data:`~elastic_pm_dyn.bags.decode.SURPRISES`) and :mod:`~elastic_pm_dyn.bags.decode`
falls back to rosbags.
"""

from __future__ import annotations

import struct

import numpy as np

from elastic_pm_dyn.bags.msgtypes import NS

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian
_U32 = struct.Struct("<I")
_HDR = struct.Struct("<iI")


class _Reader:
    __slots__ = ("buf", "pos")

    def __init__(self, raw: bytes):
        if raw[:2] != b"\x00\x01":
            raise ValueError("not little-endian CDR")
        self.buf = memoryview(raw)[4:]
        self.pos = 0

    def align(self, n: int) -> None:
        self.pos += (-self.pos) % n

    def u32(self) -> int:
        self.align(4)
        v = _U32.unpack_from(self.buf, self.pos)[0]
        self.pos += 4
        return v

    def stamp_ns(self) -> int:
        self.align(4)
        sec, nsec = _HDR.unpack_from(self.buf, self.pos)
        self.pos += 8
        return sec * NS + nsec

    def string(self) -> str:
        n = self.u32()
        if n == 0:
            return ""
        s = bytes(self.buf[self.pos:self.pos + n - 1]).decode()
        self.pos += n
        return s

    def strings(self) -> list[str]:
        return [self.string() for _ in range(self.u32())]

    def doubles(self, n: int | None = None) -> np.ndarray:
        if n is None:
            n = self.u32()
        if n == 0:
            return np.zeros(0)
        self.align(8)
        end = self.pos + 8 * n
        if end > len(self.buf):
            raise ValueError("truncated message")
        a = np.frombuffer(self.buf[self.pos:end], dtype="<f8").copy()
        self.pos = end
        return a


class _Writer:
    __slots__ = ("parts", "pos")

    def __init__(self):
        self.parts = [ENCAPSULATION]
        self.pos = 0

    def _pad(self, n: int) -> None:
        k = (-self.pos) % n
        if k:
            self.parts.append(b"\x00" * k)
            self.pos += k

    def u32(self, v: int) -> None:
        self._pad(4)
        self.parts.append(_U32.pack(v))
        self.pos += 4

    def string(self, s: str) -> None:
        b = s.encode() + b"\x00"
        self.u32(len(b))
        self.parts.append(b)
        self.pos += len(b)

    def strings(self, items) -> None:
        self.u32(len(items))
        for s in items:
            self.string(s)


_RECENT: list[tuple[bytes, list[str], int]] = []  # (frame_id + names bytes, names, end) of recent messages


def _frame_and_names(r: _Reader) -> list[str]:
    """Skip frame_id and read the names after a header stamp; the bytes of a recently seen
    frame_id + names section are compared instead of decoded again (a stream repeats them)."""
    buf = r.buf
    for prefix, names, end in _RECENT:
        if buf[8:end] == prefix:
            r.pos = end
            return list(names)
    r.pos = 8
    r.string()
    names = r.strings()
    _RECENT.insert(0, (bytes(buf[8:r.pos]), names, r.pos))
    del _RECENT[8:]
    return list(names)


def decode_joint_state(raw: bytes) -> tuple[int, list[str], np.ndarray, np.ndarray, np.ndarray]:
    """(stamp ns, names, position, velocity, effort)."""
    r = _Reader(raw)
    ns = r.stamp_ns()
    return ns, _frame_and_names(r), r.doubles(), r.doubles(), r.doubles()


def decode_imu(raw: bytes) -> tuple[int, str, np.ndarray]:
    """(stamp ns, frame_id, linear acceleration xyz)."""
    r = _Reader(raw)
    ns = r.stamp_ns()
    frame = r.string()
    r.align(8)
    r.pos += 8 * (4 + 9 + 3 + 9)  # orientation, its covariance, angular velocity, its covariance
    return ns, frame, r.doubles(3)


def decode_float64_array(raw: bytes) -> np.ndarray:
    r = _Reader(raw)
    for _ in range(r.u32()):  # layout.dim: label, size, stride
        r.string()
        r.u32()
        r.u32()
    r.u32()  # data_offset
    return r.doubles()


def decode_branch_forces(raw: bytes) -> tuple[int, list[str], np.ndarray]:
    """(stamp ns, names, force)."""
    r = _Reader(raw)
    ns = r.stamp_ns()
    return ns, _frame_and_names(r), r.doubles()


_PREFIX: dict[tuple, tuple[bytes, int]] = {}


def _prefix(frame_id: str, names) -> tuple[bytes, int]:
    """Bytes after the stamp (frame_id, names) and the payload offset where they end."""
    key = (frame_id, tuple(names))
    hit = _PREFIX.get(key)
    if hit is None:
        w = _Writer()
        w.pos = 8  # after the stamp
        w.parts = []
        w.string(frame_id)
        w.strings(names)
        hit = _PREFIX[key] = (b"".join(w.parts), w.pos)
        if len(_PREFIX) > 256:
            _PREFIX.clear()
    return hit


def _with_arrays(ns: int, frame_id: str, names, arrays) -> bytes:
    prefix, pos = _prefix(frame_id, names)
    sec, nsec = divmod(int(ns), NS)
    parts = [ENCAPSULATION, _HDR.pack(sec, nsec), prefix]
    for a in arrays:
        a = np.ascontiguousarray(a, dtype="<f8")
        k = (-pos) % 4
        parts.append(b"\x00" * k + _U32.pack(len(a)))
        pos += k + 4
        if len(a):
            k = (-pos) % 8
            parts.append(b"\x00" * k + a.tobytes())
            pos += k + 8 * len(a)
    return b"".join(parts)


def encode_joint_state(ns: int, names, position, velocity, effort, frame_id: str = "") -> bytes:
    return _with_arrays(ns, frame_id, names, (position, velocity, effort))


def encode_branch_forces(ns: int, names, force, deflection, rate, stddev, frame_id: str = "") -> bytes:
    return _with_arrays(ns, frame_id, names, (force, deflection, rate, stddev))


def _batch_layout(frame_id: str, names, lengths, counted: bool) -> tuple[np.ndarray, list[int]]:
    """Template message (zeros where the values go) and the byte offset of each double array."""
    if names is None:
        w = _Writer()
        w.pos = 8
        w.parts = []
        w.string(frame_id)
        prefix, pos = b"".join(w.parts), w.pos
    else:
        prefix, pos = _prefix(frame_id, names)
    parts = [ENCAPSULATION, b"\x00" * 8, prefix]
    offsets = []
    for n in lengths:
        if counted:
            k = (-pos) % 4
            parts.append(b"\x00" * k + _U32.pack(n))
            pos += k + 4
        if n or not counted:
            k = (-pos) % 8
            parts.append(b"\x00" * k)
            pos += k
            offsets.append(4 + pos)
            parts.append(b"\x00" * (8 * n))
            pos += 8 * n
        else:
            offsets.append(4 + pos)
    return np.frombuffer(b"".join(parts), dtype=np.uint8), offsets


def _batch(ns, frame_id: str, names, arrays, counted: bool = True) -> np.ndarray:
    """Messages of one layout for every row at once (rows x bytes): stamps ``ns`` (int64),
    arrays (rows x length each) as float64."""
    ns = np.asarray(ns, dtype=np.int64)
    arrays = [np.asarray(a, dtype="<f8").reshape(len(ns), -1) for a in arrays]
    template, offsets = _batch_layout(frame_id, names, [a.shape[1] for a in arrays], counted)
    out = np.tile(template, (len(ns), 1))
    sec, nsec = np.divmod(ns, NS)
    out[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(-1, 4)
    out[:, 8:12] = nsec.astype("<u4").view(np.uint8).reshape(-1, 4)
    for a, off in zip(arrays, offsets, strict=True):
        if a.shape[1]:
            out[:, off:off + 8 * a.shape[1]] = np.ascontiguousarray(a).view(np.uint8)
    return out


def encode_joint_state_batch(ns, names, position, velocity, effort, frame_id: str = "") -> np.ndarray:
    """:func:`encode_joint_state` of many rows (rows x bytes, each row one message)."""
    return _batch(ns, frame_id, names, (position, velocity, effort))


def encode_branch_forces_batch(ns, names, force, deflection, rate, stddev, frame_id: str = "") -> np.ndarray:
    return _batch(ns, frame_id, names, (force, deflection, rate, stddev))


def encode_wrench_stamped_batch(ns, wrench, frame_id: str = "world") -> np.ndarray:
    """geometry_msgs/WrenchStamped of many rows: ``wrench`` rows x 6 [force; torque]."""
    return _batch(ns, frame_id, None, (np.asarray(wrench, dtype=float).reshape(-1, 6),), counted=False)


def encode_pose_stamped_batch(ns, xyz, frame_id: str = "world") -> np.ndarray:
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    pose = np.zeros((len(xyz), 7))
    pose[:, :3] = xyz
    pose[:, 6] = 1.0
    return _batch(ns, frame_id, None, (pose,), counted=False)
