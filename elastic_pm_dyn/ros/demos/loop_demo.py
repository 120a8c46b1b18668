"""The closed loop through ROS 2 (``elastic-pm-dyn ros-demo --observer``).

Five node processes on a loopback-only domain (as ``ros-demo``'s: ``--domain-id``, else
``ROS_DOMAIN_ID`` when set, else a private one), all in lockstep:
- plant (lockstep, with its sensors: encoders and an end-effector accelerometer, and an unknown
  torque disturbance, flat 2-200 Hz, 0.02 N m RMS by default): ``joint_states``,
  ``branch_forces``, ``ee_pose`` (the truth), ``measured_joint_states``, ``ee_imu``,
  ``disturbance``;
- observer node: the estimates on ``observer/joint_states``, ``observer/branch_forces`` (with
  ``force_stddev``), ``observer/ee_pose`` (never on the plant's truth topics);
- controller (the feedforward node with ``feedback.kp/kd``): paced by the observer's estimates
  (``topics.state``), so that the loop waits for the observer; the command for t_k from the
  reference at t_k and the encoder sample stamped t_k;
- recorder: every topic above, the commands and the reference.

The loop starts by itself: the lockstep plant publishes its t = 0 state and samples again until
the first command, so every node gets them however late it subscribed. Then the bag is read back: estimates against
the truth, the open-loop prediction (:func:`~elastic_pm_dyn.observer.testing.evaluation.open_loop`: the
model under the recorded commands without the disturbance), NEES, and ``observe`` over the
recorded sensor topics compared with the live estimates row by row (``summary.json``, plots).
"""

from __future__ import annotations

import json
import shutil
import signal
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from elastic_pm_dyn.analysis import plots
from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES, IMU, JOINT_STATE, stamp_ns
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.series import read_series
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.errors import InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedback import pd_torque
from elastic_pm_dyn.motion.feedforward import rigid_feedforward
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.observer.config import load_config
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.testing.evaluation import OpenLoop, offline_run, quasi_static_series, score
from elastic_pm_dyn.observer.testing.scenarios import Noise, Recording
from elastic_pm_dyn.ros.demos.demo import fresh_bag
from elastic_pm_dyn.ros.demos.local_nodes import run_domain_id
from elastic_pm_dyn.ros.demos.processes import (
    NodeProcess,
    NodeProcessError,
    ros_env,
    wait_for_exit,
    wait_for_recording,
)
from elastic_pm_dyn.ros.params import observer_config_for, share_path
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable

CONTROL_RATE = REFERENCE_MANOEUVRE.control_rate  # [Hz] plant, controller, sensors
PLANT_DT = 1e-4  # [s] the plant's RK4 step (config/plant_sensors.yaml)
DRAIN = 1.0  # [s] after the controller ends, for the last messages to reach the recorder
LATE = 0.2  # [s] the figures also from here on (after a start transient)
OPEN_LOOP_PIECE = 0.25  # [s] the open loop is integrated piece by piece (up to a singular pose)
STALL = 120.0  # [s] wall time without a new plant state after which a running loop has stalled
# What the plant simulates (names of the plant-sensors parameters, config/plant_sensors.yaml).
ENCODER_STDDEV = 2.0e-5  # [rad] the observer's test recordings' noise (observer.testing.scenarios.Noise)
IMU_STDDEV = 0.02  # [m/s^2]
OBSERVER_NS = "observer"  # the estimates' topics: observer/joint_states, ...
TOPICS = {  # role -> topic
    "truth": "/joint_states", "truth_forces": "/branch_forces", "truth_pose": "/ee_pose",
    "estimate": f"/{OBSERVER_NS}/joint_states", "estimate_forces": f"/{OBSERVER_NS}/branch_forces",
    "estimate_pose": f"/{OBSERVER_NS}/ee_pose", "command": "/torque_command", "reference": "/reference_joint_states",
    "encoders": "/measured_joint_states", "imu": "/ee_imu", "disturbance": "/disturbance",
}


@dataclass
class LoopOptions:
    """One closed-loop run (the defaults are the acceptance run's, docs/nodes.md, "Closing the loop")."""

    model: Path
    elastic_dof_per_chain: int | None = None
    seed: int = 1  # sensor noise and disturbance
    duration: float = 2.0  # [s] of loop
    # observer parameter file; None: the machine's own (observer_<model stem>.yaml beside the model, as
    # config/observer_triglide.yaml), else config/observer_node.yaml (:func:`observer_config_for`)
    observer_config: Path | None = None
    kp: list[float] | None = None  # [N m/rad] None: from the machine's inertia (:func:`default_gains`)
    kd: list[float] | None = None
    bandwidth: float = 2.0  # [Hz] of the default gains
    damping: float = 0.1  # damping ratio of the default gains
    disturbance_rms: float = 0.02  # [N m] per motor
    disturbance_band: tuple[float, float] = (2.0, 200.0)  # [Hz] flat spectrum
    imu_sample_timing: str = "before_command"  # the controller reads its sensors, then commands
    storage: str = "mcap"
    timeout: float = 1800.0  # [s] wall time for the loop (the observer is slow on spatial machines)
    domain_id: int | None = None
    extra_plant_args: list[str] = field(default_factory=list)
    # False: the controller answers the plant's states, the observer only listens (a loop that an
    # observer failure cannot stop, e.g. a recording to tune the observer on; live may then lag)
    pace_on_observer: bool = True
    # False: a plant without simulated sensors; its true joint states are the (noise-free)
    # encoders and there is no accelerometer (a check of the wiring, not of the observer)
    plant_sensors: bool = True

    def topics(self) -> dict[str, str | None]:
        """Role -> topic of this run (``imu`` None: no accelerometer)."""
        if self.plant_sensors:
            return dict(TOPICS)
        return {**TOPICS, "encoders": TOPICS["truth"], "imu": None}

    def observer_file(self) -> Path:
        """The observer parameter file of this run (``observer_config``, else the machine's own or the generic)."""
        return self.observer_config or observer_config_for(self.model)

    @property
    def sensors(self) -> list[str]:
        return ["encoders", "imu"] if self.plant_sensors else ["encoders"]


