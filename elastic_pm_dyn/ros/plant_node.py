"""The plant node: an elastic parallel manipulator simulated in the loop (console script ``plant_node``).

Sync modes (parameter ``sync_mode``):
- ``realtime``: a steady-clock timer at ``publish_rate`` advances one control period per
  tick (catching up a few periods after a late tick) and stamps with wall time.
- ``fast``: as fast as possible; stamps are simulated time, published on ``/clock``.
- ``lockstep``: each command advances exactly one period, then the state at the end of
  that period is published (stamp = simulated time, also on ``/clock``); a rejected
  command holds the last valid one (zero torque if none) for its period, so every command
  is answered within one period while the plant runs. The state at t = 0 is published at start-up
  (transient local, see :mod:`.qos`), so a controller that answers every state with the
  next command drives the plant deterministically: the same torques give the same states
  as offline ``simulate``.

Callbacks only validate and store; the timers and the lockstep handler (a guard
condition) advance the :class:`~elastic_pm_dyn.sim.plant.Plant`. Nothing a message or a
service request holds makes the node die: a fault stops integration at the last good
state, ``~/reset`` and ``~/set_state`` recover, and a request that cannot be served is
answered ``success: false`` with the reason. Warnings are throttled per kind. With ``mode: observer``
the node does not simulate: :class:`~elastic_pm_dyn.ros.observer_mode.ObserverMode`
subscribes to commands and measurements and publishes the state observer's estimates on
the same output topics (the sync parameters then do not apply): the observer node
(``observer_node``, :mod:`~elastic_pm_dyn.ros.observer_node`) under the plant's name, with
the same parameters (:mod:`~elastic_pm_dyn.ros.machine_params`, ``observer.*``).
Torque held over a period: the last valid command, or zero when it is older than
``command_timeout`` (wall time in realtime, simulated time in fast; lockstep waits).

Simulated sensors (``sensors.*``) and an unknown disturbance torque on the motors
(``disturbance.*``): :mod:`~elastic_pm_dyn.ros.plant_sensors` (all off by default).
"""

from __future__ import annotations

import collections
import sys
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from elastic_pm_dyn_msgs.msg import BranchForces
from elastic_pm_dyn_msgs.srv import SetJointState
from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from elastic_pm_dyn.bags.msgtypes import NS
from elastic_pm_dyn.dynamics.direct import FORMULATIONS
from elastic_pm_dyn.errors import InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.ros.losses import SequenceGaps
from elastic_pm_dyn.ros.machine_params import DESCRIPTION_PARAMS, ESTIMATE_PARAMS, MACHINE_PARAMS, load_machine
from elastic_pm_dyn.ros.markers import MechanismMarkers
from elastic_pm_dyn.ros.messages import PlantMessages, stamp
from elastic_pm_dyn.ros.node_main import ManagedNode, run_node
from elastic_pm_dyn.ros.params import COMMAND_JOINTS, Param, read_parameters, reject_unknown
from elastic_pm_dyn.ros.plant_sensors import (
    DISTURBANCE_PARAMS,
    SENSOR_PARAMS,
    SensorOutputs,
    disturbance_message,
    sensor_spec,
    spectrum_disturbance,
)
from elastic_pm_dyn.ros.qos import (
    CLOCK_QOS,
    COMMAND_QOS,
    DIAGNOSTICS_QOS,
    LOCKSTEP_COMMAND_QOS,
    STATE_OUT_QOS,
    VIEWER_QOS,
)
from elastic_pm_dyn.ros.robot_description import publish_robot_description
from elastic_pm_dyn.ros.throttle import KindThrottle
from elastic_pm_dyn.sim.plant import START_STATES, Plant
from elastic_pm_dyn.sim.simulator import INTEGRATORS, STABILIZATIONS, SimulationOptions

MODES = ("plant", "observer")
SYNC_MODES = ("realtime", "fast", "lockstep")
MAX_CATCH_UP = 5  # realtime: periods advanced in one late tick before the schedule slips
FAST_SLICE = 0.005  # [s] fast mode: wall time per executor turn (amortises its ~0.2 ms, stays responsive)
WARN_EVERY = 1.0  # [s] throttle of repeated warnings, per kind

