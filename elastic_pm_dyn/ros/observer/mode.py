"""The state observer on a node: the observer node (``observer_node``) and the plant node in
``mode: observer`` (which does not simulate then, it estimates) run this, with the same
parameters: :data:`~elastic_pm_dyn.ros.machine_params.MACHINE_PARAMS` and
:data:`~elastic_pm_dyn.ros.machine_params.ESTIMATE_PARAMS` (model, command message, output
topics, frames, rates) and :data:`OBSERVER_PARAMS` (every ``observer.*`` of config/observer.yaml).

Inputs (topics ``observer.topics.*``, QoS :data:`~elastic_pm_dyn.ros.qos.OBSERVER_INPUT_QOS`,
overridable per topic with ``qos_overrides.<topic>.subscription.*``):
``torque_command`` (sensor_msgs/JointState effort, or std_msgs/Float64MultiArray in
``command_joints`` order, stamped on arrival with the node's clock as it has no header),
``measured_joint_states`` (sensor_msgs/JointState), ``ee_imu`` (sensor_msgs/Imu, if
``imu`` is among ``observer.sensors``), ``measured_branch_forces``
(elastic_pm_dyn_msgs/BranchForces, if ``branch_forces`` is and its source is that topic).
Time is the messages' header stamps, never their arrival: the filter counts seconds from the
first one (an integer-ns origin, so epoch stamps keep their nanoseconds) and every estimate
is published at the exact stamp of its message. A message stamped more than
``observer.timing.max_future`` ahead of the filter is not used (counted as ``future``); one
ahead by less that the next joint states contradict (three late in a row) restarts the filter
from them (:class:`~elastic_pm_dyn.ros.observer.session.ObserverSession`), and
a joint state with duplicate names, without a measured joint or with no joint of the model
is not used either (counted per reason); one throttled warning line each, the counts in
``/diagnostics``.

Outputs on the plant's own topics, so RViz and the analysis work unchanged:
``joint_states`` (every tree joint; effort = command + estimated disturbance on the motors,
spring force on the elastic joints), ``branch_forces`` (with ``force_stddev``), ``ee_pose``,
``markers``; plus ``topics.joint_states_stddev`` (default ``~/joint_states_stddev``:
JointState whose position/velocity hold the standard deviations) and ``/diagnostics``
(health, NIS statistics, gated samples, update times, the accelerometer sample timing in
use, and per sensor whose NIS is far off its likely cause, ``<sensor>.nis_diagnosis``).
The diagnostics timer also logs each new choice of ``imu.sample_timing: auto`` (info) and
those causes (a throttled warning). ``~/reset`` restarts the filter from
the latest measured joint state it used (never from one stamped too far ahead),
``~/set_state`` from a given one.

The callbacks convert messages and call :class:`~elastic_pm_dyn.ros.observer.session.ObserverSession`
(no physics here). They never overlap: the node runs in a single-threaded executor.
"""

from __future__ import annotations

import copy
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from elastic_pm_dyn_msgs.msg import BranchForces
from elastic_pm_dyn_msgs.srv import SetJointState
from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64MultiArray, Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from elastic_pm_dyn.bags.msgtypes import stamp_ns
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.config import DEFAULT_PARAMETERS, PREFIX, RUNTIME_PARAMETERS
from elastic_pm_dyn.ros.drain import Drain
from elastic_pm_dyn.ros.graph_checks import refuse_if_taken, resolved_topics
from elastic_pm_dyn.ros.losses import SequenceGaps
from elastic_pm_dyn.ros.markers import MechanismMarkers
from elastic_pm_dyn.ros.messages import EstimateMessages, stamp
from elastic_pm_dyn.ros.observer.input_order import AFTER, BEFORE, COMMAND, PRIMARY, InputOrder
from elastic_pm_dyn.ros.observer.session import ObserverSession, Outcome, observer_config, parameter_message
from elastic_pm_dyn.ros.observer.wrench_output import WrenchOutput
from elastic_pm_dyn.ros.params import COMMAND_JOINTS, Param, ParameterError, read_parameters
from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS, OBSERVER_INPUT_QOS, STATE_OUT_QOS, VIEWER_QOS
from elastic_pm_dyn.ros.throttle import KindThrottle