def default_gains(mech: Mechanism, bandwidth: float = 2.0, damping: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """PD gains per motor from the rigid machine's inertia at the start pose seen by each motor
    alone (diagonal of W^T M W): kp = m w^2, kd = 2 zeta m w at ``bandwidth`` [Hz]. The rate is
    differenced from 1 kHz encoder samples, a period late: a large kd feeds the spring modes
    (the Triglide at n_ek = 2 rang up to 60 kN within 0.25 s at 5 Hz / 0.7, the Hexa went
    singular); 2 Hz / 0.1 keeps every machine's loop stable (the feedforward does the tracking)."""
    ff = rigid_feedforward(mech.model)
    rigid = ff.mech
    t = rigid.terms(ff.q, np.zeros(rigid.n))
    W, _ = rigid.passive_map(t)
    m = np.diag(W.T @ t.M @ W)[: len(rigid.active)]
    w = 2 * np.pi * bandwidth
    return m * w * w, 2 * damping * m * w


def rk4_limit(mech: Mechanism) -> float:
    """[s] the largest stable RK4 step for the fastest elastic mode at the start pose
    (|h omega| <= 2 sqrt 2, as ``elastic-pm-dyn check`` reports it); inf without springs."""
    from elastic_pm_dyn.dynamics.linear import elastic_modes
    from elastic_pm_dyn.kinematics.assembly import initial_state
    if not len(mech.elastic):
        return float("inf")
    f = float(np.max(elastic_modes(mech, initial_state(mech), clamp_motors=True).natural_hz))
    return 2 * np.sqrt(2) / (2 * np.pi * f) if f > 0 else float("inf")


def plant_numerics(mech: Mechanism) -> list[str]:
    """The plant's integrator: the project's RK4 at 1e-4 s where it is stable with a margin, else
    ETD2 at 5e-4 s (springs integrated exactly: docs/simulation.md's choice for stiff machines, e.g.
    the Triglide at n_ek = 2 whose fastest mode, 4.8 kHz, needs an RK4 step below 9.3e-5 s)."""
    if rk4_limit(mech) > 2 * PLANT_DT:
        return []
    return ["-p", "integrator:=etd2", "-p", "dt:=0.0005"]


def open_loop_prediction(rec: Recording) -> OpenLoop:
    """:func:`~elastic_pm_dyn.observer.testing.evaluation.open_loop` with the plant's own integrator: the
    model under the recorded commands (ZOH) from the true start state, without the disturbance;
    so its error is the disturbance's alone (the strictest open loop to beat)."""
    mech = rec.mech
    numerics = plant_numerics(mech)
    integrator, dt = ("etd2", 5e-4) if numerics else ("rk4", PLANT_DT)
    sim = Simulator(mech, SimulationOptions(formulation="scdd", integrator=integrator, dt=dt,
                                            sample=1.0 / CONTROL_RATE, stabilization="projection"))
    table = TorqueTable(rec.t, rec.acting, "zoh")
    n = len(rec.t)
    out = OpenLoop(np.full_like(rec.q, np.nan), np.full_like(rec.qd, np.nan), np.full_like(rec.F, np.nan))
    # In pieces: without the feedback's corrections an open loop may drift into a singular pose
    # (the Hexa holding its pose under gravity, at 1.97 s); it is then compared up to there.
    per = round(OPEN_LOOP_PIECE * CONTROL_RATE)
    q, qd = rec.q[0], rec.qd[0]
    for k0 in range(0, n - 1, per):
        k1 = min(k0 + per, n - 1)
        try:
            res = sim.run(table, rec.t[k1] - rec.t[k0], q, qd, t0=rec.t[k0])
        except SingularConfigurationError:
            break
        m = k1 - k0 + 1
        out.q[k0:k1 + 1], out.qd[k0:k1 + 1], out.F[k0:k1 + 1] = res.q[:m], res.qd[:m], res.branch_forces[:m]
        q, qd = res.q[m - 1], res.qd[m - 1]
    return out


def motion_params(mech: Mechanism, duration: float) -> dict[str, Any]:
    """The controller's reference on this machine: the reference line on the five-bar, a straight
    line in x, y, z on a translational machine (its end-effector point fixes the pose), else the
    start pose held against gravity."""
    ff = rigid_feedforward(mech.model)
    start = mech.end_effector(ff.q if len(mech.elastic) == 0 else initial_state(mech))
    move = REFERENCE_MANOEUVRE.move
    if len(mech.ee_components) != len(mech.active) or duration <= move:
        return {"source": "hold", "hold.duration": float(duration)}
    if len(start) == 2 and np.allclose(start, REFERENCE_MANOEUVRE.start):
        end = np.array(REFERENCE_MANOEUVRE.end, dtype=float)
    else:
        end = start + 0.03  # [m] along each axis: a 52 mm diagonal on a spatial machine
    return {"source": "line", "line.start": [float(x) for x in start], "line.end": [float(x) for x in end],
            "line.move": float(move), "line.hold": float(duration - move)}


def run_loop_demo(out: Path, opts: LoopOptions) -> dict:
    """Run the five nodes, record, analyse; returns the summary (also in out/summary.json)."""
    if not opts.duration > 0:
        raise InputError(f"--duration must be > 0, got {opts.duration}")
    opts = replace(opts, domain_id=run_domain_id(opts.domain_id))  # a bad ROS_DOMAIN_ID: one line, nothing written
    bag = fresh_bag(out)
    mech = Mechanism(load_model(opts.model, opts.elastic_dof_per_chain))
    print(f"  observer parameters: {opts.observer_file()}")
    wall = time.monotonic()
    _run_nodes(out, bag, mech, opts)
    wall = time.monotonic() - wall
    print(f"  bag -> {bag} ({wall:.1f} s)")
    return analyse_loop(out, bag, mech, opts, wall)


def _p(name: str, value: Any) -> list[str]:
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, (list, tuple)):  # strings quoted: a bare y would be read as true
        text = "[" + ", ".join(f"'{v}'" if isinstance(v, str) else _p_item(v) for v in value) + "]"
    else:
        text = _p_item(value)
    return ["-p", f"{name}:={text}"]


