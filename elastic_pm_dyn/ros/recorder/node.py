"""Record topics into a rosbag2 (console script ``recorder_node``, ``elastic-pm-dyn record``).

There is no ``ros2 bag`` with pip-only ROS; this node writes the same format (mcap by
default, sqlite3 as an option) through :class:`~elastic_pm_dyn.bags.writer.BagWriter`,
with the message definitions stored in the bag, so that ``ros2 bag`` users and
``rosbags``-based analysis read it alike.

A topic whose type the configuration gives (``topic_types``; :data:`DEMO_TYPES`, in config/recorder.yaml)
is subscribed at start-up, before any publisher exists, so the first message of a run is
in the bag even from a publisher that starts sending as soon as its other subscribers
matched. Until a publisher shows, two readers wait, reliable: a transient-local one (a writer that
offers the same (the plant's states, our controllers' commands) hands it the samples sent
before the reader's side of the match completed, which a volatile reader would miss) and a
volatile one (a volatile writer, a user's controller on default QoS, matches only that one, at
once); each message is recorded once. When nothing has arrived by the time the publishers
show, a reader with their QoS is made. Other topics are subscribed once the ROS graph shows a publisher (its type
is used). Subscriptions take ``raw=True``: the wire bytes are written as they are, never
re-serialised (rclpy's ``serialize_message`` can append bytes that rosbags rejects). Like
``ros2 bag record``, the subscription QoS follows the publishers: transient local when all
of them offer it (so samples published before the recorder matched are still recorded),
best effort when any of them is best effort. Bag time stamps are receive times on the node
clock (simulated time with use_sim_time).

Keeping up: a callback only takes the serialized message and queues it; a writer thread
(:class:`~elastic_pm_dyn.bags.queued_writer.QueuedWriter`) writes and flushes. The
subscription keeps ``rate_hint * max_lag`` messages (at least the publishers' own
history), so the executor may fall ``max_lag`` seconds behind a topic at ``rate_hint``
before the middleware drops anything. What is lost anyway is counted per topic
(:mod:`~elastic_pm_dyn.ros.losses`: DDS message-lost events and publication sequence gaps,
plus messages the writer dropped) and reported in the log (throttled), on /diagnostics
and, at close, in the bag's ``metadata.yaml`` (``custom_data: elastic_pm_dyn.losses``).
A topic that is matched but delivers nothing for :data:`SILENT_AFTER` seconds is reported
the same way (a publisher that is silent, or a transport that does not deliver), and read by a
new reader beside the old one: a publisher that was only silent (the observer before its loop
starts) serves the old reader at once, while a new participant's reader may take a second to
match; a message both deliver is recorded once (:class:`_Once`).

Topic names resolve as a node's own do: a relative name (``joint_states``) in the recorder's
namespace (``-r __ns:=/r1``: ``/r1/joint_states``), with its remappings; an absolute one stays.
A wanted topic that no publisher serves yet is said in /diagnostics (WARN, ``no publisher:``),
so a recorder in the wrong namespace never reports "recording, nothing lost" over an empty bag.

Killed at any moment (even SIGKILL), the node leaves a bag that ``analyze``, ``export``
and ``observe`` read up to at most ~1 s before the kill: the writer flushes (an mcap chunk,
a sqlite3 commit) every :data:`FLUSH_PERIOD` of wall-clock time. "recording <topic>" is
logged once the topic's first message is in the file, not when it is subscribed.
"""

from __future__ import annotations

import importlib
import json
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks, UnsupportedEventTypeError
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.queued_writer import QueuedWriter
from elastic_pm_dyn.bags.typestore import register_msg_text
from elastic_pm_dyn.bags.writer import STORAGES, BagWriter
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.drain import Drain
from elastic_pm_dyn.ros.graph_checks import resolve_topic
from elastic_pm_dyn.ros.losses import TopicLosses
from elastic_pm_dyn.ros.node_main import ManagedNode, run_node
from elastic_pm_dyn.ros.params import Param, ParameterError, read_parameters, reject_unknown
from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS
from elastic_pm_dyn.ros.realtime_process import PROCESS_PARAMS, schedule_process
from elastic_pm_dyn.ros.recorder.second_participant import SecondParticipant

