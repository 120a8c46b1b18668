"""Scoring the observer on simulated recordings (the figures bench/benchmarks/bench_observer.py reports).

- Elastic part of a branch force: F minus its quasi-static rigid-model value F_qs, the
  force the rod would carry were it rigid, at the same state under the same (true) motor
  torques: the elastic joints locked (u, du/dt frozen), the lock forces from the rigid
  tree's constrained dynamics (:func:`quasi_static_branch_forces`).
- Branch-force error ratio: RMS(F_hat - F) / RMS(F - F_qs) over all samples and branches
  after a settling time; the same for an open-loop elastic simulation driven by the same
  commands (:func:`open_loop`), which knows the model but not the disturbance.
- Motor-angle error RMS, against the encoder noise.
- NEES of the mechanical states [q_ae, qd_ae] and the fraction of samples in its
  two-sided 95 % chi-square band.

Runs come from :func:`feed` (the stream fed sample by sample) or from ``observe`` over a
bag (:func:`offline_run`: its estimate rows matched to the samples by stamp).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.layout import JF_REST, JF_STIFFNESS
from elastic_pm_dyn.observer.core.chi_square import chi2_quantile
from elastic_pm_dyn.observer.core.observer_model import branch_arrays
from elastic_pm_dyn.observer.drivers.rows import Rows
from elastic_pm_dyn.observer.drivers.stream import ObserverStream
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.observer.testing.scenarios import Recording
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable


def quasi_static_branch_forces(mech: Mechanism, q: np.ndarray, qd: np.ndarray, tau_active: np.ndarray) -> np.ndarray:
    """Branch forces of the rigid machine (elastic joints locked at their current u) at (q, qd_a) under tau."""
    n, m = mech.n, mech.m
    el = mech.elastic
    qd_ae = qd[mech.ae].copy()
    qd_ae[len(mech.active):] = 0.0
    qd_r = mech.tree_velocity(q, qd_ae)
    t = mech.terms(q, qd_r)
    stiff, rest = mech.arrays.jf[el, JF_STIFFNESS], mech.arrays.jf[el, JF_REST]
    h = t.h.copy()
    h[el] -= stiff * (q[el] - rest)  # the spring is replaced by the lock
    ne = len(el)
    E = np.zeros((ne, n))
    E[np.arange(ne), el] = 1.0
    K = np.zeros((n + m + ne, n + m + ne))
    K[:n, :n] = t.M
    K[:n, n:n + m] = -t.A.T
    K[:n, n + m:] = -E.T
    K[n:n + m, :n] = t.A
    K[n + m:, :n] = E
    rhs = np.concatenate([mech.split_tau(tau_active) - h, t.gamma, np.zeros(ne)])
    mu = np.linalg.solve(K, rhs)[n + m:]
    lock = {int(j): -mu[k] for k, j in enumerate(el)}
    return np.array([lock[int(j)] for j in branch_arrays(mech)[0]])


def quasi_static_series(rec: Recording) -> np.ndarray:
    return np.array([quasi_static_branch_forces(rec.mech, rec.q[k], rec.qd[k], rec.true_torque(k))
                     for k in range(len(rec.t))])


@dataclass
class OpenLoop:
    q: np.ndarray
    qd: np.ndarray
    F: np.ndarray


def open_loop(rec: Recording, dt: float = 1e-4, as_acted: bool = True) -> OpenLoop:
    """The elastic model driven by the recorded commands alone (ZOH), without the disturbance,
    from the true start state; each command acting when it acted on the plant (``as_acted``: a
    command delay known) or from its stamp on (as the observer applies it)."""
    mech = rec.mech
    sim = Simulator(mech, SimulationOptions(formulation="scdd", dt=dt, sample=rec.t[1] - rec.t[0],
                                            stabilization="projection"))
    table = TorqueTable(rec.t, rec.acting if as_acted else rec.tau_cmd, "zoh")
    res = sim.run(table, rec.t[-1] - rec.t[0], rec.q[0], rec.qd[0], t0=rec.t[0])
    n = len(rec.t)
    return OpenLoop(res.q[:n], res.qd[:n], res.branch_forces[:n])


@dataclass
class Run:
    """Estimates at the sample times (after the corrections at t_k)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    F: np.ndarray
    F_std: np.ndarray
    x: np.ndarray
    P: np.ndarray
    q_std: np.ndarray
    accepted: dict
    rejected: dict
    update_times: np.ndarray  # [s] wall time of each period's calls