def _p_item(v: Any) -> str:
    return repr(float(v)) if isinstance(v, float) else str(v)


def node_arguments(bag: Path, mech: Mechanism, opts: LoopOptions) -> dict[str, list[str]]:
    """The --ros-args of each node (docs/nodes.md, "Closing the loop" lists the same wiring)."""
    model = ["-p", f"model:={opts.model}"]
    dof = (_p("elastic_dof_per_chain", int(opts.elastic_dof_per_chain))
           if opts.elastic_dof_per_chain is not None else [])
    cfg_path = opts.observer_file()
    topics = opts.topics()
    # config/plant_sensors.yaml: encoders and accelerometer on, a flat disturbance; this run's numbers
    sensors = [*_p("sensors.seed", int(opts.seed)),
               *_p("sensors.encoders.position_stddev", ENCODER_STDDEV),
               *_p("sensors.imu.stddev", IMU_STDDEV),
               *_p("sensors.imu.sample_timing", opts.imu_sample_timing),
               *_p("disturbance.spectrum", "flat" if opts.disturbance_rms > 0 else "none"),
               *_p("disturbance.rms", float(opts.disturbance_rms)),
               *_p("disturbance.band", [float(b) for b in opts.disturbance_band]),
               *_p("disturbance.seed", int(opts.seed)),
               *_p("disturbance.duration", float(opts.duration))]  # the RMS holds over the run
    plant = ["--params-file", str(share_path("config", "plant_sensors.yaml" if opts.plant_sensors else "plant.yaml")),
             *(sensors if opts.plant_sensors else []),
             *model, *dof, "-p", "sync_mode:=lockstep", *_p("publish_rate", CONTROL_RATE), *plant_numerics(mech),
             *opts.extra_plant_args]
    observer = ["--params-file", str(cfg_path), *model, *dof,
                *_p("topics.joint_states", f"{OBSERVER_NS}/joint_states"),
                *_p("topics.branch_forces", f"{OBSERVER_NS}/branch_forces"),
                *_p("topics.ee_pose", f"{OBSERVER_NS}/ee_pose"),
                *_p("topics.markers", f"{OBSERVER_NS}/markers"),
                *_p("topics.robot_description", f"{OBSERVER_NS}/robot_description"),
                *_p("observer.sensors", opts.sensors),
                *_p("observer.topics.measured_joint_states", topics["encoders"]),
                *_p("observer.imu.sample_timing", opts.imu_sample_timing)]
    kp, kd = default_gains(mech, opts.bandwidth, opts.damping)
    kp = np.broadcast_to(opts.kp if opts.kp is not None else kp, kp.shape)
    kd = np.broadcast_to(opts.kd if opts.kd is not None else kd, kd.shape)
    controller = ["--params-file", str(share_path("config", "feedforward.yaml")), *model,
                  *_p("rate", CONTROL_RATE), "-p", "trigger:=state",
                  *_p("topics.state", f"{OBSERVER_NS}/joint_states" if opts.pace_on_observer else topics["truth"]),
                  *_p("topics.measured_joint_states", topics["encoders"]),
                  *_p("feedback.kp", [float(x) for x in kp]), *_p("feedback.kd", [float(x) for x in kd]),
                  "-p", "autostart:=true", "-p", "exit_when_done:=true",
                  "-p", "wait_for_subscribers:=3"]  # the plant, the observer and the recorder
    for name, value in motion_params(mech, opts.duration).items():
        controller += _p(name, value)
    recorder = ["--params-file", str(share_path("config", "recorder.yaml")), "-p", f"output:={bag}",
                "-p", f"storage:={opts.storage}", *_p("topics", sorted({t for t in topics.values() if t}))]
    return {"plant": plant, "observer": observer, "controller": controller, "recorder": recorder}


