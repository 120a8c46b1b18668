"""Linearisation about a static pose: natural frequencies of the elastic modes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from elastic_pm_dyn.kinematics.assembly import solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.layout import JF_COULOMB, JF_SLIP


@dataclass
class Modes:
    """Linear modes about a pose; frequencies in Hz, shapes in q_ae coordinates."""

    natural_hz: np.ndarray  # undamped natural frequencies
    damped_hz: np.ndarray  # imaginary parts of the damped eigenvalues / 2 pi (NaN: none oscillates)
    damping_ratio: np.ndarray  # per natural_hz entry (NaN at 0 Hz)
    shapes: np.ndarray  # columns: mode shapes over the free coordinates
    coordinates: list[str]  # names of the free coordinates


def compact_matrices(mech: Mechanism, q: np.ndarray, tau_active: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """M_c (eq 21), D_c (eq 25) and the tangent stiffness dQ/dq_ae at a static pose.

    The stiffness is the derivative of the static generalised force
    Q(q_ae) = W^T (h_t(q_t(q_ae), 0) - tau_t) by central differences, so it contains the
    springs (K_c, eq 24), gravity and the geometric stiffness of the loaded closure.
    """
    tau_t = mech.split_tau(np.zeros(len(mech.active)) if tau_active is None else tau_active)
    t = mech.terms(q)
    W, _ = mech.passive_map(t)
    Mc = W.T @ t.M @ W
    # Damping: h is affine in qd at fixed q only through D and friction at zero speed.
    probe = np.zeros(mech.n)
    Dt = np.zeros((mech.n, mech.n))
    for j in range(mech.n):
        probe[:] = 0.0
        probe[j] = 1.0
        # Coriolis terms are quadratic in qd: the central difference removes them.
        Dt[:, j] = (mech.terms(q, 1e-3 * probe).h - mech.terms(q, -1e-3 * probe).h) / 2e-3
    Dc = W.T @ Dt @ W

    def generalised_force(q_ae: np.ndarray) -> np.ndarray:
        qq = q.copy()
        qq[mech.ae] = q_ae
        qq = solve_pose(mech, qq, mech.passive)
        tt = mech.terms(qq)
        Wq, _ = mech.passive_map(tt)
        return Wq.T @ (tt.h - tau_t)

    q_ae = q[mech.ae]
    K = np.zeros((len(q_ae), len(q_ae)))
    for j in range(len(q_ae)):
        # Steps scaled to what each coordinate moves in practice: rad vs m of a stiff spring.
        step = 1e-9 if j >= len(mech.active) else 1e-6
        e = np.zeros(len(q_ae))
        e[j] = step
        K[:, j] = (generalised_force(q_ae + e) - generalised_force(q_ae - e)) / (2 * step)
    return Mc, Dc, 0.5 * (K + K.T)


def elastic_modes(mech: Mechanism, q: np.ndarray, clamp_motors: bool = True,
                  tau_active: np.ndarray | None = None) -> Modes:
    """Modes about q; with ``clamp_motors`` the active joints are held (stiff position
    control), leaving the elastic modes; otherwise the motors are free (zero torque
    change) and rigid-body modes appear at 0 Hz."""
    Mc, Dc, K = compact_matrices(mech, q, tau_active)
    n_a = len(mech.active)
    names = [mech.joint_names[i] for i in mech.ae]
    keep = np.arange(n_a, len(mech.ae)) if clamp_motors else np.arange(len(mech.ae))
    M, D, Kk = Mc[np.ix_(keep, keep)], Dc[np.ix_(keep, keep)], K[np.ix_(keep, keep)]
    w2, shapes = scipy.linalg.eigh(Kk, M)
    natural = np.sqrt(np.clip(w2, 0.0, None)) / (2 * np.pi)
    n = len(keep)
    state = np.block([[np.zeros((n, n)), np.eye(n)],
                      [-np.linalg.solve(M, Kk), -np.linalg.solve(M, D)]])
    eig = np.linalg.eigvals(state)
    osc = list(eig[eig.imag > 0])
    # Each undamped mode with the oscillating eigenvalue nearest to it (|lambda| = omega_n for a
    # light damping); a mode at 0 Hz (a free joint: no spring) or one damped past oscillating
    # gets NaN, so the three arrays stay aligned with natural_hz.
    damped, ratio = np.full(n, np.nan), np.full(n, np.nan)
    for k in np.argsort(-natural):
        if natural[k] <= 0 or not osc:
            continue
        i = int(np.argmin([abs(abs(lam) - 2 * np.pi * natural[k]) for lam in osc]))
        lam = osc.pop(i)
        damped[k], ratio[k] = lam.imag / (2 * np.pi), -lam.real / abs(lam)
    return Modes(natural, damped, ratio, shapes, [names[i] for i in keep])


RK4_REAL_LIMIT = 2.785  # RK4 is stable for a real eigenvalue -lambda while h lambda <= 2.785


def dry_friction_step(mech: Mechanism, q: np.ndarray) -> tuple[float, str] | None:
    """The fixed RK4 step the regularised dry friction allows (about): F / v_s is a viscous slope
    within the slip band, over the joint's own inertia (the mass matrix's diagonal at q) a rate
    lambda; (2.785 / the largest lambda, its joint), None without regularised dry friction (Coulomb's
    law, slip speed 0, has no slope: its stops are found within the steps, sim/kernels.py)."""
    jf = mech.arrays.jf
    dry = np.flatnonzero((jf[:, JF_COULOMB] > 0) & (jf[:, JF_SLIP] > 0))
    if not len(dry):
        return None
    M = mech.terms(q).M
    rates = jf[dry, JF_COULOMB] / (jf[dry, JF_SLIP] * np.diag(M)[dry])
    k = int(np.argmax(rates))
    return RK4_REAL_LIMIT / float(rates[k]), mech.joint_names[dry[k]]
