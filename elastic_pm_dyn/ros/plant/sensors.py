"""The plant node's simulated sensors and unknown disturbance torque (parameters ``sensors.*`` and
``disturbance.*``); the numbers come from :mod:`elastic_pm_dyn.sim.sensors` and
:mod:`elastic_pm_dyn.sim.disturbances`, this module only declares, validates and publishes.

Sensors (each off by default; with all off and no disturbance the node's topics are what
they were without this module), published on the observer's default input topics, stamped
with the plant's state stamps:
- ``measured_joint_states`` (sensor_msgs/JointState): the motors' encoder angles (and rates);
- ``ee_imu`` (sensor_msgs/Imu, linear_acceleration): the end effector's accelerometer. The
  sample of t_k is a(t_k-) (``before_command``: published with the state of t_k) or a(t_k+)
  (``after_command``: under the command that starts to act at t_k, published when that
  command is applied: in lockstep when it arrives, before the state of t_k+1);
- ``measured_branch_forces`` (elastic_pm_dyn_msgs/BranchForces, force only): strain gauges.

Disturbance: a spectrum d(t) (``disturbance.spectrum``, the offline recordings' generator)
plus, with ``disturbance.input``, a torque received on ``topics.disturbance_torque`` (the
command's message type), held until its ``disturbance.timeout``. Their sum at t_k (the held part
of the period that ended) goes to the truth topic ``topics.disturbance``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from elastic_pm_dyn_msgs.msg import BranchForces
from rclpy.node import Node
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu, JointState

from elastic_pm_dyn.bags import cdr
from elastic_pm_dyn.bags.msgtypes import NS
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.messages import SerializedMessage, doubles, stamp
from elastic_pm_dyn.ros.params import Param, ParameterError
from elastic_pm_dyn.ros.qos import STATE_OUT_QOS
from elastic_pm_dyn.sim.disturbances import SPECTRA, SpectrumDisturbance, seeded_disturbance
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.sensors import SAMPLE_TIMINGS, EncoderSpec, GaugeSpec, ImuSpec, SensorModel, SensorSpec

SENSOR_PARAMS = [
    Param("sensors.seed", 0, "seed of the sensor noise (each sensor its own stream of it)"),
    Param("sensors.encoders.enabled", False,
          "publish the motors' encoder angles on sensors.topics.measured_joint_states"),
    Param("sensors.encoders.position_stddev", 2.0e-5, "[rad or m] Gaussian noise of the angles"),
    Param("sensors.encoders.velocity", False, "also publish the motors' rates (velocity field)"),
    Param("sensors.encoders.velocity_stddev", 1.0e-2, "[rad/s or m/s] Gaussian noise of the rates"),
    Param("sensors.encoders.counts_per_revolution", 0, "revolute motors: angles rounded to 2 pi / counts; 0 = none"),
    Param("sensors.encoders.counts_per_metre", 0, "prismatic motors: positions rounded to 1 m / counts (a linear "
          "scale's 1 / resolution); 0 = none"),
    Param("sensors.imu.enabled", False, "publish the end effector's accelerometer on sensors.topics.ee_imu"),
    Param("sensors.imu.frame_id", "ee_imu", "header.frame_id of the Imu messages"),
    Param("sensors.imu.rpy", [0.0, 0.0, 0.0], "[rad] sensor axes w.r.t. the world (world-fixed mounting)"),
    Param("sensors.imu.specific_force", True, "read a - g (an accelerometer) rather than a"),
    Param("sensors.imu.sample_timing", "before_command", "before_command: a(t_k-) under the last period's torque, "
          "with the state; after_command: a(t_k+) under the command of t_k, published when it is applied",
          choices=SAMPLE_TIMINGS),
    Param("sensors.imu.stddev", 0.02, "[m/s^2] Gaussian noise per axis"),
    Param("sensors.imu.bias", [0.0, 0.0, 0.0], "[m/s^2] constant bias on the sensor axes"),
    Param("sensors.branch_forces.enabled", False, "publish strain gauges on sensors.topics.measured_branch_forces"),
    Param("sensors.branch_forces.stddev", 0.5, "[N] Gaussian noise of the branch forces"),
    Param("sensors.topics.measured_joint_states", "measured_joint_states", "encoders: sensor_msgs/JointState"),
    Param("sensors.topics.ee_imu", "ee_imu", "accelerometer: sensor_msgs/Imu (linear_acceleration)"),
    Param("sensors.topics.measured_branch_forces", "measured_branch_forces",
          "strain gauges: elastic_pm_dyn_msgs/BranchForces (force)"),
]
DISTURBANCES = ("none", *SPECTRA)
MAX_DISTURBANCE_RMS = 1.0e4  # [N m or N] far beyond any motor; larger only faults the plant
MAX_DISTURBANCE_DURATION = 60.0  # [s] its RMS is scaled on a 0.1 ms grid over it: ~0.4 s of start-up per second
DISTURBANCE_PARAMS = [
    Param("disturbance.spectrum", "none", "unknown torque on the motors: none | flat | pink | tones | drift",
          choices=DISTURBANCES),
    Param("disturbance.rms", 0.02, "[N m or N] RMS per motor over disturbance.duration (at most 1e4)"),
    Param("disturbance.band", [], "[Hz] [low, high] of the spectrum; unset = its own (flat, pink 2-200, tones "
          "5-150, drift 0.05-1)", item=float),
    Param("disturbance.seed", 0, "seed: a test recording with this seed and duration has the same d(t)"),
    Param("disturbance.duration", 1.0, "[s] window over which the RMS is scaled (periodic beyond; above 0, at most 60)",
          positive=True),
    Param("disturbance.input", False, "subscribe topics.disturbance_torque: an unknown torque added to the command"),
    Param("disturbance.timeout", 0.1, "[s] an older disturbance_torque means zero (as command_timeout: on the "
          "plant's clock, simulated time; wall time in realtime with overrun skip)", positive=True, runtime=True),
    Param("topics.disturbance_torque", "disturbance_torque", "input: disturbance torque (command_type's message)"),
    Param("topics.disturbance", "disturbance", "truth: sensor_msgs/JointState, effort = the disturbance on the motors"),
]


def sensor_spec(p: dict[str, Any]) -> SensorSpec:
    """The ``sensors.*`` parameters as a :class:`SensorSpec`; ParameterError (one line) when out of range."""
    e, i = "sensors.encoders.", "sensors.imu."
    spec = SensorSpec(
        encoders=EncoderSpec(p[e + "enabled"], p[e + "position_stddev"], p[e + "velocity"], p[e + "velocity_stddev"],
                             p[e + "counts_per_revolution"], p[e + "counts_per_metre"]),
        imu=ImuSpec(p[i + "enabled"], p[i + "frame_id"], tuple(p[i + "rpy"]), p[i + "specific_force"],
                    p[i + "sample_timing"], p[i + "stddev"], tuple(p[i + "bias"])),
        branch_forces=GaugeSpec(p["sensors.branch_forces.enabled"], p["sensors.branch_forces.stddev"]),
        seed=p["sensors.seed"])
    try:
        spec.validate()
    except InputError as err:
        raise ParameterError(f"parameter {err}") from None
    return spec


def spectrum_disturbance(p: dict[str, Any], channels: int) -> SpectrumDisturbance | None:
    """The ``disturbance.*`` spectrum, or None; ParameterError (one line) when out of range."""
    rms, band, seed = p["disturbance.rms"], p["disturbance.band"], p["disturbance.seed"]
    if not (np.isfinite(rms) and 0 <= rms <= MAX_DISTURBANCE_RMS):
        raise ParameterError(f"parameter 'disturbance.rms' must be a number in [0, {MAX_DISTURBANCE_RMS:g}] "
                             f"[N m or N], got {rms!r}")
    duration = p["disturbance.duration"]
    if not 0 < duration <= MAX_DISTURBANCE_DURATION:
        raise ParameterError(f"parameter 'disturbance.duration' must be in (0, {MAX_DISTURBANCE_DURATION:g}] s "
                             f"(its spectrum is scaled on a 0.1 ms grid over it; periodic beyond), got {duration!r}")
    if band and not (len(band) == 2 and np.all(np.isfinite(band)) and 0 < band[0] < band[1]):
        raise ParameterError(f"parameter 'disturbance.band' must be [low, high] with 0 < low < high [Hz], got {band!r}")
    if seed < 0:
        raise ParameterError(f"parameter 'disturbance.seed' must be >= 0, got {seed}")
    if p["disturbance.spectrum"] == "none":
        return None
    return seeded_disturbance(p["disturbance.spectrum"], channels, rms, p["disturbance.duration"], seed,
                              tuple(band) if band else None)


class SensorOutputs:
    """Publishers of the enabled sensors and the samples they publish (noise from :class:`SensorModel`).
    Each message is serialized once and refilled in place, as the plant's own topics are
    (:class:`~elastic_pm_dyn.ros.messages.SerializedMessage`): three rclpy messages built per period
    cost about as much as the plant's step."""

    def __init__(self, node: Node, plant: Plant, spec: SensorSpec, p: dict[str, Any]):
        self.plant, self.spec = plant, spec
        self.model = SensorModel(plant.mech, spec, plant.options.formulation)
        mech = plant.mech
        n_a, n_b = len(mech.active), len(mech.model.branches)
        self.after = spec.imu.sample_timing == "after_command"
        self.pub_encoders = self.pub_imu = self.pub_gauges = None
        self.imu_published = False
        if spec.encoders.enabled:
            self.pub_encoders = node.create_publisher(JointState, p["sensors.topics.measured_joint_states"],
                                                      STATE_OUT_QOS)
            names = list(mech.active_names)
            self.encoders = SerializedMessage(lambda a: cdr.encode_joint_state(0, names, *a),
                                              (n_a, n_a if spec.encoders.velocity else 0, 0))
        if spec.imu.enabled:
            self.pub_imu = node.create_publisher(Imu, p["sensors.topics.ee_imu"], STATE_OUT_QOS)
            self.imu = SerializedMessage(lambda a: serialize_message(_imu_template(spec.imu, a[0])), (3,))
        if spec.branch_forces.enabled:
            self.pub_gauges = node.create_publisher(BranchForces, p["sensors.topics.measured_branch_forces"],
                                                    STATE_OUT_QOS)
            branches = [b.name for b in mech.model.branches]
            self.gauges = SerializedMessage(lambda a: cdr.encode_branch_forces(0, branches, *a), (n_b, 0, 0, 0))

    def publish_state(self, ns: int, branch_force: np.ndarray) -> None:
        """The samples of the state at ``ns`` (the accelerometer here only when it samples before the command)."""
        plant = self.plant
        sec, nanosec = divmod(ns, NS)
        # The encoders last: an observer publishes its estimate of t_k on the joint state of t_k,
        # holding the samples that came before it (each sensor draws from its own noise stream,
        # so the order changes no value).
        if self.pub_imu is not None and not self.after:
            self.publish_imu(ns, plant.motor_torque())
        if self.pub_gauges is not None:
            self.gauges.set_stamp(sec, nanosec)
            self.gauges.arrays[0][:] = self.model.branch_forces(branch_force)
            self.pub_gauges.publish(self.gauges.raw())
        if self.pub_encoders is not None:
            position, velocity = self.model.encoders(plant.q, plant.qd)
            m = self.encoders
            m.set_stamp(sec, nanosec)
            m.arrays[0][:] = position
            if velocity is not None:
                m.arrays[1][:] = velocity
            self.pub_encoders.publish(m.raw())

    def publishers(self) -> list[Any]:
        """The sensors' publishers (a lockstep plant waiting for its first command looks at their readers)."""
        return [p for p in (self.pub_encoders, self.pub_imu, self.pub_gauges) if p is not None]

    def publish_again(self) -> None:
        """The samples published last, once more, the same bytes (the noise is drawn once per stamp;
        an accelerometer sampling after the command has published nothing before it)."""
        if self.pub_imu is not None and not self.after and self.imu_published:
            self.pub_imu.publish(self.imu.raw())
        if self.pub_gauges is not None:
            self.pub_gauges.publish(self.gauges.raw())
        if self.pub_encoders is not None:  # last, as in publish_state
            self.pub_encoders.publish(self.encoders.raw())

    def publish_imu(self, ns: int, torque: np.ndarray) -> None:
        """The accelerometer at the plant's state under the motor ``torque`` (commands + disturbance)
        and the external wrench."""
        if self.pub_imu is None:
            return
        self.imu.set_stamp(*divmod(ns, NS))
        self.imu.arrays[0][:] = self.model.accelerometer(self.plant.q, self.plant.qd, torque,
                                                         self.plant.wrench_tree_forces())
        self.pub_imu.publish(self.imu.raw())
        self.imu_published = True


def _imu_template(spec: ImuSpec, acceleration: np.ndarray) -> Imu:
    msg = Imu()
    msg.header.frame_id = spec.frame_id
    msg.orientation_covariance[0] = -1.0  # not measured (REP 145)
    msg.angular_velocity_covariance[0] = -1.0
    msg.linear_acceleration_covariance = doubles(np.diag(np.full(3, spec.stddev ** 2)).ravel())
    a = msg.linear_acceleration
    a.x, a.y, a.z = (float(v) for v in acceleration)
    return msg


def disturbance_message(names: list[str], ns: int, effort: np.ndarray) -> JointState:
    msg = JointState(name=names)
    msg.header.stamp = stamp(ns)
    msg.effort = doubles(effort)
    return msg