def _run_nodes(out: Path, bag: Path, mech: Mechanism, opts: LoopOptions) -> None:
    domain_id = run_domain_id(opts.domain_id)
    env = ros_env(domain_id)
    logs = out / "logs"
    args = node_arguments(bag, mech, opts)
    procs: list[NodeProcess] = []
    previous = signal.signal(signal.SIGTERM, _interrupt)  # a terminated run stops its nodes too
    try:
        # The plant publishes its t = 0 state at start-up, and again until the first command.
        procs.append(NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", args["plant"], env, logs))
        procs.append(NodeProcess("recorder", "elastic_pm_dyn.ros.recorder.node", args["recorder"], env, logs))
        procs.append(NodeProcess("observer", "elastic_pm_dyn.ros.observer.node", args["observer"], env, logs))
        print(f"  plant (lockstep), recorder and observer started on ROS domain {domain_id}; logs in {logs}")
        with Kicker(domain_id, opts.topics(), pace_on_observer=opts.pace_on_observer) as kick:
            kick.wait_for_graph(opts.timeout, procs, controller=False)
            # A subscriber in the graph is not yet a reader the plant serves (issue #29): the
            # controller starts (and with it the loop) once the recorder has the plant's start
            # state. Started with the others, it could run the whole loop before the recorder
            # was served, and end before this wait did (a CI run).
            wait_for_recording([opts.topics()["truth"]], domain_id, opts.timeout, procs)
            controller = NodeProcess("controller", "elastic_pm_dyn.ros.feedforward.node", args["controller"],
                                     env, logs)
            procs.append(controller)
            print("  every node subscribed, the recorder receiving; controller started")
            how = kick.start_loop(opts.timeout, procs[:3])  # the controller may have finished already
            print(f"  loop running ({how})")
            kick.watch(controller, procs[:3], opts.timeout, logs)
        code = wait_for_exit(controller, procs[:3], opts.timeout)
        if code:
            raise controller.failure(code)
    except BaseException:  # also Ctrl+C: never leave nodes running
        for p in reversed(procs):
            p.stop()
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
    time.sleep(DRAIN)
    for p in (procs[2], procs[1], procs[0]):  # the recorder before the plant: it closes the bag
        p.stop()


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


class Kicker:
    """The orchestrator's own node: waits for every node, then for the loop to start (the plant
    re-publishes its t = 0 state and samples until the first command). Running is told by the
    plant's newest state: its stamp moves on only when commands come."""

    def __init__(self, domain_id: int, topics: dict[str, str | None], localhost: bool = True,
                 pace_on_observer: bool = True):
        import os

        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import JointState
        self._rclpy = rclpy
        # topic -> subscribers it needs: the recorder on the loop's topics, the observer on the
        # commands and sensors, the controller on the encoders and the estimates
        self.needed = Counter({topics[k] for k in ("truth", "estimate", "command", "encoders", "imu", "reference")
                               if topics[k]})
        self.needed.update(t for t in (topics["command"], topics["encoders"], topics["imu"]) if t)
        self.controller_reads = Counter((topics["encoders"], topics["estimate" if pace_on_observer else "truth"]))
        self.sensor_topics = [t for t in (topics["encoders"], topics["imu"]) if t]
        if localhost:  # the demo's loopback-only domain (ros_env); a launch keeps the user's setting
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("elastic_pm_dyn_loop_orchestrator", context=self.context)
        self.newest = -1  # [ns] stamp of the plant's newest state
        self.estimates = 0
        latest = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(JointState, topics["truth"], self._on_state, latest)
        self.node.create_subscription(JointState, topics["estimate"], self._on_estimate, latest)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _on_state(self, msg: Any) -> None:
        self.newest = max(self.newest, stamp_ns(msg.header.stamp))

    def _on_estimate(self, msg: Any) -> None:
        self.estimates += 1

    def __enter__(self) -> Kicker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)

    def _spin_for(self, seconds: float, watch: list[NodeProcess], until=lambda: False) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            for p in watch:
                p.check_running()
            self.executor.spin_once(timeout_sec=0.05)

    def wait_for_graph(self, timeout: float, watch: list[NodeProcess], controller: bool = True) -> None:
        """Until every node reads and writes its topics (``controller`` False: every node but the
        controller)."""
        deadline = time.monotonic() + timeout
        needed = self.needed + self.controller_reads if controller else self.needed
        # the plant's robot_description comes after its t = 0 state: from then on it publishes only on commands
        while (missing := [t for t, n in needed.items() if self.node.count_subscribers(t) < n]
               + [t for t in (*self.sensor_topics, "/robot_description") if not self.node.count_publishers(t)]):
            if time.monotonic() > deadline:
                raise NodeProcessError(f"no complete loop within {timeout:g} s: missing readers or writers on "
                                       f"{', '.join(missing)} (does the plant simulate its sensors?)")
            self._spin_for(0.05, watch)

    def watch(self, controller: NodeProcess, others: list[NodeProcess], timeout: float, logs: Path) -> None:
        """Until the controller ends: a loop whose plant state stops moving for :data:`STALL` s
        has stalled (an observer that stopped publishes no estimate to pace the controller)."""
        deadline = time.monotonic() + timeout
        last, since = self.newest, time.monotonic()
        while controller.proc.poll() is None and time.monotonic() < deadline:
            self._spin_for(0.2, others)
            if self.newest != last:
                last, since = self.newest, time.monotonic()
            elif time.monotonic() - since > STALL:
                raise NodeProcessError(f"the loop stalled at t = {last * 1e-9:.6f} s: no plant state for {STALL:g} s "
                                       f"(an observer that stopped? see {logs / 'observer.log'})")

    def start_loop(self, timeout: float, watch: list[NodeProcess]) -> str:
        """Wait for the loop to start by itself: the lockstep plant publishes its t = 0 state and
        samples again until the first command, so every node gets them however late it
        subscribed. No reset: one that crossed a slow first command (a loaded machine) sent the
        plant back to t = 0 under a controller that had answered that stamp already, and the loop
        stalled at t = 0.001 s."""
        self._spin_for(timeout, watch, lambda: self.newest > 0)
        if self.newest > 0:
            return "from the plant's t = 0 state"
        raise NodeProcessError(f"the loop did not start within {timeout:g} s (see the node logs)")


