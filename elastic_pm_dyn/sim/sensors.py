"""Simulated sensors of a plant: motor encoders, an end-effector accelerometer, strain gauges.

What the plant node publishes as measurements when its ``sensors.*`` are on, in the state
observer's conventions (:mod:`elastic_pm_dyn.observer.core.sensors`), computed here without ROS:

- encoders: the active joints' positions (and optionally rates) plus Gaussian noise, the
  positions then rounded to the count grid of the encoder (2 pi / counts per revolution on a
  revolute joint, 1 / counts per metre on a prismatic one);
- accelerometer: the true acceleration of the end-effector point at the state, from the
  model's own direct dynamics under the torque acting there, J qdd + Jdot qd, as specific
  force a - g if asked, on axes rotated by rpy from the world: y = R^T (a - g) + bias + noise;
- strain gauges: the branch forces plus Gaussian noise.

Each sensor draws its noise from its own stream of one seed, so that switching one sensor
on or off does not change another's noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import PRISMATIC, rpy_to_matrix

SAMPLE_TIMINGS = ("before_command", "after_command")


def ee_acceleration(mech: Mechanism, dyn: Dynamics, q: np.ndarray, qd: np.ndarray, tau_active: np.ndarray,
                    chain: int, extra_tree: np.ndarray | None = None) -> np.ndarray:
    """World acceleration (3,) of ``chain``'s end point at (q, qd) under the motor torques
    ``tau_active`` (and tree forces ``extra_tree``, an external wrench's): J qdd + Jdot qd with qdd
    from the direct dynamics (gravity acts in qdd; the sensor's -g is the caller's)."""
    terms = mech.terms(q, qd)
    qdd = dyn.accelerations(q, qd, tau_active, extra_tree=extra_tree)
    return terms.J[chain] @ qdd + terms.a_tip[chain]


MAX_STDDEV = 1.0e3  # sensor noise std [rad, m, m/s^2, N]: beyond, no sensor (and squares near overflow)

@dataclass
class EncoderSpec:
    enabled: bool = False
    position_stddev: float = 2.0e-5  # [rad or m]
    velocity: bool = False  # publish rates too
    velocity_stddev: float = 1.0e-2  # [rad/s or m/s]
    counts_per_revolution: int = 0  # revolute joints; 0 = no quantisation
    counts_per_metre: int = 0  # prismatic joints; 0 = no quantisation


@dataclass
class ImuSpec:
    enabled: bool = False
    frame_id: str = "ee_imu"
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor axes w.r.t. the world [rad]
    specific_force: bool = True  # reads a - g
    sample_timing: str = "before_command"  # see SAMPLE_TIMINGS and the plant node's docs
    stddev: float = 0.02  # [m/s^2]
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)  # [m/s^2] on the sensor axes


@dataclass
class GaugeSpec:
    enabled: bool = False
    stddev: float = 0.5  # [N]


@dataclass
class SensorSpec:
    encoders: EncoderSpec = field(default_factory=EncoderSpec)
    imu: ImuSpec = field(default_factory=ImuSpec)
    branch_forces: GaugeSpec = field(default_factory=GaugeSpec)
    seed: int = 0

    @property
    def any(self) -> bool:
        return self.encoders.enabled or self.imu.enabled or self.branch_forces.enabled

    def validate(self) -> None:
        """InputError naming the setting (as the plant node's ``sensors.*`` parameter) when one is out of range."""
        e, i, b = self.encoders, self.imu, self.branch_forces
        for name, value in (("encoders.position_stddev", e.position_stddev),
                            ("encoders.velocity_stddev", e.velocity_stddev), ("imu.stddev", i.stddev),
                            ("branch_forces.stddev", b.stddev)):
            if not (np.isfinite(value) and 0 <= value <= MAX_STDDEV):
                raise InputError(f"'sensors.{name}' must be a number in [0, {MAX_STDDEV:g}], got {value!r}")
        for name, value in (("encoders.counts_per_revolution", e.counts_per_revolution),
                            ("encoders.counts_per_metre", e.counts_per_metre), ("seed", self.seed)):
            if value < 0:
                raise InputError(f"'sensors.{name}' must be >= 0, got {value!r}")
        for name, value in (("imu.rpy", i.rpy), ("imu.bias", i.bias)):
            if len(value) != 3 or not np.all(np.isfinite(np.asarray(value, dtype=float))):
                raise InputError(f"'sensors.{name}' must be 3 finite numbers, got {list(value)!r}")
        if i.sample_timing not in SAMPLE_TIMINGS:
            raise InputError(f"'sensors.imu.sample_timing' is {i.sample_timing!r}, expected one of: "
                             f"{', '.join(SAMPLE_TIMINGS)}")


class SensorModel:
    """The sensors of ``spec`` on ``mech``: noise-free values from a state, noisy samples (seeded)."""

    def __init__(self, mech: Mechanism, spec: SensorSpec, formulation: str = "scdd"):
        spec.validate()
        self.mech, self.spec = mech, spec
        e = spec.encoders
        prismatic = np.array([mech.model.joints[i].type == PRISMATIC for i in mech.active], dtype=bool)
        counts = np.where(prismatic, e.counts_per_metre, e.counts_per_revolution).astype(float)
        # [rad or m] per count; 0: not quantised
        self.resolution = np.where(counts > 0, np.where(prismatic, 1.0, 2 * np.pi) / np.where(counts > 0, counts, 1),
                                   0.0)
        # the one-pass variant lags by design; every exact formulation equals SCDD to round-off
        self.dyn = Dynamics(mech, "scdd" if formulation == "scdd_one_pass" else formulation)
        self.chain = int(mech.model.end_effector_chain)
        self.R_T = rpy_to_matrix(np.asarray(spec.imu.rpy, dtype=float)).T
        self.g = np.asarray(mech.model.gravity, dtype=float) if spec.imu.specific_force else np.zeros(3)
        self.bias = np.asarray(spec.imu.bias, dtype=float)
        streams = np.random.SeedSequence(spec.seed).spawn(3)
        self.rng_encoders, self.rng_imu, self.rng_gauges = (np.random.default_rng(s) for s in streams)

    # ------------------------------------------------------------------ noise-free
    def quantise(self, position: np.ndarray) -> np.ndarray:
        """Round to the encoder's count grid where it has one."""
        r = self.resolution
        return np.where(r > 0, np.round(position / np.where(r > 0, r, 1.0)) * r, position)

    def accelerometer_true(self, q: np.ndarray, qd: np.ndarray, tau_active: np.ndarray,
                           extra_tree: np.ndarray | None = None) -> np.ndarray:
        """y = R^T (a - g) + bias, noise-free, at (q, qd) under ``tau_active`` (commands and
        disturbance) and tree forces ``extra_tree`` (an external wrench's, :meth:`Plant.wrench_tree_forces`)."""
        a = ee_acceleration(self.mech, self.dyn, q, qd, tau_active, self.chain, extra_tree)
        return self.R_T @ (a - self.g) + self.bias

    # ------------------------------------------------------------------- samples
    def encoders(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Measured active positions (noise, then the count grid) and rates (None unless configured)."""
        e, a, rng = self.spec.encoders, self.mech.active, self.rng_encoders
        position = self.quantise(q[a] + e.position_stddev * rng.standard_normal(len(a)))
        velocity = qd[a] + e.velocity_stddev * rng.standard_normal(len(a)) if e.velocity else None
        return position, velocity

    def accelerometer(self, q: np.ndarray, qd: np.ndarray, tau_active: np.ndarray,
                      extra_tree: np.ndarray | None = None) -> np.ndarray:
        return (self.accelerometer_true(q, qd, tau_active, extra_tree)
                + self.spec.imu.stddev * self.rng_imu.standard_normal(3))

    def branch_forces(self, force: np.ndarray) -> np.ndarray:
        return force + self.spec.branch_forces.stddev * self.rng_gauges.standard_normal(len(force))
