"""Simulated recordings for testing and benchmarking the observer (truth + noisy sensors).

The core simulator integrates the elastic model at fine steps (default RK4 at 50 us, half
the observer's substep, so the filter's model is not the truth's discretisation; or DOP853)
under the commanded torques, held over each 1 ms period as a digital controller applies
them, plus an unknown smooth disturbance torque the observer is not given. At each sample
time t_k the recording holds the true tree state, the noisy encoder angles, the noisy
specific force of the end effector and noisy branch forces; then the command of t_k is
computed (it may use the noisy samples: a PD loop) and applied.

Two timing choices real recordings differ in:
- ``command_delay`` (periods): the command stamped t_k acts on [t_k+d, t_k+d+1) (d = 0: at once);
- ``accel_timing``: the accelerometer sample of t_k is taken just before the command
  acting from t_k is applied (``"before_command"``, a(t_k-): the torque of the period that
  just ended) or just after (``"after_command"``, a(t_k+): a jump where the command jumps).
  Encoder angles and branch forces are continuous in time: the same either way.

Two manoeuvres (the observer's test cases):
- :func:`manoeuvre_recording`: the reference quintic line's rigid feedforward torques;
- :func:`chirp_recording`: a chirp of a few N m through the spring resonance on top of a
  PD loop that holds the start pose (an open-loop chirp would push the machine away).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from elastic_pm_dyn.bags.msgtypes import NS
from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state  # rest_state: used from here too
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.motion.feedforward import line_torques
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.sim.sensors import ee_acceleration
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import HeldPlusSmooth

PERIOD = 1.0 / REFERENCE_MANOEUVRE.control_rate  # [s] the reference manoeuvre's torques are held this long
ACCEL_TIMINGS = ("before_command", "after_command")


class Multisine:
    """Sum of sines with log-spaced frequencies in [f_lo, f_hi] (equal amplitudes: equal power
    per octave), random phases, given RMS per channel; faded in over ``fade`` seconds (a
    disturbance switched on as a step would ring the springs, which no real one does)."""

    def __init__(self, rng: np.random.Generator, channels: int, rms: float, f_lo: float = 2.0, f_hi: float = 200.0,
                 n_freq: int = 24, fade: float = 0.02):
        self.f = np.geomspace(f_lo, f_hi, n_freq)
        self.phase = rng.uniform(0, 2 * np.pi, (channels, n_freq))
        self.amp = np.full((channels, n_freq), rms * np.sqrt(2.0 / n_freq))  # RMS of the sum = rms
        self.fade = fade

    def __call__(self, t: float) -> np.ndarray:
        w = 1.0 if t >= self.fade else 0.5 - 0.5 * np.cos(np.pi * max(t, 0.0) / self.fade)
        return w * np.sum(self.amp * np.sin(2 * np.pi * self.f * t + self.phase), axis=1)


@dataclass
class Noise:
    encoder: float = 2e-5  # [rad]
    accelerometer: float = 0.02  # [m/s^2]
    branch_force: float = 0.5  # [N]


@dataclass
class Recording:
    """Samples k = 0..N-1 at t_k = k * period, stamped ``stamp_ns`` (= T0 + t_k); the torque
    ``applied[k]`` acts on [t_k, t_k+1): the command tau_cmd[k - d] of ``command_delay`` d
    (zero before the first command acts); ``applied`` None: tau_cmd itself (d = 0)."""

    mech: Mechanism
    t: np.ndarray
    stamp_ns: np.ndarray
    tau_cmd: np.ndarray  # (N, n_a) commanded torques
    disturbance: np.ndarray  # (N, n_a) the unknown torque at t_k
    q: np.ndarray  # (N, n_t) truth
    qd: np.ndarray
    accel_true: np.ndarray  # (N, 3) specific force at the end effector (world axes)
    F: np.ndarray  # (N, n_b) true branch forces
    encoder: np.ndarray  # (N, n_a) noisy motor angles
    accel: np.ndarray  # (N, 3) noisy accelerometer
    branch: np.ndarray  # (N, n_b) noisy branch forces
    noise: Noise
    label: str = ""
    info: dict = field(default_factory=dict)
    applied: np.ndarray | None = None  # (N, n_a) the command acting on [t_k, t_k+1)
    accel_timing: str = "before_command"
    command_delay: int = 0  # [periods]

    @property
    def acting(self) -> np.ndarray:
        """(N, n_a) the command acting on [t_k, t_k+1)."""
        return self.tau_cmd if self.applied is None else self.applied

    @property
    def active_names(self) -> list[str]:
        return self.mech.active_names

    @property
    def branch_names(self) -> list[str]:
        return [b.name for b in self.mech.model.branches]

    def true_torque(self, k: int) -> np.ndarray:
        """Torque acting just before t_k (command of the previous period + disturbance at t_k)."""
        prev = self.acting[k - 1] if k > 0 else np.zeros(self.tau_cmd.shape[1])
        return prev + self.disturbance[k]


def simulate(mech: Mechanism, command: Callable[[int, float, np.ndarray], np.ndarray], duration: float,
             disturbance: Callable[[float], np.ndarray] | None, noise: Noise, rng: np.random.Generator,
             truth_dt: float = 5e-5, period: float = PERIOD, q0: np.ndarray | None = None, label: str = "",
             accel_timing: str = "before_command", command_delay: int = 0, integrator: str = "rk4",
             rtol: float = 1e-10, stamp0_ns: int = 0) -> Recording:
    """Closed-loop recording: command(k, t_k, noisy encoder angles) -> torque held on
    [t_k+d, t_k+d+1), d = ``command_delay`` periods; the accelerometer sample of t_k per
    ``accel_timing`` (module docstring); ``integrator`` "rk4" (step ``truth_dt``) or "dop853"
    (``rtol``, atol 1e-3 rtol); stamps ``stamp0_ns`` + t_k [ns]."""
    if accel_timing not in ACCEL_TIMINGS:
        raise ValueError(f"accel_timing must be one of {ACCEL_TIMINGS}, got {accel_timing!r}")
    if command_delay < 0 or int(command_delay) != command_delay:
        raise ValueError(f"command_delay must be a whole number of periods >= 0, got {command_delay!r}")
    n_a = len(mech.active)
    n_steps = round(duration / period)
    sim = Simulator(mech, SimulationOptions(formulation="scdd", integrator=integrator, dt=truth_dt, rtol=rtol,
                                            atol=1e-3 * rtol, stabilization="projection"))
    dyn = Dynamics(mech, "scdd")
    q = rest_state(mech) if q0 is None else np.array(q0, dtype=float)
    qd = np.zeros(mech.n)
    chain = int(mech.model.end_effector_chain)
    g = np.asarray(mech.model.gravity, dtype=float)
    rows: dict[str, list] = {k: [] for k in ("t", "tau", "dist", "q", "qd", "acc", "F", "enc", "accn", "br", "app")}
    prev = np.zeros(n_a)  # the torque that acted on [t_k-1, t_k)
    queue = [np.zeros(n_a)] * command_delay  # commands issued, not yet acting
    for k in range(n_steps + 1):
        t = k * period
        d = disturbance(t) if disturbance is not None else np.zeros(n_a)
        F = mech.branch_forces(q, qd)
        enc = q[mech.active] + noise.encoder * rng.standard_normal(n_a)
        tau = np.asarray(command(k, t, enc), dtype=float)
        queue.append(tau)
        acting = queue.pop(0)  # on [t_k, t_k+1)
        # a(t_k-) under the torque of the period that ended; a(t_k+) under the one that starts
        sampled = prev if accel_timing == "before_command" else acting
        acc = ee_acceleration(mech, dyn, q, qd, sampled + d, chain) - g
        for key, v in (("t", t), ("tau", tau), ("dist", d), ("q", q.copy()), ("qd", qd.copy()), ("acc", acc),
                       ("F", F), ("enc", enc), ("accn", acc + noise.accelerometer * rng.standard_normal(3)),
                       ("br", F + noise.branch_force * rng.standard_normal(len(F))), ("app", acting)):
            rows[key].append(v)
        if k < n_steps:
            sim.advance(q, qd, HeldPlusSmooth(acting, disturbance), t, t + period)
        prev = acting
    t = np.array(rows["t"])
    return Recording(mech, t, int(stamp0_ns) + np.round(t * NS).astype(np.int64), np.array(rows["tau"]),
                     np.array(rows["dist"]), np.array(rows["q"]), np.array(rows["qd"]), np.array(rows["acc"]),
                     np.array(rows["F"]), np.array(rows["enc"]), np.array(rows["accn"]), np.array(rows["br"]), noise,
                     label, applied=np.array(rows["app"]), accel_timing=accel_timing, command_delay=int(command_delay))


def manoeuvre_recording(mech: Mechanism, seed: int = 1, disturbance_rms: float = 0.02, noise: Noise | None = None,
                        duration: float | None = None, truth_dt: float = 5e-5,
                        disturbance_band: tuple[float, float] = (2.0, 200.0),
                        disturbance: Callable[[float], np.ndarray] | None = None, **timing) -> Recording:
    """The reference manoeuvre (rigid feedforward of the quintic line, 1 kHz, ZOH; the last
    torque held after its end) + a multisine in ``disturbance_band`` [Hz] (2-200 Hz: the
    observer's test case) or the given ``disturbance``; ``timing``: :func:`simulate`'s
    accel_timing, command_delay, integrator, rtol, stamp0_ns."""
    line = REFERENCE_MANOEUVRE.line
    _, torques, _ = line_torques(mech.model, line, 1.0 / PERIOD)
    rng = np.random.default_rng(seed)
    dist = Multisine(rng, len(mech.active), disturbance_rms, *disturbance_band) if disturbance_rms > 0 else None
    dist = dist if disturbance is None else disturbance
    duration = line.duration if duration is None else duration

    def command(k: int, t: float, enc: np.ndarray) -> np.ndarray:
        return torques[min(k, len(torques) - 1)]

    rec = simulate(mech, command, duration, dist, noise or Noise(), rng, truth_dt, label="manoeuvre", **timing)
    rec.info = {"disturbance_rms": disturbance_rms, "disturbance_band": disturbance_band, "seed": seed}
    return rec


def chirp_recording(mech: Mechanism, seed: int = 2, amplitude: float = 3.0, f0: float = 20.0, f1: float = 800.0,
                    duration: float = 0.5, disturbance_rms: float = 0.02, noise: Noise | None = None,
                    kp: float = 40.0, kd: float = 1.0, truth_dt: float = 5e-5,
                    disturbance: Callable[[float], np.ndarray] | None = None, **timing) -> Recording:
    """A linear chirp f0 -> f1 of ``amplitude`` N m (the motors in opposite phase), on a PD
    loop (kp [N m/rad], kd [N m s/rad] on differenced encoder angles) that holds the start pose
    with the static torque that carries the machine's weight there;
    a 2-200 Hz multisine or the given ``disturbance``; ``timing`` as :func:`manoeuvre_recording`."""
    rng = np.random.default_rng(seed)
    dist = Multisine(rng, len(mech.active), disturbance_rms) if disturbance_rms > 0 else None
    dist = dist if disturbance is None else disturbance
    q0 = rest_state(mech)
    ref = q0[mech.active]
    hold = holding_torques(mech, q0)  # zero on a horizontal machine
    last = {"enc": ref.copy()}
    sign = np.array([1.0, -1.0] + [1.0] * (len(mech.active) - 2))
    ramp = 0.02  # [s] amplitude ramp at both ends

    def command(k: int, t: float, enc: np.ndarray) -> np.ndarray:
        phase = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / duration * t * t)
        env = min(1.0, t / ramp, max(0.0, (duration - t) / ramp))
        vel = (enc - last["enc"]) / PERIOD if k > 0 else np.zeros_like(enc)
        last["enc"] = enc
        return hold + amplitude * env * np.sin(phase) * sign + kp * (ref - enc) - kd * vel

    rec = simulate(mech, command, duration, dist, noise or Noise(), rng, truth_dt, q0=q0, label="chirp", **timing)
    rec.info = {"amplitude": amplitude, "f0": f0, "f1": f1, "disturbance_rms": disturbance_rms, "seed": seed}
    return rec
