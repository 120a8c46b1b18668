"""The extended Kalman filter itself over the exact SCDD model: its state, predict and correct.

State x = [q_ae, qd_ae, z]: motor and elastic coordinates, their rates, and (optionally)
disturbance torques d = Lz z on chosen joints from a linear model
(:mod:`elastic_pm_dyn.observer.core.disturbance`; default: a random-walk bias plus band-limited
parts). Unknown torques (friction, payload, cable forces) move the machine as the commanded
torques do not; with d in the state the sensors estimate them, and with them the
quasi-static branch forces they cause: encoders the slow part (d moves a motor only through
a double integration, so it must act for a while, ~10 ms for 0.02 N m on the reference
five-bar, before the encoders see it), an accelerometer or strain gauges also the fast
part (see bench/studies/observer_bound.py for what is possible at all). The tree state (every
joint) follows from x through the closure; a start from encoders puts the springs in
static equilibrium.

Prediction (:meth:`Ekf._predict`): the commanded torques are held (zero-order hold, as the
controller applies them); the mean goes through the plant's integrator (``process.integrator``,
a row of sim/integrators.py's table: ETD2 or RK4) over the nonlinear SCDD model, the
covariance through the transition of the model linearised at the interval's start, with its
discrete process noise (:mod:`~elastic_pm_dyn.observer.core.kernels`,
:mod:`~elastic_pm_dyn.observer.core.propagation`), all in the compiled ``advance`` of
:mod:`~elastic_pm_dyn.observer.core.period`. Correction (``_correct_*``): one compiled call per
message, Joseph form, chi-square gating of the normalised innovation squared (NIS) at
:meth:`Ekf.gate`. Outputs: one compiled call writes the estimate row
(:class:`~elastic_pm_dyn.observer.core.estimate.EstimateLayout`).

The filter knows no messages, stamps or queues: the scheduler
(:class:`~elastic_pm_dyn.observer.schedule.observer.Observer`, a subclass) says when to predict
and with which commands, and which samples to correct with.
"""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import ACTIVE
from elastic_pm_dyn.model.layout import JF_COULOMB
from elastic_pm_dyn.observer.config import RUNTIME_PARAMETERS, ObserverConfig
from elastic_pm_dyn.observer.core import correction, disturbance, kernels, period, wrench_kernels
from elastic_pm_dyn.observer.core.chi_square import chi2_quantile
from elastic_pm_dyn.observer.core.estimate import Estimate, EstimateLayout
from elastic_pm_dyn.observer.core.observer_model import ObserverModel
from elastic_pm_dyn.observer.core.sensors import Sample
from elastic_pm_dyn.pinned_kernels import KernelPins
from elastic_pm_dyn.sim.integrators import METHODS


class ObserverFault(ElasticPmDynError):
    """The filter cannot go on (model singular, state or covariance not finite): reset it."""