PARAMS = [
    Param("mode", "plant", "plant: simulate the machine; observer: estimate its state from commands and measurements",
          choices=MODES),
    Param("formulation", "scdd", "direct dynamics formulation", choices=FORMULATIONS),
    Param("integrator", "rk4", "rk4 (fixed step dt), etd2 (fixed step dt, the springs exactly: a step of "
          "0.25-1 ms, see elastic-pm-dyn check) or dop853 (adaptive, offline accuracy)", choices=INTEGRATORS),
    Param("dt", 1.0e-4, "internal RK4 / ETD2 step [s]; shortened so steps end on control periods", positive=True),
    Param("start", "relaxed", "start (and ~/reset) state: relaxed (the model's initial pose, springs unloaded, "
          "as simulate) or static (springs deflected by gravity, motors held: a machine at rest, as the "
          "observer assumes)", choices=START_STATES),
    Param("stabilization", "projection", "closure drift stabilisation", choices=tuple(STABILIZATIONS)),
    Param("publish_rate", 1000.0, "control and publish rate [Hz]; a command is held for one period",
          positive=True),
    Param("sync_mode", "realtime", "realtime | fast | lockstep", choices=SYNC_MODES),
    Param("command_timeout", 0.1, "[s] an older command means zero torque (wall time in realtime, "
          "simulated time in fast; unused in lockstep)", positive=True),
    Param("topics.command", "torque_command", "torque command topic"),
    *SENSOR_PARAMS,
    *DISTURBANCE_PARAMS,
    *MACHINE_PARAMS,
    *DESCRIPTION_PARAMS,
    *ESTIMATE_PARAMS,
]
# Parameters that only one mode uses (a warning lists the ones given to the other mode); and observer.*
ONLY = {"plant": ("formulation", "integrator", "dt", "start", "stabilization", "publish_rate", "sync_mode",
                  "command_timeout", "topics.command", *(s.name for s in SENSOR_PARAMS),
                  *(s.name for s in DISTURBANCE_PARAMS)),
        "observer": tuple(s.name for s in ESTIMATE_PARAMS)}
