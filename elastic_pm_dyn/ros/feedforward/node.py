"""Inverse-dynamics feedforward of a desired motion (console script ``feedforward_node``).

Publishes motor torques on ``torque_command`` at the control rate and the model's motion on
``reference_joint_states``. ``method``: ``rigid`` (the rigid model's inverse dynamics, sampled
at each control instant), ``elastic`` (a line or a Cartesian goal: the elastic model's inverse,
computed when the line or goal is made; ``elastic_inverse: held``, the default, solves for the
torques the plant holds over each period so that it follows the path and ends at rest
(:mod:`~elastic_pm_dyn.sim.held_inverse`), ``continuous`` holds the continuous inverse's mean over
each period; the reference motion then has the motors at their deflection-compensated angles) or ``shaped`` (a line or a
Cartesian goal: the rigid inverse of the path through the ``shaper`` of the free-motor elastic modes,
the move longer by the shaper's length). ``line.law``: the time law of lines and Cartesian
goals (empty: quintic for rigid, nonic, C^4, for elastic). Desired motion (parameter ``source``):
- ``line``: the reference manoeuvre, a Cartesian straight line with quintic time law
  (``line.*`` parameters); started at start-up (``autostart``) or by ``~/start``;
- ``trajectory``: trajectory_msgs/JointTrajectory of the active joints on ``trajectory``,
  started at its header stamp (see Goals below); joint_trajectory_controller's spline
  rules (cubic with velocities, quintic with accelerations too), positions alone as
  rest-to-rest 9th-order segments (logged once; :class:`~elastic_pm_dyn.motion.trajectory.JointSpline`);
- ``trajectory`` also takes Cartesian goals: trajectory_msgs/MultiDOFJointTrajectory of the end
  effector or platform on ``topics.cartesian_trajectory`` (:mod:`~elastic_pm_dyn.ros.feedforward.cartesian_goals`):
  rest-to-rest segments through its poses, computed with ``method`` (rigid, elastic, shaped) when
  the goal arrives; a JointTrajectory takes the rigid method only;
- ``hold``: the model's start pose at rest for ``hold.duration`` seconds, with the torques
  that hold it against gravity (any machine, also one whose end-effector point does not fix
  its pose, such as a hexapod); started like the line.
After the end the final pose is held (its static torque keeps being published).

Goals (JointTrajectory, MultiDOFJointTrajectory) and their stamps. A goal is checked in its
callback (a bad one: one line) and its reference computed in a child process beside the
command stream (:mod:`~elastic_pm_dyn.ros.feedforward.goal_worker`): meanwhile the current reference goes
on (after its end its end pose is held, the last torque published again), which the node
says once; a newer goal supersedes one still being computed; Ctrl-C or SIGTERM kills the
computation at once (the node stops within its spin timeout). The elastic line of ``source:
line`` is computed the same way from start-up, and starts once ready (autostart or ``~/start``);
a line it refuses ends the node with that line (exit status 2), as a bad parameter does.
``header.stamp`` (:mod:`~elastic_pm_dyn.ros.feedforward.goal_stamps`): 0 is now, i.e. when its reference
is ready, from its first point; any other stamp is its start on the node's clock (wall
time, simulated time with use_sim_time, with ``trigger: state`` the plant states' stamps),
refused in one line beyond 5 s before or 60 s after the node's now; a start that has passed
starts the goal now, whole, with a warning (never cut: that would jump to a later pose).
Until a future start the goal's first pose is held.

Feedback (``feedback.kp``, ``feedback.kd``: one value or one per active joint; 0 and 0, the
default, is the pure feedforward): tau = tau_ff + kp (q_ref - q_meas) + kd (qd_ref - qd_meas)
on the encoder samples of ``topics.measured_joint_states`` (``motion.feedback``; qd_meas is
the sample's velocity if it has one, else differenced from the previous sample). With the
state trigger the command for t_k uses the encoder sample stamped t_k: it waits for it. A
sample that never comes (a newer one arrived, or ``feedback.max_wait`` seconds passed) is
replaced by the newest older one, or by none (feedforward alone), with a warning each time
and a count; with the timer trigger the newest sample is used, with a warning when it is
more than two periods old.

Pacing (parameter ``trigger``):
- ``timer``: a timer at ``rate`` on the node clock (simulated time with use_sim_time). It
  cannot keep up with a plant that runs ahead of the wall clock (``sync_mode: fast``): the
  executor wakes at wall-clock moments, /clock has moved on by several periods, and the
  control instants in between get no command (each skipped one is counted and warned about);
  drive a fast plant with ``trigger: state``;
- ``state``: one command per new plant state (``topics.state``), for the time of its
  stamp: with a lockstep plant this is deterministic and reproduces offline
  ``simulate`` with the same torque table. ``topics.state`` may be any JointState stamped
  like the plant's, e.g. an observer's estimates: the loop then waits for the observer too.
"""

