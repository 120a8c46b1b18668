"""Recovery from divergence (``gating.recover_after``, default 10): the encoders are the motor angles' ground truth.

When they have been gated out that many times in a row, the estimate has followed another
sensor or a mis-modelled input (a disturbance far stronger than the model's, a wrong command
delay or sample timing) away from them; instead of gating them out wholesale the filter falls
back (:meth:`EncoderRecovery.on_gated`): motors re-initialised from the sample (rates by a
finite difference of the last two), the motor/elastic blocks of P back to the initial prior,
the disturbance states kept, and the process-noise intensities multiplied by
:data:`RECOVERY_PSD_GROWTH` (up to :data:`RECOVERY_PSD_MAX` in all: the model's noise was too
small for the data). Each recovery is counted (``stats``, summary.json, /diagnostics, the
sensor's NIS finding and so health WARN) and kept with its time (:class:`Recovery`). The
compiled steps stop at a gated sample, so the Python scheduler takes every gated one and the
recovery is the same live and offline.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from elastic_pm_dyn.errors import ElasticPmDynError
from elastic_pm_dyn.kinematics.assembly import solve_pose
from elastic_pm_dyn.observer.core import correction, kernels
from elastic_pm_dyn.observer.core.sensors import motor_positions

RECOVERY_PSD_GROWTH = 4.0  # each recovery multiplies the process noise intensities by this ...
RECOVERY_PSD_MAX = 256.0  # ... up to this factor in all (the model's noise was too small for the data)


@dataclass
class Recovery:
    """A fall-back (:meth:`EncoderRecovery.on_gated`): at time t the encoders had been gated out
    ``rejections`` times in a row (motor error ``motor_error`` [rad], the largest) and the
    motors were re-initialised from them."""

    t: float
    sensor: str
    rejections: int
    motor_error: float
    psd_scale: float = 1.0  # the process noise intensities' factor from here on

    def text(self) -> str:
        return (f"recovered from divergence at t = {self.t:.6f} s: {self.sensor} gated out {self.rejections} times "
                f"in a row (motor error {self.motor_error:.3g} rad); motors re-initialised from {self.sensor}, "
                f"disturbance estimates kept")


class EncoderRecovery:
    """The fall-backs of one filter: the last gated encoder sample and the recoveries since the last reset."""

    def __init__(self) -> None:
        self.last_gated: tuple[float, np.ndarray] | None = None  # (t, motor positions)
        self.done: list[Recovery] = []

    def reset(self) -> None:
        self.last_gated = None
        self.done = []

    def on_gated(self, obs: Any, t: float, names, position) -> None:
        """An encoder sample of ``obs`` (an Observer) gated out: remember it; after
        ``gating.recover_after`` in a row (0: never) fall back."""
        st = obs.stats["encoders"]
        motors = motor_positions(obs.mech, names, position)
        prev, self.last_gated = self.last_gated, None if motors is None else (t, motors)
        after = obs.cfg.gating.recover_after
        if after > 0 and obs.gating and motors is not None and st.consecutive_rejections >= after:
            self._fall_back(obs, t, motors, prev)

    def _fall_back(self, obs: Any, t: float, motors: np.ndarray, prev: tuple[float, np.ndarray] | None) -> None:
        """Fall back after a run of gated encoder samples: the estimate has followed another
        sensor (or a mis-modelled input) away from the encoders, which are the ground truth of
        the motor angles. The motor positions are re-initialised from this sample, their rates
        from it and the previous gated one (a finite difference), the elastic coordinates and
        rates kept (the passive joints from the closure); the motor/elastic blocks of P go back
        to the initial prior (the motor rates' to the finite difference's spread), their
        cross-covariance with the disturbance states is dropped, the disturbance states and
        their covariance are kept (each at least its prior). So the next samples are accepted
        again; counted in ``stats['encoders'].recoveries`` and :attr:`done`."""
        mech, nae = obs.mech, obs.nae
        act = np.asarray(mech.active, dtype=np.int64)
        error = float(np.max(np.abs(obs.q[act] - motors)))
        q, qd = obs.q.copy(), obs.qd.copy()
        q[act] = motors
        P0 = obs.P0
        na = len(act)
        vel_var = np.full(na, np.nan)
        if prev is not None and t - prev[0] > obs.cfg.timing.stamp_tolerance:
            dt = t - prev[0]
            qd[act] = (motors - prev[1]) / dt
            enc = obs.encoders
            var = dict(zip(enc.pos, enc.pos_var, strict=True))
            noise = np.array([var.get(int(j), float(np.max(enc.pos_var, initial=0.0))) for j in act])
            vel_var = 2.0 * noise / dt ** 2
        try:
            q = solve_pose(mech, q, mech.passive)
        except ElasticPmDynError:
            return  # no closure there: keep reporting the divergence
        qd_ae = qd[obs.ae].copy()
        qd = np.zeros(mech.n)
        qd[obs.ae] = qd_ae
        gap, ratio = correction.apply_correction(mech.arrays, q, qd, np.zeros(obs.nz), np.zeros(obs.nx))
        if not (gap <= 1e-9 and ratio >= kernels.SINGULAR_TOL):
            return
        P = np.zeros_like(obs.P)
        n2 = 2 * nae
        P[:n2, :n2] = P0[:n2, :n2]
        for i, j in enumerate(act):
            if np.isfinite(vel_var[i]):
                k = nae + obs.x_of_ae[int(j)]
                P[k, k] = max(P0[k, k], vel_var[i])
        Pz = obs.P[n2:, n2:]
        P[n2:, n2:] = Pz
        for i in range(obs.nz):
            P[n2 + i, n2:] = Pz[i]
            P[n2 + i, n2 + i] = max(Pz[i, i], P0[n2 + i, n2 + i])
        if RECOVERY_PSD_GROWTH > 1.0 and obs._psd_scale * RECOVERY_PSD_GROWTH <= RECOVERY_PSD_MAX:
            obs._grow_process_noise(RECOVERY_PSD_GROWTH)  # the model's noise was too small for what the data did
        obs._jump_to(q, qd, P)
        st = obs.stats["encoders"]
        self.done.append(Recovery(t, "encoders", st.consecutive_rejections, error, obs._psd_scale))
        st.recoveries += 1
        st.consecutive_rejections = 0
        self.last_gated = None