DEMO_TOPICS = ["/joint_states", "/branch_forces", "/ee_pose", "/torque_command", "/reference_joint_states"]
DEMO_TYPES = ["/joint_states sensor_msgs/msg/JointState", "/branch_forces elastic_pm_dyn_msgs/msg/BranchForces",
              "/ee_pose geometry_msgs/msg/PoseStamped", "/torque_command sensor_msgs/msg/JointState",
              "/reference_joint_states sensor_msgs/msg/JointState"]
DISCOVERY_PERIOD = 0.1  # [s] wall-clock poll of the ROS graph for the wanted topics
FLUSH_PERIOD = 0.5  # [s] wall clock: at most this much of the recording is lost to a kill (plus the queue)
REPORT_PERIOD = 1.0  # [s] /diagnostics, loss warnings and the silent-topic check
SILENT_AFTER = 5.0  # [s] a matched topic without any message for this long is reported and subscribed anew
MAX_RESUBSCRIBE = 2  # new subscriptions for a silent topic before it is reported as not recorded
MAX_DEPTH = 100_000  # subscription history bound (memory: depth x message size)
LOSSES_KEY = "elastic_pm_dyn.losses"  # metadata.yaml custom_data: per-topic loss counts (JSON)

PARAMS = [
    Param("output", "bag", "bag directory to create (must not exist)"),
    Param("storage", "mcap", "mcap or sqlite3", choices=STORAGES),
    Param("topics", DEMO_TOPICS, "topics to record (relative names resolve in the node's namespace)"),
    Param("topic_types", [], "'<topic> <pkg/msg/Type>' per topic to subscribe at start-up, names resolved as in "
          "'topics' (the others "
          "wait for a publisher to show their type; config/recorder.yaml lists the demo's); a listed topic that is "
          "not in 'topics' is not recorded", item=str),
    Param("rate_hint", 1000.0, "[Hz] the highest message rate expected on one topic", positive=True),
    Param("max_lag", 2.0, "[s] how far the recorder may fall behind a topic at rate_hint before "
          "the middleware drops messages (subscription depth = rate_hint * max_lag)", positive=True),
    *PROCESS_PARAMS,  # a recorder beside a realtime loop on a loaded machine is scheduled as the loop is
]


def subscription_depth(rate_hint: float, max_lag: float, offered_depths: list[int]) -> int:
    """Messages a subscription keeps: ``max_lag`` seconds at ``rate_hint``, at least every publisher's
    history (transient local hands it over at once), within 10 .. :data:`MAX_DEPTH`."""
    return int(min(MAX_DEPTH, max(10, math.ceil(rate_hint * max_lag), *offered_depths)))


class _Once:
    """Each message once when several readers of a topic deliver it, keyed by the writer's source
    stamp and publication sequence number. Their callbacks run on several threads (a second
    participant spins its own): the recording of a message happens under :attr:`lock`."""

    SIZE = 4096  # keys remembered: far more than two readers of one topic are ever apart

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self._keys: set[tuple[Any, Any]] = set()
        self._order: deque[tuple[Any, Any]] = deque()

    def new(self, info: dict[str, Any]) -> bool:
        """True the first time a message is seen (always, if the RMW gives no stamp or number)."""
        key = (info.get("source_timestamp"), info.get("publication_sequence_number"))
        if key == (None, None):
            return True
        if key in self._keys:
            return False
        self._keys.add(key)
        self._order.append(key)
        if len(self._order) > self.SIZE:
            self._keys.discard(self._order.popleft())
        return True