class Ekf:
    """The filter over one :class:`~elastic_pm_dyn.observer.core.observer_model.ObserverModel` and
    configuration: state (q, qd, z, P and the last linearisation), time ``t``, the process model,
    the sensors with their noise levels, predict, correct and the estimate row.

    ``mech``: the mechanism, or an ObserverModel built for it (the fixed part, shared by many
    filters with configurations of one
    :func:`~elastic_pm_dyn.observer.core.observer_model.model_key`)."""

    def __init__(self, mech: Mechanism | ObserverModel, config: ObserverConfig | None = None):
        cfg = (config or ObserverConfig.from_parameters()).for_machine(
            mech.mech if isinstance(mech, ObserverModel) else mech)
        if isinstance(mech, ObserverModel):
            if not mech.serves(cfg):
                raise InputError("observer: the configuration's sensors or disturbance joints are not its model's")
            model = mech
        else:
            model = ObserverModel.build(mech, cfg)
        self.model = model
        self.mech = model.mech
        self.cfg = cfg
        self.ae, self.x_of_ae, self.eps_q, self.eps_v = model.ae, model.x_of_ae, model.eps_q, model.eps_v
        self.nae = nae = model.nae
        self.nd = len(model.dist_idx)
        pc = cfg.process
        self.disturbance_model = dm = disturbance.build(pc, cfg.initial, model.dist_names)
        # with wrench states (process.wrench) z ends with them and d = Lz z with the wrench's
        # joint forces on every q_ae joint (disturbance.with_wrench; Lz's block follows the pose)
        self.nw = len(model.wrench_names)
        zm = disturbance.with_wrench(dm, model, pc, cfg.initial) if self.nw else None
        self.dist_idx, self.dist_col = (model.dist_idx, model.dist_col) if zm is None else (zm.dist_idx, zm.dist_col)
        self.Lz, self.Fz, self.psd_z = (dm.Lz, dm.Fz, dm.psd) if zm is None else (zm.Lz, zm.Fz, zm.psd)
        self._z_initial_stddev = dm.initial_stddev if zm is None else zm.initial_stddev
        self._z_names = dm.names if zm is None else zm.names
        self.nz = len(self.psd_z)
        self.nx = 2 * nae + self.nz
        roles = model.roles
        self.psd_ae = np.array([pc.torque_noise_psd if r == ACTIVE else pc.elastic_force_psd for r in roles])
        self.psd_ae += pc.friction_psd(self.mech.arrays.jf[self.ae, JF_COULOMB])  # friction's own uncertainty
        self.rel_ae = np.array([0.0 if r == ACTIVE else pc.vibration_noise for r in roles])
        self._psd_scale = 1.0  # the noise intensities' factor (a recovery grows it; a reset undoes it)
        # the kernels' bundle of this configuration (psd_ae and psd_z grow in place at a recovery)
        integrator = METHODS[pc.integrator]  # the mean's (sim/integrators.py)
        method = np.zeros(4, dtype=np.int64)  # kernels.Process.method
        method[kernels.INTEGRATOR], method[kernels.SCHEME] = integrator.kernel
        method[kernels.STABILIZATION] = kernels.MEAN_STABILIZATION[integrator.method]
        method[kernels.LINEARIZATION] = kernels.SPRINGS if pc.linearization == "springs" else kernels.DIFFERENCES
        self._proc = tuple(kernels.Process(self.dist_idx, self.dist_col, self.Lz, self.Fz, self.psd_ae, self.rel_ae,
                                           self.psd_z, method, np.full(1 + self.nz, np.nan),
                                           np.empty((4, self.nz, self.nz)), np.empty((self.nz, self.nz)),
                                           model.wrench_points, model.wrench_axes))
        self.period = pc.max_interval
        # the mean's step in use: process.dt if given, else from the model's fastest spring
        self.dt = model.mean_step(integrator, pc.dt, pc.max_interval)
        # False: no sample is gated (gate = inf), so that a likelihood cannot be won by gating
        # (observer.tuning.tuning sets it before the first sample)
        self.gating = True
        self._gates: dict[int, float] = {}
        self._take_noise(cfg)  # the sensors: the model's geometry with this configuration's noise levels
        self.point = model.point
        self.with_point = model.with_point
        self.branch_names = model.branch_names
        self.state_names = ([self.mech.joint_names[j] for j in self.ae]
                            + [f"{self.mech.joint_names[j]}_vel" for j in self.ae] + self._z_names)
        self.P0 = np.diag(self._initial_variances())
        self.layout = EstimateLayout.of(model, self.nx)  # of the estimate rows (estimate_flat)
        self._pin = KernelPins()  # the kernels called per message, without numba's type dispatch
        self.t = 0.0  # [s] the filter's time
        self.tau_last = np.zeros(len(self.mech.active))  # the motor torques of the last prediction piece
        self.initialised = True  # a state to estimate from (the scheduler may wait for a measured one)
        self.fault: str | None = None

    def _initial_variances(self) -> np.ndarray:
        i = self.cfg.initial
        roles = self.model.roles
        pos = [i.active_position_stddev if r == ACTIVE else i.elastic_position_stddev for r in roles]
        vel = [i.active_velocity_stddev if r == ACTIVE else i.elastic_velocity_stddev for r in roles]
        return np.concatenate([pos, vel, self._z_initial_stddev]) ** 2

    def _take_noise(self, cfg: ObserverConfig) -> None:
        """The sensor models with ``cfg``'s noise levels, the compiled steps' accelerometer bundle,
        and no cached gate (``gating.probability``)."""
        model = self.model
        self.encoders = model.encoders.with_noise(cfg) if model.encoders is not None else None
        self.imu = model.imu.with_noise(cfg) if model.imu is not None else None
        self.branch = model.branch.with_noise(cfg) if model.branch is not None else None
        self._imu = None if self.imu is None else tuple(kernels.ImuModel(self.imu.S, self.imu.g, self.imu.var))
        self._imu_bundle = self._imu or (np.zeros((0, 3)), np.zeros(3), np.zeros(0))
        self._gates.clear()

    def set_measurement_noise(self, cfg: ObserverConfig) -> None:
        """Take the sensors' noise levels and the gate of ``cfg`` (``config.RUNTIME_PARAMETERS``)
        from the next sample on; state, covariance, schedule and model stay. ``cfg`` must differ
        from the current configuration only there (InputError otherwise)."""
        cfg = cfg.for_machine(self.mech)  # as at construction (imu.axes: auto resolved)
        old, new = self.cfg.parameters, cfg.parameters
        other = sorted(k for k in old if old[k] != new.get(k) and k not in RUNTIME_PARAMETERS)
        if other:
            raise InputError(f"only the noise levels and the gate change in a running filter, not {', '.join(other)}")
        self.cfg = cfg
        self._take_noise(cfg)

    def gate(self, dof: int) -> float:
        """The NIS gate of a sample with ``dof`` entries (``gating.probability``; inf with :attr:`gating` off)."""
        if not self.gating:
            return np.inf
        g = self._gates.get(dof)
        if g is None:
            g = self._gates[dof] = float(chi2_quantile(self.cfg.gating.probability, dof))
        return g

    def imu_gate(self, dof: int) -> float:
        """The accelerometer's NIS gate in the per-sample steps: :meth:`gate`, or with wrench states the
        lower ``process.wrench_jump_probability`` quantile, above which a sample is first taken as the
        wrench's jump (the scheduler's ``_wrench_jump``) and gated only if it stays beyond :meth:`gate` after it."""
        if not self.nw or not self.gating:
            return self.gate(dof)
        key = -dof  # cached beside the gates of gating.probability
        g = self._gates.get(key)
        if g is None:
            # never above the full gate (a gating.probability set below the jump's)
            p = min(self.cfg.process.wrench_jump_probability, self.cfg.gating.probability)
            g = self._gates[key] = float(chi2_quantile(p, dof))
        return g

    # ------------------------------------------------------------------ state
    def _state(self) -> tuple:
        """The kernels' :class:`~elastic_pm_dyn.observer.core.kernels.State` bundle (the arrays: changed in place)."""
        return self.q, self.qd, self.z, self.P, self.Phi, self.Qd, self.Hpt, self.info

    def _set_state(self, q: np.ndarray | None, qd: np.ndarray | None, P0: np.ndarray | None) -> None:
        """State (q, qd) (default: the model's initial pose at rest; the closure fixes q_p and qd_p),
        no disturbance, covariance ``P0`` (default: the initial prior), no linearisation yet."""
        mech = self.mech
        q = self.model.q_initial.copy() if q is None else np.array(q, dtype=float)
        qd = np.zeros(mech.n) if qd is None else np.array(qd, dtype=float)
        if q.shape != (mech.n,) or qd.shape != (mech.n,):
            raise InputError(f"observer reset: a state needs {mech.n} tree coordinates")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise InputError("observer reset: NaN or Inf in the state")
        gap, ratio = correction.apply_correction(mech.arrays, q, qd, np.zeros(self.nz), np.zeros(self.nx))
        if not (gap <= 1e-9 and ratio >= kernels.SINGULAR_TOL):
            raise InputError(f"observer reset: the closure cannot be solved there (gap {gap:.3g} m)")
        self.q, self.qd = q, qd
        self.z = np.zeros(self.nz)
        self.P = (self.P0 if P0 is None else np.array(P0, dtype=float)).copy()
        if self.P.shape != (self.nx, self.nx):
            raise InputError(f"observer reset: covariance must be {self.nx} x {self.nx}")
        self.fault = None
        if self._psd_scale != 1.0:  # a reset forgets what the recoveries learned
            self.psd_ae /= self._psd_scale
            self.psd_z /= self._psd_scale
        self._psd_scale = 1.0
        self.Phi = np.eye(self.nx)
        self.Qd = np.zeros((self.nx, self.nx))
        self._lin_age, self._lin_T = 1 << 30, -1.0  # intervals since the last linearisation, its length
        self.Hpt = np.zeros((3, self.nx))
        self.info = np.zeros(2)
        self._refresh_wrench()

    def _refresh_wrench(self) -> None:
        """The wrench states' joint forces at the current pose (as every linearisation refreshes them)."""
        if self.nw:
            self._pin(wrench_kernels.refresh_wrench)(self.mech.arrays, self._proc, self.q)

    def _grow_process_noise(self, factor: float) -> None:
        """The noise intensities ``factor`` times larger (in place: the offline fast path holds these arrays)."""
        self._psd_scale *= factor
        self.psd_ae *= factor
        self.psd_z *= factor

    def _jump_to(self, q: np.ndarray, qd: np.ndarray, P: np.ndarray) -> None:
        """A new consistent state and covariance (a fall-back): linearised again at the next
        prediction, the accelerometer's Jacobian at once."""
        self.q, self.qd, self.P = q, qd, P
        self._lin_age = 1 << 30
        self._refresh_wrench()
        if self.with_point:
            self._linearize_here()

    def _linearize_here(self) -> None:
        """Accelerometer Jacobian at the current state (before the first prediction)."""
        from elastic_pm_dyn.observer.core.observability import linear_model
        _, _, self.Hpt = linear_model(self, self.q, self.qd, self.tau_last)

    def _fail(self, message: str) -> None:
        self.fault = message
        raise ObserverFault(message)

    # ------------------------------------------------------------------ predict, correct
    def _predict(self, cmd: tuple, ctl: np.ndarray, timing: np.ndarray, t_to: float, tree: np.ndarray) -> int:
        """``period.advance`` to ``t_to`` with the command bundle ``cmd`` and the control array
        ``ctl`` (the scheduler's, who takes them back); its status for :meth:`_check_prediction`."""
        return self._pin(period.advance)(self.mech.arrays, self.model.fixed, self._proc, self._state(), cmd, ctl,
                                         timing, float(t_to), tree)

    def _check_prediction(self, status: int) -> None:
        """A failed prediction (at the time :attr:`t` it stopped) is a fault."""
        if status != 0 and status != kernels.COVARIANCE_LOST:
            self._fail(f"prediction failed at t = {self.t:.6f} s: "
                       + ("singular configuration" if status == 1 else "the state became NaN/Inf")
                       + f" (conditioning {self.info[0]:.3g})")
        if status == kernels.COVARIANCE_LOST:
            self._fail(f"covariance lost positive definiteness at t = {self.t:.6f} s")

    def _correct_sample(self, s: Sample, gate: float) -> tuple[float, int, float]:
        """``correction.correct`` with a sample's H, R and innovation: (NIS, status, log det S)."""
        return self._pin(correction.correct)(self.mech.arrays, self._state(), np.ascontiguousarray(s.H), s.R, s.r, gate)

    def _correct_encoders(self, bundle: tuple, meas: np.ndarray, gate: float) -> tuple[float, int, float]:
        """``correction.encoder_correct`` (``bundle``: a :class:`~elastic_pm_dyn.observer.core.kernels.EncoderPlan`)."""
        return self._pin(correction.encoder_correct)(self.mech.arrays, self._state(), bundle, meas, gate)

    def _correct_imu(self, tau: np.ndarray, meas: np.ndarray, gate: float, a: np.ndarray) -> tuple[float, int, float]:
        """``correction.imu_correct`` under tree forces ``tau`` (``a`` receives the point's acceleration)."""
        return self._pin(correction.imu_correct)(self.mech.arrays, self.model.fixed, self._proc, self._state(),
                                                 self._imu, tau, meas, gate, a)

    def _correct_imu_weighed(self, tau_before: np.ndarray, tau_after: np.ndarray, use_after: bool, meas: np.ndarray,
                             gate: float, evidence: np.ndarray) -> tuple[float, int, float]:
        """``correction.imu_correct_auto``: both sample-timing hypotheses weighed into ``evidence``,
        the correction under ``use_after``'s."""
        return self._pin(correction.imu_correct_auto)(self.mech.arrays, self.model.fixed, self._proc, self._state(),
                                                   self._imu, tau_before, tau_after, use_after, meas, gate, evidence)

    def _weigh_imu(self, prior: tuple, tau_before: np.ndarray, tau_after: np.ndarray, meas: np.ndarray,
                   evidence: np.ndarray, a_before: np.ndarray) -> None:
        """``correction.imu_innovations`` of a sample at its ``prior`` (a State) into ``evidence`` (no correction)."""
        self._pin(correction.imu_innovations)(self.mech.arrays, self.model.fixed, self._proc, prior, self._imu,
                                              tau_before, tau_after, meas, self.imu_gate(len(meas)), evidence,
                                              a_before, True)

    # ------------------------------------------------------------------ outputs
    def x(self) -> np.ndarray:
        return np.concatenate([self.q[self.ae], self.qd[self.ae], self.z])

    def disturbance(self) -> np.ndarray:
        """Estimated disturbance torques d = Lz z on ``dist_idx`` joints (with wrench states: then
        its joint forces on every q_ae joint, the last n_ae)."""
        return self.Lz @ self.z

    def _passive_jacobian(self) -> np.ndarray:
        W = np.empty((self.mech.n, self.nae))
        kernels.passive_rows(self.mech.arrays, self.q, W)
        return W

    def estimate(self) -> Estimate:
        """Current estimates (every tree joint, branch forces, end effector) with standard deviations."""
        return self.unpack_estimate(self.estimate_flat())

    def flat_layout(self) -> dict[str, slice]:
        """Where each :class:`Estimate` field sits in :meth:`estimate_flat`'s array (:attr:`layout`'s slices)."""
        return self.layout.slices

    def estimate_flat(self) -> np.ndarray:
        """:meth:`estimate` as one float array (layout: :attr:`layout`), in one compiled call."""
        out = np.empty(self.layout.width)
        self._pin(kernels.estimate_flat)(self.mech.arrays, self.model.fixed, self._proc, self._state(), self.tau_last,
                                         self.t, out)
        return out

    def unpack_estimate(self, flat: np.ndarray, initialised: bool | None = None) -> Estimate:
        """The :class:`Estimate` of an :meth:`estimate_flat` array (fields are views into it)."""
        return self.layout.unpack(flat, self.initialised if initialised is None else initialised)

    def observability(self, horizon: float | None = None):
        """Observability of the states at the current state; see :mod:`.observability`."""
        from elastic_pm_dyn.observer.core.observability import analyse
        return analyse(self, horizon)
