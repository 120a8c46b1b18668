"""Test recordings that vary what real recordings vary, made by a simulator other than the observer's.

A :class:`RecordingSpec` names one recording: the motion (the reference manoeuvre's rigid
feedforward torques, or a strong chirp through the spring mode on a PD loop), its
duration, an unknown torque disturbance on the motors (its spectrum, RMS and seed), the
sensor noise, the accelerometer's sample timing (a(t_k-) or a(t_k+)), a command delay, the
stamp origin T0 (0 or an epoch) and the truth's integrator. :func:`generate` simulates it
(:func:`~elastic_pm_dyn.observer.testing.scenarios.simulate`); :func:`write_bag` writes the
measurements and commands as a rosbag2 bag (mcap or sqlite3) with the usual conventions:
header stamps = sample times T0 + t_k, receive times a little later, the command of t_k
after the samples of t_k. The truth stays in the :class:`~elastic_pm_dyn.observer.testing.scenarios.Recording`,
never in the bag.

The truth is integrated by RK4 at 25 us (a quarter of the observer's 100 us RK4 substep,
so the filter's discretisation is not the truth's) or by DOP853 at rtol 1e-10; either is
converged to far below the sensor noise (test_observer_recordings checks two step sizes).

Disturbance spectra: :class:`~elastic_pm_dyn.sim.disturbances.SpectrumDisturbance` (in the
``sim`` layer, so the plant node's ``disturbance.*`` makes the same d(t) for the same seed),
each channel scaled to the asked RMS over the recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from elastic_pm_dyn.bags.msgtypes import NS
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag
from elastic_pm_dyn.observer.testing.scenarios import (
    ACCEL_TIMINGS,
    Noise,
    Recording,
    chirp_recording,
    manoeuvre_recording,
)
from elastic_pm_dyn.sim.disturbances import SPECTRA, seeded_disturbance

MOTIONS = ("manoeuvre", "chirp")
EPOCH = 1.7e9  # [s] a stamp origin like a wall clock's (2023-11-14)
# Receive time - header stamp [ns] per kind of message: samples arrive a little after they are
# taken, the command of t_k after the samples it is computed from (all well within the period).
RECEIVE_DELAY_NS = {"encoders": 120_000, "imu": 180_000, "branch_forces": 240_000, "command": 400_000}
RECEIVE_JITTER_NS = 50_000


@dataclass(frozen=True)
class RecordingSpec:
    """One test recording; see the module docstring. ``command_delay`` in periods (0 or 1)."""

    motion: str = "manoeuvre"  # manoeuvre | chirp
    duration: float = 1.0  # [s] 0.5-5
    spectrum: str = "flat"  # one of SPECTRA
    disturbance_rms: float = 0.05  # [N m] per motor, 0.01-0.1
    seed: int = 1000
    accel_timing: str = "before_command"  # one of ACCEL_TIMINGS
    command_delay: int = 0
    t0: float = 0.0  # [s] stamp origin: 0 or EPOCH
    noise: Noise = field(default_factory=Noise)
    integrator: str = "rk4"  # rk4 | dop853
    truth_dt: float = 2.5e-5  # [s] RK4 step
    rtol: float = 1e-10  # DOP853
    chirp_amplitude: float = 3.0  # [N m]

    def __post_init__(self) -> None:
        checks = [(self.motion in MOTIONS, f"motion must be one of {MOTIONS}"),
                  (self.spectrum in SPECTRA, f"spectrum must be one of {SPECTRA}"),
                  (self.accel_timing in ACCEL_TIMINGS, f"accel_timing must be one of {ACCEL_TIMINGS}"),
                  (self.command_delay in (0, 1), "command_delay must be 0 or 1 period"),
                  (self.integrator in ("rk4", "dop853"), "integrator must be rk4 or dop853"),
                  (0 < self.duration <= 10 and self.disturbance_rms >= 0, "duration or disturbance_rms out of range")]
        for ok, what in checks:
            if not ok:
                raise ValueError(f"{what}: {self}")

    @property
    def name(self) -> str:
        """A short unique label, e.g. ``manoeuvre-flat-0.05-after-d1-epoch-s1000``."""
        return (f"{self.motion}-{self.spectrum}-{self.disturbance_rms:g}-{self.accel_timing.split('_')[0]}"
                f"-d{self.command_delay}-{'epoch' if self.t0 else 't0'}-s{self.seed}")

    def with_(self, **changes) -> RecordingSpec:
        return replace(self, **changes)


def generate(mech: Mechanism, spec: RecordingSpec) -> Recording:
    """Simulate ``spec``: the truth, the noisy samples and the commands (``info`` holds the spec)."""
    # the disturbance's own stream: noise draws do not move it
    dist = (seeded_disturbance(spec.spectrum, len(mech.active), spec.disturbance_rms, spec.duration, spec.seed)
            if spec.disturbance_rms > 0 else None)
    timing = {"accel_timing": spec.accel_timing, "command_delay": spec.command_delay,
              "integrator": spec.integrator, "rtol": spec.rtol, "stamp0_ns": round(spec.t0 * NS)}
    if spec.motion == "manoeuvre":
        rec = manoeuvre_recording(mech, seed=spec.seed, disturbance_rms=0.0, noise=spec.noise,
                                  duration=spec.duration, truth_dt=spec.truth_dt, disturbance=dist, **timing)
    else:
        rec = chirp_recording(mech, seed=spec.seed, amplitude=spec.chirp_amplitude, duration=spec.duration,
                              disturbance_rms=0.0, noise=spec.noise, truth_dt=spec.truth_dt, disturbance=dist,
                              **timing)
    rec.label = spec.name
    rec.info = {"spec": spec, "disturbance_rms": spec.disturbance_rms, "spectrum": spec.spectrum, "seed": spec.seed}
    return rec


def receive_times(rec: Recording, seed: int = 0) -> dict[str, np.ndarray]:
    """Receive time [ns] of each kind of message per sample: the stamp + :data:`RECEIVE_DELAY_NS`
    + a uniform jitter of up to :data:`RECEIVE_JITTER_NS` (seeded)."""
    rng = np.random.default_rng([seed, 11])
    stamps = np.asarray(rec.stamp_ns, dtype=np.int64)
    return {kind: stamps + delay + rng.integers(0, RECEIVE_JITTER_NS, len(stamps))
            for kind, delay in RECEIVE_DELAY_NS.items()}


def write_bag(rec: Recording, path: str | Path, storage: str = "mcap",
              use: tuple[str, ...] = ("encoders", "imu", "branch_forces")) -> Path:
    """The recording's measurements (``use``) and commands as a bag at ``path`` with the
    conventions of the module docstring; returns ``path``."""
    seed = rec.info["spec"].seed if "spec" in rec.info else 0
    recording_to_bag(rec, path, use=use, storage=storage, receive_ns=receive_times(rec, seed))
    return Path(path)

