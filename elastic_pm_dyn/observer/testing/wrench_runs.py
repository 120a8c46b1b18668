"""Lockstep runs of the plant under an external wrench with the observer beside it (tests, bench/).

One period k: the plant's state at t_k is sampled (encoders; the accelerometer under the
torque of the period that ended, the unknown motor torque and the wrench at t_k, a(t_k-)),
the samples go to the :class:`~elastic_pm_dyn.observer.schedule.observer.Observer`, the
controller's command of t_k too, then the plant steps to t_k+1 under it. The controller is
a PD on the true motor angles around the start pose (plus gravity's holding torque and an
optional feedforward ``extra(t)``): it keeps the machine where a push can be measured, as a
real position loop would. The truth is the plant's own (:class:`~elastic_pm_dyn.sim.plant.Plant`
with ETD2 at 1e-4 s or RK4), not the observer's model run again.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from elastic_pm_dyn.dynamics.statics import holding_torques
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.sim.disturbances import seeded_disturbance
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.sensors import EncoderSpec, ImuSpec, SensorModel, SensorSpec
from elastic_pm_dyn.sim.simulator import SimulationOptions
from elastic_pm_dyn.sim.wrench import ExternalWrench

PERIOD = 1e-3  # [s]


@dataclass
class WrenchRun:
    """Per period k (t_k = k PERIOD): the true wrench projected on the estimate's components,
    the estimate and its standard deviation (n_w columns), and the estimate rows' NEES of the
    wrench states."""

    t: np.ndarray
    true: np.ndarray
    estimate: np.ndarray
    stddev: np.ndarray
    names: list[str]
    ee: np.ndarray  # true end-effector point (world) per period
    cov: np.ndarray  # (periods, n_w, n_w) the wrench states' covariance block
    rows: list[np.ndarray] = field(default_factory=list)  # estimate rows (observer layout), if kept
    stopped_at: float | None = None  # t at which ``stop`` returned True (the run then ends)
    period_s: np.ndarray | None = None  # wall time of the observer's calls per period (its live cost)
    jumps: list[float] = field(default_factory=list)  # stamps where the observer let the wrench jump


# The motor disturbance model and the wrench's random walk that go together (docs/state_observer.md,
# "Choosing the disturbance model"): no bias state (a constant joint load and a constant wrench give
# the same joint forces: with both random walks their difference is unobservable on a stiff
# machine and its variance grows without bound), bands up to the unknown torque's top (the runs'
# flat 2-200 Hz multisine has 3/4 of its power above 50 Hz, where the generic [5, 50] Hz model
# rolls off: then the wrench states absorb it), and a quieter wrench random walk, steps being
# carried by the accelerometer's jump gate.
FORCE_SENSING = {"process.disturbance": "band_limited", "process.disturbance_bandwidth": [5.0, 100.0],
                 "process.wrench_intensity": 0.5}


def wrench_config(**overrides) -> ObserverConfig:
    """Encoders + accelerometer (a(t_k-)), the wrench states on with :data:`FORCE_SENSING`'s
    disturbance model; ``overrides`` flat parameters (``process__wrench_intensity=10.0``)."""
    params = {"sensors": ["encoders", "imu"], "imu.sample_timing": "before_command", "process.wrench": "random_walk",
              **FORCE_SENSING}
    params.update({k.replace("__", "."): v for k, v in overrides.items()})
    return ObserverConfig.from_parameters(params)


def run(mech: Mechanism, wrench: ExternalWrench, duration: float, config: ObserverConfig | None = None,
        disturbance_rms: float = 0.02, seed: int = 4301, kp: float | None = None, kd: float | None = None,
        extra: Callable[[float], np.ndarray] | None = None, keep_rows: bool = False,
        stop: Callable[[int, np.ndarray, np.ndarray], bool] | None = None, integrator: str = "etd2",
        ref_rate: np.ndarray | None = None) -> WrenchRun:
    """Plant and observer in lockstep for ``duration`` s (module docstring). ``stop(k, row, layout)``
    -> True ends the run after period k (a contact detector's verdict). Gains default to the
    motors' inertia scale (a stiff hold that still leaves a push measurable); ``ref_rate``
    [rad/s or m/s per motor] moves the held angles at constant rates (a slow move, e.g. into a
    wall)."""
    n_a = len(mech.active)
    dist = seeded_disturbance("flat", n_a, disturbance_rms, max(duration, 0.1), seed) if disturbance_rms > 0 else None
    plant = Plant(mech, SimulationOptions(integrator=integrator), PERIOD, dist, start="static", wrench=wrench)
    sensors = SensorModel(mech, SensorSpec(EncoderSpec(enabled=True), ImuSpec(enabled=True), seed=seed))
    obs = Observer(mech, config or wrench_config())
    layout = obs.layout
    axes = obs.model.wrench_axes
    hold = holding_torques(mech, plant.q)
    ref = plant.q[mech.active].copy()
    inertia = np.diag(mech.terms(plant.q).M)[mech.active]
    kp = 500.0 * inertia.mean() if kp is None else kp  # the chirp runs' PD (bench/tools/observer_runs.py)
    kd = 12.5 * inertia.mean() if kd is None else kd
    names = list(mech.active_names)
    n = round(duration / PERIOD)
    t_out, true, est, sd, ee, cov = [], [], [], [], [], []
    ws = np.arange(obs.nx - obs.nw, obs.nx)
    rows = []
    stopped = None
    wall = []
    tau = hold.copy()
    for k in range(n + 1):
        t = plant.t
        pos, _ = sensors.encoders(plant.q, plant.qd)
        acc = sensors.accelerometer(plant.q, plant.qd, plant.motor_torque(), plant.wrench_tree_forces())
        start = time.perf_counter()
        obs.update_joint_states(t, names, pos)
        obs.update_imu(t, acc)
        wall.append(time.perf_counter() - start)
        target, rate = (ref, 0.0) if ref_rate is None else (ref + ref_rate * t, ref_rate)
        tau = hold + kp * (target - plant.q[mech.active]) + kd * (rate - plant.qd[mech.active])
        if extra is not None:
            tau = tau + extra(t)
        start = time.perf_counter()
        obs.command(t, tau)
        row = obs.estimate_flat()
        wall[-1] += time.perf_counter() - start
        t_out.append(t)
        true.append(axes[:, :3] @ plant.true_wrench[:3] + axes[:, 3:] @ plant.true_wrench[3:])
        est.append(row[layout["wrench"]].copy())
        sd.append(row[layout["wrench_std"]].copy())
        ee.append(plant.wrench_map.point_state(plant.q, plant.qd)[0])
        cov.append(obs.P[np.ix_(ws, ws)].copy())
        if keep_rows:
            rows.append(row)
        if stop is not None and stop(k, row, layout):
            stopped = t
            break
        if k < n:
            plant.step(tau)
    return WrenchRun(np.array(t_out), np.array(true), np.array(est), np.array(sd), list(obs.model.wrench_names),
                     np.array(ee), np.array(cov), rows, stopped, np.array(wall), list(obs.wrench_jumps))


def step_scores(run_: WrenchRun, t_step: float, component: int, size: float) -> dict:
    """The step response of one component: |error| / size 20 ms after the step; in the steady
    state (the last 30 % of the samples from 100 ms after the step on) the bias |mean error| / size
    (``steady_error``) and the mean |error| / size (``steady_abs_error``: bias and noise); the
    fraction of samples (after 50 ms of settling) whose NEES of the wrench states (their full
    covariance block) lies in its two-sided 95 % chi-square band."""
    from scipy.stats import chi2
    k20 = int(np.searchsorted(run_.t, t_step + 0.020 - 1e-9))
    err = run_.estimate[:, component] - run_.true[:, component]
    after = run_.t >= t_step + 0.1
    tail = np.flatnonzero(after)[int(0.7 * after.sum()):] if after.any() else np.array([], dtype=int)
    settled = run_.t >= 0.05
    e = (run_.estimate - run_.true)[settled]
    nees = np.einsum("ki,ki->k", e, np.linalg.solve(run_.cov[settled], e[..., None])[..., 0])
    dof = run_.estimate.shape[1]
    lo, hi = chi2.ppf(0.025, dof), chi2.ppf(0.975, dof)
    return {"error_at_20ms": float(abs(err[k20]) / size),
            "steady_error": float(abs(np.mean(err[tail])) / size) if len(tail) else float("nan"),
            "steady_abs_error": float(np.mean(np.abs(err[tail])) / size) if len(tail) else float("nan"),
            "nees_in_band": float(np.mean((nees >= lo) & (nees <= hi))),
            "mean_nees_per_dof": float(np.mean(nees) / dof)}
