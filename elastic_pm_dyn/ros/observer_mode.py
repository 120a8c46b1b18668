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
from them (:class:`~elastic_pm_dyn.ros.observer_session.ObserverSession`), and
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

The callbacks convert messages and call :class:`~elastic_pm_dyn.ros.observer_session.ObserverSession`
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
from elastic_pm_dyn.ros.markers import MechanismMarkers
from elastic_pm_dyn.ros.messages import EstimateMessages, stamp
from elastic_pm_dyn.ros.observer_session import ObserverSession, Outcome, observer_config, parameter_message
from elastic_pm_dyn.ros.params import COMMAND_JOINTS, Param, ParameterError, read_parameters
from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS, OBSERVER_INPUT_QOS, STATE_QOS, VIEWER_QOS
from elastic_pm_dyn.ros.throttle import KindThrottle

WARN_EVERY = 1.0  # [s] throttle of repeated warnings, per kind
MAX_HOLD = 10.0  # [s] wall time messages wait (lockstep_order; a loaded machine's controller may take
# seconds, a stopped one never answers) before they go without what they wait for
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
        self.cfg = cfg
        self.model_name = mech.model.name
        self.messages = EstimateMessages(mech, p["frames.base"])
        self.markers = MechanismMarkers(mech, p["frames.base"])
        self.last_stamp = 0  # [ns] of the latest published estimate
        self.timing_logged = 0  # sample timing decisions logged so far
        self.warn = KindThrottle(node, WARN_EVERY)
        # lockstep_order: messages of different topics may arrive in any order (the plant may answer
        # the command of t_k with the samples of t_k+1 before that command got here; the joint state
        # of t_k may overtake the accelerometer sample of t_k); they wait here for what comes first
        # in offline observe's order: the command of t_k, then the samples of t_k+1, the joint
        # state (which publishes the estimate) last
        self.lockstep_order = bool(p.get("lockstep_order", False))
        self.awaiting: int | None = None  # [ns] stamp of the newest estimate whose command has not come
        self.held: list[tuple[str, Any, Any]] = []  # (kind, handler, message) in arrival order
        self.held_since = 0.0  # monotonic [s]
        # samples of a stamp that come before its joint state: an accelerometer sampling before the
        # command (published with the state), strain gauges
        self.same_stamp = [k for k, on in (
            ("imu", "imu" in cfg.sensors and cfg.imu.sample_timing != "after_command"),
            ("branch_forces", "branch_forces" in cfg.sensors and cfg.branch_forces.source == "branch_forces")) if on]
        self.latest: dict[str, int] = {}  # kind -> newest stamp taken

        self.pub_joint_states = node.create_publisher(JointState, p["topics.joint_states"], STATE_QOS)
        self.pub_branch_forces = node.create_publisher(BranchForces, p["topics.branch_forces"], STATE_QOS)
        self.pub_ee_pose = node.create_publisher(PoseStamped, p["topics.ee_pose"], STATE_QOS)
        self.pub_stddev = node.create_publisher(JointState, p["topics.joint_states_stddev"], STATE_QOS)
        self.pub_markers = node.create_publisher(MarkerArray, p["topics.markers"], VIEWER_QOS)
        self.pub_diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)

        topics = cfg.topics
        # Creation order is the order in which the executor serves messages that wait together:
        # the command of t_k-1, then the samples of t_k, the joint state (which publishes the
        # estimate of t_k) after the accelerometer and gauges of its stamp.
        inputs = [(JointState if p["command_type"] == "joint_state" else Float64MultiArray,
                   topics.torque_command, self._on_command)]
        if "imu" in cfg.sensors:
            inputs.append((Imu, topics.ee_imu, self._held("imu", self._on_imu)))
        if "branch_forces" in cfg.sensors and cfg.branch_forces.source == "branch_forces":
            inputs.append((BranchForces, topics.measured_branch_forces, self._held("branch_forces",
                                                                                    self._on_branch_forces)))
        inputs.append((JointState, topics.measured_joint_states, self._held("joint_state", self._on_joint_state)))
        for msg_type, topic, callback in inputs:  # a copy each: rclpy writes the overrides into the profile
            node.create_subscription(msg_type, topic, callback, copy.copy(OBSERVER_INPUT_QOS),
                                     qos_overriding_options=QoSOverridingOptions.with_default_policies())
        node.create_service(Trigger, "~/reset", self._on_reset)
        node.create_service(SetJointState, "~/set_state", self._on_set_state)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if self.lockstep_order:
            node.create_timer(0.1, self._check_held, clock=steady)
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
        if name not in self.timers:
            return "fixed at start-up in an observer (restart the node)"
        callback = self._publish_markers if name == "marker_rate" else self._publish_diagnostics
        self.node.destroy_timer(self.timers[name])
        self.timers[name] = self.node.create_timer(1.0 / value, callback, clock=self.steady)
        return None

    # ------------------------------------------------------------------ inputs
    def _held(self, kind: str, handler: Any) -> Any:
        """``handler``, or with lockstep_order: the message waits until it is its turn (see __init__)."""
        if not self.lockstep_order:
            return handler

        def gate(msg: Any) -> None:
            if not self.held:
                self.held_since = time.monotonic()
            self.held.append((kind, handler, msg))
            self._release()
        return gate

    def _ready(self, kind: str, ns: int) -> bool:
        if self.awaiting is not None and ns > self.awaiting:
            return False  # the command of the newest estimate first
        return kind != "joint_state" or all(self.latest.get(k, -1) >= ns for k in self.same_stamp)

    def _release(self, force: bool = False) -> None:
        """Take the waiting messages that may go now, the earliest first (``force``: all, in arrival order)."""
        while self.held:
            i = 0 if force else next((i for i, (k, _, m) in enumerate(self.held)
                                      if self._ready(k, stamp_ns(m.header.stamp))), None)
            if i is None:
                return
            kind, handler, msg = self.held.pop(i)
            if kind != "joint_state":
                self.latest[kind] = max(self.latest.get(kind, -1), stamp_ns(msg.header.stamp))
            handler(msg)
            self.held_since = time.monotonic()

    def _check_held(self) -> None:
        if self.held and time.monotonic() - self.held_since > MAX_HOLD:
            what = (f"the torque command stamped {self.awaiting * 1e-9:.6f} s" if self.awaiting is not None
                    else "the samples of the joint state's stamp")
            self.warn.warning("waited", f"no {what} within {MAX_HOLD:g} s: {len(self.held)} messages taken "
                              "without it (lockstep_order)")
            self.awaiting = None
            self._release(force=True)

    def _on_command(self, msg: JointState | Float64MultiArray) -> None:
        t0 = time.perf_counter()
        if isinstance(msg, JointState):
            ns = stamp_ns(msg.header.stamp)
            out = self.session.torque_command(ns, msg.name, msg.effort)
        else:  # no header: the arrival time on the node's clock
            ns = self.node.get_clock().now().nanoseconds
            out = self.session.torque_command(ns, (), msg.data)
        self._after(out, ns, t0)
        if self.awaiting is not None and ns >= self.awaiting:
            self.awaiting = None
            if self.lockstep_order:
                self._release()

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
        m.fill(ns, self.session.estimate())
        self.pub_joint_states.publish(m.joint_state)
        self.pub_branch_forces.publish(m.branch_forces)
        self.pub_ee_pose.publish(m.ee_pose)
        self.pub_stddev.publish(m.stddev)
        self.session.published += 1
        self.last_stamp = ns
        if self.lockstep_order:
            self.awaiting = ns

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
        status = DiagnosticStatus(name=f"{self.node.get_fully_qualified_name()}: observer", hardware_id=self.model_name,
                                  level=LEVELS[level], message=message,
                                  values=[KeyValue(key=k, value=v) for k, v in values.items()])
        header = Header(stamp=stamp(self.node.get_clock().now().nanoseconds))
        self.pub_diagnostics.publish(DiagnosticArray(header=header, status=[status]))

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
