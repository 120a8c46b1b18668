"""Which states do the configured sensors make observable? (Reported at start-up.)

The filter's model is linearised at a state (by default the start pose at rest, no
torque), discretised at the sample period (``process.max_interval``), and two questions
are answered per state:

1. Information over a horizon (deterministic observability): with the prior covariance
   P0 = diag(s^2) (the configured initial standard deviations, but for an elastic joint at
   least the deflection and rate of a 1 N vibration, so that the verdict does not hang on
   how tight the start-up prior is), the information
   I_N = sum_k (C Phi^k)^T R^-1 (C Phi^k) of N noisy samples gives the posterior
   std sqrt(diag((P0^-1 + I_N)^-1)). Its ratio to the prior std says how much the sensors
   alone, without process noise, pin a state down within the horizon: < 0.1 observable,
   < 0.9 weakly observable, else not observable in practice. The singular values of the
   scaled Gramian S I_N S (relative to the largest) tell the same for directions.
2. Steady state (with the process noise): the discrete algebraic Riccati equation gives
   the filter's stationary posterior std per state and per branch force, if the pair is
   detectable (it is not, e.g., for an accelerometer alone: it cannot see a constant
   motor offset).

On the reference five-bar the spring acts radially to the motor: 1 N of vibrating branch
force moves a motor by 1e-8..1e-7 rad, far below encoder noise, so with encoders only the
elastic states come out weakly observable (their quasi-static part through the model and
the disturbance states), with an accelerometer or strain gauges observable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from elastic_pm_dyn.observer.core import kernels

OBSERVABLE = 0.1
WEAK = 0.9


def linear_model(obs, q: np.ndarray, qd: np.ndarray, tau_active: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, G Q_c G^T, H_point) of the observer's continuous model at a consistent tree state."""
    mech = obs.mech
    nae = obs.nae
    tau = mech.split_tau(tau_active)
    if hasattr(obs, "z"):
        tau[obs.dist_idx] += obs.disturbance()
    Aq, Av, Bf = np.empty((nae, nae)), np.empty((nae, nae)), np.empty((nae, nae))
    Eq, Ev, Ef = np.empty((3, nae)), np.empty((3, nae)), np.empty((3, nae))
    kernels.linearize(mech.arrays, np.array(q, dtype=float), np.array(qd, dtype=float), tau, obs.point, True,
                      obs.eps_q, obs.eps_v, Aq, Av, Bf, Eq, Ev, Ef, np.empty(mech.n), np.empty(3))
    Ac, Qc = np.empty((obs.nx, obs.nx)), np.empty((obs.nx, obs.nx))
    kernels.continuous_model(Aq, Av, Bf, obs.dist_col, obs.Lz, obs.Fz, obs.psd_ae, obs.psd_z, Ac, Qc)
    H = np.zeros((3, obs.nx))
    H[:, :nae], H[:, nae:2 * nae] = Eq, Ev
    H[:, 2 * nae:] = Ef[:, obs.dist_col] @ obs.Lz
    return Ac, Qc, H


def reference_scale(obs, Ac: np.ndarray) -> np.ndarray:
    """Prior std per state for the horizon analysis: the initial std, for elastic joints at
    least 1 N / stiffness (position) and w / stiffness (rate, w from the linearised model)."""
    s = np.sqrt(np.diag(obs.P0)).copy()
    nae = obs.nae
    for i, j in enumerate(obs.ae):
        c = obs.mech.model.joints[int(j)].stiffness
        if c > 0:
            w = np.sqrt(max(-Ac[nae + i, i], 0.0))
            s[i] = max(s[i], 1.0 / c)
            s[nae + i] = max(s[nae + i], w / c)
    return s


