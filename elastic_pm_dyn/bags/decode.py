"""Raw CDR -> plain values (stamps as integer ns, names, float arrays) for the types read in bulk.

The hand-written decoders of :mod:`~elastic_pm_dyn.bags.cdr` first; for bytes they do not
expect (another encapsulation, a field layout they do not know), rosbags' deserialiser
with the bag's own definitions, giving the same values.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from elastic_pm_dyn.bags import cdr
from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES, FLOAT64_ARRAY, IMU, JOINT_STATE, stamp_ns

# What the fast decoders raise on bytes they do not expect (then rosbags decodes them).
SURPRISES = (ValueError, UnicodeDecodeError, struct.error, IndexError)


class Decoder:
    """The fast decoders with ``deserialize(raw, msgtype)`` (rosbags') as the fallback."""

    def __init__(self, deserialize: Callable[[bytes, str], Any]):
        self._slow = deserialize

    def joint_state(self, raw: bytes) -> tuple[int, list[str], np.ndarray, np.ndarray, np.ndarray]:
        """(stamp ns, names, position, velocity, effort)."""
        try:
            return cdr.decode_joint_state(raw)
        except SURPRISES:
            m = self._slow(raw, JOINT_STATE)
            return stamp_ns(m.header.stamp), list(m.name), _floats(m.position), _floats(m.velocity), \
                _floats(m.effort)

    def imu(self, raw: bytes) -> tuple[int, str, np.ndarray]:
        """(stamp ns, frame_id, linear acceleration xyz)."""
        try:
            return cdr.decode_imu(raw)
        except SURPRISES:
            m = self._slow(raw, IMU)
            a = m.linear_acceleration
            return stamp_ns(m.header.stamp), m.header.frame_id, np.array([a.x, a.y, a.z])

    def float64_array(self, raw: bytes) -> np.ndarray:
        """The data (the message has no header: its time is the bag's receive time)."""
        try:
            return cdr.decode_float64_array(raw)
        except SURPRISES:
            return _floats(self._slow(raw, FLOAT64_ARRAY).data)

    def branch_forces(self, raw: bytes) -> tuple[int, list[str], np.ndarray]:
        """(stamp ns, names, force)."""
        try:
            return cdr.decode_branch_forces(raw)
        except SURPRISES:
            m = self._slow(raw, BRANCH_FORCES)
            return stamp_ns(m.header.stamp), list(m.name), _floats(m.force)


def _floats(values: Any) -> np.ndarray:
    return np.asarray(values, dtype=float)
