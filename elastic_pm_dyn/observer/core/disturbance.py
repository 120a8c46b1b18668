"""Linear models of the unknown torques d on chosen joints (the observer's disturbance states).

d = Lz z with z' = Fz z + w, w white with intensity diag(psd). Unknown torques (friction,
payload, cable forces, cogging) move the machine as the commanded torques do not; with d in
the state the sensors estimate them, and with them the branch forces they cause.

Models (``process.disturbance``):
- ``random_walk``: d' white (a wandering bias).
- ``gauss_markov``: first-order, stationary std and correlation time.
- ``integrated_random_walk``: d'' white (smooth, unbounded).
- ``band_limited``: a sum of stationary second-order processes, one per corner frequency
  B_i in ``disturbance_bandwidth`` (f'' = -2 zeta w f' - w^2 f + white, w = 2 pi B_i,
  zeta = 1/sqrt 2: flat below B_i, falling as f^-4 above), or with
  ``disturbance_band_order: 4`` fourth-order Butterworth processes (f^-8 above B_i: a band
  that ends, as a multisine's does, instead of a tail that reaches the spring modes and
  sets the filter's confidence there). Smooth like a real disturbance
  (no steps that would ring the springs) and bounded where the sensors cannot see it. The
  total variance ``disturbance_stddev``^2 is split equally between the corners: corners
  spaced by a constant ratio then give about equal power per octave between the lowest
  and the highest (a 1/f spectrum, as of a multisine with log-spaced tones), one corner a
  flat band.
- ``bias_band_limited`` (default): a random-walk bias (what encoders can follow) plus the
  band-limited sum (what an accelerometer or strain gauges also see).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from elastic_pm_dyn.observer.config import BAND_MODELS, InitialConfig, ProcessConfig

if TYPE_CHECKING:
    from elastic_pm_dyn.observer.core.observer_model import ObserverModel

ZETA = 1.0 / np.sqrt(2.0)


@dataclass
class DisturbanceModel:
    Lz: np.ndarray  # (nd, nz): d = Lz z
    Fz: np.ndarray  # (nz, nz)
    psd: np.ndarray  # (nz,) white-noise intensities
    initial_stddev: np.ndarray  # (nz,) of z at a (re)start
    names: list[str]  # (nz,) state names

    @property
    def nz(self) -> int:
        return self.Fz.shape[0]

    @property
    def joint_of_state(self) -> np.ndarray:
        """(nz,) the disturbance joint (index into the model's joint list given to build) of each state."""
        nd = self.Lz.shape[0]
        return np.tile(np.arange(nd), self.nz // nd) if nd else np.zeros(0, dtype=int)

    @property
    def rate_order(self) -> np.ndarray:
        """(nz,) which time derivative of a disturbance each state is (0: the torque itself;
        names end in ``_rate``, ``_rate2``, ``_rate3``)."""
        orders = [re.search(r"_rate(\d*)$", n) for n in self.names]
        return np.array([0 if m is None else int(m.group(1) or 1) for m in orders], dtype=int)

    @property
    def is_rate(self) -> np.ndarray:
        """(nz,) True for states that are a disturbance's rate of change (of any order)."""
        return self.rate_order > 0


def butterworth(order: int, w: float) -> tuple[np.ndarray, np.ndarray]:
    """A Butterworth low-pass of ``order`` and corner ``w`` [rad/s] driven by unit white noise,
    in companion form (f, f', ...): the state matrix, and the stationary stds of the states."""
    poles = w * np.exp(1j * np.pi * (2 * np.arange(1, order + 1) + order - 1) / (2 * order))
    a = np.real(np.poly(poles))  # s^n + a_1 s^(n-1) + ... + a_n
    A = np.zeros((order, order))
    A[:-1, 1:] = np.eye(order - 1)
    A[-1, :] = -a[:0:-1]
    from scipy.linalg import solve_continuous_lyapunov
    B = np.zeros((order, order))
    B[-1, -1] = 1.0
    P = solve_continuous_lyapunov(A, -B)
    return A, np.sqrt(np.diag(P))


def _bands(pc: ProcessConfig, nd: int, names: list[str]) -> tuple[list, list, list, list]:
    """The band-limited sum, per corner: Lz and Fz blocks, intensities, initial stds, state names."""
    eye, zero = np.eye(nd), np.zeros((nd, nd))
    corners = list(pc.disturbance_bandwidth)
    sigma = pc.disturbance_stddev / np.sqrt(len(corners))
    order = pc.disturbance_band_order
    L, F, psd, sd, zn = [], [], [], [], []
    for i, b in enumerate(corners):
        w = 2 * np.pi * b
        tag = "band" if len(corners) == 1 else f"band{i}"
        if order == 2:
            L += [eye, zero]
            F.append(np.block([[zero, eye], [-w * w * eye, -2 * ZETA * w * eye]]))
            psd += [0.0] * nd + [4 * ZETA * w ** 3 * sigma ** 2] * nd  # stationary variance sigma^2
            sd += [sigma] * nd + [sigma * w] * nd
            zn += [f"d_{n}_{tag}" for n in names] + [f"d_{n}_{tag}_rate" for n in names]
            continue
        A, unit_sd = butterworth(order, w)
        gain = sigma / unit_sd[0]  # white-noise std scale for stationary variance sigma^2
        L += [eye] + [zero] * (order - 1)
        F.append(np.kron(A, eye))
        psd += [0.0] * nd * (order - 1) + [gain ** 2] * nd
        sd += [s for k in range(order) for s in [gain * unit_sd[k]] * nd]
        zn += [f"d_{n}_{tag}" + ("" if k == 0 else "_rate" if k == 1 else f"_rate{k}") for k in range(order)
               for n in names]
    return L, F, psd, sd, zn


def build(pc: ProcessConfig, initial: InitialConfig, names: list[str]) -> DisturbanceModel:
    """The disturbance model of ``pc.disturbance`` on the joints ``names`` (nd = len(names))."""
    nd = len(names)
    eye = np.eye(nd)
    kind = pc.disturbance
    if kind in BAND_MODELS:
        L, F, psd, sd, zn = _bands(pc, nd, names)
        if kind == "bias_band_limited":
            L = [eye] + L
            F = [np.zeros((nd, nd))] + F
            psd = [pc.disturbance_intensity] * nd + psd
            sd = [initial.disturbance_stddev] * nd + sd
            zn = [f"d_{n}_bias" for n in names] + zn
        from scipy.linalg import block_diag
        return DisturbanceModel(np.ascontiguousarray(np.hstack(L)), block_diag(*F), np.array(psd), np.array(sd), zn)
    if kind == "integrated_random_walk":  # z = [d, d']
        zero = np.zeros((nd, nd))
        return DisturbanceModel(np.ascontiguousarray(np.hstack([eye, zero])), np.block([[zero, eye], [zero, zero]]),
                                np.array([0.0] * nd + [pc.disturbance_intensity] * nd),
                                np.array([initial.disturbance_stddev] * nd + [initial.disturbance_rate_stddev] * nd),
                                [f"d_{n}" for n in names] + [f"d_{n}_rate" for n in names])
    if kind == "gauss_markov":
        tc = pc.disturbance_time_constant
        return DisturbanceModel(eye.copy(), -eye / tc, np.full(nd, 2.0 * pc.disturbance_stddev ** 2 / tc),
                                np.full(nd, initial.disturbance_stddev), [f"d_{n}" for n in names])
    # random_walk (or none: nd = 0)
    return DisturbanceModel(eye.copy(), np.zeros((nd, nd)), np.full(nd, pc.disturbance_intensity),
                            np.full(nd, initial.disturbance_stddev), [f"d_{n}" for n in names])


@dataclass
class WithWrench:
    """The motor disturbance model and the end-effector wrench states together: z = [z_d, w],
    d = Lz z on ``dist_idx`` = [the disturbance joints, every q_ae joint]."""

    Lz: np.ndarray  # (n_d + n_ae, n_zd + n_w): [[Lz_d, 0], [0, G(q)]], G filled by the kernels
    Fz: np.ndarray
    psd: np.ndarray
    initial_stddev: np.ndarray
    names: list[str]
    dist_idx: np.ndarray
    dist_col: np.ndarray


def with_wrench(dm: DisturbanceModel, model: ObserverModel, pc: ProcessConfig, initial: InitialConfig) -> WithWrench:
    """``dm`` with the wrench states of ``model`` appended (``process.wrench: random_walk``).

    Each component w_c is a random walk, w_c' white (``wrench_intensity`` for a force,
    ``wrench_torque_intensity`` for a couple): a contact or a push is a step or a ramp that
    stays, which a random walk follows with no bias once it has settled, where a band-limited
    state would let it decay. Its joint forces G(q) w (G = W^T J^T: seed eq 31's G^{+T}) act on
    every q_ae joint, springs included: a force on the tool loads the springs as a motor torque
    does not, which is what tells the two apart (with the accelerometer's help)."""
    nae, nw = model.nae, len(model.wrench_names)
    couple = np.abs(model.wrench_axes[:, 3:]).sum(axis=1) > 0
    Lz = np.zeros((dm.Lz.shape[0] + nae, dm.nz + nw))
    Lz[:dm.Lz.shape[0], :dm.nz] = dm.Lz
    Fz = np.zeros((dm.nz + nw, dm.nz + nw))
    Fz[:dm.nz, :dm.nz] = dm.Fz
    psd = np.r_[dm.psd, np.where(couple, pc.wrench_torque_intensity, pc.wrench_intensity)]
    sd = np.r_[dm.initial_stddev, np.where(couple, initial.wrench_torque_stddev, initial.wrench_stddev)]
    return WithWrench(np.ascontiguousarray(Lz), Fz, psd, sd, [*dm.names, *(f"wrench_{c}" for c in model.wrench_names)],
                      np.r_[model.dist_idx, model.ae].astype(np.int64),
                      np.r_[model.dist_col, np.arange(nae)].astype(np.int64))
