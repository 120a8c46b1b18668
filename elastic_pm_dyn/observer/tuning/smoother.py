"""Offline Rauch-Tung-Striebel smoother over the EKF's per-stamp results (``observe --smoother rts``).

The filter's estimate at stamp t_k holds only the samples up to t_k; offline, every sample
is known, and a backward pass over the filter's results gives the estimate from all of
them (Rauch, Tung and Striebel 1965). Per estimate row the filter stores the posterior
x_k, P_k (``Observer.estimate_flat``: x and the full P). Between consecutive rows the pass
needs the filter's prediction: the predicted x_{k+1|k}, P_{k+1|k} and the transition
Phi_k over [t_k, t_k+1] (the product of the prediction pieces' Phi). Then, backwards from
the last row of a segment (where the smoothed estimate is the filtered one)::

    C_k   = P_k Phi_k^T P_{k+1|k}^-1                   (a solve with P_{k+1|k}, scaled to unit diagonal)
    x_k^s = x_k + C_k (x_{k+1}^s - x_{k+1|k})
    P_k^s = P_k + C_k (P_{k+1}^s - P_{k+1|k}) C_k^T

The prediction is recomputed, not stored: :class:`Replay` is an :class:`Observer` of the
same configuration that takes the torque commands in the filter's order (so it holds,
delays and times out the same commands) and, for each interval, restarts from the
filter's posterior at t_k and predicts to t_k+1 with the filter's own code, one piece at a
time (the pieces the filter cut: ``process.max_interval``, a command timeout, a delayed
command starting to act), keeping each piece's Phi. Its linearisation schedule
(``process.relinearize_every``) runs as the filter's did, so x_{k+1|k}, P_{k+1|k} and Phi_k
are the filter's own numbers; storing them in the filter instead would mean a third output
of ``period.run_periods`` (the offline fast path) for a pass that needs them once. A
sample the filter held for a command that never came (``imu.sample_timing``
``after_command``) is corrected after its row was recorded; the replay predicts from the
row (that sample is not in the smoothed estimate at that one stamp).

The state x = [q_ae, qd_ae, z] is a chart of the closure manifold (the minimal coordinates);
a smoothed x goes back to the tree state by the closure (``correction.apply_correction``, the
filter's partitioning) and to the outputs (every joint, branch forces, deflections, the end
effector and their standard deviations) by ``kernels.estimate_flat``, as the filter's.

Rows not joined by one prediction (the filter faulted, the replay could not predict, the
filter fell back at a recovery: ``Observer.recoveries``, whose grown process noise the replay
then takes on) end a segment; each is smoothed on its own.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.core import correction, kernels, period
from elastic_pm_dyn.observer.core.ekf import ObserverFault
from elastic_pm_dyn.observer.drivers.bag_input import Event
from elastic_pm_dyn.observer.drivers.rows import Rows
from elastic_pm_dyn.observer.drivers.stream import ObserverStream
from elastic_pm_dyn.observer.schedule.observer import Observer

SMOOTHERS = ("rts",)


@dataclass
class Predictions:
    """The filter's prediction from each row k to row k+1 (index k; the last row's unused):
    ``joined[k]`` False where rows k and k+1 are not joined by one prediction (a segment ends
    at k); ``tau_last[k]``: the torque of the last prediction piece before row k (its effort)."""

    x_pred: np.ndarray  # (N, nx) x_{k+1|k}
    P_pred: np.ndarray  # (N, nx, nx) P_{k+1|k}
    Phi: np.ndarray  # (N, nx, nx) Phi_k
    joined: np.ndarray  # (N,) bool
    tau_last: np.ndarray  # (N, n_active)


@dataclass
class SmoothedPass:
    """The smoothed rows (the filter's NIS kept) and a few numbers for summary.json."""

    rows: Rows
    stats: dict


class Replay(Observer):
    """An :class:`Observer` that predicts one piece at a time, keeping each piece's Phi."""

    def advance_pieces(self, t_to: float) -> np.ndarray:
        """Predict to t_to as :meth:`Observer._advance` does, piece by piece (the ends it cuts);
        returns the product of the pieces' Phi."""
        tol = self.cfg.timing.stamp_tolerance
        timeout = self.cfg.timing.command_timeout
        Phi = np.eye(self.nx)
        commands = self.commands
        commands.activate_due(self.t)
        no_pending = np.zeros(0)
        while t_to - self.t > tol:
            next_t = np.array([commands.pending[0][0]]) if commands.pending else no_pending
            end = period.piece_end(self.t, t_to, self.cfg.process.max_interval, commands.t_command, timeout, next_t,
                                   0, len(next_t), tol)
            self._advance(end)  # exactly one piece up to ``end``
            Phi = self.Phi @ Phi
        return Phi

    def restart_from(self, flat: np.ndarray) -> None:
        """The filter's posterior of an estimate row: tree state, disturbance states, covariance."""
        lay = self.layout
        nae, nx = self.nae, self.nx
        self.q = flat[lay["q"]].copy()
        self.qd = flat[lay["qd"]].copy()
        self.z = flat[lay["x"]][2 * nae:].copy()
        self.P = flat[lay["P"]].reshape(nx, nx).copy()
        self.t = float(flat[0])
        self.fault = None


def _in_filter_order(events: list[Event], order: str) -> list[Event]:
    if order == "stamp":
        return sorted(events, key=lambda e: (e.stamp_ns, e.index))
    if order != "arrival":
        raise InputError(f"unknown message order {order!r} (expected stamp or arrival)")
    return events


def predictions(mech: Mechanism, cfg: ObserverConfig, events: list[Event], order: str, rows: Rows,
                recoveries: list | None = None) -> Predictions:
    """The filter's prediction between consecutive rows of a pass over ``events`` (module
    docstring); ``recoveries``: the filter's (``Observer.recoveries``), each ends a segment."""
    rep = Replay(mech, cfg, t0=0.0)
    base_ae, base_z = rep.psd_ae.copy(), rep.psd_z.copy()
    recovered = [(r.t, r.psd_scale) for r in recoveries or ()]
    lay = rep.layout
    nx, n_rows = rep.nx, len(rows.t)
    stream = ObserverStream(rep, origin_ns=rows.origin_ns)
    row_at = {int(ns): k for k, ns in enumerate(rows.t)}
    out = Predictions(np.zeros((n_rows, nx)), np.zeros((n_rows, nx, nx)), np.zeros((n_rows, nx, nx)),
                      np.zeros(n_rows, dtype=bool), np.zeros((n_rows, len(mech.active))))
    k = -1  # the row the replay stands at
    last_ns = int(rows.t[-1])
    for ev in _in_filter_order(events, order):
        if k == n_rows - 1 and ev.stamp_ns > last_ns:
            break  # after the last row (the filter may have faulted): nothing left to predict
        j = row_at.get(int(ev.stamp_ns))
        if j is not None and j > k:
            t_j = stream.seconds(ev.stamp_ns)
            scale = next((s for t_r, s in recovered if abs(t_r - rows.flat[j][0]) <= cfg.timing.stamp_tolerance),
                         None)
            if k < 0 or j != k + 1 or scale is not None:  # the first row, rows not joined, a recovery:
                flat = rows.flat[j]  # the filter (re)started here (a reset keeps the held command)
                psd_scale = rep._psd_scale if scale is None else scale
                rep.reset(t_j, flat[lay["q"]], flat[lay["qd"]], flat[lay["P"]].reshape(nx, nx))
                rep.psd_ae[:], rep.psd_z[:] = base_ae * psd_scale, base_z * psd_scale
                rep._psd_scale = psd_scale
            else:
                rep.restart_from(rows.flat[k])
                try:
                    Phi = rep.advance_pieces(t_j)
                except ObserverFault:
                    Phi = None
                if Phi is not None and abs(rep.t - t_j) <= cfg.timing.stamp_tolerance:
                    out.x_pred[k], out.P_pred[k], out.Phi[k] = rep.x(), rep.P, Phi
                    out.joined[k] = True
                rep.t = t_j
            out.tau_last[j] = rep.tau_last
            k = j
        if ev.kind == "command":
            try:
                stream.on_torque_command(ev.stamp_ns, *ev.data)
            except ObserverFault:  # where the filter faulted too (no later rows)
                break
    return out


def _gain(P: np.ndarray, P_pred: np.ndarray, Phi: np.ndarray) -> np.ndarray:
    """C = P Phi^T P_pred^-1 by a Cholesky solve of P_pred scaled to unit diagonal (the state
    mixes radians and micrometres: unscaled, its condition number is round-off's)."""
    s = np.sqrt(np.clip(np.diag(P_pred), 1e-300, None))
    B = (Phi @ P) / s[:, None]  # P_pred C^T = Phi P, with P_pred = S R S
    R = P_pred / np.outer(s, s)
    try:
        Ct = cho_solve(cho_factor(R, lower=True, check_finite=False), B, check_finite=False)
    except LinAlgError:
        Ct = np.linalg.lstsq(R, B, rcond=1e-12)[0]
    return (Ct / s[:, None]).T


def rts(x: np.ndarray, P: np.ndarray, x_pred: np.ndarray, P_pred: np.ndarray, Phi: np.ndarray,
        joined: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The RTS backward pass: filtered x (N, nx), P (N, nx, nx); x_pred[k], P_pred[k], Phi[k]
    the prediction from k to k+1 where ``joined[k]`` (else k ends a segment: smoothed =
    filtered there). Returns smoothed (x^s, P^s)."""
    xs, Ps = np.array(x, dtype=float), np.array(P, dtype=float)
    for k in range(len(xs) - 2, -1, -1):
        if not joined[k]:
            continue
        C = _gain(P[k], P_pred[k], Phi[k])
        xs[k] = x[k] + C @ (xs[k + 1] - x_pred[k])
        Pk = P[k] + C @ (Ps[k + 1] - P_pred[k]) @ C.T
        Ps[k] = 0.5 * (Pk + Pk.T)
    return xs, Ps


def smoothed_rows(obs: Observer, rows: Rows, xs: np.ndarray, Ps: np.ndarray, tau_last: np.ndarray) -> Rows:
    """Estimate rows of the smoothed states: x^s -> tree state through the closure (from the
    filtered one), then every output with ``kernels.estimate_flat`` (as the filter's rows)."""
    lay = rows.layout
    nae = obs.nae
    ma, fixed, proc = obs.mech.arrays, obs.model.fixed, obs._proc
    out = Rows(rows.layout, list(rows.t), [], [list(v) for v in rows.nis], rows.origin_ns, rows.stats)
    for k, flat in enumerate(rows.flat):
        q, qd = flat[lay["q"]].copy(), flat[lay["qd"]].copy()
        x = flat[lay["x"]]
        z = x[2 * nae:].copy()
        dx = xs[k] - x
        if np.any(dx):
            correction.apply_correction(ma, q, qd, z, dx)
        new = np.empty_like(flat)
        # the smoothed state as the kernels' State bundle (Phi, Qd, Hpt and info are not read)
        state = (q, qd, z, np.ascontiguousarray(Ps[k]), obs.Phi, obs.Qd, obs.Hpt, obs.info)
        kernels.estimate_flat(ma, fixed, proc, state, tau_last[k], float(flat[0]), new)
        out.flat.append(new)
    return out


def smooth(mech: Mechanism, cfg: ObserverConfig, obs: Observer, events: list[Event], order: str,
           rows: Rows) -> SmoothedPass:
    """RTS-smoothed rows of a filter pass (``rows`` of ``obs`` over ``events`` in ``order``)."""
    wall = time.perf_counter()
    if not rows.t:
        return SmoothedPass(Rows(rows.layout, origin_ns=rows.origin_ns, stats=rows.stats), {"rows": 0})
    pred = predictions(mech, cfg, events, order, rows, obs.recoveries)
    wall_pred = time.perf_counter() - wall
    lay = rows.layout
    nx = obs.nx
    table = rows.table()
    x = table[:, lay["x"]]
    P = table[:, lay["P"]].reshape(-1, nx, nx)
    xs, Ps = rts(x, P, pred.x_pred, pred.P_pred, pred.Phi, pred.joined)
    out = smoothed_rows(obs, rows, xs, Ps, pred.tau_last)
    smoothed = out.table()
    F_f, F_s = table[:, lay["branch_force_std"]], smoothed[:, lay["branch_force_std"]]
    ratio = F_s / np.where(F_f > 0, F_f, np.nan)
    stats = {"rows": len(rows.t), "segments": int(1 + np.count_nonzero(~pred.joined[:-1])),
             "branch_force_std_ratio_mean": float(np.nanmean(ratio)),
             "branch_force_std_ratio_max": float(np.nanmax(ratio)),
             "branch_force_change_rms_N": float(np.sqrt(np.mean(np.square(
                 smoothed[:, lay["branch_force"]] - table[:, lay["branch_force"]])))),
             "wall_replay_s": wall_pred, "wall_smooth_s": time.perf_counter() - wall}
    return SmoothedPass(out, stats)