from __future__ import annotations

import sys
import time
from collections import OrderedDict
from functools import partial
from typing import Any

import numpy as np
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

from elastic_pm_dyn.bags.msgtypes import NS, stamp_ns
from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedback import EncoderError, EncoderRates, gains, pd_torque
from elastic_pm_dyn.motion.feedforward import path_shaper, rigid_feedforward
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.references import (
    ElasticLineReference,
    HoldReference,
    JointReference,
    LineReference,
    TaskReference,
    joint_path,
)
from elastic_pm_dyn.motion.shaping import SHAPERS, ShapedPath
from elastic_pm_dyn.motion.time_laws import LAWS, law_order
from elastic_pm_dyn.motion.trajectory import Line, QuinticLine, make_line
from elastic_pm_dyn.motion.waypoints import MAX_WAYPOINTS
from elastic_pm_dyn.ros.commands import CommandDecoder
from elastic_pm_dyn.ros.feedforward.cartesian_goals import goal_path
from elastic_pm_dyn.ros.feedforward.goal_stamps import goal_start, late_start
from elastic_pm_dyn.ros.feedforward.goal_worker import (
    GoalJob,
    cartesian_reference,
    elastic_line_reference,
    joint_reference,
    prestart,
)
from elastic_pm_dyn.ros.losses import SequenceGaps
from elastic_pm_dyn.ros.messages import joint_state, torque_command
from elastic_pm_dyn.ros.node_main import EXIT_START_FAILED, ManagedNode, run_node, stopping
from elastic_pm_dyn.ros.params import (
    COMMAND_JOINTS,
    Param,
    ParameterError,
    command_joints_param,
    model_path,
    read_parameters,
    reject_unknown,
)
from elastic_pm_dyn.ros.qos import COMMAND_OUT_QOS, COMMAND_QOS, OBSERVER_INPUT_QOS, STATE_QOS
from elastic_pm_dyn.ros.throttle import KindThrottle
from elastic_pm_dyn.sim.held_feedforward import INVERSES

READY_POLL = 0.05  # [s] wall-clock check for subscribers while waiting to start
# Our errors (unreachable, singular), and numpy's should a solver inside it fail outright.
SOLVE_ERRORS = (ElasticPmDynError, np.linalg.LinAlgError)
WARN_EVERY = 1.0  # [s] throttle of repeated warnings, per kind
KEEP_SAMPLES = 1000  # encoder samples kept for matching by stamp (1 s at 1 kHz)
MAX_RATE = 1e4  # [Hz] rate: a Python node answers a timer or a plant state up to a few kHz
JOIN_WAIT = 2.0  # [s] close(): how long to wait for a cancelled goal's thread (its child is killed)