# ------------------------------------------------------------------------------------ analysis
@dataclass
class _Stamped:
    ns: np.ndarray  # (N,) int64 header stamps
    names: list[str]
    values: dict[str, np.ndarray]


def _read_topics(bag: Path, wanted: dict[str, str]) -> dict[str, _Stamped]:
    """JointState / BranchForces / Imu topics with integer stamps (and BranchForces' force_stddev)."""
    fields = {JOINT_STATE: ("position", "velocity", "effort"),
              BRANCH_FORCES: ("force", "force_stddev", "deflection", "deflection_rate")}
    rows: dict[str, dict[str, list]] = {}
    names: dict[str, list[str]] = {}
    with open_bag(bag) as b:
        conns = [c for c in b.connections if c.topic in wanted.values() and c.msgtype in (*fields, IMU)]
        for conn, _, msg in b.decoded(conns):
            r = rows.setdefault(conn.topic, {"ns": []})
            r["ns"].append(stamp_ns(msg.header.stamp))
            if conn.msgtype == IMU:
                a = msg.linear_acceleration
                r.setdefault("accel", []).append([a.x, a.y, a.z])
                names.setdefault(conn.topic, ["x", "y", "z"])
                continue
            names.setdefault(conn.topic, list(msg.name))
            for f in fields[conn.msgtype]:
                r.setdefault(f, []).append(np.asarray(getattr(msg, f), dtype=float))
    out = {}
    for topic, r in rows.items():
        ns = np.array(r.pop("ns"), dtype=np.int64)
        out[topic] = _Stamped(ns, names[topic], {f: np.array([np.asarray(x) for x in v]).reshape(len(ns), -1)
                                                  for f, v in r.items()})
    return out


def _at(s: _Stamped, stamps: np.ndarray, field_: str, names: list[str]) -> np.ndarray:
    """Rows of ``s`` at ``stamps`` (each present: the last message of that stamp), columns ``names``."""
    idx = {int(ns): i for i, ns in enumerate(s.ns)}
    rows = np.array([idx[int(ns)] for ns in stamps], dtype=np.int64)
    cols = [s.names.index(n) for n in names]
    return s.values[field_][rows][:, cols]


def observer_input_bag(bag: Path, out: Path, first_ns: int, topics: dict[str, str | None]) -> Path:
    """The observer's input topics of ``bag`` from ``first_ns`` on (what the live observer saw), in the
    order it takes them per stamp: accelerometer, encoders, then the command (its subscriptions
    are served in that order when several messages wait)."""
    rank = {t: k for k, t in enumerate((topics["imu"], topics["encoders"], topics["command"])) if t}
    msgs = []
    seen: set[tuple[str, int]] = set()
    with open_bag(bag) as b:
        conns = [c for c in b.connections if c.topic in rank]
        for i, (conn, _, raw) in enumerate(b.messages(conns)):
            ns = stamp_ns(b.deserialize(raw, conn.msgtype).header.stamp)
            sample = (conn.topic, ns)
            if ns >= first_ns and not (conn.topic != topics["command"] and sample in seen):
                msgs.append((ns, rank[conn.topic], i, conn, raw))
                seen.add(sample)  # a sample published again (the lockstep plant's first state) once, as live
    if out.exists():
        shutil.rmtree(out)
    with BagWriter(out) as w:
        made = {}
        for ns, _, _, conn, raw in sorted(msgs, key=lambda m: m[:3]):
            if conn.topic not in made:
                made[conn.topic] = w.add_connection(conn.topic, conn.msgtype)
            w.write(made[conn.topic], ns + 1000 * rank[conn.topic], raw)
    return out