def measurement_matrix(obs, q: np.ndarray, H_point: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """C, noise variances and row labels of the configured sensor set at pose q."""
    rows, var, labels = [], [], []
    nx = obs.nx
    if obs.encoders is not None:
        e = obs.encoders
        W = np.empty((obs.mech.n, obs.nae))
        kernels.passive_rows(obs.mech.arrays, np.array(q, dtype=float), W)
        if e.pos:
            rows.append(e.rows(e.pos, W, nx, 0))
            var.append(e.pos_var)
            labels += [f"{obs.mech.joint_names[j]}.position" for j in e.pos]
        if e.vel:
            rows.append(e.rows(e.vel, W, nx, obs.nae))
            var.append(e.vel_var)
            labels += [f"{obs.mech.joint_names[j]}.velocity" for j in e.vel]
    if obs.imu is not None:
        rows.append(obs.imu.S @ H_point)
        var.append(obs.imu.var)
        labels += obs.imu.labels
    if obs.branch is not None:
        for b in obs.branch.names:
            row = np.zeros(nx)
            row[:2 * obs.nae] = obs.branch.rows[b][0]
            rows.append(row[None, :])
            labels.append(f"F_{b}")
        var.append(obs.branch.var)
    if not rows:
        return np.zeros((0, nx)), np.zeros(0), []
    return np.vstack(rows), np.concatenate(var), labels


@dataclass
class ObservabilityReport:
    sensors: list[str]
    measurements: list[str]
    state_names: list[str]
    units: list[str]
    horizon: float
    prior_std: np.ndarray
    posterior_std: np.ndarray
    ratio: np.ndarray
    classes: list[str]
    singular_values: np.ndarray  # of the scaled Gramian, relative to the largest
    steady_std: np.ndarray | None  # stationary filter std per state (None if not detectable)
    steady_branch_std: np.ndarray | None
    branch_names: list[str]
    note: str

    def elastic_summary(self, elastic_names: list[str]) -> str:
        parts = [f"{n}: {c}" for n, c in zip(self.state_names, self.classes, strict=True)
                 if n.removesuffix("_vel") in elastic_names]
        return "; ".join(parts)

    def text(self) -> str:
        lines = [f"observability of the linearised model (sensors: {', '.join(self.sensors) or 'none'}; "
                 f"measurements: {', '.join(self.measurements) or 'none'}; horizon {self.horizon * 1e3:.0f} ms)",
                 f"  {'state':24s} {'prior std':>11s} {'after horizon':>13s} {'ratio':>7s}  "
                 f"{'class':18s} {'steady-state std':>16s}"]
        for i, name in enumerate(self.state_names):
            ss = "-" if self.steady_std is None else f"{self.steady_std[i]:.3g}"
            lines.append(f"  {name:24s} {self.prior_std[i]:11.3g} {self.posterior_std[i]:13.3g} "
                         f"{self.ratio[i]:7.3f}  {self.classes[i]:18s} {ss:>16s} {self.units[i]}")
        sv = ", ".join(f"{v:.2g}" for v in self.singular_values)
        lines.append(f"  relative singular values of the scaled Gramian: {sv}")
        if self.steady_branch_std is not None:
            lines.append("  steady-state branch-force std: " + ", ".join(
                f"{b} {s:.3g} N" for b, s in zip(self.branch_names, self.steady_branch_std, strict=True)))
        if self.note:
            lines.append(f"  {self.note}")
        return "\n".join(lines)


def analyse(obs, horizon: float | None = None, q: np.ndarray | None = None, qd: np.ndarray | None = None,
            tau_active: np.ndarray | None = None) -> ObservabilityReport:
    """Observability report of ``obs``'s sensor set at (q, qd, tau) (default: its current state, no torque)."""
    mech = obs.mech
    q = obs.q if q is None else q
    qd = obs.qd if qd is None else qd
    tau_active = np.zeros(len(mech.active)) if tau_active is None else tau_active
    horizon = obs.cfg.observability_horizon if horizon is None else horizon
    T = obs.period
    Ac, Qc, Hpt = linear_model(obs, q, qd, tau_active)
    Phi, Qd = np.empty_like(Ac), np.empty_like(Ac)
    kernels.discretize(Ac, Qc, T, Phi, Qd)
    C, R, labels = measurement_matrix(obs, q, Hpt)
    s = reference_scale(obs, Ac)
    n_steps = max(1, round(horizon / T))
    info = np.zeros((obs.nx, obs.nx))
    Ck = C * s  # scaled: x = S xi
    Rinv = 1.0 / R if R.size else R
    for _ in range(n_steps):
        info += Ck.T @ (Rinv[:, None] * Ck)
        Ck = Ck @ (np.diag(1.0 / s) @ Phi @ np.diag(s))
    post = np.linalg.inv(np.eye(obs.nx) + info)
    ratio = np.sqrt(np.clip(np.diag(post), 0.0, None))
    classes = ["observable" if r < OBSERVABLE else "weakly observable" if r < WEAK else "not observable"
               for r in ratio]
    sv = np.linalg.svd(info, compute_uv=False)
    sv = sv / sv[0] if sv.size and sv[0] > 0 else sv
    steady, steady_F, note = None, None, ""
    if C.shape[0]:
        try:
            Pp = scipy.linalg.solve_discrete_are(Phi.T, C.T, Qd + 1e-30 * np.eye(obs.nx), np.diag(R))
            S = C @ Pp @ C.T + np.diag(R)
            Pu = Pp - Pp @ C.T @ np.linalg.solve(S, C @ Pp)
            if np.all(np.isfinite(Pu)) and np.all(np.diag(Pu) >= 0):
                steady = np.sqrt(np.diag(Pu))
                HF = np.zeros((len(obs.branch_names), obs.nx))  # the branch forces' rows of H
                HF[:, :2 * obs.nae] = obs.model.H_F
                steady_F = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", HF, Pu, HF), 0.0))
        except (np.linalg.LinAlgError, ValueError) as exc:
            note = f"no steady-state filter: the pair (Phi, C) is not detectable ({exc})"
    units = []
    for k in range(2 * obs.nae):  # [q_ae, qd_ae]
        joint = mech.model.joints[int(obs.ae[k % obs.nae])]
        u = "rad" if joint.type == "revolute" else "m"
        units.append(u if k < obs.nae else u + "/s")
    dm = obs.disturbance_model
    for j, order in zip(dm.joint_of_state, dm.rate_order, strict=True):
        joint = mech.model.joints[int(obs.dist_idx[j])]
        units.append(("N m" if joint.type == "revolute" else "N") + ("" if order == 0 else "/s" if order == 1
                                                                     else f"/s^{order}"))
    units += ["N m" if c.startswith("torque") else "N" for c in obs.model.wrench_names]
    return ObservabilityReport(list(obs.cfg.sensors), labels, list(obs.state_names), units, horizon, s,
                               s * ratio, ratio, classes, sv, steady, steady_F, list(obs.branch_names), note)
