"""Observer configuration: sensors, noise levels, process noise, gating.

One source of truth for the offline command and the plant node in ``mode: observer``:
the parameters live under the ``observer.`` prefix of a standard ``ros__parameters``
file (``config/observer.yaml``), so they can sit in the plant node's own parameter file.
ROS flattens nested YAML maps into dotted names; :data:`DEFAULT_PARAMETERS` lists every
flat name with its default (the node declares exactly these), and
:meth:`ObserverConfig.from_parameters` builds the typed configuration from such a flat
mapping, whichever way it was obtained (node parameters or a YAML file).

Joint lists accept role keywords besides joint names: ``active``, ``elastic``, ``passive``,
``all`` (ROS parameter files cannot hold an empty list, so "every motor" is ``[active]``).
A noise list is either one value for every entry or one value per entry.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model import yaml12

PREFIX = "observer."
SENSOR_KINDS = ("encoders", "imu", "branch_forces")
DISTURBANCE_MODELS = ("none", "random_walk", "gauss_markov", "integrated_random_walk", "band_limited",
                      "bias_band_limited")
WRENCH_MODELS = ("none", "random_walk")  # process.wrench: the end-effector wrench as states, or not
BAND_MODELS = ("band_limited", "bias_band_limited")  # the disturbance models with band corners and an order
BAND_ORDERS = (2, 4)  # Butterworth orders of a disturbance band
INTEGRATORS = ("etd2", "rk4")  # of the mean (process.integrator): fixed-step rows of sim/integrators.py's METHODS
LINEARIZATIONS = ("springs", "differences")  # of the covariance (process.linearization)
BRANCH_SOURCES = ("branch_forces", "joint_state_effort")
SAMPLE_TIMINGS = ("before_command", "after_command", "auto")
AXES = ("x", "y", "z")
AUTO_AXES = "auto"  # imu.axes: the sensor axes in the machine's plane (planar), all three (spatial)

# Every parameter (without the "observer." prefix) and its default. Floats are floats,
# so that a ROS node can declare them with the right type.
# What may change while a filter runs (Observer.set_measurement_noise): the sensors' noise levels
# and the gate; everything else shapes the state, the model or the schedule.
RUNTIME_PARAMETERS = ("encoders.position_stddev", "encoders.velocity_stddev", "imu.stddev", "branch_forces.stddev",
                      "gating.probability")
DEFAULT_PARAMETERS: dict[str, Any] = {
    "sensors": ["encoders", "imu"],
    # --- sensors
    "encoders.position_joints": ["active"],
    "encoders.position_stddev": [2.0e-5],  # [rad or m]
    "encoders.velocity_joints": ["none"],
    "encoders.velocity_stddev": [1.0e-2],  # [rad/s or m/s]
    "imu.chain": "",  # chain whose end carries the accelerometer; "" = the end effector
    "imu.frame_id": "",  # expected header.frame_id of sensor_msgs/Imu; "" = accept any
    "imu.rpy": [0.0, 0.0, 0.0],  # sensor axes in the world frame (roll, pitch, yaw) [rad]
    "imu.axes": [AUTO_AXES],  # measured sensor axes; auto: those in the machine's plane (planar), x, y, z (spatial)
    "imu.stddev": [0.02],  # [m/s^2]
    "imu.specific_force": True,  # True: the sensor reads a - g (a real accelerometer)
    "imu.sample_timing": "auto",  # the sample of t_k: before_command | after_command (a(t_k+)) | auto (from the data)
    "branch_forces.source": "branch_forces",  # branch_forces (BranchForces msg) | joint_state_effort
    "branch_forces.branches": ["all"],
    "branch_forces.stddev": [0.5],  # [N]
    "command_delay": 0.0,  # [s] actuation latency: the command stamped t_k acts from t_k + command_delay
    # --- process model
    "process.integrator": "etd2",  # the mean's integrator: etd2 (the plant's; springs exact) | rk4
    "process.dt": 0.0,  # [s] its step: etd2 0 = one step per interval; rk4 0 = from the fastest elastic mode
    "process.linearization": "springs",  # springs (elastic columns from the springs, motors differenced) |
    #                                      differences (every column differenced, dense expm: the reference)
    "process.max_interval": 1.0e-3,  # [s] longest prediction piece
    "process.relinearize_every": 8,  # prediction pieces per linearisation (Phi, Q and the accelerometer's H)
    "process.disturbance": "bias_band_limited",  # see DISTURBANCE_MODELS
    "process.disturbance_joints": ["active"],
    "process.disturbance_intensity": 3.0e-4,  # random walk (bias): PSD of d' [(N m)^2/s]; integrated: of d''
    #                                         [(N m)^2/s^3]
    "process.disturbance_stddev": 0.02,  # gauss_markov, band_limited: stationary std [N m]
    "process.disturbance_bandwidth": [5.0, 50.0],  # band_limited: corner frequencies [Hz] (a sum, equal variance each)
    "process.disturbance_band_order": 2,  # band_limited: Butterworth order of each band (2 or 4)
    "process.disturbance_time_constant": 0.02,  # gauss_markov: correlation time [s]
    # the external wrench on the end effector as task-space disturbance states (docs/state_observer.md,
    # "External wrench"): none (default) | random_walk
    "process.wrench": "none",
    "process.wrench_intensity": 10.0,  # random walk: PSD of a force component's rate [N^2/s]
    "process.wrench_torque_intensity": 0.1,  # ... of a couple component's rate [(N m)^2/s] (platforms)
    "process.wrench_jump_stddev": 10.0,  # [N] a gated accelerometer sample: the forces' variances grow by this^2
    "process.wrench_jump_torque_stddev": 1.0,  # [N m] ... the couples'
    "process.wrench_jump_probability": 0.999,  # the accelerometer's NIS quantile above which the wrench jumps
    "process.torque_noise_psd": 1.0e-10,  # white torque on active joints [(N m)^2 s]
    "process.elastic_force_psd": 1.0e-12,  # white force on elastic joints (model error) [N^2 s]
    "process.vibration_noise": 2.0e-11,  # ... plus this times the vibration-force amplitude^2 [s]
    # dry friction F on a q_ae joint (MJCF frictionloss, URDF friction), a known term with its own
    # uncertainty: a white force of PSD this times F^2 on it [s]. 1e-4 s is 2 sigma^2 tau of a
    # friction force off by sigma = 0.1 F for tau = 5 ms at a time (the PSD of such a process)
    "process.friction_noise": 1.0e-4,
    # --- initial uncertainty (1 sigma)
    "initial.source": "measurement",  # measurement (first joint state) | model (its initial_state)
    "initial.active_position_stddev": 1.0e-4,  # [rad]
    "initial.elastic_position_stddev": 1.0e-8,  # [m] at rest, in static equilibrium
    "initial.active_velocity_stddev": 1.0e-3,  # [rad/s]
    "initial.elastic_velocity_stddev": 3.0e-5,  # [m/s] (the same force as a vibration: c v / w)
    "initial.disturbance_stddev": 0.02,  # [N m]
    "initial.disturbance_rate_stddev": 1.0,  # [N m/s] (integrated random walk)
    "initial.wrench_stddev": 1.0,  # [N] of each force component (process.wrench)
    "initial.wrench_torque_stddev": 0.1,  # [N m] of each couple component
    # --- robustness
    # chi-square quantile of the NIS gate: 1 - 1e-9, about 6 standard deviations for one entry. At
    # 0.9999 (3.9) the model error's heavy NIS tail (linearisation age, the disturbance's spectrum)
    # gated 7-16 % of accelerometer samples on chirps and manoeuvres, and the filter lost up to half its
    # accuracy with them (bench/studies/observer_gate.py); sensor faults lie far beyond either.
    "gating.probability": 0.999999999,
    "gating.max_consecutive_rejections": 50,  # then the filter reports divergence
    "gating.recover_after": 10,  # encoder samples gated in a row, then the motors are re-initialised from
    # them (schedule/recovery.py; 0: never, divergence is reported after max_consecutive_rejections)
    "gating.nis_window": 200,  # samples in the windowed NIS consistency check
    "gating.nis_warn_factor": 2.0,  # health WARN when the windowed mean NIS / dof leaves [1/f, f]
    "timing.stamp_tolerance": 1.0e-6,  # [s] stamps this close count as simultaneous
    "timing.command_timeout": 0.0,  # [s] older command -> zero torque; 0 = hold forever
    "timing.max_future": 1.0,  # [s] a stamp further ahead of the filter is not used ("future"); .inf: no limit
    # --- topics (live node; defaults of the offline command)
    "topics.torque_command": "torque_command",
    # the torque the drives applied, stamped at the start of its period (the plant node publishes it);
    # where it comes it is the torque input and torque_command is not used any more; "" = never
    "topics.applied_torque": "applied_torque",
    "topics.measured_joint_states": "measured_joint_states",
    "topics.ee_imu": "ee_imu",
    "topics.measured_branch_forces": "measured_branch_forces",
    "observability.horizon": 0.05,  # [s] of the observability Gramian at start-up
}


@dataclass
class EncoderConfig:
    position_joints: list[str]
    position_stddev: list[float]
    velocity_joints: list[str]
    velocity_stddev: list[float]


@dataclass
class ImuConfig:
    chain: str
    frame_id: str
    rpy: list[float]
    axes: list[str]
    stddev: list[float]
    specific_force: bool
    sample_timing: str


@dataclass
class BranchForceConfig:
    source: str
    branches: list[str]
    stddev: list[float]


@dataclass
class ProcessConfig:
    integrator: str
    linearization: str
    dt: float
    max_interval: float
    relinearize_every: int
    disturbance: str
    disturbance_joints: list[str]
    disturbance_intensity: float
    disturbance_stddev: float
    disturbance_bandwidth: list[float]
    disturbance_time_constant: float
    disturbance_band_order: int
    torque_noise_psd: float
    elastic_force_psd: float
    vibration_noise: float
    wrench: str = "none"
    wrench_intensity: float = 10.0
    wrench_torque_intensity: float = 0.1
    wrench_jump_stddev: float = 10.0
    wrench_jump_torque_stddev: float = 1.0
    wrench_jump_probability: float = 0.999
    friction_noise: float = 1.0e-4  # [s] PSD of a q_ae joint's friction uncertainty over its F^2

    def friction_psd(self, coulomb: np.ndarray) -> np.ndarray:
        """The white force's PSD [(N m)^2 s or N^2 s] on joints with dry friction ``coulomb`` (F)."""
        return self.friction_noise * np.asarray(coulomb, dtype=float) ** 2