class _Topic:
    """One recorded topic: its bag connection, subscription and what it lost."""

    def __init__(self, conn: Any):
        self.conn = conn
        self.losses = TopicLosses()
        self.subscribed_at = time.monotonic()
        self.matched = 0  # publishers matched (the matched event; the graph's count until it fires)
        self.matched_by: dict[object, int] = {}  # per reader of the topic
        self.early = False  # subscribed before any publisher showed: its QoS is still a guess
        self.subscription: Any = None
        self.node: Any = None  # the node whose participant holds the subscription
        self.once: _Once | None = None  # set once the topic has several readers
        self.msg_class: type | None = None
        self.arrive_reported = False
        self.resubscribed = 0  # times the subscription was made anew because it stayed silent
        self.silent_reported = False
        self.reported_lost = 0  # lost as of the last warning


class RecorderNode(ManagedNode):
    """Writes every message of the chosen topics into one bag (see module doc)."""

    def __init__(self, **node_kwargs: Any):
        super().__init__("recorder", **node_kwargs)
        self.drains: dict[Any, Drain] = {}  # per participant's node (each spun by its own thread)
        reject_unknown(self, [s.name for s in PARAMS])
        p = read_parameters(self, PARAMS)
        schedule_process(self, p)
        # resolved as a publisher of this node would resolve them: namespace, ~, remappings
        self.wanted = [self._resolve("topics", t) for t in p["topics"]]
        if not self.wanted:
            raise ParameterError("parameter 'topics' is empty: nothing to record")
        if p["rate_hint"] > 1e6 or p["max_lag"] > 3600:
            raise ParameterError(f"parameters 'rate_hint' {p['rate_hint']:g} Hz / 'max_lag' {p['max_lag']:g} s: "
                                 "at most 1e6 Hz and 3600 s")
        self.rate_hint, self.max_lag = p["rate_hint"], p["max_lag"]
        self.path = Path(p["output"])
        try:
            self.writer = QueuedWriter(lambda: BagWriter(self.path, p["storage"], flush_period=FLUSH_PERIOD),
                                       on_flush=self._announce)
        except BagError as err:
            raise ParameterError(f"parameter 'output': {err}") from None
        self.topics: dict[str, _Topic] = {}
        self.on_disk: set[str] = set()  # topics whose first message is in the file (logged once)
        self.skipped: set[str] = set()  # topics whose type cannot be recorded (warned once)
        self.lost_events_supported = True
        self.participants: list[SecondParticipant] = []  # made for silent topics (_resubscribe)
        self.write_error_reported = False
        for topic, msgtype in _topic_types(p["topic_types"], lambda t: self._resolve("topic_types", t)).items():
            if topic in self.wanted:
                try:
                    self._subscribe(topic, msgtype, early=True)
                except InputError as err:  # BagError too
                    raise ParameterError(f"parameter 'topic_types': {topic}: {err}") from None
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(DISCOVERY_PERIOD, self._discover, clock=steady)
        self.create_timer(REPORT_PERIOD, self._report, clock=steady)
        self.get_logger().info(f"waiting for {', '.join(self.wanted)} -> {self.path} ({p['storage']})")

    def _resolve(self, parameter: str, topic: str) -> str:
        """The fully qualified name of ``topic``; ParameterError (one line) when it is no topic name."""
        return resolve_topic(self, parameter, topic)

    @property
    def connections(self) -> dict[str, Any]:
        """topic -> bag connection, for the topics subscribed so far."""
        return {t: s.conn for t, s in self.topics.items()}

    def count(self, topic: str) -> int:
        """Messages of ``topic`` handed to the bag writer so far."""
        s = self.topics.get(topic)
        return self.writer.written[s.conn.id] if s else 0

    def _discover(self) -> None:
        types = dict(self.get_topic_names_and_types())
        for topic, s in self.topics.items():
            if s.early and self.count_publishers(topic):
                self._settle(topic, s, types.get(topic, []))
        for topic in self.wanted:
            # Wait for a publisher: its type and QoS decide the subscription. (The two graph
            # queries are not atomic: a publisher can show before its topic is listed.)
            if topic in self.topics or topic in self.skipped or not types.get(topic) \
                    or not self.count_publishers(topic):
                continue
            msgtype = types[topic][0]
            try:
                self._subscribe(topic, msgtype)
            except InputError as err:  # BagError too
                self.skipped.add(topic)
                self.get_logger().warning(f"not recording {topic}: {err}")

    def _subscribe(self, topic: str, msgtype: str, early: bool = False) -> None:
        msg_class = _message_class(msgtype)
        if msgtype not in self.writer.typestore.types:
            register_msg_text(self.writer.typestore, msgtype, _installed_definition(msgtype))
        state = _Topic(self.writer.add_connection(topic, msgtype))
        state.msg_class = msg_class
        state.early = early
        self.topics[topic] = state
        if not early:
            self._create_subscription(topic, state)
            return
        # Before any publisher shows: a transient-local reader (a durable writer's first messages,
        # published before discovery matched, still arrive) and a volatile one (a volatile writer,
        # e.g. a user's controller on default QoS, never matches a transient-local reader); each
        # message is recorded once, from whichever delivers it first.
        state.once = _Once()
        for durability in (DurabilityPolicy.TRANSIENT_LOCAL, DurabilityPolicy.VOLATILE):
            self._create_subscription(topic, state, QoSProfile(
                depth=subscription_depth(self.rate_hint, self.max_lag, []), reliability=ReliabilityPolicy.RELIABLE,
                durability=durability))

    def _create_subscription(self, topic: str, state: _Topic, qos: QoSProfile | None = None,
                             node: Any = None) -> None:
        """Subscribe ``topic`` (``qos``, else the publishers' QoS) in ``node``'s participant (else this node's).
        ``topic`` is resolved already (__init__): another participant's node, without this node's
        namespace and remappings, subscribes the same topic."""
        node = node or self
        state.matched = self.count_publishers(topic)
        state.subscribed_at = time.monotonic()
        qos = qos or self._qos(topic)
        put, losses, clock = self.writer.put, state.losses, self.get_clock()
        conn = state.conn

        def record(raw: bytes, info: dict[str, Any]) -> None:  # the hot path: queue and count, nothing else
            put(conn, clock.now().nanoseconds, raw)
            losses.received += 1
            losses.gaps.take(info.get("publication_sequence_number"), state.matched)

        def take(raw: bytes, info: dict[str, Any]) -> None:
            once = state.once
            if once is None:
                record(raw, info)
                return
            with once.lock:  # several readers: each message once, from whichever delivers it first
                if once.new(info):
                    record(raw, info)

        def lost(event: Any) -> None:
            losses.dds_lost += event.total_count_change

        # the executor wakes the node for one message; what else is queued on its readers is taken in the
        # same turn (ros/drain.py: a dozen topics at 1 kHz cost a core through the executor alone)
        drain = self.drains.setdefault(node, Drain())
        reader = object()  # this reader's key: a topic may have several (the most matched counts)

        def matched(event: Any) -> None:
            state.matched_by[reader] = event.current_count
            state.matched = max(state.matched_by.values())

        if self.lost_events_supported:
            try:
                state.subscription = drain.subscribe(
                    node, state.msg_class, topic, take, qos, raw=True,
                    event_callbacks=SubscriptionEventCallbacks(message_lost=lost, matched=matched))
            except UnsupportedEventTypeError:  # an RMW without them: sequence gaps remain
                self.lost_events_supported = False
                self.get_logger().warning("this RMW reports no message-lost events: losses are counted "
                                          "from sequence gaps only")
        if not self.lost_events_supported:
            state.subscription = drain.subscribe(node, state.msg_class, topic, take, qos, raw=True)
        state.node = node
        where = "" if node is self else f" through a new DDS participant ({node.get_name()})"
        self.get_logger().info(f"subscribed to {topic} [{conn.msgtype}], depth {qos.depth}{where}")

    def _settle(self, topic: str, s: _Topic, offered_types: list[str]) -> None:
        """A topic subscribed at start-up, now that publishers show: its transient-local reader
        takes their QoS when they are volatile or best effort (they do not match it, so nothing has
        arrived); a publisher of another type than configured is reported once."""
        s.early = False
        s.subscribed_at = time.monotonic()  # silence counts from now: there was no one to hear before
        if offered_types and s.conn.msgtype not in offered_types:
            self.get_logger().warning(f"{topic}: configured as {s.conn.msgtype}, published as "
                                      f"{', '.join(offered_types)}: those publishers are not recorded")
        wanted, current = self._qos(topic), s.subscription.qos_profile
        if s.losses.received == 0 and (wanted.durability, wanted.reliability) != (current.durability,
                                                                                 current.reliability):
            self.drains[s.node].remove(s.subscription)
            s.node.destroy_subscription(s.subscription)
            s.losses.gaps.last = None
            self._create_subscription(topic, s, wanted, s.node)

    def _resubscribe(self, topic: str, state: _Topic) -> None:
        """A new reader for a topic that is matched but silent, in a new DDS participant: Fast DDS
        can leave a reader that its writer never serves, and then every new reader of the same
        participant too, while other participants' readers are served (issue #29; see
        :mod:`~elastic_pm_dyn.ros.recorder.second_participant`). The k-th new subscription of any topic is
        made in the k-th extra participant, so at most :data:`MAX_RESUBSCRIBE` are ever made."""
        # The old reader stays subscribed (its node keeps it): if the publisher was only silent it
        # serves that one at once, while the new participant's reader may take a second to match
        # (a loop's first estimates were lost so)
        if state.once is None:
            state.once = _Once()
        state.resubscribed += 1
        while len(self.participants) < state.resubscribed:
            self.participants.append(SecondParticipant(
                self.context.get_domain_id(), f"{self.get_name()}_{len(self.participants) + 1}"))
        self._create_subscription(topic, state, None, self.participants[state.resubscribed - 1].node)

    def _qos(self, topic: str) -> QoSProfile:
        offered = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
        durable = bool(offered) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
        reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
        depth = subscription_depth(self.rate_hint, self.max_lag,
                                   [q.depth for q in offered if q.history == HistoryPolicy.KEEP_LAST])
        return QoSProfile(depth=depth,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL if durable else DurabilityPolicy.VOLATILE,
                          reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT)

    def _announce(self, writer: BagWriter) -> None:
        """Log "recording <topic>" for each topic whose first message just reached the file
        (called by the writer thread after a flush)."""
        for topic, s in list(self.topics.items()):
            if topic not in self.on_disk and writer.durable(s.conn):
                self.on_disk.add(topic)
                self.get_logger().info(f"recording {topic} [{s.conn.msgtype}]: first message in {self.path}")

    def losses(self) -> dict[str, dict[str, int]]:
        """Per topic: received, lost (the exact witness where there is one), lost (DDS events),
        skipped (sequence gaps), dropped (by the writer), new subscriptions made because it stayed silent."""
        return {t: {"received": s.losses.received, "lost": s.losses.lost() + self.writer.dropped[s.conn.id],
                    "lost_dds": s.losses.dds_lost,
                    "sequence_gaps": s.losses.sequence_gaps, "dropped_by_writer": self.writer.dropped[s.conn.id],
                    "resubscribed": s.resubscribed}
                for t, s in self.topics.items()}

    def _without_publisher(self) -> list[str]:
        """Wanted topics that nothing has come on and no publisher serves (matched, or in the graph
        for a topic not subscribed yet); a topic of a type that cannot be recorded is not among them."""
        out = []
        for topic in self.wanted:
            s = self.topics.get(topic)
            if s is None:
                if topic not in self.skipped:  # subscribed once a publisher shows
                    out.append(topic)
            elif s.losses.received == 0 and s.matched == 0 and s.subscription.get_publisher_count() == 0:
                out.append(topic)
        return out

    def _silent(self, s: _Topic) -> bool:
        return (s.losses.received == 0 and s.matched > 0
                and time.monotonic() - s.subscribed_at > SILENT_AFTER)

    def _report(self) -> None:
        """Warn about new losses and silent topics; /diagnostics with every topic's counts."""
        log = self.get_logger()
        problems = []
        for topic, s in self.topics.items():
            lost = s.losses.lost() + self.writer.dropped[s.conn.id]
            if lost:
                problems.append(f"{topic} lost {lost}")
            if lost > s.reported_lost:
                s.reported_lost = lost
                log.warning(f"{topic}: {lost} message(s) lost so far ({s.losses.summary()}, "
                            f"{self.writer.dropped[s.conn.id]} dropped by the bag writer)")
            if self._silent(s):
                problems.append(f"{topic} silent")
                waited = time.monotonic() - s.subscribed_at
                if s.resubscribed < MAX_RESUBSCRIBE:
                    log.warning(f"{topic}: {s.matched} publisher(s) matched but no message in {waited:.0f} s; "
                                "subscribing again (a silent publisher, or a reader the middleware does not serve)")
                    self._resubscribe(topic, s)
                elif not s.silent_reported:
                    s.silent_reported = True
                    log.warning(f"{topic}: {s.matched} publisher(s) matched but still no message after "
                                f"{s.resubscribed} new subscription(s): nothing of it is recorded (a silent "
                                "publisher, or a transport that does not deliver: see docs/nodes.md, 'Recorder "
                                "QoS and losses')")
            elif (s.silent_reported or s.resubscribed) and s.losses.received and not s.arrive_reported:
                s.arrive_reported = True
                log.info(f"{topic}: messages arrive now (after {s.resubscribed} new subscription(s))")
        unserved = self._without_publisher()
        if unserved:  # a namespace or a name that is wrong looks like this: never "nothing lost"
            problems.insert(0, f"no publisher: {', '.join(unserved)}")
        if self.skipped:  # the log said why, once
            problems.insert(0, f"not recordable: {', '.join(sorted(self.skipped))}")
        if self.writer.error is not None:
            problems.insert(0, f"bag write failed: {self.writer.error}")
            if not self.write_error_reported:
                self.write_error_reported = True
                log.error(f"{self.writer.error}; recording stopped")
                self.done = True
        status = DiagnosticStatus(name=f"{self.get_fully_qualified_name()}: recorder", hardware_id=str(self.path))
        status.level = (DiagnosticStatus.ERROR if self.writer.error is not None
                        else DiagnosticStatus.WARN if problems else DiagnosticStatus.OK)
        status.message = "; ".join(problems) or "recording, nothing lost"
        values = {"queued_bytes": str(self.writer.queued_bytes()), "no_publisher": " ".join(unserved)}
        for topic, counts in self.losses().items():
            values.update({f"{topic} {k}": str(v) for k, v in counts.items()})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        diag = DiagnosticArray(status=[status])
        diag.header.stamp = self.get_clock().now().to_msg()
        self.pub_diagnostics.publish(diag)

    def close(self) -> None:
        for participant in self.participants:  # no message may come after the writer closed
            participant.close()
        losses = self.losses()
        try:
            self.writer.call(lambda w: w.set_custom_data(LOSSES_KEY, json.dumps(losses, sort_keys=True)))
            self.writer.close()
        except BagError as err:
            self.get_logger().error(f"{err}; the bag keeps what was flushed before")
        counts = {t: self.count(t) for t in self.topics}
        missing = [t for t in self.wanted if t not in self.topics]
        lost = {t: s.losses.lost() + self.writer.dropped[s.conn.id] for t, s in self.topics.items()}
        self.get_logger().info(
            f"bag {self.path} closed: "
            + (", ".join(f"{t} {n} (lost {lost[t]})" for t, n in counts.items()) or "no messages")
            + (f"; never seen: {', '.join(missing)}" if missing else ""))


def _topic_types(entries: list[str], resolve: Callable[[str], str]) -> dict[str, str]:
    """'<topic> <pkg/msg/Type>' entries -> {resolved topic: type}; a malformed one is a ParameterError."""
    out = {}
    for entry in entries:
        parts = entry.split()
        if len(parts) != 2 or parts[1].count("/") != 2:
            raise ParameterError(f"parameter 'topic_types': {entry!r} is not '<topic> <pkg/msg/Type>'")
        out[resolve(parts[0])] = parts[1]
    return out


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
