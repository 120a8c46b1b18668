"""The plant node: an elastic parallel manipulator simulated in the loop (console script ``plant_node``).

Sync modes (parameter ``sync_mode``):
- ``realtime``: a steady-clock timer at ``publish_rate`` advances one control period per
  tick (catching up at most ``realtime.max_catch_up`` periods after a late tick, each counted
  and logged as late). A plant further behind (:mod:`~elastic_pm_dyn.ros.plant.realtime_schedule`),
  with ``realtime.overrun``:

  - ``slow`` (default): slows its clock, as Gazebo does. The stamps are the plant's own
    clock, ``stamp = wall time of its first period + simulated time``: on the simulated-time
    grid, every period stamped, no gap; equal to the wall clock while the plant keeps up,
    behind it by the time it slowed (and was paused). Published on ``topics.clock``, so a
    node with ``use_sim_time`` follows the slowed clock. The achieved real-time factor and
    the slowed periods are in /diagnostics (WARN while it slows).
  - ``skip``: stamps with wall time; the periods it is behind are skipped (the stamps jump,
    counted as ``slipped_periods``); no clock topic.
- ``fast``: as fast as possible; stamps are simulated time, published on ``topics.clock``.
- ``lockstep``: each command advances exactly one period, then the state at the end of
  that period is published (stamp = simulated time, also on ``topics.clock``); a rejected
  command holds the last valid one (zero torque if none) for its period, so every command
  is answered within one period while the plant runs. The state at t = 0 is published at
  start-up and, until the first command arrives, again (same stamp and bytes: states, clock,
  sensor samples, disturbance truth) every ``lockstep.waiting_republish_period`` seconds of
  wall time: a controller with any QoS (a default volatile subscriber that matched late), reading
  any of these topics, gets it and starts the loop; it should answer each stamp once.
  The same torques give the same states as offline ``simulate``.

Simulator services (docs/ros.md): ``~/pause``, ``~/unpause`` (std_srvs/Trigger), ``~/step``
(elastic_pm_dyn_msgs/StepPeriods: N periods while paused), ``~/reset`` (Trigger),
``~/set_state`` (SetJointState). Runtime parameters: ``command_timeout``, ``disturbance.timeout``,
``marker_rate``, ``diagnostics_rate``, ``lockstep.waiting_republish_period`` (``ros2 param set``,
checked as at start-up); the rest is read-only. Several plants in one domain: each in its own
namespace; ``topics.clock`` is relative (``<ns>/clock``), /diagnostics names each plant by its
fully qualified node name and ``hardware_id``.

Callbacks only validate and store; the sync mode (:mod:`~elastic_pm_dyn.ros.plant.sync_modes`:
its timer, or the lockstep handler on a guard condition) advances the
:class:`~elastic_pm_dyn.sim.plant.Plant` one period at a time through :meth:`PlantNode.step_period`;
the services are :mod:`~elastic_pm_dyn.ros.plant.services`, the status on /diagnostics
:mod:`~elastic_pm_dyn.ros.plant.diagnostics`. Nothing a message or a
service request holds makes the node die: a fault stops integration at the last good
state, ``~/reset`` and ``~/set_state`` recover, and a request that cannot be served is
answered ``success: false`` with the reason. Warnings are throttled per kind. With ``mode: observer``
the node does not simulate: :class:`~elastic_pm_dyn.ros.observer.mode.ObserverMode`
subscribes to commands and measurements and publishes the state observer's estimates on
the same output topics (the sync parameters then do not apply): the observer node
(``observer_node``, :mod:`~elastic_pm_dyn.ros.observer.node`) under the plant's name, with
the same parameters (:mod:`~elastic_pm_dyn.ros.machine_params`, ``observer.*``).
Torque held over a period: the last valid command, or zero when it is older than
``command_timeout`` on the plant's clock: simulated time in fast and realtime ``slow`` (a
stall that stops the plant's clock does not age the command: the plant applies it when it
goes on), wall time in realtime ``skip`` (its stamps are the wall clock); lockstep waits.
That torque goes out on ``topics.applied_torque`` as each period is stepped, stamped at the
period's start, before the state it led to: what a drive reports. In realtime a command that
arrives late acts from the next tick, not from its stamp; an observer that predicts with the
applied torque follows the plant however late the controller answers.

Simulated sensors (``sensors.*``) and an unknown disturbance torque on the motors
(``disturbance.*``): :mod:`~elastic_pm_dyn.ros.plant.sensors` (all off by default).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from elastic_pm_dyn_msgs.msg import BranchForces
from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header
from visualization_msgs.msg import MarkerArray

from elastic_pm_dyn.bags import cdr
from elastic_pm_dyn.bags.msgtypes import NS
from elastic_pm_dyn.dynamics.direct import FORMULATIONS
from elastic_pm_dyn.errors import InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.ros.graph_checks import refuse_if_taken, resolved_topics
from elastic_pm_dyn.ros.losses import SequenceGaps
from elastic_pm_dyn.ros.machine_params import DESCRIPTION_PARAMS, ESTIMATE_PARAMS, MACHINE_PARAMS, load_machine
from elastic_pm_dyn.ros.markers import MechanismMarkers
from elastic_pm_dyn.ros.messages import PlantMessages, SerializedMessage, stamp
from elastic_pm_dyn.ros.node_main import ManagedNode, run_node
from elastic_pm_dyn.ros.params import (
    COMMAND_JOINTS,
    Param,
    ParameterError,
    on_runtime_change,
    read_parameters,
    reject_unknown,
)
from elastic_pm_dyn.ros.plant.command_hold import CommandHold
from elastic_pm_dyn.ros.plant.diagnostics import plant_status
from elastic_pm_dyn.ros.plant.realtime_schedule import OVERRUNS
from elastic_pm_dyn.ros.plant.sensors import (
    DISTURBANCE_PARAMS,
    SENSOR_PARAMS,
    SensorOutputs,
    disturbance_message,
    sensor_spec,
    spectrum_disturbance,
)
from elastic_pm_dyn.ros.plant.services import PlantServices
from elastic_pm_dyn.ros.plant.stats import PlantStats
from elastic_pm_dyn.ros.plant.step_check import rk4_step_warning
from elastic_pm_dyn.ros.plant.sync_modes import SYNC_MODES
from elastic_pm_dyn.ros.plant.wrench_input import WRENCH_PARAMS, WrenchIO, external_wrench
from elastic_pm_dyn.ros.qos import (
    CLOCK_QOS,
    COMMAND_QOS,
    DIAGNOSTICS_QOS,
    LOCKSTEP_COMMAND_QOS,
    STATE_OUT_QOS,
    VIEWER_QOS,
)
from elastic_pm_dyn.ros.realtime_process import PROCESS_PARAMS, restore
from elastic_pm_dyn.ros.realtime_process import refusal as process_refusal
from elastic_pm_dyn.ros.robot_description import publish_robot_description
from elastic_pm_dyn.ros.throttle import KindThrottle
from elastic_pm_dyn.sim.plant import START_STATES, Plant
from elastic_pm_dyn.sim.simulator import INTEGRATORS, STABILIZATIONS, SimulationOptions

MODES = ("plant", "observer")
RUNTIME_RATES = ("marker_rate", "diagnostics_rate")
WARN_EVERY = 1.0  # [s] throttle of repeated warnings, per kind

PARAMS = [
    Param("mode", "plant", "plant: simulate the machine; observer: estimate its state from commands and measurements",
          choices=MODES),
    Param("formulation", "scdd", "direct dynamics formulation", choices=FORMULATIONS),
    Param("integrator", "rk4", "rk4 (fixed step dt), etd2 (fixed step dt, the springs exactly: a step of "
          "0.25-1 ms, see elastic-pm-dyn check) or dop853 (adaptive, offline accuracy)", choices=INTEGRATORS),
    Param("dt", 1.0e-4, "internal RK4 / ETD2 step [s]; shortened so steps end on control periods", positive=True,
          fixed="the integrator is set up at start-up: restart the node"),
    Param("start", "relaxed", "start (and ~/reset) state: relaxed (the model's initial pose, springs unloaded, "
          "as simulate) or static (springs deflected by gravity, motors held: a machine at rest, as the "
          "observer assumes)", choices=START_STATES, fixed="the start state is set up at start-up: restart the node"),
    Param("stabilization", "projection", "closure drift stabilisation", choices=tuple(STABILIZATIONS)),
    Param("publish_rate", 1000.0, "control and publish rate [Hz]; a command is held for one period",
          positive=True, fixed="the control period is built into the integrator's steps and the stamps: "
          "restart the node"),
    Param("sync_mode", "realtime", "realtime | fast | lockstep", choices=tuple(SYNC_MODES),
          fixed="QoS, clock and timers depend on it: restart the node"),
    Param("command_timeout", 0.1, "[s] an older command means zero torque (the plant's clock: simulated "
          "time in fast and realtime with overrun slow, wall time with overrun skip; unused in lockstep)",
          positive=True, runtime=True),
    Param("topics.command", "torque_command", "torque command topic"),
    Param("topics.applied_torque", "applied_torque", "sensor_msgs/JointState, effort = the motor torque the plant "
          "applied over the period that starts at the stamp (the command, one held, or zero when stale; a drive's "
          "report), published as each period is stepped; the observer prefers it to torque_command"),
    Param("topics.clock", "clock", "rosgraph_msgs/Clock in fast, lockstep and realtime with overrun slow "
          "(the plant's clock); relative: <namespace>/clock (a node with use_sim_time in that namespace "
          "remaps /clock:=clock)"),
    Param("topics.diagnostics", "/diagnostics", "diagnostic_msgs/DiagnosticArray (status name: the node's "
          "fully qualified name)"),
    Param("hardware_id", "", "hardware_id of the diagnostics status; empty: <model name> <node's full name>"),
    Param("lockstep.waiting_republish_period", 0.5, "[s] wall time: lockstep re-publishes the latest state "
          "this often until the first command arrives", positive=True, runtime=True),
    Param("realtime.max_catch_up", 5, "realtime: periods advanced in one late tick (each one counted as late); "
          "further behind, realtime.overrun applies", positive=True),
    Param("realtime.overrun", "slow", "realtime, more than max_catch_up periods behind: slow (the plant's "
          "clock slows, the stamps stay on the simulated-time grid, published on topics.clock) or skip (the "
          "stamps follow the wall clock and jump over the periods behind)", choices=OVERRUNS,
          fixed="the clock topic depends on it: restart the node"),
    Param("realtime.keep_gc_out", True, "realtime: no automatic garbage collection in the loop (the node "
          "collects the young generations between periods, at the diagnostics rate)"),
    *PROCESS_PARAMS,
    *SENSOR_PARAMS,
    *DISTURBANCE_PARAMS,
    *WRENCH_PARAMS,
    # the wall-clock rates may change while the plant runs (their timers are made anew)
    *(dataclasses.replace(s, runtime=True) if s.name in RUNTIME_RATES else s for s in MACHINE_PARAMS),
    *DESCRIPTION_PARAMS,
    *ESTIMATE_PARAMS,
]
# Parameters that only one mode uses (a warning lists the ones given to the other mode); and observer.*
ONLY = {"plant": ("formulation", "integrator", "dt", "start", "stabilization", "publish_rate", "sync_mode",
                  "command_timeout", "topics.command", "topics.applied_torque", "topics.clock", "hardware_id",
                  *(s.name for s in PARAMS if s.name.startswith(("lockstep.", "realtime."))),
                  *(s.name for s in SENSOR_PARAMS), *(s.name for s in DISTURBANCE_PARAMS),
                  *(s.name for s in WRENCH_PARAMS)),
        "observer": tuple(s.name for s in ESTIMATE_PARAMS)}
OBSERVER_PREFIX = "observer."
TOPIC_PARAMS = ("topics.", "sensors.topics.")  # every topic name among the parameters


class PlantNode(ManagedNode):
    """Simulated elastic manipulator: torque commands in, states out; or, with ``mode: observer``,
    commands and measurements in, estimated states out (see module doc)."""

    def __init__(self, **node_kwargs: Any):
        super().__init__("plant", **node_kwargs)
        known = [s.name for s in PARAMS] + [COMMAND_JOINTS]
        if any(n.startswith(OBSERVER_PREFIX) for n in self._parameter_overrides):
            from elastic_pm_dyn.observer.config import DEFAULT_PARAMETERS  # imports the observer (scipy.stats)
            known += [OBSERVER_PREFIX + n for n in DEFAULT_PARAMETERS]
        reject_unknown(self, known)
        p = read_parameters(self, PARAMS)
        self.mode: str = p["mode"]
        self.resolved = resolved_topics(self, p, [s.name for s in PARAMS if s.name.startswith(TOPIC_PARAMS)])
        mech, self.decoder = load_machine(self, p)
        self._warn_unused()
        if self.mode == "observer":
            from elastic_pm_dyn.ros.observer.mode import OBSERVER_PARAMS, ObserverMode
            self.observer = ObserverMode(self, mech, p)
            on_runtime_change(self, [*PARAMS, *OBSERVER_PARAMS], self.observer.apply_parameter)
        else:
            self._start_plant(mech, p)
            on_runtime_change(self, PARAMS, self._apply_parameter)
        # Both modes show the same machine; only once started, so a node that refuses to start says one line.
        self.pub_robot_description = publish_robot_description(self, mech, p)

    def _warn_unused(self) -> None:
        other = "observer" if self.mode == "plant" else "plant"
        unused = sorted(n for n in self._parameter_overrides if n in ONLY[other])
        if other == "observer" and any(n.startswith(OBSERVER_PREFIX) for n in self._parameter_overrides):
            unused.append(OBSERVER_PREFIX + "*")
        if unused:
            self.get_logger().warning(f"mode {self.mode} does not use: {', '.join(unused)}")

    def _start_plant(self, mech: Mechanism, p: dict[str, Any]) -> None:
        self.sync_mode: str = p["sync_mode"]
        if (why := process_refusal(p)) is not None:
            raise ParameterError(why)
        period = 1.0 / p["publish_rate"]
        options = SimulationOptions(formulation=p["formulation"], integrator=p["integrator"], dt=p["dt"],
                                    stabilization=p["stabilization"], sample=period)
        spec = sensor_spec(p)
        self.plant = Plant(mech, options, period, spectrum_disturbance(p, len(mech.active)), start=p["start"],
                           wrench=external_wrench(p))
        if p["integrator"] == "rk4":  # as elastic-pm-dyn check computes it, at the start pose
            coarse = rk4_step_warning(mech, self.plant.q, min(p["dt"], period))
            if coarse:
                self.get_logger().warning(coarse)
        self.period_ns = round(period * NS)
        self.formulation = p["formulation"]
        # what paces the periods (its timers start at the end of set-up)
        self.sync = SYNC_MODES[self.sync_mode](self, p, period)
        # The stamps are the plant's clock, not the wall clock: fast, lockstep, realtime slowing
        self.own_clock = self.sync.own_clock
        self.hardware_id = p["hardware_id"] or f"{mech.model.name} {self.get_fully_qualified_name()}"
        self.messages = PlantMessages(self.plant, p["frames.base"])
        self.markers = MechanismMarkers(mech, p["frames.base"])
        self.stamp_base = 0  # [ns] stamp = stamp_base + k * period_ns
        self.stamp_set = False  # realtime: stamp_base taken from the wall clock (slow: once, at the first tick)
        self.warn = KindThrottle(self, WARN_EVERY)

        # not a second machine where one runs (its states would interleave with this one's)
        refuse_if_taken(self, [self.resolved["topics.joint_states"]], self.created)
        self.pub_joint_states = self.create_publisher(JointState, p["topics.joint_states"], STATE_OUT_QOS)
        self.pub_branch_forces = self.create_publisher(BranchForces, p["topics.branch_forces"], STATE_OUT_QOS)
        self.pub_ee_pose = self.create_publisher(PoseStamped, p["topics.ee_pose"], STATE_OUT_QOS)
        self.pub_markers = self.create_publisher(MarkerArray, p["topics.markers"], VIEWER_QOS)
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, p["topics.diagnostics"], DIAGNOSTICS_QOS)
        self.pub_clock = self.create_publisher(ClockMsg, p["topics.clock"], CLOCK_QOS) if self.own_clock else None
        self.pub_applied = self.create_publisher(JointState, p["topics.applied_torque"], STATE_OUT_QOS)
        motors = list(mech.active_names)
        self.applied = SerializedMessage(lambda a: cdr.encode_joint_state(0, motors, *a), (0, 0, len(motors)))
        msg_type = JointState if p["command_type"] == "joint_state" else Float64MultiArray
        self.command_sub = self.create_subscription(
            msg_type, p["topics.command"], lambda msg, info: self._on_command(msg, info),  # two args: with info
            LOCKSTEP_COMMAND_QOS if self.sync.answers_every_command else COMMAND_QOS)
        self.command_gaps = SequenceGaps()  # commands that never reached the callback (overwritten)
        # Sensors and disturbance: nothing of them exists unless configured (the topics stay as they were).
        self.sensors = SensorOutputs(self, self.plant, spec, p) if spec.any else None
        self.wrench_io = WrenchIO(self, self.plant, p, p["frames.base"]) if self.plant.wrench is not None else None
        # Commands (and the disturbance input): the callbacks give them, the stepping takes the torque.
        self.hold = CommandHold(len(mech.active), self.sync.answers_every_command, p["command_timeout"],
                                p["disturbance.input"], p["disturbance.timeout"])
        self.pub_disturbance = None
        if p["disturbance.input"] or self.plant.disturbance is not None:
            self.pub_disturbance = self.create_publisher(JointState, p["topics.disturbance"], STATE_OUT_QOS)
        if p["disturbance.input"]:
            self.create_subscription(msg_type, p["topics.disturbance_torque"], self._on_disturbance, COMMAND_QOS)
        self.sim_services = PlantServices(self)

        self.stats = PlantStats()
        self.paused = False
        self.last_command_wall = time.monotonic()
        self.last_state_wall = time.monotonic()

        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.marker_timer = self.create_timer(1.0 / p["marker_rate"], self._publish_markers, clock=self.steady)
        self.diagnostics_timer = self.create_timer(1.0 / p["diagnostics_rate"], self._publish_diagnostics,
                                                   clock=self.steady)
        self.step_timer = None  # realtime and fast: the timer that steps (cancelled while paused or stopped)
        extra = self.sync.start(p, period)
        self.get_logger().info(
            f"{mech.model.name}: {self.formulation}, {p['integrator']} dt {p['dt']:g} s, "
            f"{p['publish_rate']:g} Hz, {self.sync_mode}{extra}; commands ({p['command_type']}) on "
            f"'{self.command_sub.topic_name}' for {', '.join(self.decoder.array_order)}"
            + (f"; clock on '{self.pub_clock.topic_name}'" if self.pub_clock is not None else ""))

    def destroy_node(self) -> None:
        if hasattr(self, "sync"):  # the process may go on without this node (tests)
            restore(self.sync.keep_gc_out)
        super().destroy_node()

    # ------------------------------------------------------- runtime parameters
    def _apply_parameter(self, name: str, value: Any) -> str | None:
        """Take a runtime parameter (already checked); a reason when it cannot be taken."""
        if name == "command_timeout":
            self.hold.timeout = value
        elif name == "disturbance.timeout":
            self.hold.disturbance_timeout = value
        elif name == "marker_rate":
            self.destroy_timer(self.marker_timer)
            self.marker_timer = self.create_timer(1.0 / value, self._publish_markers, clock=self.steady)
        elif name == "diagnostics_rate":
            self.destroy_timer(self.diagnostics_timer)
            self.diagnostics_timer = self.create_timer(1.0 / value, self._publish_diagnostics, clock=self.steady)
        elif name == "lockstep.waiting_republish_period":
            # taken by a lockstep plant; the others keep it for nothing (checked, not used)
            self.sync.apply_parameter(name, value)
        else:
            return "not changeable at run time"
        return None

    # ------------------------------------------------------------------ inputs
    def _on_command(self, msg: JointState | Float64MultiArray, info: dict[str, Any] | None = None) -> None:
        arrival = time.monotonic()
        self.last_command_wall = arrival
        if info is not None:
            self._count_overwritten(info.get("publication_sequence_number"))
        try:
            tau = (self.decoder.from_joint_state(msg.name, msg.effort) if isinstance(msg, JointState)
                   else self.decoder.from_array(msg.data))
        except InputError as err:
            self.stats.rejected += 1
            held = "; holding the last valid one for the period" if self.sync.answers_every_command else ""
            self.warn.warning(getattr(err, "kind", "rejected"), f"command rejected: {err}{held}")
            self.sync.command_rejected(arrival)
            return
        self.stats.accepted += 1
        if self.hold.take(tau, arrival, self.command_clock()):
            self.get_logger().info("first torque command received")
        self.sync.command_taken()

    def _count_overwritten(self, seq: int | None) -> None:
        """Lockstep answers every command it gets: one that a queue overwrote is reported, never silent."""
        skipped = self.command_gaps.take(seq, self.command_sub.get_publisher_count())
        if skipped and self.sync.answers_every_command:
            self.warn.warning("overwritten", f"{self.command_gaps.missed} command(s) overwritten before the plant "
                              "took them (unanswered; publish the next command after the state, or deepen the "
                              "publisher's queue)")

    def _on_disturbance(self, msg: JointState | Float64MultiArray) -> None:
        try:
            d = (self.decoder.from_joint_state(msg.name, msg.effort) if isinstance(msg, JointState)
                 else self.decoder.from_array(msg.data))
        except InputError as err:
            self.warn.warning("disturbance " + getattr(err, "kind", "rejected"),
                              f"disturbance torque rejected: {err}; the last valid one holds")
            return
        self.hold.take_disturbance(d, self.command_clock())

    def command_clock(self) -> float:
        """The clock a command's age is measured on: the stamps' (simulated time unless they are the wall clock)."""
        return self.plant.t if self.own_clock else time.monotonic()

    def held_torque(self) -> np.ndarray:
        """The torque for the next period in realtime/fast: the command, or zero when stale."""
        tau, stale_age = self.hold.held(self.command_clock())
        if stale_age is not None:
            self.warn.warning("stale", f"last torque command is {stale_age:.3g} s old (timeout "
                              f"{self.hold.timeout:g} s): applying zero torque")
        if stale_age is not None or self.hold.command is None:
            self.stats.stale += 1
        return tau

    def restarted(self) -> None:
        """After reset/set_state: forget old commands, resume stepping, show the new state."""
        self.hold.restart()
        self.resume(publish=True)

    def resume(self, publish: bool = False) -> None:
        """Stepping goes on (unless paused or stopped by a fault); the new realtime schedule's
        first tick, or here ``publish``, shows the state."""
        if self.paused:
            if publish:
                self.publish_state()
            return
        if self.step_timer is not None and self.step_timer.is_canceled() and self.plant.fault is None:
            self.step_timer.reset()
        self.sync.resume(publish)

    # ---------------------------------------------------------------- stepping
    def step_period(self, tau: np.ndarray, arrival: float | None = None) -> bool:
        """Advance one period and publish; False when integration stopped. ``arrival``: when the
        command of this period arrived, if it is a new one (latency, fresh-command share)."""
        t0 = time.perf_counter()
        held = self.hold.held_disturbance(self.command_clock())
        start_ns = self._stamp_ns()
        try:
            if self.sensors is not None and self.sensors.after:  # a(t_k+): under the command that starts now
                self.sensors.publish_imu(self._stamp_ns(), self.plant.motor_torque(tau, held))
            self.plant.step(tau, held)
        except SingularConfigurationError as err:  # also a diverged state; the plant keeps the last good one
            self.get_logger().error(f"integration stopped: {err}; call ~/reset or ~/set_state to recover")
            if self.step_timer is not None:
                self.step_timer.cancel()
            return False
        except Exception as err:  # never die in a step: the state is unchanged, say why
            self.stats.rejected += 1
            self.warn.warning("step failed", f"period not advanced: {type(err).__name__}: {err}")
            return False
        t1 = time.perf_counter()
        # what acted over the period, before the state it led to (an observer predicts with it)
        self.applied.set_stamp(*divmod(start_ns, NS))
        self.applied.arrays[2][:] = tau
        self.pub_applied.publish(self.applied.raw())
        self.publish_state()
        t2 = time.perf_counter()
        self.stats.add(t1 - t0, t2 - t0)
        if arrival is not None:
            self.stats.fresh += 1
            self.stats.latency.append(time.monotonic() - arrival)
        return True

    # ----------------------------------------------------------------- outputs
    def _stamp_ns(self) -> int:
        return self.stamp_base + self.plant.k * self.period_ns

    def publish_state(self, again: bool = False) -> None:
        """The state of the current period on every output; ``again``: the same state and samples
        once more (the sensors' bytes as published: their noise is drawn once per stamp)."""
        m = self.messages
        self.last_state_wall = time.monotonic()
        if not again:
            m.fill(self._stamp_ns())
        # Serialized once, refilled in place: rclpy hands the bytes to the middleware as they are.
        self.pub_joint_states.publish(m.joint_state_raw)
        self.pub_branch_forces.publish(m.branch_forces_raw)
        self.pub_ee_pose.publish(m.ee_pose_raw)
        if self.pub_clock is not None:
            self.pub_clock.publish(m.clock_raw)
        if again:
            if self.sensors is not None:
                self.sensors.publish_again()
        elif self.sensors is not None:
            self.sensors.publish_state(m.stamp_ns, m.force)
        if self.wrench_io is not None:  # the true external wrench at t_k
            self.wrench_io.publish(m.stamp_ns)
        if self.pub_disturbance is not None:  # the truth at t_k: the held part of the period that ended + d(t_k)
            self.pub_disturbance.publish(disturbance_message(
                self.plant.mech.active_names, m.stamp_ns, self.plant.disturbance_at(self.plant.t)))

    def period_publishers(self) -> list[Any]:
        """The publishers of every period's state (a lockstep controller may read any of them)."""
        pubs = [self.pub_joint_states, self.pub_branch_forces, self.pub_ee_pose]
        if self.sensors is not None:
            pubs += self.sensors.publishers()
        if self.pub_disturbance is not None:
            pubs.append(self.pub_disturbance)
        return pubs

    def _publish_diagnostics(self) -> None:
        status = plant_status(self)
        self.pub_diagnostics.publish(DiagnosticArray(header=Header(stamp=stamp(self._stamp_ns())), status=[status]))

    def _publish_markers(self) -> None:
        if self.pub_markers.get_subscription_count():
            self.pub_markers.publish(self.markers.build(self.plant.q, self._stamp_ns()))

def main(args: list[str] | None = None) -> int:
    return run_node("plant_node", PlantNode, args)


if __name__ == "__main__":
    sys.exit(main())