OBSERVER_PREFIX = "observer."


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
        mech, self.decoder = load_machine(self, p)
        self._warn_unused()
        if self.mode == "observer":
            from elastic_pm_dyn.ros.observer_mode import ObserverMode
            self.observer = ObserverMode(self, mech, p)
        else:
            self._start_plant(mech, p)
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
        period = 1.0 / p["publish_rate"]
        options = SimulationOptions(formulation=p["formulation"], integrator=p["integrator"], dt=p["dt"],
                                    stabilization=p["stabilization"], sample=period)
        spec = sensor_spec(p)
        self.plant = Plant(mech, options, period, spectrum_disturbance(p, len(mech.active)), start=p["start"])
        self.period_ns = round(period * NS)
        self.timeout = p["command_timeout"]
        self.formulation = p["formulation"]
        self.messages = PlantMessages(self.plant, p["frames.base"])
        self.markers = MechanismMarkers(mech, p["frames.base"])
        self.stamp_base = 0  # [ns] stamp = stamp_base + k * period_ns
        self.warn = KindThrottle(self, WARN_EVERY)

        self.pub_joint_states = self.create_publisher(JointState, p["topics.joint_states"], STATE_OUT_QOS)
        self.pub_branch_forces = self.create_publisher(BranchForces, p["topics.branch_forces"], STATE_OUT_QOS)
        self.pub_ee_pose = self.create_publisher(PoseStamped, p["topics.ee_pose"], STATE_OUT_QOS)
        self.pub_markers = self.create_publisher(MarkerArray, p["topics.markers"], VIEWER_QOS)
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        self.pub_clock = (self.create_publisher(ClockMsg, "/clock", CLOCK_QOS)
                          if self.sync_mode != "realtime" else None)
        msg_type = JointState if p["command_type"] == "joint_state" else Float64MultiArray
        self.command_sub = self.create_subscription(
            msg_type, p["topics.command"], lambda msg, info: self._on_command(msg, info),  # two args: with info
            LOCKSTEP_COMMAND_QOS if self.sync_mode == "lockstep" else COMMAND_QOS)
        self.command_gaps = SequenceGaps()  # commands that never reached the callback (overwritten)
        # Sensors and disturbance: nothing of them exists unless configured (the topics stay as they were).
        self.sensors = SensorOutputs(self, self.plant, spec, p) if spec.any else None
        self.disturbance_input: bool = p["disturbance.input"]
        self.disturbance_timeout = p["disturbance.timeout"]
        self.disturbance_command: np.ndarray | None = None  # the last valid disturbance_torque
        self.disturbance_time = 0.0  # when it arrived (the command clock)
        self.pub_disturbance = None
        if self.disturbance_input or self.plant.disturbance is not None:
            self.pub_disturbance = self.create_publisher(JointState, p["topics.disturbance"], STATE_OUT_QOS)
        if self.disturbance_input:
            self.create_subscription(msg_type, p["topics.disturbance_torque"], self._on_disturbance, COMMAND_QOS)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetJointState, "~/set_state", self._on_set_state)

        # Command state: the callbacks write these, the stepping reads them.
        self.command: np.ndarray | None = None
        self.command_time = 0.0  # when it arrived: monotonic [s] (realtime) or simulated [s] (fast)
        self.queue: collections.deque[np.ndarray] = collections.deque()  # lockstep
        self.stats = _Stats()

        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0 / p["marker_rate"], self._publish_markers, clock=steady)
        self.create_timer(1.0 / p["diagnostics_rate"], self._publish_diagnostics, clock=steady)
        self.wall_start: float | None = None  # realtime schedule origin (monotonic)
        self.k_start = 0  # plant period count at wall_start
        self.step_timer = None
        if self.sync_mode == "realtime":
            self.step_timer = self.create_timer(period, self._on_realtime_tick, clock=steady)
        elif self.sync_mode == "fast":
            self.step_timer = self.create_timer(0.0, self._on_fast_tick, clock=steady)
        else:
            self.lockstep_trigger = self.create_guard_condition(self._on_lockstep)
            self._publish_state()
        self.get_logger().info(
            f"{mech.model.name}: {self.formulation}, {p['integrator']} dt {p['dt']:g} s, "
            f"{p['publish_rate']:g} Hz, {self.sync_mode}; commands ({p['command_type']}) on "
            f"'{p['topics.command']}' for {', '.join(self.decoder.array_order)}")

    # ------------------------------------------------------------------ inputs
    def _on_command(self, msg: JointState | Float64MultiArray, info: dict[str, Any] | None = None) -> None:
        if info is not None:
            self._count_overwritten(info.get("publication_sequence_number"))
        try:
            tau = (self.decoder.from_joint_state(msg.name, msg.effort) if isinstance(msg, JointState)
                   else self.decoder.from_array(msg.data))
        except InputError as err:
            self.stats.rejected += 1
            if self.sync_mode == "lockstep":  # answered all the same: the last valid command holds
                self.warn.warning(getattr(err, "kind", "rejected"),
                                  f"command rejected: {err}; holding the last valid one for the period")
                self.queue.append(self.command if self.command is not None else np.zeros(len(self.plant.tau)))
                self.lockstep_trigger.trigger()
            else:
                self.warn.warning(getattr(err, "kind", "rejected"), f"command rejected: {err}")
            return
        self.stats.accepted += 1
        if self.command is None:
            self.get_logger().info("first torque command received")
        self.command = tau
        if self.sync_mode == "lockstep":
            self.queue.append(tau)
            self.lockstep_trigger.trigger()
        else:
            self.command_time = self._command_clock()

    def _count_overwritten(self, seq: int | None) -> None:
        """Lockstep answers every command it gets: one that a queue overwrote is reported, never silent."""
        skipped = self.command_gaps.take(seq, self.command_sub.get_publisher_count())
        if skipped and self.sync_mode == "lockstep":
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
        self.disturbance_command = d
        self.disturbance_time = self._disturbance_clock()

    def _disturbance_clock(self) -> float:
        return time.monotonic() if self.sync_mode == "realtime" else self.plant.t

    def _held_disturbance(self) -> np.ndarray | None:
        """The disturbance_torque for the next period: the last valid one, zero when stale; None
        without the input (the plant then integrates the command alone, as before)."""
        if not self.disturbance_input:
            return None
        if (self.disturbance_command is not None
                and self._disturbance_clock() - self.disturbance_time <= self.disturbance_timeout):
            return self.disturbance_command
        return np.zeros(len(self.plant.tau))

    def _command_clock(self) -> float:
        return time.monotonic() if self.sync_mode == "realtime" else self.plant.t

    def _held_torque(self) -> np.ndarray:
        """The torque for the next period in realtime/fast: the command, or zero when stale."""
        if self.command is not None:
            age = self._command_clock() - self.command_time
            if age <= self.timeout:
                return self.command
            self.warn.warning("stale", f"last torque command is {age:.3g} s old (timeout {self.timeout:g} s): "
                              "applying zero torque")
        self.stats.stale += 1
        return np.zeros(len(self.plant.tau))

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        try:
            self.plant.reset()
            self._restarted()
            response.success = True
            response.message = f"reset to the initial state at t = {self.plant.t:.6g} s"
            self.get_logger().info(response.message)
        except Exception as err:  # never die on a service call: answer why
            response.success = False
            response.message = f"reset failed: {type(err).__name__}: {err}"
            self.get_logger().error(response.message)
        return response

    def _on_set_state(self, request: SetJointState.Request,
                      response: SetJointState.Response) -> SetJointState.Response:
        s = request.state
        try:
            response.message = self.plant.set_state(s.name, s.position, s.velocity)
            response.success = True
            self._restarted()
            self.get_logger().info(response.message)
        except InputError as err:
            response.success = False
            response.message = f"set_state rejected: {err}"
            self.get_logger().warning(response.message)
        except Exception as err:  # never die on a service call: answer why (the state is unchanged)
            response.success = False
            response.message = f"set_state failed: {type(err).__name__}: {err}"
            self.get_logger().error(response.message)
        return response

    def _restarted(self) -> None:
        """After reset/set_state: forget old commands, resume stepping, show the new state."""
        self.command = None
        self.queue.clear()
        if self.step_timer is not None and self.step_timer.is_canceled():
            self.step_timer.reset()
        if self.sync_mode == "realtime":
            self.wall_start = None  # a fresh schedule; its first tick publishes the new state
        else:
            self._publish_state()

    # ---------------------------------------------------------------- stepping
    def _step(self, tau: np.ndarray) -> bool:
        """Advance one period and publish; False when integration stopped."""
        t0 = time.perf_counter()
        held = self._held_disturbance()
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
        self._publish_state()
        self.stats.add(t1 - t0, time.perf_counter() - t0)
        return True

    def _on_realtime_tick(self) -> None:
        now = time.monotonic()
        if self.wall_start is None:
            self.wall_start, self.k_start = now, self.plant.k
            self.stamp_base = self.get_clock().now().nanoseconds - self.plant.k * self.period_ns
            self._publish_state()
            return
        # Periods due by now; the half period tolerates ticks that come a little early.
        due = int((now - self.wall_start) / self.plant.period + 0.5) - (self.plant.k - self.k_start)
        if due > MAX_CATCH_UP:  # too far behind: let the schedule (and the stamps) slip
            self.stats.overruns += 1
            slip = due - MAX_CATCH_UP
            self.wall_start += slip * self.plant.period
            self.stamp_base += slip * self.period_ns
            due = MAX_CATCH_UP
        for _ in range(due):
            if not self._step(self._held_torque()):
                return

    def _on_fast_tick(self) -> None:
        end = time.perf_counter() + FAST_SLICE
        while time.perf_counter() < end:
            if not self._step(self._held_torque()):
                return

    def _on_lockstep(self) -> None:
        """One period per command (a rejected one holds the last valid command). Every command
        is answered, so a controller that waits for the state never waits more than one period:
        while integration is stopped (ERROR in /diagnostics until ~/reset or ~/set_state) the
        last good state is published again, with its own stamp (time does not advance)."""
        while self.queue:
            tau = self.queue.popleft()
            if self.plant.fault is not None:
                self.stats.rejected += 1
                self.warn.warning("stopped", f"command ignored, integration stopped: {self.plant.fault}; "
                                  "call ~/reset or ~/set_state")
                self._publish_state()
            elif not self._step(tau):
                self._publish_state()  # the last good state: the plant keeps it on a fault

    # ----------------------------------------------------------------- outputs
    def _stamp_ns(self) -> int:
        return self.stamp_base + self.plant.k * self.period_ns

    def _publish_state(self) -> None:
        m = self.messages
        m.fill(self._stamp_ns())
        # Serialized once, refilled in place: rclpy hands the bytes to the middleware as they are.
        self.pub_joint_states.publish(m.joint_state_raw)
        self.pub_branch_forces.publish(m.branch_forces_raw)
        self.pub_ee_pose.publish(m.ee_pose_raw)
        if self.sensors is not None:
            self.sensors.publish_state(m.stamp_ns, m.force)
        if self.pub_disturbance is not None:  # the truth at t_k: the held part of the period that ended + d(t_k)
            self.pub_disturbance.publish(disturbance_message(
                self.plant.mech.active_names, m.stamp_ns, self.plant.disturbance_at(self.plant.t)))
        if self.pub_clock is not None:
            self.pub_clock.publish(m.clock_raw)

    def _publish_markers(self) -> None:
        if self.pub_markers.get_subscription_count():
            self.pub_markers.publish(self.markers.build(self.plant.q, self._stamp_ns()))

    def _publish_diagnostics(self) -> None:
        s, plant = self.stats, self.plant
        wall = time.monotonic()
        rtf = (plant.t - s.window_sim) / (wall - s.window_wall) if wall > s.window_wall else 0.0
        age = (f"{self._command_clock() - self.command_time:.6g}" if self.command is not None
               and self.sync_mode != "lockstep" else "")
        status = DiagnosticStatus(name=f"{self.get_name()}: plant", hardware_id=plant.mech.model.name)
        if plant.fault is not None:
            status.level, status.message = DiagnosticStatus.ERROR, f"integration stopped: {plant.fault}"
        else:
            issues = [text for changed, text in (
                (s.window_rejected != s.rejected, "commands rejected"),
                (s.window_stale != s.stale, "zero torque (no command or a stale one)"),
                (s.window_overruns != s.overruns, "realtime overrun: the schedule slipped"),
                (s.window_overwritten != self.command_gaps.missed and self.sync_mode == "lockstep",
                 "commands overwritten (unanswered)"))
                if changed]
            status.level = DiagnosticStatus.WARN if issues else DiagnosticStatus.OK
            status.message = "; ".join(issues) or "running"
        values = {
            "sync_mode": self.sync_mode, "formulation": self.formulation, "sim_time_s": f"{plant.t:.6f}",
            "periods": str(plant.k), "real_time_factor": f"{rtf:.4g}",
            "step_time_mean_us": f"{s.mean(s.step) * 1e6:.1f}", "step_time_max_us": f"{s.max(s.step) * 1e6:.1f}",
            "cycle_time_mean_us": f"{s.mean(s.cycle) * 1e6:.1f}",
            "cycle_time_max_us": f"{s.max(s.cycle) * 1e6:.1f}",
            "headroom": f"{s.mean(s.cycle) / plant.period:.4g}",  # cycle time / period: < 1 keeps up
            "closure_gap_m": f"{plant.gap():.3g}", "command_age_s": age,
            "commands_accepted": str(s.accepted), "commands_rejected": str(s.rejected),
            "zero_torque_periods": str(s.stale), "overruns": str(s.overruns),
            "commands_overwritten": str(self.command_gaps.missed),
        }
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        self.pub_diagnostics.publish(DiagnosticArray(header=Header(stamp=stamp(self._stamp_ns())), status=[status]))
        s.new_window(plant.t, wall)
        s.window_overwritten = self.command_gaps.missed


class _Stats:
    """Counters for /diagnostics; timing over the window since the last report."""

    def __init__(self) -> None:
        self.accepted = self.rejected = self.stale = self.overruns = 0
        self.window_overwritten = 0  # commands_overwritten at the start of the window
        self.step: list[float] = []
        self.cycle: list[float] = []
        self.new_window(0.0, time.monotonic())

    def add(self, step: float, cycle: float) -> None:
        self.step.append(step)
        self.cycle.append(cycle)

    def new_window(self, sim: float, wall: float) -> None:
        self.window_sim, self.window_wall = sim, wall
        self.window_rejected, self.window_stale, self.window_overruns = self.rejected, self.stale, self.overruns
        self.step.clear()
        self.cycle.clear()

    @staticmethod
    def mean(x: list[float]) -> float:
        return float(np.mean(x)) if x else 0.0

    @staticmethod
    def max(x: list[float]) -> float:
        return float(np.max(x)) if x else 0.0


def main(args: list[str] | None = None) -> int:
    return run_node("plant_node", PlantNode, args)


if __name__ == "__main__":
    sys.exit(main())