@dataclass
class InitialConfig:
    source: str
    active_position_stddev: float
    elastic_position_stddev: float
    active_velocity_stddev: float
    elastic_velocity_stddev: float
    disturbance_stddev: float
    disturbance_rate_stddev: float
    wrench_stddev: float = 1.0
    wrench_torque_stddev: float = 0.1


@dataclass
class GatingConfig:
    probability: float
    max_consecutive_rejections: int
    nis_window: int
    nis_warn_factor: float
    recover_after: int = 10


@dataclass
class TimingConfig:
    stamp_tolerance: float
    command_timeout: float
    max_future: float = 1.0


@dataclass
class Topics:
    torque_command: str
    measured_joint_states: str
    ee_imu: str
    measured_branch_forces: str
    applied_torque: str = ""


@dataclass
class ObserverConfig:
    """Typed observer settings; see :data:`DEFAULT_PARAMETERS` for names, units, defaults."""

    sensors: list[str]
    encoders: EncoderConfig
    imu: ImuConfig
    branch_forces: BranchForceConfig
    process: ProcessConfig
    initial: InitialConfig
    gating: GatingConfig
    timing: TimingConfig
    topics: Topics
    observability_horizon: float
    command_delay: float
    source: str = "<defaults>"
    parameters: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------------ building
    @classmethod
    def from_parameters(cls, params: Mapping[str, Any] | None = None, source: str = "<parameters>"
                        ) -> ObserverConfig:
        """From flat names (with or without the ``observer.`` prefix); missing ones take defaults.

        Raises InputError naming the parameter for unknown names and wrong types/values.
        """
        given = {}
        for name, value in (params or {}).items():
            key = name[len(PREFIX):] if name.startswith(PREFIX) else name
            if key not in DEFAULT_PARAMETERS:
                raise InputError(f"{source}: unknown observer parameter {_shown(PREFIX + key, bare=True)}")
            given[key] = value
        p = {k: _coerce(source, k, given.get(k, default), default) for k, default in DEFAULT_PARAMETERS.items()}
        cfg = cls(
            sensors=p["sensors"],
            encoders=EncoderConfig(p["encoders.position_joints"], p["encoders.position_stddev"],
                                   p["encoders.velocity_joints"], p["encoders.velocity_stddev"]),
            imu=ImuConfig(p["imu.chain"], p["imu.frame_id"], p["imu.rpy"], p["imu.axes"], p["imu.stddev"],
                          p["imu.specific_force"], p["imu.sample_timing"]),
            branch_forces=BranchForceConfig(p["branch_forces.source"], p["branch_forces.branches"],
                                            p["branch_forces.stddev"]),
            process=ProcessConfig(p["process.integrator"], p["process.linearization"], p["process.dt"],
                                  p["process.max_interval"], p["process.relinearize_every"],
                                  p["process.disturbance"],
                                  p["process.disturbance_joints"], p["process.disturbance_intensity"],
                                  p["process.disturbance_stddev"], p["process.disturbance_bandwidth"],
                                  p["process.disturbance_time_constant"], p["process.disturbance_band_order"],
                                  p["process.torque_noise_psd"], p["process.elastic_force_psd"],
                                  p["process.vibration_noise"], p["process.wrench"], p["process.wrench_intensity"],
                                  p["process.wrench_torque_intensity"], p["process.wrench_jump_stddev"],
                                  p["process.wrench_jump_torque_stddev"], p["process.wrench_jump_probability"],
                                  p["process.friction_noise"]),
            initial=InitialConfig(p["initial.source"], p["initial.active_position_stddev"],
                                  p["initial.elastic_position_stddev"], p["initial.active_velocity_stddev"],
                                  p["initial.elastic_velocity_stddev"], p["initial.disturbance_stddev"],
                                  p["initial.disturbance_rate_stddev"], p["initial.wrench_stddev"],
                                  p["initial.wrench_torque_stddev"]),
            gating=GatingConfig(p["gating.probability"], p["gating.max_consecutive_rejections"],
                                p["gating.nis_window"], p["gating.nis_warn_factor"], p["gating.recover_after"]),
            timing=TimingConfig(p["timing.stamp_tolerance"], p["timing.command_timeout"],
                                max_future=p["timing.max_future"]),
            topics=Topics(p["topics.torque_command"], p["topics.measured_joint_states"], p["topics.ee_imu"],
                          p["topics.measured_branch_forces"], p["topics.applied_torque"]),
            observability_horizon=p["observability.horizon"],
            command_delay=p["command_delay"],
            source=source, parameters=p,
        )
        cfg.validate()
        return cfg

    def for_machine(self, mech: Any) -> ObserverConfig:
        """This configuration with what it leaves to the machine decided (``imu.axes: [auto]``: the
        sensor axes that lie in a planar machine's plane, all three on a spatial one); itself if nothing."""
        if self.imu.axes != [AUTO_AXES]:
            return self
        from elastic_pm_dyn.model.description import rpy_to_matrix

        sensor_axes = rpy_to_matrix(np.asarray(self.imu.rpy, dtype=float))  # columns: the axes in the world
        in_plane = np.linalg.norm(np.asarray(mech.ee_axes, dtype=float) @ sensor_axes, axis=0) > 0.5
        return self.with_overrides(imu__axes=[a for a, keep in zip(AXES, in_plane, strict=True) if keep])

    def with_overrides(self, **flat: Any) -> ObserverConfig:
        """A copy with some flat parameters replaced, e.g. ``with_overrides(sensors=["encoders", "imu"])``;
        dots in names are written as double underscores (``process__dt=2e-4``)."""
        params = dict(self.parameters)
        params.update({k.replace("__", "."): v for k, v in flat.items()})
        return ObserverConfig.from_parameters(params, self.source)

    def validate(self) -> None:
        src = self.source

        def bad(key: str, msg: str) -> InputError:
            return InputError(f"{src}: {PREFIX}{key}: {msg}")

        for s in self.sensors:
            if s not in SENSOR_KINDS:
                raise bad("sensors", f"unknown sensor {_shown(s)} (expected some of {', '.join(SENSOR_KINDS)})")
        if len(set(self.sensors)) != len(self.sensors):
            raise bad("sensors", "a sensor is listed twice")
        positive = {"process.max_interval": self.process.max_interval,
                    "process.disturbance_time_constant": self.process.disturbance_time_constant,
                    "initial.active_position_stddev": self.initial.active_position_stddev,
                    "initial.elastic_position_stddev": self.initial.elastic_position_stddev,
                    "initial.active_velocity_stddev": self.initial.active_velocity_stddev,
                    "initial.elastic_velocity_stddev": self.initial.elastic_velocity_stddev,
                    "initial.disturbance_stddev": self.initial.disturbance_stddev,
                    "initial.disturbance_rate_stddev": self.initial.disturbance_rate_stddev,
                    "initial.wrench_stddev": self.initial.wrench_stddev,
                    "initial.wrench_torque_stddev": self.initial.wrench_torque_stddev,
                    "timing.stamp_tolerance": self.timing.stamp_tolerance,
                    "timing.max_future": self.timing.max_future,
                    "observability.horizon": self.observability_horizon}
        for key, value in positive.items():
            if not value > 0:
                raise bad(key, f"must be > 0, got {_shown(value)}")
        non_negative = {"process.disturbance_intensity": self.process.disturbance_intensity,
                        "process.disturbance_stddev": self.process.disturbance_stddev,
                        "process.torque_noise_psd": self.process.torque_noise_psd,
                        "process.elastic_force_psd": self.process.elastic_force_psd,
                        "process.vibration_noise": self.process.vibration_noise,
                        "process.friction_noise": self.process.friction_noise,
                        "process.wrench_intensity": self.process.wrench_intensity,
                        "process.wrench_torque_intensity": self.process.wrench_torque_intensity,
                        "process.wrench_jump_stddev": self.process.wrench_jump_stddev,
                        "process.wrench_jump_torque_stddev": self.process.wrench_jump_torque_stddev,
                        "timing.command_timeout": self.timing.command_timeout,
                        "command_delay": self.command_delay, "process.dt": self.process.dt}
        for key, value in non_negative.items():
            if not value >= 0:
                raise bad(key, f"must be >= 0, got {_shown(value)}")
        # Ranges with a physical sense, so an absurd value is one line instead of an endless run.
        ceilings = {"command_delay": (self.command_delay, MAX_COMMAND_DELAY, "an actuation latency"),
                    "process.max_interval": (self.process.max_interval, MAX_PREDICTION_INTERVAL,
                                             "one linearised prediction piece"),
                    "observability.horizon": (self.observability_horizon, MAX_HORIZON, "the start-up Gramian")}
        for key, (value, ceiling, what) in ceilings.items():
            if value > ceiling:
                raise bad(key, f"{value:g} s is more than the {ceiling:g} s {what} may take")
        if 0 < self.process.dt < MIN_STEP:
            raise bad("process.dt", f"{self.process.dt:g} s is below {MIN_STEP:g} s (a thousandth of the fastest "
                                    "elastic period modelled; 0 chooses the step)")
        if self.process.dt > self.process.max_interval:
            raise bad("process.dt", f"the step {self.process.dt:g} s exceeds process.max_interval "
                                    f"{self.process.max_interval:g} s")
        for key, values in (("encoders.position_stddev", self.encoders.position_stddev),
                            ("encoders.velocity_stddev", self.encoders.velocity_stddev),
                            ("imu.stddev", self.imu.stddev), ("branch_forces.stddev", self.branch_forces.stddev)):
            if not values or not all(v > 0 for v in values):
                raise bad(key, f"needs one or more values > 0, got {_shown(values)}")
        bands = self.process.disturbance_bandwidth
        if not bands or not all(b > 0 for b in bands) or len(set(bands)) != len(bands):
            raise bad("process.disturbance_bandwidth", f"needs distinct corner frequencies > 0, got {_shown(bands)}")
        choices = (("process.disturbance_band_order", self.process.disturbance_band_order, BAND_ORDERS),
                   ("process.disturbance", self.process.disturbance, DISTURBANCE_MODELS),
                   ("process.wrench", self.process.wrench, WRENCH_MODELS),
                   ("process.integrator", self.process.integrator, INTEGRATORS),
                   ("process.linearization", self.process.linearization, LINEARIZATIONS),
                   ("branch_forces.source", self.branch_forces.source, BRANCH_SOURCES),
                   ("imu.sample_timing", self.imu.sample_timing, SAMPLE_TIMINGS))
        for key, value, allowed in choices:
            if value not in allowed:
                raise bad(key, f"expected one of {', '.join(map(str, allowed))}, got {_shown(value)}")
        if self.initial.source not in ("measurement", "model"):
            raise bad("initial.source", f"expected measurement or model, got {_shown(self.initial.source)}")
        if self.imu.axes != [AUTO_AXES] and (not self.imu.axes or any(a not in AXES for a in self.imu.axes)
                                             or len(set(self.imu.axes)) != len(self.imu.axes)):
            raise bad("imu.axes", f"expected distinct axes among x, y, z, or [{AUTO_AXES}], "
                      f"got {_shown(self.imu.axes)}")
        if len(self.imu.rpy) != 3:
            raise bad("imu.rpy", f"expected 3 angles, got {_shown(self.imu.rpy)}")
        if not 0.5 < self.process.wrench_jump_probability < 1.0:
            raise bad("process.wrench_jump_probability",
                      f"expected a probability in (0.5, 1), got {_shown(self.process.wrench_jump_probability)}")
        if not 0.5 < self.gating.probability < 1.0:
            raise bad("gating.probability",
                      f"expected a probability in (0.5, 1), got {_shown(self.gating.probability)}")
        if self.process.relinearize_every < 1:
            raise bad("process.relinearize_every", f"must be >= 1, got {self.process.relinearize_every}")
        if not self.gating.nis_warn_factor > 1.0:
            raise bad("gating.nis_warn_factor", f"must be > 1, got {_shown(self.gating.nis_warn_factor)}")
        if self.gating.recover_after < 0:
            raise bad("gating.recover_after", f"must be >= 0, got {_shown(self.gating.recover_after)}")
        if self.gating.max_consecutive_rejections < 1 or self.gating.nis_window < 1:
            raise bad("gating", "max_consecutive_rejections and nis_window must be >= 1")


