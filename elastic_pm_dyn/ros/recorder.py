"""Record topics into a rosbag2 (console script ``recorder_node``, ``elastic-pm-dyn record``).

There is no ``ros2 bag`` with pip-only ROS; this node writes the same format (mcap by
default, sqlite3 as an option) through :class:`~elastic_pm_dyn.bags.writer.BagWriter`,
with the message definitions stored in the bag, so that ``ros2 bag`` users and
``rosbags``-based analysis read it alike.

Topics are subscribed once the ROS graph shows a publisher (its type is used), and
with ``raw=True``: the wire bytes are written as they are, never re-serialised (rclpy's
``serialize_message`` can append bytes that rosbags rejects). Like ``ros2 bag record``,
the subscription QoS follows the publishers: transient local when all of them offer it
(so samples published before the recorder matched are still recorded), best effort
when any of them is best effort. Bag time stamps are receive times on the node clock
(simulated time with use_sim_time).

Killed at any moment (even SIGKILL), the node leaves a bag that ``analyze``, ``export``
and ``observe`` read up to at most ~1 s before the kill: the writer flushes (an mcap chunk,
a sqlite3 commit) every :data:`FLUSH_PERIOD` of wall-clock time, from the message stream
and from a timer when messages stop. "recording <topic>" is logged once the topic's first
message is in the file, not when it is subscribed.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.typestore import register_msg_text
from elastic_pm_dyn.bags.writer import STORAGES, BagWriter
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.node_main import ManagedNode, run_node
from elastic_pm_dyn.ros.params import Param, ParameterError, read_parameters, reject_unknown

DEMO_TOPICS = ["/joint_states", "/branch_forces", "/ee_pose", "/torque_command", "/reference_joint_states"]
DISCOVERY_PERIOD = 0.1  # [s] wall-clock poll of the ROS graph for the wanted topics
DEPTH = 1000  # a recorder must not drop samples in bursts
FLUSH_PERIOD = 0.5  # [s] wall clock: at most this much of the recording is lost to a kill (plus a callback)

PARAMS = [
    Param("output", "bag", "bag directory to create (must not exist)"),
    Param("storage", "mcap", "mcap or sqlite3", choices=STORAGES),
    Param("topics", DEMO_TOPICS, "topics to record (absolute names)"),
]


class RecorderNode(ManagedNode):
    """Writes every message of the chosen topics into one bag (see module doc)."""

    def __init__(self, **node_kwargs: Any):
        super().__init__("recorder", **node_kwargs)
        reject_unknown(self, [s.name for s in PARAMS])
        p = read_parameters(self, PARAMS)
        self.wanted = [t if t.startswith("/") else "/" + t for t in p["topics"]]
        if not self.wanted:
            raise ParameterError("parameter 'topics' is empty: nothing to record")
        self.path = Path(p["output"])
        try:
            self.writer = BagWriter(self.path, p["storage"], flush_period=FLUSH_PERIOD)
        except BagError as err:
            raise ParameterError(f"parameter 'output': {err}") from None
        self.connections: dict[str, Any] = {}  # topic -> bag connection
        self.on_disk: set[str] = set()  # topics whose first message is in the file (logged once)
        self.skipped: set[str] = set()  # topics whose type cannot be recorded (warned once)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(DISCOVERY_PERIOD, self._discover, clock=steady)
        self.create_timer(FLUSH_PERIOD / 2, self._flush, clock=steady)  # when messages stop coming
        self.get_logger().info(f"waiting for {', '.join(self.wanted)} -> {self.path} ({p['storage']})")

    def _discover(self) -> None:
        types = dict(self.get_topic_names_and_types())
        for topic in self.wanted:
            # Wait for a publisher: its type and QoS decide the subscription. (The two graph
            # queries are not atomic: a publisher can show before its topic is listed.)
            if topic in self.connections or topic in self.skipped or not types.get(topic) \
                    or not self.count_publishers(topic):
                continue
            msgtype = types[topic][0]
            try:
                self._subscribe(topic, msgtype)
            except InputError as err:  # BagError too
                self.skipped.add(topic)
                self.get_logger().warning(f"not recording {topic}: {err}")

    def _subscribe(self, topic: str, msgtype: str) -> None:
        msg_class = _message_class(msgtype)
        if msgtype not in self.writer.typestore.types:
            register_msg_text(self.writer.typestore, msgtype, _installed_definition(msgtype))
        self.connections[topic] = self.writer.add_connection(topic, msgtype)
        self.create_subscription(msg_class, topic, lambda raw, t=topic: self._write(t, raw),
                                 self._qos(topic), raw=True)
        self.get_logger().info(f"subscribed to {topic} [{msgtype}]")

    def _qos(self, topic: str) -> QoSProfile:
        offered = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
        durable = bool(offered) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
        reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
        return QoSProfile(depth=DEPTH,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL if durable else DurabilityPolicy.VOLATILE,
                          reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT)

    def _write(self, topic: str, raw: bytes) -> None:
        if self.writer.write(self.connections[topic], self.get_clock().now().nanoseconds, raw):
            self._announce()

    def _flush(self) -> None:
        if self.writer.flush():
            self._announce()

    def _announce(self) -> None:
        """Log "recording <topic>" for each topic whose first message just reached the file."""
        for topic, conn in self.connections.items():
            if topic not in self.on_disk and self.writer.durable(conn):
                self.on_disk.add(topic)
                self.get_logger().info(f"recording {topic} [{conn.msgtype}]: first message in {self.path}")

    def close(self) -> None:
        counts = {c.topic: self.writer.count(c) for c in self.connections.values()}
        self.writer.close()
        missing = [t for t in self.wanted if t not in self.connections]
        self.get_logger().info(f"bag {self.path} closed: "
                               + (", ".join(f"{t} {n}" for t, n in counts.items()) or "no messages")
                               + (f"; never seen: {', '.join(missing)}" if missing else ""))


def _message_class(msgtype: str) -> type:
    """'pkg/msg/Type' -> the rclpy message class (needed for the type support, even raw)."""
    pkg, _, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.msg"), name)
    except (ImportError, AttributeError):
        raise InputError(f"message type {msgtype} is not installed for Python") from None


def _installed_definition(msgtype: str) -> str:
    """The .msg text of a message type the typestore lacks, as installed (share/<pkg>/msg)."""
    pkg, _, name = msgtype.split("/")
    module = importlib.import_module(pkg)
    # <prefix>/lib/pythonX.Y/site-packages/<pkg>/__init__.py -> <prefix>/share/<pkg>/msg/<name>.msg
    msg_file = Path(module.__file__).resolve().parents[4] / "share" / pkg / "msg" / f"{name}.msg"
    if not msg_file.is_file():
        raise InputError(f"no definition of {msgtype} found at {msg_file}")
    return msg_file.read_text()


def main(args: list[str] | None = None) -> int:
    return run_node("recorder_node", RecorderNode, args)


if __name__ == "__main__":
    sys.exit(main())