def analyse_loop(out: Path, bag: Path, mech: Mechanism, opts: LoopOptions, wall: float) -> dict:
    """Bag -> summary.json and plots (module docstring)."""
    series = read_series(bag)
    topics = opts.topics()
    data = _read_topics(bag, {k: t for k, t in topics.items() if t})
    missing = [topics[k] for k in ("truth", "truth_forces", "estimate", "estimate_forces", "command", "encoders")
               if topics[k] not in data]
    if missing:
        raise InputError(f"{bag}: no messages on {', '.join(missing)} (see {out / 'logs'})")
    truth, est, cmd, enc = (data[topics[k]] for k in ("truth", "estimate", "command", "encoders"))
    first = int(est.ns[0])  # the loop: from the first estimate (the plant's t = 0 state) on
    # Samples: stamps with a true state, an estimate and the command computed for them.
    # Every period of the loop: a true state and the command computed for it (the open loop and
    # the scores need them all); the live estimates are compared where they exist (all of them
    # when the observer paces the loop).
    stamps = np.intersect1d(truth.ns, cmd.ns)
    stamps = stamps[stamps >= first]
    if len(stamps) < 10:
        raise InputError(f"{bag}: only {len(stamps)} loop periods recorded (see {out / 'logs'})")
    t = (stamps - stamps[0]) * 1e-9
    names, active = mech.joint_names, mech.active_names
    branches = [b.name for b in mech.model.branches]
    q = _at(truth, stamps, "position", names)
    qd = _at(truth, stamps, "velocity", names)
    F = _at(data[TOPICS["truth_forces"]], stamps, "force", branches)
    tau = _at(cmd, stamps, "effort", active)
    have_enc = np.isin(stamps, enc.ns)
    encoder = np.full((len(stamps), len(active)), np.nan)
    encoder[have_enc] = _at(enc, stamps[have_enc], "position", active)
    dist = np.zeros_like(tau)
    if TOPICS["disturbance"] in data:
        d = data[TOPICS["disturbance"]]
        ok = np.isin(stamps, d.ns)
        dist[ok] = _at(d, stamps[ok], "effort", active)
    cfg = load_config(opts.observer_file())
    rec = Recording(mech, t, stamps, tau, dist, q, qd, np.zeros((len(t), 3)), F, encoder,
                    np.zeros((len(t), 3)), np.zeros_like(F), Noise(encoder=ENCODER_STDDEV, accelerometer=IMU_STDDEV),
                    label="ros loop")

    # live estimates at the same stamps
    ef = data[TOPICS["estimate_forces"]]
    live = np.isin(stamps, np.intersect1d(est.ns, ef.ns))
    F_live = np.full_like(F, np.nan)
    F_std = np.full_like(F, np.nan)
    q_live = np.full_like(q, np.nan)
    F_live[live] = _at(ef, stamps[live], "force", branches)
    F_std[live] = _at(ef, stamps[live], "force_stddev", branches)
    q_live[live] = _at(est, stamps[live], "position", names)

    # observe over the recorded sensor topics, from the first sample the live observer had
    obs_bag = observer_input_bag(bag, out / "observer_input", first, topics)
    cfg_live = cfg.with_overrides(sensors=opts.sensors, **{"imu.sample_timing": opts.imu_sample_timing},
                                  **{"topics.measured_joint_states": topics["encoders"]},
                                  **({"imu.axes": ["x", "y", "z"]} if len(mech.ee_components) == 3 else {}))
    offline = observe_bag(mech, cfg_live, obs_bag, None, order="arrival", log=lambda s: None)
    rows = offline.rows
    identical, diff, compared = compare_live_offline(est, ef, rows)

    ol = open_loop_prediction(rec)
    run = offline_run(rec, rows)
    F_qs = quasi_static_series(rec)
    scores = score(rec, run, ol, F_qs)
    valid = np.all(np.isfinite(ol.F), axis=1)  # the open loop up to a singular pose, if it met one
    keep = (t >= 0.02 - 1e-12) & live & valid  # after the settling time score() uses
    rms = lambda x, k=keep: float(np.sqrt(np.mean(np.square(x[k]))))  # noqa: E731
    err_live, err_ol = rms(F_live - F), rms(ol.F - F)
    # The same after the start: a plant that starts off the observer's initial state (springs at
    # rest under gravity, where the observer assumes them in equilibrium) rings for ~0.1 s first
    late = (t >= LATE - 1e-12) & live & valid
    late_scores = score(rec, run, ol, F_qs, settle=LATE) if np.any(late) else None

    # the controller used the encoder sample of each stamp: its command is the PD law on it
    ref = data.get(TOPICS["reference"])
    pd_check = _check_pd(ref, enc, cmd, stamps, opts, mech) if ref is not None else None

    summary: dict[str, Any] = {
        "model": str(opts.model), "elastic_dof_per_chain": opts.elastic_dof_per_chain, "seed": opts.seed,
        "duration_s": opts.duration, "bag": str(bag), "run_wall_time_s": round(wall, 3),
        "options": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(opts).items()},
        "observer_config": str(opts.observer_file()),
        "messages": {topic: len(s.t) for topic, s in series.items()},
        "loop_periods": len(stamps),
        "estimates": len(est.ns),
        # distinct stamps: the lockstep plant publishes its first state again until a command comes
        "plant_states_in_loop": len(np.unique(truth.ns[truth.ns >= first])),
        "plant_states_without_estimate": len(np.setdiff1d(truth.ns[truth.ns >= first], est.ns)),
        "estimates_per_stamp_max": int(np.unique(est.ns, return_counts=True)[1].max()),
        "encoder_samples_in_loop": len(np.unique(enc.ns[enc.ns >= first])),
        "branch_force_error_rms_N": err_live,
        "branch_force_error_rms_open_loop_N": err_ol,
        "branch_force_error_ratio_to_open_loop": err_live / err_ol if err_ol > 0 else float("nan"),
        "elastic_force_rms_N": scores["elastic_rms_N"],
        f"after_{LATE:g}s": None if late_scores is None else {
            "branch_force_error_rms_N": rms(F_live - F, late),
            "branch_force_error_rms_open_loop_N": rms(ol.F - F, late),
            "branch_force_error_ratio_to_open_loop": rms(F_live - F, late) / rms(ol.F - F, late),
            "nees_mean": late_scores["nees_mean"], "nees_in_band": late_scores["nees_in_band"]},
        "F_ratio": scores["F_ratio"], "F_ratio_open_loop": scores["F_ratio_open_loop"],
        "nees_mean": scores["nees_mean"], "nees_in_band": scores["nees_in_band"], "nees_band": scores["nees_band"],
        "nees_dof": 2 * len(mech.ae),
        "nees_from": "observe over the recorded bag (the live messages carry no covariance); "
                     "equal to the live estimates where live_equals_offline",
        "motor_rmse_rad": scores["motor_rmse_rad"],
        "force_stddev_mean_N": float(np.mean(F_std[keep])),
        "live_equals_offline": identical, "live_offline_max_difference": diff,
        "live_offline_compared_rows": compared, "offline_rows": len(rows.t),
        "observer_sensors": {k: {"accepted": v, "rejected": scores["rejected"][k]}
                             for k, v in scores["accepted"].items()},
        "controller": pd_check,
        "plant_integrator": " ".join(plant_numerics(mech)[1::2]) or "rk4 dt 1e-4 (config/plant_sensors.yaml)",
        "open_loop": "the plant's integrator (" + (" ".join(plant_numerics(mech)[1::2]) or "rk4 dt 1e-4")
                     + ") from the true start state under the recorded commands, without the disturbance",
        "periods_with_live_estimate": int(live.sum()),
        "open_loop_compared_until_s": float(t[valid][-1]) if np.any(valid) else 0.0,
        "disturbance_recorded": TOPICS["disturbance"] in data,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=_json))
    _plots(out, mech, t, F, F_live, F_std, ol.F, branches, q, q_live, stamps, cmd, rec)
    print(f"  plots (branch_forces, path, torques) and summary.json in {out}")
    for key in ("loop_periods", "branch_force_error_rms_N", "branch_force_error_rms_open_loop_N",
                "branch_force_error_ratio_to_open_loop", "nees_in_band", "live_equals_offline",
                "live_offline_max_difference"):
        print(f"  {key}: {summary[key]}")
    return summary