# Rate and line default to the reference manoeuvre (config/feedforward.yaml repeats them; a test holds them equal).
PARAMS = [
    Param("model", "", "model YAML file; empty = the five-bar shipped with the package"),
    Param("rate", REFERENCE_MANOEUVRE.control_rate, "control rate [Hz]: timer period and the time grid of the commands",
          positive=True, maximum=MAX_RATE),
    Param("source", "line", "line (parameters line.*), trajectory (JointTrajectory topic) or hold (the start pose)",
          choices=("line", "trajectory", "hold")),
    Param("line.start", list(REFERENCE_MANOEUVRE.start), "start point p_A [m] (2 numbers planar, 3 spatial)"),
    Param("line.end", list(REFERENCE_MANOEUVRE.end), "end point p_E [m]"),
    Param("line.move", REFERENCE_MANOEUVRE.move, "move time [s]", positive=True),
    Param("line.hold", REFERENCE_MANOEUVRE.hold, "time at the end point that belongs to the manoeuvre [s]"),
    Param("line.law", "", "time law: quintic, septic or nonic (C^2, C^3, C^4); empty: quintic for method rigid, "
          "nonic for elastic", choices=("", *LAWS)),
    Param("method", "rigid", "rigid (the rigid model's inverse dynamics), elastic (the elastic model's) or shaped "
          "(the rigid one of the line through a shaper of the elastic modes); elastic and shaped: source line, or "
          "trajectory with Cartesian goals",
          choices=("rigid", "elastic", "shaped")),
    Param("shaper", "zvd", "method shaped: zv, zvd or ei", choices=SHAPERS),
    Param("elastic_inverse", "held", "method elastic: held (the samples solved for the plant that holds them at "
          "the rate: on the path at and between the samples, at rest after the move) or continuous (the "
          "continuous inverse's mean over each period: faster to compute, micrometres off and a drift in the hold)",
          choices=INVERSES),
    Param("hold.duration", 0.5, "source hold: how long the start pose is held [s]", positive=True),
    Param("autostart", True, "line, hold: start at start-up (else call ~/start)"),
    Param("trigger", "timer", "timer (at rate, node clock) or state (one command per plant state)",
          choices=("timer", "state")),
    Param("command_type", "joint_state", "joint_state or float64_multi_array (command_joints order)",
          choices=("joint_state", "float64_multi_array")),
    Param("topics.command", "torque_command", "torque command topic"),
    Param("topics.reference", "reference_joint_states", "rigid model's reference motion"),
    Param("topics.state", "joint_states", "plant state that paces the state trigger"),
    Param("topics.trajectory", "trajectory", "JointTrajectory input (source trajectory)"),
    Param("topics.cartesian_trajectory", "cartesian_trajectory", "MultiDOFJointTrajectory input of the end "
          "effector's poses (source trajectory; any method)"),
    Param("frames.base", "world", "frame of the Cartesian goals' poses (the model's base; empty frame_id accepted)"),
    Param("topics.measured_joint_states", "measured_joint_states", "encoder samples (JointState) for the feedback"),
    Param("feedback.kp", [0.0], "PD on the encoders: [N m/rad] one value or one per active joint; 0 = none"),
    Param("feedback.kd", [0.0], "PD on the encoders: [N m s/rad] one value or one per active joint; 0 = none"),
    Param("feedback.max_wait", 2.0, "state trigger: [s] wall time to wait for the encoder sample of a stamp "
          "before the newest older one is used (with a warning)", positive=True),
    Param("wait_for_subscribers", 1, "start only when torque_command has this many subscribers"),
    Param("exit_when_done", False, "end the process when the reference is over (scripts, demos)"),
]


Reference = LineReference | ElasticLineReference | HoldReference | JointReference | TaskReference


