"""Rigid inverse-dynamics feedforward of a desired motion (console script ``feedforward_node``).

Publishes motor torques on ``torque_command`` at the control rate and the rigid model's
motion on ``reference_joint_states``. Desired motion (parameter ``source``):
- ``line``: the reference manoeuvre, a Cartesian straight line with quintic time law
  (``line.*`` parameters); started at start-up (``autostart``) or by ``~/start``;
- ``trajectory``: trajectory_msgs/JointTrajectory of the active joints on ``trajectory``,
  started at its header stamp (zero stamp: at once).
After the end the final pose is held (its static torque keeps being published).

Pacing (parameter ``trigger``):
- ``timer``: a timer at ``rate`` on the node clock (simulated time with use_sim_time);
- ``state``: one command per new plant state (``topics.state``), for the time of its
  stamp: with a lockstep plant this is deterministic and reproduces offline
  ``simulate`` with the same torque table.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from elastic_pm_dyn.bags.msgtypes import NS, stamp_ns
from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import rigid_feedforward
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.references import JointReference, LineReference
from elastic_pm_dyn.motion.trajectory import QuinticLine
from elastic_pm_dyn.ros.commands import CommandDecoder
from elastic_pm_dyn.ros.messages import joint_state, torque_command
from elastic_pm_dyn.ros.node_main import ManagedNode, run_node
from elastic_pm_dyn.ros.params import (
    COMMAND_JOINTS,
    Param,
    ParameterError,
    command_joints_param,
    model_path,
    read_parameters,
    reject_unknown,
)
from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS

READY_POLL = 0.05  # [s] wall-clock check for subscribers while waiting to start
# Our errors (unreachable, singular), and numpy's should a solver inside it fail outright.
SOLVE_ERRORS = (ElasticPmDynError, np.linalg.LinAlgError)

# Rate and line default to the reference manoeuvre (config/feedforward.yaml repeats them; a test holds them equal).
PARAMS = [
    Param("model", "", "model YAML file; empty = the five-bar shipped with the package"),
    Param("rate", REFERENCE_MANOEUVRE.control_rate, "control rate [Hz]: timer period and the time grid of the commands",
          positive=True),
    Param("source", "line", "line (parameters line.*) or trajectory (JointTrajectory topic)",
          choices=("line", "trajectory")),
    Param("line.start", list(REFERENCE_MANOEUVRE.start), "start point p_A [m] (2 numbers planar, 3 spatial)"),
    Param("line.end", list(REFERENCE_MANOEUVRE.end), "end point p_E [m]"),
    Param("line.move", REFERENCE_MANOEUVRE.move, "move time [s]", positive=True),
    Param("line.hold", REFERENCE_MANOEUVRE.hold, "time at the end point that belongs to the manoeuvre [s]"),
    Param("autostart", True, "line: start at start-up (else call ~/start)"),
    Param("trigger", "timer", "timer (at rate, node clock) or state (one command per plant state)",
          choices=("timer", "state")),
    Param("command_type", "joint_state", "joint_state or float64_multi_array (command_joints order)",
          choices=("joint_state", "float64_multi_array")),
    Param("topics.command", "torque_command", "torque command topic"),
    Param("topics.reference", "reference_joint_states", "rigid model's reference motion"),
    Param("topics.state", "joint_states", "plant state that paces the state trigger"),
    Param("topics.trajectory", "trajectory", "JointTrajectory input (source trajectory)"),
    Param("wait_for_subscribers", 1, "start only when torque_command has this many subscribers"),
    Param("exit_when_done", False, "end the process when the reference is over (scripts, demos)"),
]


class FeedforwardNode(ManagedNode):
    """Rigid feedforward torques of a line or a joint trajectory (see module doc)."""

    def __init__(self, **node_kwargs: Any):
        super().__init__("feedforward", **node_kwargs)
        reject_unknown(self, [s.name for s in PARAMS] + [COMMAND_JOINTS])
        p = read_parameters(self, PARAMS)
        self.model = load_model(model_path(p["model"]))
        rigid = rigid_feedforward(self.model).mech
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
        self.line = (LineReference(rigid_feedforward(self.model), _line(p, len(rigid.ee_components)), self.rate)
                     if self.source == "line" else None)

        self.pub_command = self.create_publisher(
            JointState if self.command_type == "joint_state" else Float64MultiArray, p["topics.command"],
            COMMAND_QOS)
        self.pub_reference = self.create_publisher(JointState, p["topics.reference"], STATE_QOS)
        self.create_service(Trigger, "~/start", self._on_start)
        if self.source == "trajectory":
            self.create_subscription(JointTrajectory, p["topics.trajectory"], self._on_trajectory, COMMAND_QOS)

        self.reference: LineReference | JointReference | None = None
        self.start_ns: int | None = None  # reference time origin; None = at the next tick/state
        self.last_ns: int | None = None  # newest control instant answered
        self.pending_ns: int | None = None  # state trigger: newest state not yet answered
        self.want_start = self.source == "line" and p["autostart"]
        if self.trigger == "timer":
            self.create_timer(1.0 / p["rate"], self._on_tick)
        else:
            self.create_subscription(JointState, p["topics.state"], self._on_state, STATE_QOS)
            self.create_timer(READY_POLL, self._respond, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"{self.model.name}: source {self.source}, trigger {self.trigger}, "
                               f"commands ({self.command_type}) on '{p['topics.command']}'")

    # ------------------------------------------------------------------ inputs
    def _on_start(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if self.source != "line":
            response.success, response.message = False, "source is 'trajectory': publish a JointTrajectory"
            return response
        self.want_start = True
        response.success, response.message = True, "line starts at the next control period"
        try:
            self._respond()
        except Exception as err:  # never die on a service call: answer why
            self.reference = None
            response.success, response.message = False, f"start failed: {type(err).__name__}: {err}"
            self.get_logger().error(response.message)
        return response

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        pts = msg.points
        try:
            times = [p.time_from_start.sec + p.time_from_start.nanosec / NS for p in pts]
            vel = [p.velocities for p in pts] if pts and all(len(p.velocities) for p in pts) else None
            acc = [p.accelerations for p in pts] if pts and all(len(p.accelerations) for p in pts) else None
            reference = JointReference(rigid_feedforward(self.model), msg.joint_names, times,
                                       [p.positions for p in pts], vel, acc)
        except SOLVE_ERRORS as err:
            self.get_logger().warning(f"trajectory rejected: {err}")
            return
        self.reference = reference
        self.start_ns = stamp_ns(msg.header.stamp) or None
        self.want_start = False
        self.get_logger().info(f"trajectory of {len(pts)} points, {reference.duration:.3g} s accepted")
        self._respond()

    def _on_state(self, msg: JointState) -> None:
        ns = stamp_ns(msg.header.stamp)
        if self.last_ns is None or ns > self.last_ns:
            self.pending_ns = ns
            self._respond()

    # ---------------------------------------------------------------- stepping
    def _ready(self) -> bool:
        return self.pub_command.get_subscription_count() >= self.wait_for

    def _on_tick(self) -> None:
        if self._ready():
            self._command_at(self.get_clock().now().nanoseconds, quantise=True)

    def _respond(self) -> None:
        """State trigger: answer the newest plant state once there is something to send."""
        if self.pending_ns is not None and self._ready() and self._command_at(self.pending_ns):
            self.pending_ns = None

    def _command_at(self, ns: int, quantise: bool = False) -> bool:
        """Publish the command for time ``ns`` (and the reference); False if there is none.

        ``quantise``: a timer tick stands for the nearest control instant k / rate (as a
        digital controller samples its reference), whatever its jitter; an instant already
        answered (two ticks close together) is not sent again.
        """
        if self.want_start:
            self.want_start = False
            self.reference = self.line
            self.start_ns = ns
            self.get_logger().info(f"line {self.line.line.start} -> {self.line.line.end} m started")
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
        if self.exit_when_done and t >= self.reference.duration:
            self.get_logger().info(f"reference finished at t = {t:.6g} s")
            self.done = True
            return True
        try:
            s = self.reference.sample(t)
        except SOLVE_ERRORS as err:
            self.get_logger().error(f"reference stopped at t = {t:.6g} s: {err}")
            self.reference = None
            return False
        self.pub_command.publish(torque_command(self.command_type, self.command_names, s.tau[self.command_index],
                                                ns))
        effort = np.zeros(len(self.ff_names))
        effort[self.active_index] = s.tau
        self.pub_reference.publish(joint_state(self.ff_names, ns, s.q, s.qd, effort))
        self.last_ns = ns
        return True


def _line(p: dict[str, Any], n_coordinates: int) -> QuinticLine:
    if len(p["line.start"]) != n_coordinates or len(p["line.end"]) != n_coordinates:
        raise ParameterError(f"parameters 'line.start' and 'line.end' need {n_coordinates} coordinates each "
                             "(the model's end-effector point)")
    try:
        return QuinticLine(np.array(p["line.start"]), np.array(p["line.end"]), p["line.move"], p["line.hold"])
    except InputError as err:
        raise ParameterError(f"parameters 'line.*': {err}") from None


def main(args: list[str] | None = None) -> int:
    return run_node("feedforward_node", FeedforwardNode, args)


if __name__ == "__main__":
    sys.exit(main())