def compare_live_offline(est: _Stamped, ef: _Stamped, rows: Any) -> tuple[bool, float, int]:
    """(bit-identical, largest difference, rows compared): the live estimates (joint positions and
    rates, branch forces and their standard deviations) against ``observe``'s rows of the same stamps."""
    row_of = {int(ns): i for i, ns in enumerate(rows.t)}
    ef_row = {int(ns): i for i, ns in enumerate(ef.ns)}
    identical = len(est.ns) == len(rows.t) == len(ef.ns)
    diff, compared = 0.0, 0
    for i, ns in enumerate(est.ns):
        r, j = row_of.get(int(ns)), ef_row.get(int(ns))
        if r is None or j is None:
            identical = False
            continue
        e = rows.est[r]
        for live, off in ((est.values["position"][i], e.q), (est.values["velocity"][i], e.qd),
                          (ef.values["force"][j], e.branch_force), (ef.values["force_stddev"][j], e.branch_force_std)):
            diff = max(diff, float(np.max(np.abs(live - off))))
            identical &= bool(np.array_equal(live, off))
        compared += 1
    return identical, diff, compared


def _json(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


def _check_pd(ref: _Stamped, enc: _Stamped, cmd: _Stamped, stamps: np.ndarray, opts: LoopOptions,
              mech: Mechanism) -> dict:
    """Recompute each command from the reference, the encoder sample of its stamp and the one
    before (the node's own arithmetic, :func:`pd_torque`): equal bit for bit if the node used them.
    The first command's rate is zero or differenced from a sample before the loop, depending on
    whether the controller had matched by then; a sample published again (the lockstep plant's
    first, until a command comes) is one sample."""
    active = mech.active_names
    kp, kd = _gains_used(opts, mech)
    enc_idx = {int(ns): i for i, ns in enumerate(enc.ns)}
    ref_idx = {int(ns): i for i, ns in enumerate(ref.ns)}
    cols_enc = [enc.names.index(n) for n in active]
    cols_ref = [ref.names.index(n) for n in active]
    tau = _at(cmd, stamps, "effort", active)
    matched = worst = 0
    worst_diff = 0.0
    for k, ns in enumerate(stamps):
        i, r = enc_idx.get(int(ns)), ref_idx.get(int(ns))
        if i is None or r is None:
            continue
        q_m = enc.values["position"][i][cols_enc]
        rates = []
        if enc.values["velocity"].shape[1] == len(enc.names):  # the sample's own rates
            rates.append(enc.values["velocity"][i][cols_enc])
        else:
            j = i - 1
            while j >= 0 and enc.ns[j] == enc.ns[i]:  # the plant's first sample published again
                j -= 1
            if j >= 0:
                dt = (int(enc.ns[i]) - int(enc.ns[j])) * 1e-9
                rates.append((q_m - enc.values["position"][j][cols_enc]) / dt)
            if j < 0 or k == 0:
                rates.append(np.zeros(len(active)))
        d = min(float(np.abs(pd_torque(ref.values["effort"][r][cols_ref], ref.values["position"][r][cols_ref],
                                       ref.values["velocity"][r][cols_ref], q_m, qd_m, kp, kd) - tau[k]).max())
                for qd_m in rates)
        worst_diff = max(worst_diff, d)
        matched += d == 0.0
        worst += 1
    return {"kp": kp.tolist(), "kd": kd.tolist(), "commands_checked": worst,
            "commands_equal_to_pd_on_their_sample": matched, "max_difference_N_m": worst_diff}


def _gains_used(opts: LoopOptions, mech: Mechanism) -> tuple[np.ndarray, np.ndarray]:
    kp, kd = default_gains(mech, opts.bandwidth, opts.damping)
    kp = np.broadcast_to(opts.kp if opts.kp is not None else kp, kp.shape).astype(float)
    kd = np.broadcast_to(opts.kd if opts.kd is not None else kd, kd.shape).astype(float)
    return kp, kd


def _plots(out: Path, mech: Mechanism, t: np.ndarray, F: np.ndarray, F_live: np.ndarray, F_std: np.ndarray,
           F_ol: np.ndarray, branches: list[str], q: np.ndarray, q_live: np.ndarray, stamps: np.ndarray,
           cmd: _Stamped, rec: Recording) -> None:
    from matplotlib.figure import Figure
    n = len(branches)
    # per branch: the forces (left) and the errors against the truth with the stated band (right)
    fig = Figure(figsize=(12.0, 2.2 * n + 0.8), dpi=110, layout="constrained")
    axes = fig.subplots(n, 2, squeeze=False)
    for i, name in enumerate(branches):
        ax, ae = axes[i]
        ax.plot(t, F[:, i], "k", lw=0.8, label="true")
        ax.plot(t, F_live[:, i], "C0", lw=0.7, label="estimate (live)")
        ax.plot(t, F_ol[:, i], "C3", lw=0.6, alpha=0.7, label="open loop")
        ax.set_ylabel(f"{name} [N]")
        ae.fill_between(t, -2 * F_std[:, i], 2 * F_std[:, i], color="C0", alpha=0.25, lw=0, label="+- 2 sigma (stated)")
        ae.plot(t, F_ol[:, i] - F[:, i], "C3", lw=0.6, alpha=0.7, label="open loop - true")
        ae.plot(t, F_live[:, i] - F[:, i], "C0", lw=0.7, label="estimate - true")
        ae.set_ylabel("error [N]")
        for a_ in (ax, ae):
            a_.grid(True, alpha=0.3)
    axes[0, 0].set_title("branch forces")
    axes[0, 1].set_title("errors against the truth")
    axes[0, 0].legend(loc="best", fontsize="x-small")
    axes[0, 1].legend(loc="best", fontsize="x-small")
    for a_ in axes[-1]:
        a_.set_xlabel("time [s]")
    fig.savefig(out / "branch_forces.png")
    ee_true = np.array([mech.end_effector(x) for x in q])
    ee_est = np.array([mech.end_effector(x) for x in q_live if np.all(np.isfinite(x))]).reshape(-1, len(ee_true[0]))
    plots.plot_path(out / "path.png", {"plant (truth)": ee_true, "observer estimate": ee_est})
    active = mech.active_names
    tau = _at(cmd, stamps, "effort", active)
    plots.plot_torques(out / "torques.png", t, {n: tau[:, k] for k, n in enumerate(active)})


def start_loop_main(argv: list[str] | None = None) -> int:
    """``python -m elastic_pm_dyn.ros.demos.loop_demo``: start a closed loop that a launch file brought
    up (launch/closed_loop.launch.py) on this ROS domain: wait for every node and for the loop to
    start (from the plant's t = 0 state, which it publishes again until the first command), exit."""
    import argparse
    import os
    import sys
    p = argparse.ArgumentParser(prog="python -m elastic_pm_dyn.ros.demos.loop_demo",
                                description=start_loop_main.__doc__)
    p.add_argument("--timeout", type=float, default=300.0, help="[s] for the nodes to come up and the loop to start")
    args = p.parse_args(argv)
    try:
        with Kicker(int(os.environ.get("ROS_DOMAIN_ID", "0")), dict(TOPICS), localhost=False) as kick:
            kick.wait_for_graph(args.timeout, [])
            print(f"loop running ({kick.start_loop(args.timeout, [])})")
    except NodeProcessError as err:
        print(f"loop_demo: error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(start_loop_main())
