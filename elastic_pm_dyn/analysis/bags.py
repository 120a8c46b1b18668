"""The analysis topics of a bag: topic discovery by role, streaming with bounded memory.

Bags are opened and read through :mod:`elastic_pm_dyn.bags` (mcap or sqlite3, a directory
or a single storage file, with or without definitions; errors as one-line ``BagError``).

- :func:`discover_topics` maps the analysis roles (joint states, branch forces, ...) to
  topics: names given by the user first, then the default names, then by message type
  (and, among several ``JointState`` topics, by words in the name).
- :func:`read_bag` iterates the messages once and keeps, per topic, bounded arrays
  (:mod:`elastic_pm_dyn.analysis.streams`): every sample while a topic has at most
  ``max_samples`` messages, else a uniformly decimated overview plus a full-rate window
  of ``window_samples`` rows from the detected (or given) hold start, with exact
  peaks and timing statistics over all messages.

Times: the header stamp when a topic's messages carry a non-zero one (simulated time for
our plant), else the bag's receive time; both are kept.

Memory, per topic of row width w (2 + fields x columns; a six-joint JointState: 20):
at most ``max_samples`` x w x 8 bytes for the overview, ``window_samples`` x w x 8 for
the full-rate window and 2 x 5 x ``max_samples`` x 8 bytes of stamps for exact timing
statistics (beyond that, histograms). Defaults: about 60 MB for a six-joint JointState
topic, whatever the length of the bag.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from elastic_pm_dyn.analysis.metrics import StreamTiming
from elastic_pm_dyn.analysis.streams import HoldDetector, SampleBuffer, StreamTimer, WindowBuffer
from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.msgtypes import (
    BRANCH_FORCES,
    DIAGNOSTIC_ARRAY,
    FLOAT64_ARRAY,
    JOINT_STATE,
    NS,
    POSE_STAMPED,
    WRENCH_STAMPED,
    stamp_ns,
)
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.series import FIELDS, numeric_values

# role -> (accepted message types, default topic, words that mark it among JointState topics)
ROLES: dict[str, tuple[tuple[str, ...], str, tuple[str, ...]]] = {
    "joint_states": ((JOINT_STATE,), "/joint_states", ()),
    "branch_forces": ((BRANCH_FORCES,), "/branch_forces", ()),
    "torque_command": ((JOINT_STATE, FLOAT64_ARRAY), "/torque_command", ("torque", "command", "cmd", "effort")),
    "reference": ((JOINT_STATE,), "/reference_joint_states", ("reference", "ref", "desired", "target")),
    "measured": ((JOINT_STATE,), "/measured_joint_states", ("measured", "meas", "sensor")),
    "ee_pose": ((POSE_STAMPED,), "/ee_pose", ()),
    "diagnostics": ((DIAGNOSTIC_ARRAY,), "/diagnostics", ()),
    # the observer's wrench estimate (observe's bag, the observer node), the plant's true wrench, the contacts
    "wrench": ((WRENCH_STAMPED,), "/observer/wrench", ()),
    "wrench_stddev": ((WRENCH_STAMPED,), "/observer/wrench_stddev", ()),
    "wrench_truth": ((WRENCH_STAMPED,), "/wrench", ()),
    "contact": ((WRENCH_STAMPED,), "/observer/contact", ()),
}
# Roles whose absence is normal (observer input, plant extras): not reported as missing.
OPTIONAL = ("measured", "ee_pose", "diagnostics", "wrench", "wrench_stddev", "wrench_truth", "contact")
# Roles taken by their default name only (all of one message type: a guess by type would mix them up).
BY_NAME_ONLY = ("wrench", "wrench_stddev", "wrench_truth", "contact")
MAX_SAMPLES = 200_000  # per topic at full rate (JointState of 6 joints: ~30 MB)
WINDOW_SAMPLES = 50_000  # full-rate rows kept for the vibration fit when decimating
TIMER_STAMPS = 5  # x max_samples: stamps kept per topic for exact timing statistics (8 bytes each)


@dataclass
class TopicSeries:
    """Numeric samples of one topic.

    ``fields[f]`` is (N, len(names)); a column missing from a message is NaN. ``t`` are
    the stamps used (header or receive time), ``t_receive`` the bag's receive times [s]
    (both relative to the origins in :class:`BagData`).
    ``count`` messages were read; ``stride`` > 1 means only every stride-th is in the
    arrays (then ``window`` holds full-rate rows). ``peak_lo``/``peak_hi`` are exact
    per-column minima/maxima over all messages; ``timing`` is a
    :class:`~elastic_pm_dyn.analysis.metrics.StreamTiming` over ``t``, ``timing_receive`` over
    receive times (None in a ``window``).
    """

    topic: str
    msgtype: str
    names: list[str]
    t: np.ndarray
    t_receive: np.ndarray
    fields: dict[str, np.ndarray]
    count: int
    stride: int
    stamp_source: str  # "header" or "receive"
    timing: StreamTiming | None
    timing_receive: StreamTiming | None
    peak_lo: dict[str, np.ndarray]
    peak_hi: dict[str, np.ndarray]
    window: TopicSeries | None = None
    notes: list[str] = field(default_factory=list)

    def column(self, fld: str, name: str) -> np.ndarray:
        return self.fields[fld][:, self.names.index(name)]

    def columns(self, fld: str, names: list[str]) -> np.ndarray | None:
        """(N, len(names)) in the given order, or None if a name is missing or the field is empty."""
        if fld not in self.fields or any(n not in self.names for n in names):
            return None
        cols = self.fields[fld][:, [self.names.index(n) for n in names]]
        return None if cols.size and np.isnan(cols).all() else cols


@dataclass
class Diagnostics:
    """Numeric key-values of DiagnosticArray messages: ``values[key]`` = (t, value) arrays.

    Keys are ``<status name>/<key>``; ``levels`` counts statuses per level (OK, WARN, ...),
    ``messages`` lists the distinct non-OK status messages.
    """

    topic: str
    count: int
    values: dict[str, tuple[np.ndarray, np.ndarray]]
    levels: dict[str, int]
    messages: list[str]


@dataclass
class BagData:
    path: Path
    storage: str
    topics: dict[str, tuple[str, int]]  # every topic in the bag: name -> (type, message count)
    roles: dict[str, str | None]  # role -> topic (None: not found)
    series: dict[str, TopicSeries]  # role -> samples (roles with messages only)
    diagnostics: Diagnostics | None
    hold_start: float | None  # absolute [s], detected online or given
    notes: list[str]
    start_ns: int  # receive times [s] of the series count from here
    end_ns: int
    header_origin_ns: int  # header stamps [s] of the series count from here


# --------------------------------------------------------------------------- discovery
def discover_topics(topics: Mapping[str, tuple[str, int]], given: Mapping[str, str | None] | None = None
                    ) -> tuple[dict[str, str | None], list[str]]:
    """Role -> topic for every role in :data:`ROLES`, and notes on what was not found.

    ``given`` maps roles to topic names chosen by the user (a leading '/' is optional);
    a given topic must exist with an accepted type, else :class:`BagError`.
    """
    given = {k: v for k, v in (given or {}).items() if v}
    roles: dict[str, str | None] = dict.fromkeys(ROLES)
    notes: list[str] = []
    taken: set[str] = set()

    def accept(role: str, topic: str) -> None:
        roles[role] = topic
        taken.add(topic)

    for role, (types, default, _) in ROLES.items():  # a known topic name with another type: a wrong recording
        if role not in given and default in topics and topics[default][0] not in types:
            found = f"{default} is {topics[default][0]}, but {role} needs {' or '.join(types)}"
            if role not in OPTIONAL:
                raise BagError(f"topic {found} (or name another topic with --{role.replace('_', '-')})")
            notes.append(f"{role}: topic {found}: not used")
    for role, name in given.items():
        if role not in ROLES:
            raise BagError(f"unknown topic role {role!r}")
        topic = name if name in topics or name.startswith("/") else "/" + name
        if topic not in topics:
            have = ", ".join(sorted(topics)) or "none"
            raise BagError(f"topic {topic} (--{role.replace('_', '-')}) is not in the bag (its topics: {have})")
        if topics[topic][0] not in ROLES[role][0]:
            raise BagError(f"topic {topic} is {topics[topic][0]}, but {role} needs {' or '.join(ROLES[role][0])}")
        accept(role, topic)

    free = [r for r in ROLES if r not in given]
    for role in free:  # default names, also under a namespace (/robot1/joint_states)
        types, default, _ = ROLES[role]
        cands = [t for t, (ty, _) in topics.items() if ty in types and t not in taken
                 and (t == default or t.endswith(default))]
        if len(cands) == 1 or default in cands:
            accept(role, default if default in cands else cands[0])
    for role in free:  # words in the name among topics of an accepted type
        types, _, words = ROLES[role]
        if roles[role] is not None or not words or role in BY_NAME_ONLY:
            continue
        cands = [t for t, (ty, _) in topics.items() if ty in types and t not in taken
                 and any(w in t.rsplit("/", 1)[-1].lower() for w in words)]
        if len(cands) == 1:
            accept(role, cands[0])
    all_words = {w for _, _, ws in ROLES.values() for w in ws}
    for role in free:  # the only remaining topic of an accepted type
        types, default, words = ROLES[role]
        if roles[role] is not None or role in BY_NAME_ONLY:
            continue
        cands = [t for t, (ty, _) in topics.items() if ty in types and t not in taken
                 and (words or not any(w in t.rsplit("/", 1)[-1].lower() for w in all_words))]
        if len(cands) == 1 and (words == () or topics[cands[0]][0] != JOINT_STATE):
            accept(role, cands[0])
        elif len(cands) > 1:
            notes.append(f"{role}: several candidate topics ({', '.join(cands)}); choose one with "
                         f"--{role.replace('_', '-')}")
    for role, topic in roles.items():
        if topic is None and role in OPTIONAL:
            continue
        if topic is None and not any(n.startswith(f"{role}:") for n in notes):
            notes.append(f"{role}: no topic of type {' or '.join(ROLES[role][0])} found "
                         f"(default name {ROLES[role][1]})")
        elif topic is not None and topics[topic][1] == 0:
            notes.append(f"{role}: topic {topic} has no messages")
    return roles, notes


# --------------------------------------------------------------------------- reading
class Clock:
    """Seconds relative to integer-ns origins (a float of epoch seconds resolves only ~0.2 us).

    Receive times count from the bag's start; header stamps from the first stamp seen
    (floored to a whole second), shared by all topics so their stamps stay comparable.
    """

    def __init__(self, receive_origin_ns: int):
        self.receive_origin_ns = receive_origin_ns
        self.header_origin_ns: int | None = None

    def header(self, msg: Any) -> tuple[float, bool]:
        """(stamp [s] or NaN without a header, whether the stamp is set, i.e. non-zero)."""
        h = getattr(msg, "header", None)
        if h is None:
            return math.nan, False
        ns = stamp_ns(h.stamp)
        if self.header_origin_ns is None:
            self.header_origin_ns = ns // NS * NS
        return (ns - self.header_origin_ns) * 1e-9, ns != 0

    def receive(self, t_ns: int) -> float:
        return (t_ns - self.receive_origin_ns) * 1e-9


class _TopicReader:
    """Accumulates one topic: row = [header stamp, receive time, field columns...]."""

    def __init__(self, topic: str, msgtype: str, clock: Clock, max_samples: int, window_samples: int):
        self.clock = clock
        self.topic = topic
        self.msgtype = msgtype
        self.fields = FIELDS[msgtype]
        self.max_samples = max_samples
        self.window_samples = window_samples
        self.names: list[str] | None = None
        self.by_name: dict[str, int] = {}
        self.buffer: SampleBuffer | None = None
        self.window: WindowBuffer | None = None
        self.timer = StreamTimer(TIMER_STAMPS * max_samples)
        self.timer_receive = StreamTimer(TIMER_STAMPS * max_samples)
        self.header_stamps = False  # any non-zero header stamp seen
        self.mismatched = 0  # messages whose names differ from the first message's
        self.lo: np.ndarray | None = None
        self.hi: np.ndarray | None = None
        # Online decisions (window, hold detection) use the header stamp where the type has one.
        self.time_col = 0 if msgtype != FLOAT64_ARRAY else 1

    def add(self, msg: Any, t_ns: int) -> np.ndarray:
        names, arrays = numeric_values(msg, self.msgtype)
        if self.names is None:
            width = max((len(a) for a in arrays), default=0)
            self.names = names if names and len(names) >= width else [str(k) for k in range(width)]
            self.by_name = {n: k for k, n in enumerate(self.names)}
            w = 2 + len(self.fields) * len(self.names)
            self.buffer = SampleBuffer(w, self.max_samples)
            self.window = WindowBuffer(w, self.window_samples, self.time_col)
            self.lo, self.hi = np.full(w, np.inf), np.full(w, -np.inf)
        n = len(self.names)
        row = np.full(2 + len(self.fields) * n, np.nan)
        stamp, stamp_set = self.clock.header(msg)
        row[0], row[1] = stamp, self.clock.receive(t_ns)
        if names is not None and names != self.names[: len(names)]:
            self.mismatched += 1
            idx = [self.by_name.get(x, -1) for x in names]
            for f, a in enumerate(arrays):
                for k, j in enumerate(idx[: len(a)]):
                    if j >= 0:
                        row[2 + f * n + j] = a[k]
        else:
            for f, a in enumerate(arrays):
                m = min(len(a), n)
                row[2 + f * n : 2 + f * n + m] = a[:m]
        self.header_stamps |= stamp_set
        self.timer.add(row[self.time_col])
        self.timer_receive.add(row[1])
        np.fmin(self.lo, row, out=self.lo)
        np.fmax(self.hi, row, out=self.hi)
        self.buffer.append(row)
        self.window.append(row)
        return row

    def series(self) -> TopicSeries | None:
        if self.buffer is None:
            return None
        use_header = self.header_stamps
        main = self._series(self.buffer.rows, use_header)
        main.count = self.buffer.seen
        main.stride = self.buffer.stride
        main.timing = (self.timer if use_header else self.timer_receive).stats()
        main.timing_receive = self.timer_receive.stats()
        n = len(self.names)
        main.peak_lo = {f: self.lo[2 + k * n : 2 + (k + 1) * n] for k, f in enumerate(self.fields)}
        main.peak_hi = {f: self.hi[2 + k * n : 2 + (k + 1) * n] for k, f in enumerate(self.fields)}
        if main.stride > 1:
            main.window = self._series(self.window.rows, use_header)
            main.notes.append(f"{self.topic}: {main.count} messages, more than {self.max_samples}: "
                              f"overview decimated by {main.stride}, full rate in a window of "
                              f"{len(main.window.t)} samples")
        if self.mismatched:
            main.notes.append(f"{self.topic}: {self.mismatched} messages name other joints/columns than "
                              f"the first one; matched by name")
        return main

    def _series(self, rows: np.ndarray, use_header: bool) -> TopicSeries:
        n = len(self.names)
        t = rows[:, 0] if use_header else rows[:, 1]
        fields = {f: rows[:, 2 + k * n : 2 + (k + 1) * n].copy() for k, f in enumerate(self.fields)}
        return TopicSeries(self.topic, self.msgtype, list(self.names), t.copy(), rows[:, 1].copy(), fields,
                           count=len(rows), stride=1, stamp_source="header" if use_header else "receive",
                           timing=None, timing_receive=None, peak_lo={}, peak_hi={})

    def arm(self, start: float) -> None:
        if self.window is not None:
            self.window.arm(start)


class _DiagnosticsReader:
    def __init__(self, topic: str, clock: Clock, cap: int):
        self.clock = clock
        self.topic = topic
        self.cap = cap
        self.count = 0
        self.values: dict[str, tuple[SampleBuffer, list]] = {}
        self.levels: dict[str, int] = {}
        self.messages: dict[str, None] = {}

    def add(self, msg: Any, t_ns: int) -> None:
        self.count += 1
        stamp, stamp_set = self.clock.header(msg)
        t = stamp if stamp_set else self.clock.receive(t_ns)  # times on the header clock where set
        level_names = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
        for status in msg.status:
            level = level_names.get(int.from_bytes(status.level, "little") if isinstance(status.level, bytes)
                                    else int(status.level), str(status.level))
            self.levels[level] = self.levels.get(level, 0) + 1
            if level != "OK" and status.message and len(self.messages) < 50:
                self.messages[f"{status.name}: {status.message}"] = None
            for kv in status.values:
                try:
                    value = float(kv.value)
                except ValueError:
                    continue  # text values (modes, names) and empty ones
                key = f"{status.name}/{kv.key}" if status.name else kv.key
                if key not in self.values:
                    self.values[key] = SampleBuffer(2, self.cap)
                self.values[key].append(np.array([t, value]))

    def result(self) -> Diagnostics:
        vals = {k: (b.rows[:, 0].copy(), b.rows[:, 1].copy()) for k, b in self.values.items()}
        return Diagnostics(self.topic, self.count, vals, self.levels, list(self.messages))


def read_bag(path: str | Path, given: Mapping[str, str | None] | None = None, hold_start: float | None = None,
             max_samples: int = MAX_SAMPLES, window_samples: int = WINDOW_SAMPLES) -> BagData:
    """Read the analysis topics of a bag in one pass with bounded memory (see module doc).

    ``given`` maps roles to topic names (see :func:`discover_topics`). ``hold_start``
    [s], relative to the first stamp of the reference (else the torque command, else
    the joint states), places the full-rate window when a topic is decimated; without
    it the window follows the last move-to-rest transition of the reference (or, with
    no reference, holds the last ``window_samples`` messages).
    """
    path = Path(path)
    with open_bag(path) as bag:
        bag.require_messages()
        topics = bag.topics()
        try:
            roles, notes = discover_topics(topics, given)
        except BagError as err:
            raise BagError(f"{path}: {err}") from None
        if bag.cut:
            notes.append(bag.cut)
        by_topic: dict[str, list[str]] = {}
        for role, topic in roles.items():
            if topic is not None and topics[topic][1] > 0:
                by_topic.setdefault(topic, []).append(role)
        clock = Clock(bag.start_ns)
        readers: dict[str, _TopicReader] = {}
        diag: _DiagnosticsReader | None = None
        for topic, rs in by_topic.items():
            if "diagnostics" in rs:
                diag = _DiagnosticsReader(topic, clock, max_samples)
            else:
                readers[topic] = _TopicReader(topic, topics[topic][0], clock, max_samples, window_samples)

        # Where the full-rate window goes: the given hold start, else the reference's rest.
        origin_topic = next((roles[r] for r in ("reference", "torque_command", "joint_states")
                             if roles[r] in readers), None)
        detector = HoldDetector()
        detector.listeners.append(lambda t: [r.arm(t) for r in readers.values()])
        ref = readers.get(roles["reference"] or "")
        user_hold: float | None = None  # absolute [s]

        conns = [c for c in bag.connections if c.topic in by_topic]
        for c in conns:
            if not bag.can_decode(c.msgtype):
                raise BagError(f"{path}: cannot decode {c.topic}: no definition of {c.msgtype} in the bag")
        for conn, t_ns, msg in bag.decoded(conns):
            if diag is not None and conn.topic == diag.topic:
                diag.add(msg, t_ns)
                continue
            r = readers[conn.topic]
            row = r.add(msg, t_ns)
            if conn.topic == origin_topic and r.buffer.seen == 1 and hold_start is not None:
                user_hold = row[r.time_col] + hold_start
                for other in readers.values():
                    other.arm(user_hold)
            elif r is ref and hold_start is None:
                detector.add(row[r.time_col], _speed(r, row))

        series: dict[str, TopicSeries] = {}
        for role, topic in roles.items():
            if topic in readers and (s := readers[topic].series()) is not None:
                series[role] = s
                notes.extend(n for n in s.notes if n not in notes)
        return BagData(path=path, storage=bag.storage, topics=topics, roles=roles, series=series,
                       diagnostics=diag.result() if diag is not None else None,
                       hold_start=user_hold if hold_start is not None else detector.hold_start,
                       notes=notes, start_ns=bag.start_ns, end_ns=bag.end_ns,
                       header_origin_ns=clock.header_origin_ns or 0)


def _speed(r: _TopicReader, row: np.ndarray) -> float:
    """Joint-space speed of a JointState row: |velocity|, or NaN if the message has none."""
    n = len(r.names)
    vel = row[2 + n : 2 + 2 * n]  # FIELDS[JOINT_STATE][1] == "velocity"
    vel = vel[np.isfinite(vel)]
    return float(np.linalg.norm(vel)) if vel.size else math.nan