def feed(obs: Observer, rec: Recording, use: tuple[str, ...] = ("encoders", "imu", "branch_forces"),
         corrupt: dict[int, dict] | None = None, timed: bool = False) -> Run:
    """Run ``obs`` over a recording as a live node would see it: at each t_k the samples,
    then the command of t_k. ``corrupt`` maps k to replacements, e.g. {k: {"encoder": [...]}}."""
    import time
    stream = ObserverStream(obs)
    names = rec.active_names
    bnames = rec.branch_names
    out = {k: [] for k in ("t", "q", "qd", "F", "F_std", "x", "P", "q_std", "dt")}
    for k in range(len(rec.t)):
        ns = int(rec.stamp_ns[k])
        enc, acc, br = rec.encoder[k], rec.accel[k], rec.branch[k]
        if corrupt and k in corrupt:
            enc = np.asarray(corrupt[k].get("encoder", enc), dtype=float)
            acc = np.asarray(corrupt[k].get("accel", acc), dtype=float)
            br = np.asarray(corrupt[k].get("branch", br), dtype=float)
        t0 = time.perf_counter() if timed else 0.0
        if "encoders" in use:
            stream.on_joint_state(ns, names, enc)
        if "imu" in use:
            stream.on_imu(ns, acc)
        if "branch_forces" in use:
            stream.on_branch_forces(ns, bnames, br)
        stream.on_torque_command(ns, names, rec.tau_cmd[k])
        if timed:
            out["dt"].append(time.perf_counter() - t0)
        e = obs.estimate()
        for key, v in (("t", e.t), ("q", e.q), ("qd", e.qd), ("F", e.branch_force), ("F_std", e.branch_force_std),
                       ("x", e.x), ("P", e.P), ("q_std", e.q_std)):
            out[key].append(v)
    st = obs.stats
    return Run(np.array(out["t"]), np.array(out["q"]), np.array(out["qd"]), np.array(out["F"]),
               np.array(out["F_std"]), np.array(out["x"]), np.array(out["P"]), np.array(out["q_std"]),
               {s: v.accepted for s, v in st.items()}, {s: v.rejected for s, v in st.items()},
               np.array(out["dt"]))


def offline_run(rec: Recording, rows: Rows) -> Run:
    """The rows of ``observe`` (:class:`~elastic_pm_dyn.observer.drivers.rows.Rows`) at the
    recording's sample stamps: for each sample the last row at or before its stamp (the first
    row before any), so that :func:`score` compares them with the truth sample by sample."""
    est = rows.est
    stamps = np.asarray(rows.t, dtype=np.int64)
    idx = np.clip(np.searchsorted(stamps, np.asarray(rec.stamp_ns, dtype=np.int64), side="right") - 1, 0, None)
    pick = [est[i] for i in idx]
    st = rows.stats
    return Run(np.array([e.t for e in pick]), np.array([e.q for e in pick]), np.array([e.qd for e in pick]),
               np.array([e.branch_force for e in pick]), np.array([e.branch_force_std for e in pick]),
               np.array([e.x for e in pick]), np.array([e.P for e in pick]), np.array([e.q_std for e in pick]),
               {s: v.accepted for s, v in st.items()}, {s: v.rejected for s, v in st.items()}, np.zeros(0))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def score(rec: Recording, run: Run, ol: OpenLoop | None = None, F_qs: np.ndarray | None = None,
          settle: float = 0.02) -> dict:
    """Scores of one run (samples with t >= t_0 + settle)."""
    mech = rec.mech
    keep = rec.t >= rec.t[0] + settle - 1e-12
    F_qs = quasi_static_series(rec) if F_qs is None else F_qs
    elastic = rec.F - F_qs
    denom = _rms(elastic[keep])
    out = {"elastic_rms_N": denom,
           "F_error_rms_N": _rms((run.F - rec.F)[keep]),
           "F_ratio": _rms((run.F - rec.F)[keep]) / denom}
    out["F_ratio_per_branch"] = [(_rms((run.F - rec.F)[keep, i]) / _rms(elastic[keep, i]))
                                 for i in range(rec.F.shape[1])]
    if ol is not None:
        out["F_ratio_open_loop"] = _rms((ol.F - rec.F)[keep]) / denom
    act = mech.active
    out["motor_rmse_rad"] = _rms((run.q[:, act] - rec.q[:, act])[keep])
    out["motor_rmse_over_noise"] = out["motor_rmse_rad"] / rec.noise.encoder
    nae = len(mech.ae)
    x_true = np.concatenate([rec.q[:, mech.ae], rec.qd[:, mech.ae]], axis=1)
    e = run.x[:, :2 * nae] - x_true
    Pm = run.P[:, :2 * nae, :2 * nae]
    s = np.sqrt(np.einsum("kii->ki", Pm))
    nees = np.array([float(ek @ np.linalg.solve(Pk / np.outer(sk, sk), ek)) for ek, Pk, sk in
                     zip(e / s, Pm, s, strict=True)])
    dof = 2 * nae
    lo, hi = chi2_quantile(0.025, dof), chi2_quantile(0.975, dof)
    out["nees_mean"] = float(np.mean(nees[keep]))
    out["nees_in_band"] = float(np.mean((nees[keep] >= lo) & (nees[keep] <= hi)))
    out["nees_band"] = (float(lo), float(hi))
    out["F_std_mean_N"] = float(np.mean(run.F_std[keep]))
    out["accepted"] = run.accepted
    out["rejected"] = run.rejected
    return out