class FeedforwardNode(ManagedNode):
    """Feedforward torques of a line (rigid, elastic or shaped) or a joint trajectory (see module doc)."""

    def __init__(self, **node_kwargs: Any):
        super().__init__("feedforward", **node_kwargs)
        reject_unknown(self, [s.name for s in PARAMS] + [COMMAND_JOINTS])
        p = read_parameters(self, PARAMS)
        self.model = load_model(model_path(p["model"]))
        rigid = self.rigid_mech = rigid_feedforward(self.model).mech
        p |= read_parameters(self, [command_joints_param(rigid.active_names)])
        self.ff_names = rigid.joint_names  # rigid tree: active + passive
        try:
            order = CommandDecoder(rigid.active_names, p[COMMAND_JOINTS]).array_order
        except InputError as err:
            raise ParameterError(f"parameter '{COMMAND_JOINTS}': {err}") from None
        self.command_names = order if p["command_type"] == "float64_multi_array" else rigid.active_names
        self.command_index = [rigid.active_names.index(n) for n in self.command_names]
        self.active_index = [self.ff_names.index(n) for n in rigid.active_names]
        self.command_type = p["command_type"]
        self.source = p["source"]
        self.trigger = p["trigger"]
        self.exit_when_done = p["exit_when_done"]
        self.wait_for = p["wait_for_subscribers"]
        self.rate = p["rate"]
        self.method, self.shaper, self.frame = p["method"], p["shaper"], p["frames.base"]
        self.inverse = p["elastic_inverse"]
        self.goal_law = law_order(p["line.law"] or ("nonic" if p["method"] == "elastic" else "quintic"))
        if p["method"] != "rigid" and self.source == "hold":
            raise ParameterError(f"parameter 'method': {p['method']} takes source line or trajectory (Cartesian "
                                 f"goals); source is {self.source!r}")
        line = _line(p, len(rigid.ee_components)) if self.source == "line" else None
        if line is not None and p["method"] == "shaped":  # the line through the shaper, then the rigid inverse
            try:
                line = ShapedPath(line, path_shaper(self.model, line, p["shaper"]))
            except InputError as err:
                raise ParameterError(f"parameter 'method': shaped: {err}") from None
        # the elastic line: computed in a child process (seconds to minutes of library calls that a
        # Ctrl-C could not interrupt here); it starts once ready (module doc: Goals)
        self.line_job: GoalJob | None = None
        if line is not None and p["method"] == "elastic":
            prestart()
            what = f"elastic line {np.asarray(line.start).tolist()} -> {np.asarray(line.end).tolist()} m"
            self.line_job = GoalJob(what, None,
                                    partial(elastic_line_reference, self.model, line, self.rate, rigid.joint_names,
                                            self.inverse),
                                    stopping)
            self.line_job.start()
        self.line = (None if self.line_job is not None else
                     LineReference(rigid_feedforward(self.model), line, self.rate) if line is not None else
                     HoldReference(rigid_feedforward(self.model), p["hold.duration"]) if self.source == "hold"
                     else None)
        try:
            self.kp = gains(p["feedback.kp"], len(rigid.active_names), "parameter 'feedback.kp'")
            self.kd = gains(p["feedback.kd"], len(rigid.active_names), "parameter 'feedback.kd'")
        except InputError as err:
            raise ParameterError(str(err)) from None
        self.feedback = bool(np.any(self.kp) or np.any(self.kd))
        self.max_wait = p["feedback.max_wait"]
        self.encoders = EncoderRates(rigid.active_names)
        self.samples: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()  # stamp -> (q, qd)
        self.waiting_since: float | None = None  # monotonic [s]: since when the pending stamp lacks its sample
        self.stale_used = 0  # commands computed without the encoder sample of their stamp
        self.skipped = 0  # control instants that got no command (the clock or the plant ran ahead)
        self.sent = 0  # commands published
        self.warn = KindThrottle(self, WARN_EVERY)
        self.told_at_rest = False  # the positions-only rule is logged once

        self.pub_command = self.create_publisher(
            JointState if self.command_type == "joint_state" else Float64MultiArray, p["topics.command"],
            COMMAND_OUT_QOS)
        self.pub_reference = self.create_publisher(JointState, p["topics.reference"], STATE_QOS)
        self.create_service(Trigger, "~/start", self._on_start)
        if self.source == "trajectory":
            self.create_subscription(JointTrajectory, p["topics.trajectory"], self._on_trajectory, COMMAND_QOS)
            self.create_subscription(MultiDOFJointTrajectory, p["topics.cartesian_trajectory"], self._on_cartesian,
                                     COMMAND_QOS)
        if self.feedback:  # volatile: matches any publisher; the samples of this run only
            self.create_subscription(JointState, p["topics.measured_joint_states"], self._on_encoders,
                                     OBSERVER_INPUT_QOS)

        self.reference: Reference | None = None
        self.goal: GoalJob | None = None  # the goal being computed (module doc: Goals)
        if self.source == "trajectory":
            prestart()  # the fork server's imports, now rather than at the first goal
        self.start_ns: int | None = None  # reference time origin; None = at the next tick/state
        self.last_ns: int | None = None  # newest control instant answered
        self.pending_ns: int | None = None  # state trigger: newest state not yet answered
        self.want_start = self.source in ("line", "hold") and p["autostart"]
        if self.trigger == "timer":
            self.create_timer(1.0 / p["rate"], self._on_tick)
        else:
            self.state_sub = self.create_subscription(JointState, p["topics.state"],
                                                      lambda msg, info: self._on_state(msg, info), STATE_QOS)
            self.state_gaps = SequenceGaps()
            self.create_timer(READY_POLL, self._respond, clock=Clock(clock_type=ClockType.STEADY_TIME))
        pd = (f"; PD on '{p['topics.measured_joint_states']}' kp {self.kp.tolist()} kd {self.kd.tolist()}"
              if self.feedback else "")
        self.get_logger().info(f"{self.model.name}: source {self.source}, trigger {self.trigger}, "
                               f"commands ({self.command_type}) on '{p['topics.command']}'{pd}")

    # ------------------------------------------------------------------ inputs
    def _on_start(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if self.source == "trajectory":
            response.success, response.message = False, ("source is 'trajectory': publish a JointTrajectory or a "
                                                          "MultiDOFJointTrajectory")
            return response
        self.want_start = True
        response.success, response.message = True, f"{self.source} starts at the next control period"
        try:
            self._respond()
        except Exception as err:  # never die on a service call: answer why
            self.reference = None
            response.success, response.message = False, f"start failed: {type(err).__name__}: {err}"
            self.get_logger().error(response.message)
        return response

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        """A JointTrajectory: checked here, its reference made beside the stream (module doc: Goals)."""
        pts = msg.points
        if self.method != "rigid":
            self.get_logger().warning(f"trajectory rejected: method {self.method} needs the end effector's path: "
                                      "send a MultiDOFJointTrajectory (a JointTrajectory takes method rigid)")
            return
        if len(pts) > MAX_WAYPOINTS:
            self.get_logger().warning(f"trajectory rejected: {len(pts)} points, more than the {MAX_WAYPOINTS} a goal "
                                      "may have; send it in parts")
            return
        times = [p.time_from_start.sec + p.time_from_start.nanosec / NS for p in pts]
        vel = [p.velocities for p in pts] if pts and all(len(p.velocities) for p in pts) else None
        acc = [p.accelerations for p in pts] if pts and all(len(p.accelerations) for p in pts) else None
        positions = [p.positions for p in pts]
        names = list(msg.joint_names)
        try:
            start = self._start_of(msg.header.stamp)
            joint_path(self.rigid_mech, names, times, positions, vel, acc)  # the checks that need no assembly
        except SOLVE_ERRORS as err:
            self.get_logger().warning(f"trajectory rejected: {err}")
            return
        self._submit(GoalJob(f"trajectory of {len(pts)} points", start,
                             partial(joint_reference, self.model, names, times, positions, vel, acc), stopping))

    def _on_cartesian(self, msg: MultiDOFJointTrajectory) -> None:
        """A Cartesian goal: checked here (bad goals: one line), its path through the node's method
        beside the stream (module doc: Goals)."""
        if len(msg.points) > MAX_WAYPOINTS:
            self.get_logger().warning(f"cartesian goal rejected: {len(msg.points)} points, more than the "
                                      f"{MAX_WAYPOINTS} a goal may have; send it in parts")
            return
        try:
            start = self._start_of(msg.header.stamp)
            path = goal_path(msg, self.model, self.frame, self.goal_law, self.rate)
        except (*SOLVE_ERRORS, ValueError) as err:  # ValueError: scipy on a degenerate input
            self.get_logger().warning(f"cartesian goal rejected: {err}")
            return
        self._submit(GoalJob(f"cartesian goal of {len(msg.points)} points ({self.method})", start,
                             partial(cartesian_reference, self.model, path, self.method, self.rate, self.shaper,
                                     self.ff_names, self.inverse), stopping))

    # ------------------------------------------------------------------- goals
    def _goal_clock(self) -> tuple[int, str]:
        """The node's now [ns] and what that clock is (the time base of the commands' stamps)."""
        if self.trigger == "state":
            seen = [ns for ns in (self.last_ns, self.pending_ns) if ns is not None]
            if seen:
                return max(seen), "the plant states' stamps (trigger state)"
        sim = self.get_parameter("use_sim_time").value
        return self.get_clock().now().nanoseconds, "simulated time (use_sim_time)" if sim else "wall time"

    def _start_of(self, stamp: Any) -> int | None:
        """A goal's start [ns] on the node's clock (None: now); InputError outside the window
        (:func:`~elastic_pm_dyn.ros.feedforward.goal_stamps.goal_start`)."""
        now, clock = self._goal_clock()
        return goal_start(stamp_ns(stamp), now, clock)

    def _submit(self, goal: GoalJob) -> None:
        """Compute ``goal``'s reference beside the stream; a goal still computing is superseded."""
        old = self.goal
        if old is not None:
            old.cancel.set()
            self.get_logger().warning(f"{old.what}: superseded by a newer goal before its reference was ready")
        meanwhile = ("the current reference goes on (after its end its end pose is held)" if self.reference is not None
                     else "no command (there is none to hold yet)")
        self.get_logger().info(f"{goal.what}: computing its reference beside the command stream; meanwhile "
                               f"{meanwhile}")
        self.goal = goal
        goal.start()

    def _poll_line(self) -> None:
        """The elastic line, once computed: it starts as the line does (autostart or ~/start); a
        line it refuses ends the node with that line, as a bad parameter does at start-up."""
        job = self.line_job
        if job is None or not job.done.is_set():
            return
        self.line_job = None
        if job.reference is None:
            if not job.cancelled:
                self.get_logger().error(f"parameters 'line.*' with method elastic: {job.error}")
                self.exit_status = EXIT_START_FAILED
            self.done = True
            return
        self.line = job.reference
        self.get_logger().info(f"{job.what}: reference ready after {time.monotonic() - job.received:.3g} s")

    def _poll_goal(self) -> None:
        """Take the goal's reference once it is ready (or say why there is none)."""
        self._poll_line()
        goal = self.goal
        if goal is None or not goal.done.is_set():
            return
        self.goal = None
        if goal.cancelled:
            return
        if goal.reference is None:
            self.get_logger().warning(f"{goal.what} rejected: {goal.error}")
            return
        took = time.monotonic() - goal.received
        reference = goal.reference
        if isinstance(reference, JointReference) and reference.path.rule == "at rest" and not self.told_at_rest:
            self.told_at_rest = True  # once: the rule does not change from one goal to the next
            self.get_logger().info("trajectory with positions only: each segment is a rest-to-rest move with the "
                                   "9th-order law, stopping at every waypoint (joint_trajectory_controller would "
                                   "join them by straight lines: a torque impulse at each); give velocities for "
                                   "a cubic, velocities and accelerations for a quintic")
        start, when = goal.start_ns, "starts now"
        if start is not None:
            now, clock = self._goal_clock()
            late = late_start(start, now, 1.0 / self.rate)
            if late:  # a late start would cut its beginning: the whole motion, shifted
                self.get_logger().warning(f"{goal.what}: its stamp passed {late:.3g} s ago ({clock}; the reference "
                                          f"took {took:.3g} s to compute): it starts now, the whole motion shifted")
                start = None
            else:
                when = f"starts at its stamp {start / NS:.9f} s"
        self.reference = reference
        self.start_ns = start
        self.want_start = False
        self.get_logger().info(f"{goal.what}, {reference.duration:.3g} s, accepted after {took:.3g} s: {when}")

    def close(self) -> None:
        """A goal still computing is cancelled: its child process is killed."""
        for job in (self.goal, self.line_job):
            if job is not None:
                job.stop(JOIN_WAIT)

    def _on_encoders(self, msg: JointState) -> None:
        ns = stamp_ns(msg.header.stamp)
        try:
            self.samples[ns] = self.encoders.sample(ns, msg.name, msg.position, msg.velocity)
        except EncoderError as err:  # one line per kind, the node goes on
            self.warn.warning(err.kind, f"encoder sample not used: {err}")
            return
        while len(self.samples) > KEEP_SAMPLES:
            self.samples.popitem(last=False)
        self._respond()

    def _on_state(self, msg: JointState, info: dict[str, Any] | None = None) -> None:
        ns = stamp_ns(msg.header.stamp)
        if info is not None:  # states that never reached this callback (the reader's queue overflowed)
            lost = self.state_gaps.take(info.get("publication_sequence_number"), self.state_sub.get_publisher_count())
            if lost and self.reference is not None:
                self._count_skipped(lost, ns)
        if self.last_ns is None or ns > self.last_ns:
            if self.pending_ns is not None and ns > self.pending_ns and self.reference is not None:
                self._count_skipped(1, self.pending_ns)  # the pending state is never answered now
            self.pending_ns = ns
            self._respond()

    # ---------------------------------------------------------------- stepping
    def _ready(self) -> bool:
        return self.pub_command.get_subscription_count() >= self.wait_for

    def _on_tick(self) -> None:
        self._poll_goal()
        if self._ready():
            self._command_at(self.get_clock().now().nanoseconds, quantise=True)

    def _respond(self) -> None:
        """State trigger: answer the newest plant state once there is something to send (and,
        with feedback, the encoder sample of its stamp or the end of waiting for it)."""
        self._poll_goal()
        if self.pending_ns is None or not self._ready() or not self._sample_ready(self.pending_ns):
            return
        if self._command_at(self.pending_ns):
            self.pending_ns = None
            self.waiting_since = None

    def _sample_ready(self, ns: int) -> bool:
        """Feedback: the sample of ``ns`` is here, or it will not come (a newer one came, or
        ``feedback.max_wait`` passed: the command then says so)."""
        if not self.feedback or ns in self.samples:
            return True
        newest = next(reversed(self.samples), None)
        if newest is not None and newest > ns:
            return True
        if self.waiting_since is None:
            self.waiting_since = time.monotonic()
        return time.monotonic() - self.waiting_since > self.max_wait

    def _measured(self, ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The encoder sample for the command of ``ns``: its own, else (with a warning) the newest older one."""
        hit = self.samples.get(ns)
        if hit is not None:
            return hit
        older = [k for k in self.samples if k < ns]
        self.stale_used += 1
        if not older:
            self.warn.warning("no sample", f"no encoder sample for t = {ns * 1e-9:.6f} s nor before: feedforward "
                              f"alone ({self.stale_used} commands without their sample so far)")
            return None
        k = older[-1]
        self.warn.warning("stale sample", f"no encoder sample for t = {ns * 1e-9:.6f} s: using the one of "
                          f"{k * 1e-9:.6f} s ({(ns - k) * 1e-9:.3g} s old; {self.stale_used} commands without "
                          "their sample so far)")
        return self.samples[k]

    def _latest_measured(self, ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Timer trigger: the newest sample, with a warning when it is more than two periods old."""
        newest = next(reversed(self.samples), None)
        if newest is None:
            self.warn.warning("no sample", "no encoder sample yet: feedforward alone")
            return None
        if ns - newest > 2 * NS / self.rate:
            self.stale_used += 1
            self.warn.warning("stale sample", f"newest encoder sample is {(ns - newest) * 1e-9:.3g} s old")
        return self.samples[newest]

    def _count_skipped(self, skipped: int, ns: int) -> None:
        """``skipped`` control instants before ``ns`` got no command: counted, warned (throttled)."""
        self.skipped += skipped
        why = ("the clock ran ahead of the timer (a fast plant? use trigger state)" if self.trigger == "timer" else
               "newer states came first (a plant running ahead: fast mode; only the newest is answered)")
        self.warn.warning("skipped", f"{skipped} control instant(s) before t = {ns * 1e-9:.6f} s got no command "
                          f"({self.skipped} so far): {why}")

    def _command_at(self, ns: int, quantise: bool = False) -> bool:
        """Publish the command for time ``ns`` (and the reference); False if there is none.

        ``quantise``: a timer tick stands for the nearest control instant k / rate (as a
        digital controller samples its reference), whatever its jitter; an instant already
        answered (two ticks close together) is not sent again.
        """
        if self.want_start and self.line is not None:  # (an elastic line: once computed)
            self.want_start = False
            self.reference = self.line
            self.start_ns = ns
            what = (f"line {self.line.line.start} -> {self.line.line.end} m" if self.source == "line"
                    else f"hold of the start pose for {self.line.duration:g} s")
            self.get_logger().info(f"{what} started")
        if self.reference is None:
            return False
        if self.start_ns is None:
            self.start_ns = ns
        t = (ns - self.start_ns) / NS
        if quantise:
            t = round(t * self.rate) / self.rate
            ns = self.start_ns + round(t * NS)
            if self.last_ns is not None and ns <= self.last_ns:
                return False
        if quantise and self.last_ns is not None and ns - self.last_ns > 1.5 * NS / self.rate:
            self._count_skipped(round((ns - self.last_ns) * self.rate / NS) - 1, ns)
        if self.exit_when_done and t >= self.reference.duration and self.goal is None:
            self.get_logger().info(f"reference finished at t = {t:.6g} s: {self.sent} command(s) sent, "
                                   f"{self.skipped} control instant(s) without one")
            self.done = True
            return True
        try:
            s = self.reference.sample(t)
        except SOLVE_ERRORS as err:
            self.get_logger().error(f"reference stopped at t = {t:.6g} s: {err}")
            self.reference = None
            return False
        tau = s.tau
        if self.feedback:
            measured = self._latest_measured(ns) if quantise else self._measured(ns)
            if measured is not None:
                a = self.active_index
                tau = pd_torque(s.tau, s.q[a], s.qd[a], measured[0], measured[1], self.kp, self.kd)
        self.pub_command.publish(torque_command(self.command_type, self.command_names, tau[self.command_index], ns))
        effort = np.zeros(len(self.ff_names))
        effort[self.active_index] = s.tau
        self.pub_reference.publish(joint_state(self.ff_names, ns, s.q, s.qd, effort))
        self.last_ns = ns
        self.sent += 1
        return True


def _line(p: dict[str, Any], n_coordinates: int) -> Line | QuinticLine:
    if len(p["line.start"]) != n_coordinates or len(p["line.end"]) != n_coordinates:
        raise ParameterError(f"parameters 'line.start' and 'line.end' need {n_coordinates} coordinates each "
                             "(the model's end-effector point)")
    law = p["line.law"] or ("nonic" if p["method"] == "elastic" else "quintic")
    try:
        return make_line(np.array(p["line.start"]), np.array(p["line.end"]), p["line.move"], p["line.hold"],
                         law_order(law))
    except InputError as err:
        raise ParameterError(f"parameters 'line.*': {err}") from None


def main(args: list[str] | None = None) -> int:
    return run_node("feedforward_node", FeedforwardNode, args)


if __name__ == "__main__":
    sys.exit(main())