MIN_STEP = 1e-7  # [s] process.dt (0 = chosen): the stiffest machines here ring at ~10 kHz
MAX_COMMAND_DELAY = 1.0  # [s] actuation latency
MAX_PREDICTION_INTERVAL = 1.0  # [s] one linearised prediction piece
MAX_HORIZON = 10.0  # [s] observability Gramian at start-up


MAX_SHOWN = 80  # characters of a value quoted in an error line


def _shown(value: Any, bare: bool = False) -> str:
    """A value as an error line quotes it: its repr (a printable name bare), at most MAX_SHOWN characters."""
    text = value if bare and isinstance(value, str) and value.isprintable() else repr(value)
    return text if len(text) <= MAX_SHOWN else text[:MAX_SHOWN - 3] + "..."


def _float(where: str, value: int | float) -> float:
    """A YAML number as a float; an integer beyond the float range is one line, not an OverflowError."""
    try:
        return float(value)
    except OverflowError:
        digits = int(value.bit_length() * 0.30103) + 1 if isinstance(value, int) else 0
        raise InputError(f"{where}: an integer of about {digits} digits, beyond the range of a float") from None


def _coerce(source: str, key: str, value: Any, default: Any) -> Any:
    """Check a value against its default's type (ints are accepted for floats)."""
    where = f"{source}: {PREFIX}{key}"
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(f"{where}: expected true or false, got {_shown(value)}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"{where}: expected a number, got {_shown(value)}")
        return _float(where, value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(f"{where}: expected an integer, got {_shown(value)}")
        return value
    if isinstance(default, str):
        if not isinstance(value, str):
            raise InputError(f"{where}: expected a string, got {_shown(value)}")
        return value
    if isinstance(default, list):
        if isinstance(value, str | int | float) and not isinstance(value, bool):
            value = [value]  # one value for a list: broadcast
        if not isinstance(value, list | tuple):
            raise InputError(f"{where}: expected a list, got {_shown(value)}")
        kind = type(default[0])
        out = []
        for v in value:
            if kind is float:
                if isinstance(v, bool) or not isinstance(v, int | float):
                    raise InputError(f"{where}: expected numbers, got {_shown(v)}")
                out.append(_float(where, v))
            else:
                if not isinstance(v, str):
                    raise InputError(f"{where}: expected names, got {_shown(v)}")
                out.append(v)
        return out
    raise AssertionError(key)


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested maps -> dotted names, as ROS reads a parameter file."""
    out: dict[str, Any] = {}
    for k, v in tree.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out


def load_config(path: str | Path | None = None, node: str | None = None) -> ObserverConfig:
    """Read the observer parameters from a ``ros__parameters`` YAML file (defaults if None).

    The file may hold several node sections (``/**``, ``plant``, ...): the ``observer``
    parameters of ``node`` (or of the first section that has any) are used. It is read as a
    node reads it: a file without a ``ros__parameters`` section, or with a value of another ROS
    type than its parameter's (an integer, ``2`` or ``[2]``, for a float or a list of floats; one
    value for a list), is refused in one line, as the node would refuse it. So is a file that ends
    in the middle of a line and leaves observer parameters at their defaults (a file cut off).
    """
    if path is None:
        return ObserverConfig.from_parameters({}, "<defaults>")
    p = Path(path)
    data, text = yaml12.load_file_text(p, "observer configuration")
    if not isinstance(data, dict):
        raise InputError(f"{p}: expected a map of node names to ros__parameters")
    sections = []
    for name, body in data.items():
        if isinstance(body, dict) and isinstance(body.get("ros__parameters"), dict):
            sections.append((name, body["ros__parameters"]))
    if not sections:
        raise InputError(f"{p}: no ros__parameters section: an observer configuration is a ROS parameter file, "
                         "<node>: ros__parameters: observer: ... (as config/observer.yaml)")
    chosen = None
    for name, params in sections:
        if (node is None or name.strip("/") == node.strip("/") or name == "/**") and "observer" in params:
            chosen = params
            break
    if chosen is None:
        raise InputError(f"{p}: no observer parameters (expected <node>: ros__parameters: observer: ...)")
    if not isinstance(chosen["observer"], dict):
        raise InputError(f"{p}: observer: expected a map of parameters")
    flat = {k: v for k, v in flatten(chosen).items() if k.startswith(PREFIX)}
    for name, value in flat.items():
        _ros_typed(p, name, value)
    missing = [k for k in DEFAULT_PARAMETERS if PREFIX + k not in flat]
    if missing and text and not text.endswith("\n"):
        raise InputError(f"{p}: ends in the middle of a line and leaves {len(missing)} observer parameter(s) at "
                         f"their defaults ({', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''}): a file cut "
                         "off? (if it is whole, end its last line)")
    return ObserverConfig.from_parameters(flat, str(p))


def _ros_typed(path: Path, name: str, value: Any) -> None:
    """InputError if a node could not take ``value`` for the parameter ``name`` (its ROS type is
    its default's: a float is written with a point, a list as a list)."""
    default = DEFAULT_PARAMETERS.get(name[len(PREFIX):])
    if default is None:
        return  # unknown: from_parameters names it
    where = f"{path}: {_shown(name, bare=True)}"

    def number(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        raise InputError(f"{where}: {_shown(value)} is an integer, a float parameter's value is written as a float "
                         f"(e.g. {_shown(float(value)) if abs(value) < 1e300 else '1.0e300'}); a node refuses it")
    if isinstance(default, list):
        item = type(default[0])
        if not isinstance(value, list):
            raise InputError(f"{where}: a list parameter takes a list, e.g. [{_shown(value)}], got "
                             f"{_shown(value)}; a node refuses it")
        if item is float and any(number(v) and not isinstance(v, float) for v in value):
            raise InputError(f"{where}: {_shown(value)} holds integers, a list of floats is written with points "
                             "(e.g. [2.0]); a node refuses it")