WARN_EVERY = 1.0  # [s] throttle of repeated warnings, per kind
ORDER_CHECK = 0.05  # [s] wall time between checks of inputs that wait too long (input_order: stamp)
FINDINGS_EVERY = 10.0  # [s] throttle of the NIS findings (they describe a window of samples, not one)
LEVELS = {0: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, 2: DiagnosticStatus.ERROR}

# Every observer parameter, typed by its default (floats are floats), as config/observer.yaml.
# The sensors' noise levels and the gate may change while the filter runs (ros2 param set).
OBSERVER_PARAMS = [Param(PREFIX + name, default, "state observer; see config/observer.yaml",
                         runtime=name in RUNTIME_PARAMETERS,
                         fixed="the filter (model, process noise, schedule) is set up at start-up: restart the node")
                   for name, default in DEFAULT_PARAMETERS.items()]


class ObserverMode:
    """Subscriptions, publishers, services and timers of ``mode: observer`` on ``node``."""

    def __init__(self, node: Node, mech: Mechanism, p: dict[str, Any]):
        self.node = node
        flat = read_parameters(node, OBSERVER_PARAMS)
        try:
            cfg = observer_config(flat)
        except InputError as err:
            raise ParameterError(str(err)) from None
        try:
            self.session = ObserverSession(mech, cfg, p[COMMAND_JOINTS])
        except InputError as err:  # e.g. an unknown joint or branch name
            raise ParameterError(parameter_message(err)) from None
        self.session.restart_on_fault = p["restart_on_fault"]
        self.cfg = cfg
        self.model_name = mech.model.name
        self.messages = EstimateMessages(mech, p["frames.base"])
        self.markers = MechanismMarkers(mech, p["frames.base"])
        self.last_stamp = 0  # [ns] of the latest published estimate
        self.timing_logged = 0  # sample timing decisions logged so far
        self.warn = KindThrottle(node, WARN_EVERY)
        # input_order stamp: the inputs in stamp order across topics (ros/observer/input_order.py), as offline
        # observe takes them; lockstep_order is its older name
        order = p["input_order"]
        if "lockstep_order" in getattr(node, "_parameter_overrides", {}):
            order = "stamp" if p["lockstep_order"] else "arrival"
            node.get_logger().warning(f"parameter 'lockstep_order' is replaced by 'input_order' (taken as "
                                      f"input_order: {order})")
        self.order: InputOrder | None = None
        if order == "stamp":
            imu_rank = AFTER if cfg.imu.sample_timing == "after_command" else BEFORE
            ranks = {"command": COMMAND, "joint_state": PRIMARY, "imu": imu_rank, "branch_forces": BEFORE}
            self.order = InputOrder(ranks, self.session.primary, p["input_wait"],
                                    int(min(cfg.timing.max_future, 1e9) * 1e9))
        self.handlers = {"command": self._take_command, "joint_state": self._on_joint_state, "imu": self._on_imu,
                         "branch_forces": self._on_branch_forces}

        # not a second observer (or plant in observer mode) where one runs: estimates would interleave
        refuse_if_taken(node, [resolved_topics(node, p, ["topics.joint_states"])["topics.joint_states"]],
                        getattr(node, "created", 0.0))
        # the plant's state writers' QoS: 1 s of history from which reliable delivery repairs a reader
        # that lags (a recorder on a loaded machine lost 227 estimates from the 100-deep one)
        self.pub_joint_states = node.create_publisher(JointState, p["topics.joint_states"], STATE_OUT_QOS)
        self.pub_branch_forces = node.create_publisher(BranchForces, p["topics.branch_forces"], STATE_OUT_QOS)
        self.pub_ee_pose = node.create_publisher(PoseStamped, p["topics.ee_pose"], STATE_OUT_QOS)
        self.pub_stddev = node.create_publisher(JointState, p["topics.joint_states_stddev"], STATE_OUT_QOS)
        self.pub_markers = node.create_publisher(MarkerArray, p["topics.markers"], VIEWER_QOS)
        self.pub_diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        obs = self.session.obs  # with wrench states: their estimate and the contact events
        self.wrench = WrenchOutput(node, obs.layout, p["frames.base"]) if obs.nw else None

        topics = cfg.topics
        inputs = [(JointState if p["command_type"] == "joint_state" else Float64MultiArray,
                   topics.torque_command, self._on_command)]
        if "imu" in cfg.sensors:
            inputs.append((Imu, topics.ee_imu, self._input("imu")))
        if "branch_forces" in cfg.sensors and cfg.branch_forces.source == "branch_forces":
            inputs.append((BranchForces, topics.measured_branch_forces, self._input("branch_forces")))
        inputs.append((JointState, topics.measured_joint_states, self._input("joint_state")))
        # the torque the drives applied (the plant's applied_torque): once it comes, the torque input
        self.applied_since: int | None = None  # stamp [ns] of its first message
        self.superseded = 0  # torque commands not used since (the applied torque says what acted)
        if topics.applied_torque:
            inputs.insert(1, (JointState, topics.applied_torque, self._on_applied))
        # messages that never reached a callback (the writer's or this reader's queue overflowed while
        # this node lagged): counted per topic from the publication sequence numbers, said once a kind
        self.lost: dict[str, SequenceGaps] = {}
        # the executor wakes the node for one input message; what else is queued on the inputs is
        # taken in the same turn (ros/drain.py: the executor costs 5-20x a direct take per message)
        self.drain = Drain()
        for msg_type, topic, callback in inputs:  # a copy each: rclpy writes the overrides into the profile
            gaps = SequenceGaps()
            take, made = self._counted(gaps, callback)
            made.append(self.drain.subscribe(node, msg_type, topic, take, copy.copy(OBSERVER_INPUT_QOS),
                                             qos_overriding_options=QoSOverridingOptions.with_default_policies()))
            self.lost[made[0].topic_name] = gaps
        node.create_service(Trigger, "~/reset", self._on_reset)
        node.create_service(SetJointState, "~/set_state", self._on_set_state)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if self.order is not None:  # inputs that wait for a topic that went silent
            node.create_timer(ORDER_CHECK, self._release, clock=steady)
        self.steady = steady
        self.timers = {"marker_rate": node.create_timer(1.0 / p["marker_rate"], self._publish_markers, clock=steady),
                       "diagnostics_rate": node.create_timer(1.0 / p["diagnostics_rate"], self._publish_diagnostics,
                                                             clock=steady)}

        log = node.get_logger()
        log.info(self.session.observability.text())
        primary = {"joint_state": topics.measured_joint_states, "imu": topics.ee_imu,
                   "branch_forces": topics.measured_branch_forces}[self.session.primary]
        log.info(f"{self.model_name}: state observer ({', '.join(cfg.sensors)}) on "
                 + ", ".join(f"'{topic}'" for _, topic, _ in inputs) + f"; one estimate per '{primary}' message")

    def apply_parameter(self, name: str, value: Any) -> str | None:
        """A runtime parameter (checked already): the wall-clock rates, the sensors' noise levels
        and the gate; a reason for anything else."""
        if name.startswith(PREFIX) and name[len(PREFIX):] in RUNTIME_PARAMETERS:
            try:  # validated as at start-up, then taken by the running filter
                cfg = self.cfg.with_overrides(**{name[len(PREFIX):].replace(".", "__"): value})
                self.session.set_measurement_noise(cfg)
            except InputError as err:  # on_runtime_change names the parameter itself
                return parameter_message(err).removeprefix(f"parameter '{name}': ")
            self.cfg = cfg
            return None
        if name == "restart_on_fault":
            self.session.restart_on_fault = value
            return None
        if name == "input_wait":
            if self.order is not None:
                self.order.max_wait = value
            return None
        if name not in self.timers:
            return "fixed at start-up in an observer (restart the node)"
        callback = self._publish_markers if name == "marker_rate" else self._publish_diagnostics
        self.node.destroy_timer(self.timers[name])
        self.timers[name] = self.node.create_timer(1.0 / value, callback, clock=self.steady)
        return None

    # ------------------------------------------------------------------ inputs
    def _counted(self, gaps: SequenceGaps, callback: Any) -> tuple[Any, list[Any]]:
        """``callback`` behind a count of the messages that never reached it; the list takes the
        subscription once made (its publishers: gaps are exact with one)."""
        made: list[Any] = []

        def take(msg: Any, info: dict[str, Any]) -> None:
            sub = made[0]
            if gaps.take(info.get("publication_sequence_number"), sub.get_publisher_count()):
                self.warn.warning("lost " + sub.topic_name, f"{gaps.missed} '{sub.topic_name}' message(s) never "
                                  "reached the observer so far (it fell more than its reader's queue behind: "
                                  "cycle times and input_order.lag_s in /diagnostics)")
            callback(msg)
        return take, made

    def _input(self, kind: str) -> Any:
        """The callback of a sample topic: straight to its handler, or through the stamp order."""
        if self.order is None:
            return self.handlers[kind]

        def queue(msg: Any) -> None:
            self.order.push(kind, stamp_ns(msg.header.stamp), msg, time.monotonic())
            self._release()
        return queue

    def _release(self) -> None:
        """Hand on the inputs whose turn it is (input_order: stamp)."""
        for kind, ns, msg in self.order.pop_ready(time.monotonic()):
            if kind == "command":
                self._take_command(msg, ns)
            else:
                self.handlers[kind](msg)

    def _on_command(self, msg: JointState | Float64MultiArray) -> None:
        if self.applied_since is not None:
            self.superseded += 1
            return
        # no header (Float64MultiArray): the arrival time on the node's clock
        ns = stamp_ns(msg.header.stamp) if isinstance(msg, JointState) else self.node.get_clock().now().nanoseconds
        self._queue_command(msg, ns)

    def _on_applied(self, msg: JointState) -> None:
        """The torque that acted over the period from its stamp: the plant applies a command that
        comes late from its next period on, not from its stamp (realtime), and holds or zeroes
        one that does not come; the filter predicts with what acted."""
        ns = stamp_ns(msg.header.stamp)
        if self.applied_since is None:
            self.applied_since = ns
            if self.order is not None:
                self.order.discard("command")  # the commands queued so far: the applied torque says what acted
            self.node.get_logger().info(
                f"torque input: '{self.cfg.topics.applied_torque}' (the torque applied, from t = {ns * 1e-9:.6f} s "
                f"on); '{self.cfg.topics.torque_command}' is not used any more")
        self._queue_command(msg, ns)

    def _queue_command(self, msg: JointState | Float64MultiArray, ns: int) -> None:
        if self.order is None:
            self._take_command(msg, ns)
            return
        self.order.push("command", ns, msg, time.monotonic())
        self._release()

    def _take_command(self, msg: JointState | Float64MultiArray, ns: int) -> None:
        t0 = time.perf_counter()
        if isinstance(msg, JointState):
            out = self.session.torque_command(ns, msg.name, msg.effort)
        else:
            out = self.session.torque_command(ns, (), msg.data)
        self._after(out, ns, t0)

    def _on_joint_state(self, msg: JointState) -> None:
        t0 = time.perf_counter()
        ns = stamp_ns(msg.header.stamp)
        self._after(self.session.joint_state(ns, msg.name, msg.position, msg.velocity, msg.effort), ns, t0)

    def _on_imu(self, msg: Imu) -> None:
        t0 = time.perf_counter()
        ns = stamp_ns(msg.header.stamp)
        a = msg.linear_acceleration
        self._after(self.session.imu(ns, (a.x, a.y, a.z), msg.header.frame_id), ns, t0)

    def _on_branch_forces(self, msg: BranchForces) -> None:
        t0 = time.perf_counter()
        ns = stamp_ns(msg.header.stamp)
        self._after(self.session.branch_forces(ns, msg.name, msg.force), ns, t0)

    def _after(self, out: Outcome, ns: int, t0: float) -> None:
        log = self.node.get_logger()
        if out.stopped:
            log.error(out.stopped)
        for kind, text in zip(out.kinds, out.problems, strict=True):
            self.warn.warning(kind, text)
        if out.publish:
            self._publish(ns)
        self.session.cycle_times.append(time.perf_counter() - t0)

    # ----------------------------------------------------------------- outputs
    def _publish(self, ns: int) -> None:
        m = self.messages
        e = self.session.estimate()
        m.fill(ns, e)
        self.pub_joint_states.publish(m.joint_state_raw)
        self.pub_branch_forces.publish(m.branch_forces_raw)
        self.pub_ee_pose.publish(m.ee_pose_raw)
        self.pub_stddev.publish(m.stddev_raw)
        if self.wrench is not None:
            self.wrench.publish(ns, e)
        self.session.published += 1
        self.last_stamp = ns

    def _publish_markers(self) -> None:
        if self.pub_markers.get_subscription_count() and self.session.published:
            self.pub_markers.publish(self.markers.build(self.session.obs.q, self.last_stamp))

    def _publish_diagnostics(self) -> None:
        log, obs = self.node.get_logger(), self.session.obs
        decisions = obs.timing_decisions
        for decision in decisions[self.timing_logged:]:
            log.info(decision.text())
        self.timing_logged = len(decisions)
        recoveries = obs.recoveries
        logged = getattr(self, "recoveries_logged", 0)
        for recovery in recoveries[logged if logged <= len(recoveries) else 0:]:  # a reset clears the list
            log.warning(recovery.text())
        self.recoveries_logged = len(recoveries)
        findings = obs.nis_findings()
        if findings:
            log.warning("; ".join(findings.values()), throttle_duration_sec=FINDINGS_EVERY)
        level, message, values = self.session.report()
        values["torque_input"] = (self.cfg.topics.torque_command if self.applied_since is None
                                  else self.cfg.topics.applied_torque)
        values["torque_commands_superseded"] = str(self.superseded)
        values |= {f"lost.{topic.lstrip('/')}": str(g.missed) for topic, g in self.lost.items()}
        if self.order is not None:
            values |= self._order_values()
        status = DiagnosticStatus(name=f"{self.node.get_fully_qualified_name()}: observer", hardware_id=self.model_name,
                                  level=LEVELS[level], message=message,
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        header = Header(stamp=stamp(self.node.get_clock().now().nanoseconds))
        self.pub_diagnostics.publish(DiagnosticArray(header=header, status=[status]))

    def _order_values(self) -> dict[str, str]:
        """The stamp-order queue for /diagnostics: depth now and deepest since the last report, how far
        the estimates lag the newest sample, and what was dropped, re-stamped or released without waiting."""
        order = self.order
        st = order.stats
        values = {"input_order.queue_depth": str(order.depth()), "input_order.queue_depth_max": str(st.max_depth),
                  "input_order.lag_s": f"{order.lag_ns() * 1e-9:.6f}",
                  "input_order.repeated_samples": str(st.repeated),
                  "input_order.commands_restamped": str(st.restamped),
                  "input_order.released_after_wait": str(st.waited_out),
                  "input_order.released_queue_full": str(st.forced)}
        st.max_depth = order.depth()
        return values

    # ---------------------------------------------------------------- services
    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        try:
            response.message = self.session.reset()
            response.success = True
            self.node.get_logger().info(response.message)
        except Exception as err:  # never die on a service call: answer why
            response.success = False
            response.message = f"reset failed: {type(err).__name__}: {err}"
            self.node.get_logger().error(response.message)
        return response

    def _on_set_state(self, request: SetJointState.Request,
                      response: SetJointState.Response) -> SetJointState.Response:
        s = request.state
        try:
            response.message = self.session.set_state(s.name, s.position, s.velocity)
            response.success = True
            self.node.get_logger().info(response.message)
        except InputError as err:
            response.success = False
            response.message = f"set_state rejected: {err}"
            self.node.get_logger().warning(response.message)
        except Exception as err:  # never die on a service call: answer why
            response.success = False
            response.message = f"set_state failed: {type(err).__name__}: {err}"
            self.node.get_logger().error(response.message)
        return response
