"""Extended Kalman filter over the exact SCDD model of an elastic parallel manipulator.

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

Prediction: the commanded torques are held (zero-order hold, as the controller applies
them); the mean goes through the plant's ETD2 steps (or RK4) of the nonlinear SCDD model,
the covariance through the transition of the model linearised at the interval's start, with
its discrete process noise (:mod:`~elastic_pm_dyn.observer.core.kernels`,
:mod:`~elastic_pm_dyn.observer.core.propagation`). Every prediction runs
the compiled ``advance`` of :mod:`~elastic_pm_dyn.observer.core.period`, whose steps
(the samples of a stamp, its command) ``observe`` runs for many periods in one call; with
:attr:`Observer.steps_compiled` each message runs one step, and what a step does not take
(gated, late, simultaneous or non-finite samples, timing decisions, recoveries, faults) the
Python here takes, with the same numbers. Correction:
sequential per message, Joseph form, chi-square gating of the normalised innovation
squared (NIS). Samples stamped before the filter's time are late and dropped (the filter
never rewinds); a stamp ahead of it is first predicted to, unless more than
``timing.max_future`` ahead (an outlier: not used, counted as ``future``, the time stays).
Missing samples just mean longer predictions; ``reset()`` without a time restarts the clock
at the next stamp.

Time: float seconds of the message stamps since an integer-ns origin (the stream's,
:mod:`~elastic_pm_dyn.observer.drivers.stream`: epoch stamps keep their nanoseconds). The command
stamped t_k acts on [t_k + delay, t_k+1 + delay) (``command_delay``, the actuation latency:
the zero-order hold shifted; a delayed command waits in a queue and the prediction starts a
new piece where it starts to act; ``timing.command_timeout`` counts from there). A sample
stamped t_k is compared with the state at t_k.

Feed-through (``imu.sample_timing``): the accelerometer reads J qdd + Jdot qd, and qdd jumps
where the torque jumps, so a sample taken at the instant a command starts to act depends on
which side of it it was taken:
- ``before_command``: a(t_k-), under the torque of the interval that ended at t_k (a
  controller that reads its sensors, then applies the next command);
- ``after_command``: a(t_k+), under the torque acting from t_k on (a logged feedforward run
  that applies the command, then samples). With no delay that is the command of t_k itself:
  an accelerometer sample waits (is held) until the command of its stamp, or any message
  stamped later, arrives, then is corrected at t_k with the torque acting then. So a live node
  and the offline pass give the same estimates whichever arrives first;
- ``auto``: both hypotheses are weighed on every sample at the same (prior) state (two
  predicted accelerations, one innovation covariance S; ``kernels.imu_innovations``). Over the
  first :data:`TIMING_TRIAL` seconds after (re)initialisation each sample is corrected with the
  likelier so far (this sample not counted); then the likelier is chosen (:class:`TimingDecision`,
  with both log-likelihoods, in ``timing_decisions``, :meth:`timing_summary` and
  :meth:`diagnostics`). Under ``before_command`` a sample is corrected at once and weighed when
  the command of its stamp arrives (so a live node's estimate at the joint state of t_k holds
  the accelerometer of t_k, as today's); under ``after_command`` it waits, as above.
  Every :data:`TIMING_RECHECK` seconds the evidence since the last check is weighed again, and
  the choice switches only if the other is likelier by :data:`TIMING_SWITCH_EVIDENCE` (logged
  likewise). Where no command starts to act at a sample (a delay that is not a whole number
  of periods, a repeated command), the hypotheses agree and the sample is no evidence.
Other corrections at one stamp and the command at that stamp commute (they do not depend
on the command), so a live node and the offline pass give the same estimates whichever
message arrives first. Strain gauges have no feed-through in this model: a branch force
F = c (u - u_rest) + d du/dt is a function of the state, continuous where the torque jumps.

Recovery (``gating.recover_after``, default 10): the encoders are the ground truth of the
motor angles. When they have been gated out that many times in a row, the estimate has followed
another sensor or a mis-modelled input (a disturbance far stronger than the model's, a wrong
command delay or sample timing) away from them; instead of gating them out wholesale the
filter falls back (:meth:`Observer._recover`): motors re-initialised from the sample (rates by a
finite difference of the last two), the motor/elastic blocks of P back to the initial prior,
the disturbance states kept, and the process-noise intensities multiplied by
:data:`RECOVERY_PSD_GROWTH` (up to :data:`RECOVERY_PSD_MAX` in all: the model's noise was too
small for the data). Each recovery is counted (``stats``, summary.json, /diagnostics, the
sensor's NIS finding and so health WARN) and logged with its time. The compiled steps stop
at a gated sample, so the Python here takes every gated one and the recovery is the same
live and offline.

Typical use (live node or offline)::

    obs = Observer(mech, load_config("config/observer.yaml"))
    obs.command(t, tau)                          # torque_command
    obs.update_joint_states(t, names, position)  # measured_joint_states
    obs.update_imu(t, accel)                     # ee_imu
    est = obs.estimate()                         # joint states, branch forces, std devs
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from elastic_pm_dyn.dynamics.statics import static_deflection
from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.kinematics.assembly import solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import ACTIVE
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.core import disturbance, kernels, period
from elastic_pm_dyn.observer.core.estimate import Estimate, EstimateLayout
from elastic_pm_dyn.observer.core.observer_model import ObserverModel
from elastic_pm_dyn.observer.core.sensors import Sample
from elastic_pm_dyn.observer.schedule import consistency
from elastic_pm_dyn.pinned_kernels import KernelPins
from elastic_pm_dyn.sim.integrators import METHODS

OK, WARN, ERROR = 0, 1, 2  # diagnostic levels (as diagnostic_msgs/DiagnosticStatus)
TIMING_MODES = {"before_command": 0, "after_command": 1, "auto": 2}  # period.run_periods' codes
TIMING_TRIAL = 0.1  # [s] auto: samples weighed before the first choice (about 100 at 1 kHz)
TIMING_MIN_SAMPLES = 20  # auto: the first choice waits for at least this many accelerometer samples
TIMING_RECHECK = 1.0  # [s] auto: evidence window of each later check
TIMING_SWITCH_EVIDENCE = 20.0  # auto: log-likelihood margin (nats) the other hypothesis needs to take over
RECOVERY_PSD_GROWTH = 4.0  # each recovery multiplies the process noise intensities by this ...
RECOVERY_PSD_MAX = 256.0  # ... up to this factor in all (the model's noise was too small for the data)
MAX_PENDING_COMMANDS = 10_000  # delayed commands kept before the filter runs (the oldest then act)


class ObserverFault(ElasticPmDynError):
    """The filter cannot go on (model singular, state or covariance not finite): reset it."""


@dataclass
class UpdateResult:
    """What became of one measurement."""

    sensor: str
    t: float
    accepted: bool
    nis: float = float("nan")
    dof: int = 0
    reason: str = ""  # "" (accepted) | gate | nan | late | future | frame | uninitialised | empty
    dropped: list[str] = field(default_factory=list)
    logdet: float = float("nan")  # log det S of the innovation covariance (with nis: the log-likelihood)


@dataclass
class SensorStats:
    accepted: int = 0
    rejected: int = 0  # gated out
    late: int = 0
    future: int = 0  # stamped more than timing.max_future ahead of the filter
    nan: int = 0  # NaN entries dropped
    other: int = 0  # wrong frame, before initialisation
    consecutive_rejections: int = 0
    last_nis: float = float("nan")
    last_reason: str = ""
    window: deque = field(default_factory=deque)  # (nis, dof) of recent accepted samples
    # Prediction-error negative log-likelihood of the samples weighed (accepted and gated; a
    # gated one counted at the gate): sum of (NIS + log det S + dof log 2 pi) / 2
    nll: float = 0.0
    nis_sum: float = 0.0  # NIS of the accepted samples, summed
    recoveries: int = 0  # re-initialisations from this sensor after a run of gated samples (Observer._recover)


LOG_2PI = float(np.log(2.0 * np.pi))


def nll_term(nis: float, logdet: float, dof: int) -> float:
    """One sample's negative Gaussian log-likelihood (NIS + log det S + dof log 2 pi) / 2."""
    return 0.5 * (nis + logdet + dof * LOG_2PI)


@dataclass
class TimingDecision:
    """A choice of ``imu.sample_timing: auto``: at time t, over ``samples`` accelerometer
    samples, the Gaussian log-likelihoods of their innovations under each hypothesis."""

    t: float
    samples: int
    loglik_before: float
    loglik_after: float
    choice: str  # before_command | after_command
    switched: bool  # a later check that changed the choice

    def text(self) -> str:
        what = "switched to" if self.switched else "chose"
        return (f"accelerometer sample timing: {what} {self.choice} at t = {self.t:.6f} s (log-likelihood of "
                f"{self.samples} samples: before_command {self.loglik_before:.6g}, after_command "
                f"{self.loglik_after:.6g})")


@dataclass
class Recovery:
    """A fall-back (:meth:`Observer._recover`): at time t the encoders had been gated out
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


class Observer:
    """EKF of an elastic parallel manipulator; see the module docstring.

    ``mech``: the mechanism, or an :class:`~elastic_pm_dyn.observer.core.observer_model.ObserverModel`
    built for it (the fixed part, shared by many observers with configurations of one
    :func:`~elastic_pm_dyn.observer.core.observer_model.model_key`); the observer holds the rest of
    its configuration (disturbance model, noise levels, gates, timing) and the filter's state."""

    def __init__(self, mech: Mechanism | ObserverModel, config: ObserverConfig | None = None, t0: float = 0.0,
                 q0: np.ndarray | None = None, qd0: np.ndarray | None = None):
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
        self.dist_idx, self.dist_col = model.dist_idx, model.dist_col
        self.nd = len(model.dist_idx)
        pc = cfg.process
        self.disturbance_model = dm = disturbance.build(pc, cfg.initial, model.dist_names)
        self.Lz, self.Fz, self.psd_z = dm.Lz, dm.Fz, dm.psd
        self.nz = dm.nz
        self._z_names = dm.names
        self.nx = 2 * nae + self.nz
        roles = model.roles
        self.psd_ae = np.array([pc.torque_noise_psd if r == ACTIVE else pc.elastic_force_psd for r in roles])
        self.rel_ae = np.array([0.0 if r == ACTIVE else pc.vibration_noise for r in roles])
        # the kernels' bundle of this configuration (psd_ae and psd_z grow in place at a recovery)
        integrator = METHODS[pc.integrator]  # the mean's (sim/integrators.py)
        method = np.zeros(4, dtype=np.int64)  # kernels.Process.method
        method[kernels.INTEGRATOR], method[kernels.SCHEME] = integrator.kernel
        method[kernels.STABILIZATION] = kernels.MEAN_STABILIZATION[integrator.method]
        method[kernels.LINEARIZATION] = kernels.SPRINGS if pc.linearization == "springs" else kernels.DIFFERENCES
        self._proc = tuple(kernels.Process(self.dist_idx, self.dist_col, self.Lz, self.Fz, self.psd_ae, self.rel_ae,
                                           self.psd_z, method, np.full(1 + self.nz, np.nan),
                                           np.empty((4, self.nz, self.nz)), np.empty((self.nz, self.nz))))
        self.period = pc.max_interval
        # the mean's step in use: process.dt if given, else from the model's fastest spring
        self.dt = model.mean_step(integrator, pc.dt, pc.max_interval)
        self._gates: dict[int, float] = {}
        self._take_noise(cfg)  # the sensors: the model's geometry with this configuration's noise levels
        self.point = model.point
        self.with_point = model.with_point
        # Sample timing and actuation latency (module docstring)
        self.delay = cfg.command_delay
        self.imu_mode = TIMING_MODES[cfg.imu.sample_timing] if self.imu is not None else 0
        self.imu_after = self.imu_mode == 1  # the hypothesis in use (auto: the choice so far)
        self.timing_trial = self.imu_mode == 2  # auto before the first choice
        # no delay: the command that starts to act at a sample is the one of its own stamp
        self._no_delay = self.delay <= cfg.timing.stamp_tolerance
        self.evidence = np.zeros(4)  # kernels.imu_innovations', since the last choice or check
        self.timing_decisions: list[TimingDecision] = []  # the first choice and every switch
        self.timing_last: TimingDecision | None = None  # the latest choice or check
        self._pending: deque = deque()  # (time it acts from, torque) of delayed commands
        self._held: tuple[float, np.ndarray] | None = None  # an accelerometer sample waiting for its command
        # (t, sample, its prior state, tau before, the point's acceleration there) to weigh when its command comes
        self._deferred: tuple | None = None
        self.released: list[UpdateResult] = []  # held samples the last call corrected
        # False: no sample is gated (gate = inf), so that a likelihood cannot be won by gating
        # (observer.tuning.tuning sets it before the first sample)
        self.gating = True
        self.branch_names = model.branch_names
        self.state_names = ([self.mech.joint_names[j] for j in self.ae]
                            + [f"{self.mech.joint_names[j]}_vel" for j in self.ae] + self._z_names)
        self.P0 = np.diag(self._initial_variances())
        self.layout = EstimateLayout.of(model, self.nx)  # of the estimate rows (estimate_flat)
        # True: each message through one compiled step (period.sample_step / command_step), the
        # Python below only for what a step refuses. The same numbers (test_observer_fastpath),
        # but measured 3-16 % slower per live period than the Python calling the kernels piece
        # by piece (bench_observer_loop): a step per message makes as many calls and adds a
        # snapshot. The speed-up needs one call per period; until then the Python is the default.
        self.steps_compiled = False
        self.reset(t0, q0, qd0, initialised=q0 is not None or cfg.initial.source == "model")
        self._timing = self.fast_timing()
        n, nx = self.mech.n, self.nx
        # the compiled steps' work arrays and snapshot (period.step_work, period.snapshot_buffers)
        self._work = (np.zeros((3, n)), tuple(a.copy() for a in self._state()), np.zeros(n), np.zeros(3))
        self._pin = KernelPins()  # the kernels called per message, without numba's type dispatch
        na = len(self.mech.active)
        self._save = (tuple(a.copy() for a in self._state()), (np.zeros(na), np.zeros(na)), np.zeros(4), np.zeros(9))
        self._row = np.empty(4)
        self._empty_plan = (np.zeros((0, nx)), np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.bool_))

    def _state(self) -> tuple:
        """The kernels' :class:`~elastic_pm_dyn.observer.core.kernels.State` bundle (the arrays: changed in place)."""
        return self.q, self.qd, self.z, self.P, self.Phi, self.Qd, self.Hpt, self.info

    # ------------------------------------------------------------------ set-up
    def _initial_variances(self) -> np.ndarray:
        i = self.cfg.initial
        roles = self.model.roles
        pos = [i.active_position_stddev if r == ACTIVE else i.elastic_position_stddev for r in roles]
        vel = [i.active_velocity_stddev if r == ACTIVE else i.elastic_velocity_stddev for r in roles]
        return np.concatenate([pos, vel, self.disturbance_model.initial_stddev]) ** 2

    def reset(self, t: float | None = None, q: np.ndarray | None = None, qd: np.ndarray | None = None,
              P0: np.ndarray | None = None, initialised: bool = True) -> None:
        """Restart at time t from tree state (q, qd); t None: at the stamp of the next sample
        or command (the time an outlier may have left behind is not kept).

        q defaults to the model's initial state, qd to rest; the closure fixes q_p and qd_p
        (q_p from q's values as the Newton guess). Statistics, disturbance estimates and
        a fault are cleared. ``initialised=False`` makes the next joint state (with every
        active joint's position) set the pose instead (``initial.source: measurement``).
        """
        mech = self.mech
        self.t = float(getattr(self, "t", 0.0) if t is None else t)
        self.time_pending = t is None  # the next stamp sets the time
        q = self.model.q_initial.copy() if q is None else np.array(q, dtype=float)
        qd = np.zeros(mech.n) if qd is None else np.array(qd, dtype=float)
        if q.shape != (mech.n,) or qd.shape != (mech.n,):
            raise InputError(f"observer reset: a state needs {mech.n} tree coordinates")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise InputError("observer reset: NaN or Inf in the state")
        gap, ratio = kernels.apply_correction(mech.arrays, q, qd, np.zeros(self.nz), np.zeros(self.nx))
        if not (gap <= 1e-9 and ratio >= kernels.SINGULAR_TOL):
            raise InputError(f"observer reset: the closure cannot be solved there (gap {gap:.3g} m)")
        self.q, self.qd = q, qd
        self.z = np.zeros(self.nz)
        self.P = (self.P0 if P0 is None else np.array(P0, dtype=float)).copy()
        if self.P.shape != (self.nx, self.nx):
            raise InputError(f"observer reset: covariance must be {self.nx} x {self.nx}")
        n_a = len(mech.active)
        self.tau_hold = getattr(self, "tau_hold", np.zeros(n_a))
        self.tau_last = self.tau_hold.copy()
        self.t_command = getattr(self, "t_command", -np.inf)
        self.fault: str | None = None
        self.initialised = initialised
        self.stats = {s: SensorStats() for s in ("encoders", "imu", "branch_forces", "command")}
        self.recoveries: list[Recovery] = []  # fall-backs since the last reset (_recover)
        if getattr(self, "_psd_scale", 1.0) != 1.0:  # a reset forgets what the recoveries learned
            self.psd_ae /= self._psd_scale
            self.psd_z /= self._psd_scale
        self._psd_scale = 1.0
        self._gated_enc: tuple[float, np.ndarray] | None = None  # the last gated encoder sample (t, motor positions)
        self.Phi = np.eye(self.nx)
        self.Qd = np.zeros((self.nx, self.nx))
        self._lin_age, self._lin_T = 1 << 30, -1.0  # intervals since the last linearisation, its length
        self.Hpt = np.zeros((3, self.nx))
        self.info = np.zeros(2)
        self._held = None
        self._deferred = None
        self.evidence[:] = 0.0
        self._t_decide = self._next_check(self.t)
        if self.with_point:
            self._linearize_here()

    def initialise_from_joint_state(self, t: float, names, position, velocity=None,
                                    velocity_stddev: float | None = None) -> bool:
        """Set the pose from measured positions of every active joint (elastic joints in static
        equilibrium with the motors there, unless measured too; passive joints from the
        closure); False if some are missing or there is no equilibrium.

        Rates come from ``velocity`` where given (active/elastic joints), else zero; a reset
        while the machine may be moving should pass ``velocity_stddev`` [rad/s] for the
        motors' rate uncertainty (default: ``initial.active_velocity_stddev``, at rest).
        """
        mech = self.mech
        lookup = {n: k for k, n in enumerate(names)}
        q = self.model.q_initial.copy()
        qd = np.zeros(mech.n)
        vel = [] if velocity is None else velocity
        motors = self._motor_positions(names, position)
        if motors is None:
            return False
        q[np.asarray(mech.active, dtype=np.int64)] = motors
        measured_elastic = False
        for j in mech.ae:
            k = lookup.get(mech.joint_names[j])
            if k is not None and j in mech.elastic and k < len(position) and np.isfinite(position[k]):
                q[j] = float(position[k])
                measured_elastic = True
            if k is not None and k < len(vel) and np.isfinite(vel[k]):
                qd[j] = float(vel[k])
        try:
            q = solve_pose(mech, q, mech.passive)
            if not measured_elastic:  # at rest the springs carry the static load (gravity)
                q = static_deflection(mech, q, np.zeros(len(mech.ee_components)))
        except ElasticPmDynError:
            return False
        P0 = self.P0.copy()
        if velocity_stddev is not None:
            for i, r in enumerate(self.model.roles):
                if r == ACTIVE:
                    P0[self.nae + i, self.nae + i] = velocity_stddev ** 2
        tau_hold, t_cmd = self.tau_hold, self.t_command
        if t_cmd > t + self.cfg.timing.stamp_tolerance:
            t_cmd = -np.inf  # a command stamped after the restart must not hold the filter's commands back
        self._pending.clear()  # delayed commands of the old time are not replayed
        self.reset(t, q, qd, P0)
        self.tau_hold, self.tau_last, self.t_command = tau_hold, tau_hold.copy(), t_cmd
        return True

    def _tree_tau(self, tau_active: np.ndarray) -> np.ndarray:
        return self.mech.split_tau(tau_active)

    def _linearize_here(self) -> None:
        """Accelerometer Jacobian at the current state (before the first prediction)."""
        from elastic_pm_dyn.observer.core.observability import linear_model
        _, _, self.Hpt = linear_model(self, self.q, self.qd, self.tau_last)

    def set_measurement_noise(self, cfg: ObserverConfig) -> None:
        """Take the sensors' noise levels and the gate of ``cfg`` (``config.RUNTIME_PARAMETERS``)
        from the next sample on; state, covariance, schedule and model stay. ``cfg`` must differ
        from the current configuration only there (InputError otherwise)."""
        from elastic_pm_dyn.observer.config import RUNTIME_PARAMETERS
        cfg = cfg.for_machine(self.mech)  # as at construction (imu.axes: auto resolved)
        old, new = self.cfg.parameters, cfg.parameters
        other = sorted(k for k in old if old[k] != new.get(k) and k not in RUNTIME_PARAMETERS)
        if other:
            raise InputError(f"only the noise levels and the gate change in a running filter, not {', '.join(other)}")
        self.cfg = cfg
        self._take_noise(cfg)

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

    def gate(self, dof: int) -> float:
        if not self.gating:
            return np.inf
        g = self._gates.get(dof)
        if g is None:
            g = self._gates[dof] = float(chi2.ppf(self.cfg.gating.probability, dof))
        return g

    # ------------------------------------------------------------------ time
    def _torque_at(self, t: float) -> np.ndarray:
        timeout = self.cfg.timing.command_timeout
        if timeout > 0 and t - self.t_command >= timeout - 1e-12:
            return np.zeros_like(self.tau_hold)
        return self.tau_hold

    def _advance(self, t_to: float) -> None:
        """Predict from self.t to t_to with the held command (zero after a timeout): ``period.advance``."""
        if self.fault is not None:
            raise ObserverFault(self.fault)
        tol = self.cfg.timing.stamp_tolerance
        if self._waiting_since() < t_to - tol:
            self._settle()  # the command of its stamp did not come: the torque acting now
        if not t_to - self.t > tol:
            self._activate_due()  # nothing to predict (what period.advance does then)
            return
        cmd, ctl = self._kernel_control(0, np.inf)
        status = self._pin(period.advance)(self.mech.arrays, self.model.fixed, self._proc, self._state(), cmd, ctl,
                                           self._timing, float(t_to), self._work[0][2])
        self._take_control(cmd, ctl)
        if status != 0 and status != kernels.COVARIANCE_LOST:
            self._fail(f"prediction failed at t = {self.t:.6f} s: "
                       + ("singular configuration" if status == 1 else "the state became NaN/Inf")
                       + f" (conditioning {self.info[0]:.3g})")
        if status == kernels.COVARIANCE_LOST:
            self._fail(f"covariance lost positive definiteness at t = {self.t:.6f} s")

    def _activate_due(self, now: float | None = None) -> None:
        """Delayed commands whose time (``now``, default the filter's) has come: the newest is held."""
        now = self.t if now is None else now
        while self._pending and self._pending[0][0] <= now + self.cfg.timing.stamp_tolerance:
            self.t_command, self.tau_hold = self._pending.popleft()

    def _newest_command(self) -> float:
        """When the newest accepted command acts from (-inf if none)."""
        return self._pending[-1][0] if self._pending else self.t_command

    def _fail(self, message: str) -> None:
        self.fault = message
        raise ObserverFault(message)

    def _sync(self, t: float, sensor: str) -> UpdateResult | None:
        """Bring the filter to stamp t; a result if the sample cannot be used."""
        st = self.stats[sensor]
        if not self.initialised:
            st.other += 1
            return UpdateResult(sensor, t, False, reason="uninitialised")
        if self.time_pending:
            self._restart_clock(t)
        if t < self.t - self.cfg.timing.stamp_tolerance:
            st.late += 1
            st.last_reason = f"late by {self.t - t:.6f} s"
            return UpdateResult(sensor, t, False, reason="late")
        if self._future(t, st):
            return UpdateResult(sensor, t, False, reason="future")
        self._timing_check(t)
        self._advance(t)
        return None

    def _future(self, t: float, st: SensorStats) -> bool:
        """A stamp more than timing.max_future ahead of the filter: an outlier (counted), the time stays."""
        if not t - self.t > self.cfg.timing.max_future:
            return False
        st.future += 1
        st.consecutive_rejections += 1
        st.last_reason = (f"stamped {t - self.t:.6g} s ahead of the filter's time {self.t:.6f} s "
                          f"(timing.max_future {self.cfg.timing.max_future:g} s)")
        return True

    def _restart_clock(self, t: float) -> None:
        """After ``reset(t=None)``: the filter (and the held command) restart at this stamp."""
        self.t = t
        if self.t_command > -np.inf:
            self.t_command = t
        self.time_pending = False
        self._t_decide = self._next_check(t)

    # ------------------------------------------------------------------ inputs
    def predict(self, tau: np.ndarray, t_to: float) -> None:
        """Integrate from the filter's time to t_to with ``tau`` (active joint order) held;
        ``tau`` stays the held command afterwards."""
        self.tau_hold = self._check_tau(tau)
        self.t_command = self.t
        self._advance(float(t_to))

    def command(self, t: float, tau: np.ndarray) -> bool:
        """A torque command stamped t (active joint order): predict to t with the previous
        command, then hold this one. A command older than the last one is ignored (False)."""
        tau = self._check_tau(tau)
        self.released = []
        if self._fast_command(t, tau):
            return True
        st = self.stats["command"]
        if self.initialised and self.time_pending:
            self._restart_clock(t)
        if self.initialised and self._future(t, st):
            return False
        tol = self.cfg.timing.stamp_tolerance
        t_act = t + self.delay  # it acts from here
        if t_act < self._newest_command() - tol:
            st.late += 1
            return False
        if self.initialised:
            if t_act < self.t - tol:
                st.late += 1  # late but newest: applies from now on
            if t >= self.t - tol:
                self._timing_check(t)
                self._advance(t)
        self._pending.append((t_act, tau))
        if len(self._pending) > MAX_PENDING_COMMANDS:
            self.t_command, self.tau_hold = self._pending.popleft()
        self._activate_due(None if self.initialised else t)
        st.accepted += 1
        st.consecutive_rejections = 0
        self._settle()  # the sample of this stamp waited for it
        return True

    def _check_tau(self, tau) -> np.ndarray:
        tau = np.asarray(tau, dtype=float).reshape(-1)
        if tau.shape != (len(self.mech.active),):
            raise InputError(f"torque command needs {len(self.mech.active)} values (active joints "
                             f"{', '.join(self.mech.active_names)}), got {tau.size}")
        if not np.all(np.isfinite(tau)):
            self.stats["command"].nan += 1
            raise InputError("torque command with NaN or Inf")
        return tau.copy()

    def update_joint_states(self, t: float, names, position=None, velocity=None, effort=None
                            ) -> list[UpdateResult]:
        """Encoder positions/rates (and elastic-joint efforts as branch forces, if so configured)."""
        self.released = []
        if self.encoders is not None and position is not None and len(position) == len(names) and not (
                self.branch is not None and self.branch.source == "joint_state_effort" and effort is not None
                and len(effort)):
            plan = self.encoders.fast_plan(names, self.nx)
            if plan is not None and (not plan.with_rates or velocity is None or len(velocity) == 0):
                done = self._fast_samples(t, plan, position, None)
                if done is not None:
                    return done
        out = []
        if not self.initialised:
            if (self.cfg.initial.source == "measurement" and position is not None and len(position)
                    and self.initialise_from_joint_state(t, names, position)):
                out.append(UpdateResult("encoders", t, True, reason="initialised"))
                return out
            self.stats["encoders"].other += 1
            return [UpdateResult("encoders", t, False, reason="uninitialised")]
        if self.encoders is not None:
            late = self._sync(t, "encoders")
            if late is not None:
                return [late]
            fast = self.encoders.fast_plan(names, self.nx) if position is not None and len(position) == len(names) \
                else None
            if fast is not None and (not fast.with_rates or velocity is None or len(velocity) == 0):
                # positions of state joints only: one compiled call (the same numbers as below)
                idx = fast.idx
                gate = self.gate(len(idx))
                nis, status, logdet = self._pin(kernels.encoder_correct)(
                    self.mech.arrays, self._state(), fast.bundle, np.asarray(position, dtype=float)[idx], gate)
                if status >= 0:
                    out.append(self._after("encoders", t, nis, status, len(idx), gate, [], logdet))
                    fast = True
            if fast is not True:
                W = self._passive_jacobian() if self.encoders.needs_w else None
                s = self.encoders.sample(list(names), position, velocity, self.q, self.qd, W, self.nx)
                if s is not None:
                    out.append(self._correct(s, t))
            if out and out[-1].reason == "gate" and position is not None:
                self._on_gated_encoders(t, names, position)
        if (self.branch is not None and self.branch.source == "joint_state_effort" and effort is not None
                and len(effort)):
            if len(effort) != len(names):
                raise InputError(f"joint state: {len(names)} names but {len(effort)} efforts")
            pairs = [(self.branch.by_joint[n], e) for n, e in zip(names, effort, strict=True)
                     if n in self.branch.by_joint]
            if pairs:
                out.append(self._branch_update(t, [p[0] for p in pairs], [p[1] for p in pairs]))
        return out

    def _motor_positions(self, names, position) -> np.ndarray | None:
        """Measured positions of every active joint (tree order of ``mech.active``), or None."""
        lookup = {n: k for k, n in enumerate(names)}
        out = np.empty(len(self.mech.active))
        for i, j in enumerate(self.mech.active):
            k = lookup.get(self.mech.joint_names[j])
            if k is None or k >= len(position) or not np.isfinite(position[k]):
                return None
            out[i] = float(position[k])
        return out

    def _on_gated_encoders(self, t: float, names, position) -> None:
        """An encoder sample gated out: remember it; after ``gating.recover_after`` in a row
        (0: never) fall back (:meth:`_recover`)."""
        st = self.stats["encoders"]
        motors = self._motor_positions(names, position)
        prev, self._gated_enc = self._gated_enc, None if motors is None else (t, motors)
        after = self.cfg.gating.recover_after
        if after > 0 and self.gating and motors is not None and st.consecutive_rejections >= after:
            self._recover(t, motors, prev)

    def _recover(self, t: float, motors: np.ndarray, prev: tuple[float, np.ndarray] | None) -> None:
        """Fall back after a run of gated encoder samples: the estimate has followed another
        sensor (or a mis-modelled input) away from the encoders, which are the ground truth of
        the motor angles. The motor positions are re-initialised from this sample, their rates
        from it and the previous gated one (a finite difference), the elastic coordinates and
        rates kept (the passive joints from the closure); the motor/elastic blocks of P go back
        to the initial prior (the motor rates' to the finite difference's spread), their
        cross-covariance with the disturbance states is dropped, the disturbance states and
        their covariance are kept (each at least its prior). So the next samples are accepted
        again; counted in ``stats['encoders'].recoveries`` and :attr:`recoveries`."""
        mech, nae = self.mech, self.nae
        act = np.asarray(mech.active, dtype=np.int64)
        error = float(np.max(np.abs(self.q[act] - motors)))
        q, qd = self.q.copy(), self.qd.copy()
        q[act] = motors
        P0 = self.P0
        na = len(act)
        vel_var = np.full(na, np.nan)
        if prev is not None and t - prev[0] > self.cfg.timing.stamp_tolerance:
            dt = t - prev[0]
            qd[act] = (motors - prev[1]) / dt
            enc = self.encoders
            var = dict(zip(enc.pos, enc.pos_var, strict=True))
            noise = np.array([var.get(int(j), float(np.max(enc.pos_var, initial=0.0))) for j in act])
            vel_var = 2.0 * noise / dt ** 2
        try:
            q = solve_pose(mech, q, mech.passive)
        except ElasticPmDynError:
            return  # no closure there: keep reporting the divergence
        qd_ae = qd[self.ae].copy()
        qd = np.zeros(mech.n)
        qd[self.ae] = qd_ae
        gap, ratio = kernels.apply_correction(mech.arrays, q, qd, np.zeros(self.nz), np.zeros(self.nx))
        if not (gap <= 1e-9 and ratio >= kernels.SINGULAR_TOL):
            return
        P = np.zeros_like(self.P)
        n2 = 2 * nae
        P[:n2, :n2] = P0[:n2, :n2]
        for i, j in enumerate(act):
            if np.isfinite(vel_var[i]):
                k = nae + self.x_of_ae[int(j)]
                P[k, k] = max(P0[k, k], vel_var[i])
        Pz = self.P[n2:, n2:]
        P[n2:, n2:] = Pz
        for i in range(self.nz):
            P[n2 + i, n2:] = Pz[i]
            P[n2 + i, n2 + i] = max(Pz[i, i], P0[n2 + i, n2 + i])
        self.q, self.qd, self.P = q, qd, P
        if RECOVERY_PSD_GROWTH > 1.0 and self._psd_scale * RECOVERY_PSD_GROWTH <= RECOVERY_PSD_MAX:
            # the model's process noise was too small for what the data did: grow it (in place:
            # the offline fast path holds these arrays)
            self._psd_scale *= RECOVERY_PSD_GROWTH
            self.psd_ae *= RECOVERY_PSD_GROWTH
            self.psd_z *= RECOVERY_PSD_GROWTH
        self._lin_age = 1 << 30  # linearise again at the next prediction (Qd with the new noise)
        if self.with_point:
            self._linearize_here()
        st = self.stats["encoders"]
        self.recoveries.append(Recovery(t, "encoders", st.consecutive_rejections, error, self._psd_scale))
        st.recoveries += 1
        st.consecutive_rejections = 0
        self._gated_enc = None

    def update_imu(self, t: float, linear_acceleration, frame_id: str = "") -> UpdateResult | None:
        """Accelerometer sample (x, y, z of sensor_msgs/Imu linear_acceleration). None if there is
        no accelerometer, or if the sample waits for the command of its stamp (no delay, under the
        after_command hypothesis): that command or the next later message corrects it (its
        result then in :attr:`released`)."""
        self.released = []
        if self.imu is None:
            return None
        st = self.stats["imu"]
        if self.imu.frame_id and frame_id and frame_id != self.imu.frame_id:
            st.other += 1
            st.last_reason = f"frame {frame_id!r}, expected {self.imu.frame_id!r}"
            return UpdateResult("imu", t, False, reason="frame")
        acc = np.array(linear_acceleration, dtype=float)
        if acc.shape == (3,):
            done = self._fast_samples(t, None, None, acc)
            if done is not None:
                return done[0] if done else None
        late = self._sync(t, "imu")
        if late is not None:
            return late
        waiting = self._waits_for_command(t)
        if waiting and self._use_after():
            self._settle()  # two samples at one stamp: the first goes now
            self._held = (t, acc)
            return None
        return self._imu_update(t, acc, defer=waiting)

    def _waits_for_command(self, t: float) -> bool:
        """With no delay the command that starts to act at sample stamp t may still come (the command of t)."""
        return (self.imu_mode != 0 and self._no_delay
                and self._newest_command() < t + self.delay - self.cfg.timing.stamp_tolerance)

    def _use_after(self) -> bool:
        """The hypothesis in use: ``auto``'s likelier so far before its first choice."""
        return bool(self.evidence[1] < self.evidence[0]) if self.timing_trial else self.imu_after

    def _waiting_since(self) -> float:
        """Stamp of a sample that waits for its command (held, or to be weighed), else inf."""
        if self._held is not None:
            return self._held[0]
        return self._deferred[0] if self._deferred is not None else np.inf

    def _settle(self) -> None:
        """What waited for the command of its stamp: a deferred weighing (``auto``: the sample's
        prior under both hypotheses, the torque acting now as the after one) and a held sample."""
        if self._deferred is not None:
            _, meas, prior, tau_before, a_before = self._deferred
            self._deferred = None
            self._pin(kernels.imu_innovations)(self.mech.arrays, self.model.fixed, self._proc, prior, self._imu,
                                               tau_before, self._tree_tau(self._torque_at(self.t)), meas,
                                               self.gate(len(meas)), self.evidence, a_before, True)
        if self._held is not None:
            t, acc = self._held
            self._held = None
            self.released.append(self._imu_update(t, acc))

    def _imu_update(self, t: float, acc: np.ndarray, defer: bool = False) -> UpdateResult:
        """Correct with an accelerometer sample at the filter's time (stamp t): the torque before
        it is the last prediction piece's, the one after it the torque acting now. ``defer``
        (``auto`` under before_command, the command of t still to come): weigh it then."""
        imu = self.imu
        meas = acc[imu.axes]
        tau_before = self._tree_tau(self.tau_last)
        tau_after = self._tree_tau(self._torque_at(self.t))
        after = self._use_after()
        if not np.all(np.isfinite(meas)):  # the slow path drops NaN axes and reports them (no evidence)
            a = np.empty(3)
            kernels.point_acceleration(self.mech.arrays, self.q, self.qd, tau_after if after else tau_before,
                                       self.dist_idx, self.disturbance(), self.point, a)
            return self._correct(imu.sample(acc, a, self.Hpt), t)
        gate = self.gate(len(meas))
        if self.imu_mode == 2 and not defer:
            nis, status, logdet = self._pin(kernels.imu_correct_auto)(
                self.mech.arrays, self.model.fixed, self._proc, self._state(), self._imu, tau_before, tau_after, after,
                meas, gate, self.evidence)
        else:
            a = np.empty(3)  # the point's acceleration at the prior: a deferred sample's weighing takes it
            if defer:  # (then under before: after would have held the sample)
                self._settle()
                # the sample's prior (the kernels' State bundle; Phi, Qd and info are not read)
                prior = (self.q.copy(), self.qd.copy(), self.z.copy(), self.P.copy(), self.Phi, self.Qd,
                         self.Hpt.copy(), self.info)
                self._deferred = (t, meas.copy(), prior, tau_before, a)
            nis, status, logdet = self._pin(kernels.imu_correct)(
                self.mech.arrays, self.model.fixed, self._proc, self._state(), self._imu,
                tau_after if after else tau_before, meas, gate, a)
        return self._after("imu", t, nis, status, len(meas), gate, [], logdet)

    # ------------------------------------------------------------------ sample timing (auto)
    def _next_check(self, t: float) -> float:
        if self.imu_mode != 2:
            return np.inf
        return t + (TIMING_TRIAL if self.timing_trial else TIMING_RECHECK)

    def _timing_check(self, t: float) -> None:
        """``auto``: at a stamp from the decision time on, choose (first) or check the choice."""
        if not t >= self._t_decide - self.cfg.timing.stamp_tolerance:
            return
        self._settle()  # what waits belongs to this window
        nis_b, nis_a, logdet, n = self.evidence
        if self.timing_trial and n < TIMING_MIN_SAMPLES:
            self._t_decide = t + TIMING_TRIAL  # too few samples yet: weigh on
            return
        self._t_decide = t + TIMING_RECHECK
        if n == 0:
            return
        ll_b, ll_a = -0.5 * (nis_b + logdet), -0.5 * (nis_a + logdet)
        if self.timing_trial:
            after, switched = bool(ll_a > ll_b), False
        else:
            gain = ll_b - ll_a if self.imu_after else ll_a - ll_b
            switched = bool(gain > TIMING_SWITCH_EVIDENCE)
            after = self.imu_after != switched
        decision = TimingDecision(t, int(n), float(ll_b), float(ll_a), "after_command" if after else "before_command",
                                  switched)
        if self.timing_trial or switched:
            self.timing_decisions.append(decision)
        self.timing_last = decision
        self.imu_after, self.timing_trial = after, False
        self.evidence[:] = 0.0

    def sample_timing(self) -> str:
        """The accelerometer sample timing in use: before_command | after_command (auto: ``auto
        (trial)`` until the first choice)."""
        if self.timing_trial:
            return "auto (trial)"
        return "after_command" if self.imu_after else "before_command"

    def timing_summary(self) -> dict:
        """The timing settings and, for ``auto``, its choices (for summary.json)."""
        return {"imu_sample_timing": self.cfg.imu.sample_timing, "in_use": self.sample_timing(),
                "command_delay_s": self.delay,
                "decisions": [vars(d) | {"text": d.text()} for d in self.timing_decisions],
                "last_check": None if self.timing_last is None else vars(self.timing_last)}

    # ------------------------------------------------------------------ offline fast path
    def fast_timing(self) -> np.ndarray:
        """``period.run_periods``' timing array (fixed for the observer's life)."""
        p, tm = self.cfg.process, self.cfg.timing
        return np.array([p.max_interval, self.dt, tm.stamp_tolerance, p.relinearize_every, tm.command_timeout,
                         self.delay, float(self.imu_mode), float(self._no_delay)])

    def _kernel_control(self, room: int, t_stop: float) -> tuple[tuple, np.ndarray]:
        """The compiled steps' ``cmd`` (copies of the held and last command, the delayed-command
        queue with room for ``room`` more) and control array (module ``period``), stopping at ``t_stop``."""
        n = len(self._pending)
        pend_t = np.empty(n + room)
        pend_tau = np.empty((n + room, len(self.mech.active)))
        for i, (ta, tau) in enumerate(self._pending):
            pend_t[i], pend_tau[i] = ta, tau
        ctl = np.array([self.t, float(self._lin_age), self._lin_T, self.t_command, 0.0, float(n), t_stop,
                        float(self.timing_trial), float(self.imu_after)])
        return (self.tau_hold.copy(), self.tau_last.copy(), pend_t, pend_tau), ctl

    def _take_control(self, cmd: tuple, ctl: np.ndarray) -> None:
        """Take back what :meth:`_kernel_control` gave a compiled step."""
        self.t, self._lin_age, self._lin_T, self.t_command = float(ctl[0]), int(ctl[1]), float(ctl[2]), float(ctl[3])
        self.tau_hold, self.tau_last, pend_t, pend_tau = cmd
        head, tail = int(ctl[4]), int(ctl[5])
        if tail > head or self._pending:
            self._pending = deque((float(pend_t[i]), pend_tau[i].copy()) for i in range(head, tail))

    def fast_state(self, periods: int) -> tuple[tuple, np.ndarray]:
        """``period.run_periods``' ``cmd`` and control array for ``periods`` more periods; a
        sample waiting for its command stops the fast path at once (the per-message API's)."""
        return self._kernel_control(periods, -np.inf if self._waiting_since() < np.inf else self._t_decide)

    def _fast_samples(self, t: float, plan: tuple | None, position, acc: np.ndarray | None
                      ) -> list[UpdateResult] | None:
        """The samples of one stamp through ``period.sample_step`` (encoder positions of
        ``plan`` (``Encoders.fast_plan``) and/or an accelerometer sample); None if it did not
        take them (the Python below then does)."""
        tol = self.cfg.timing.stamp_tolerance
        if not (self.steps_compiled and self.initialised and self.fault is None and not self.time_pending
                and self._held is None and self._deferred is None and t >= self.t - tol
                and not t - self.t > self.cfg.timing.max_future):
            return None
        has_enc, has_imu = plan is not None, acc is not None
        enc_m = np.asarray(position, dtype=float)[plan.idx] if has_enc else self._row[:0]
        meas = acc[self.imu.axes] if has_imu else self._row[:0]
        if (has_imu and not has_enc and not abs(t - self.t) > tol and t < self._t_decide - tol
                and self._waits_for_command(t) and self._use_after() and np.all(np.isfinite(meas))):
            # what sample_step would do (HELD: the command of this stamp corrects it), without a call
            self._held = (t, acc)
            return []
        enc = plan.bundle if has_enc else self._empty_plan
        dof_e = len(plan.idx) if has_enc else 0
        cmd, ctl = self._kernel_control(0, self._t_decide)
        row = self._row
        r = self._pin(period.sample_step)(self.mech.arrays, self.model.fixed, self._proc, self._state(), cmd, ctl,
                                          self._timing, self.evidence, enc,
                                          self.gate(dof_e) if has_enc else np.inf, self._imu_bundle,
                                          self.gate(len(meas)) if has_imu else np.inf, float(t), has_enc, enc_m,
                                          has_imu, meas, self._work, self._save, row)
        if r == 0:
            return None
        self._take_control(cmd, ctl)
        out = []
        if has_enc:
            out.append(self._after("encoders", t, float(row[0]), 0, dof_e, np.inf, [], float(row[2])))
        if r == period.HELD:
            self._held = (t, acc)
        elif has_imu:
            out.append(self._after("imu", t, float(row[1]), 0, len(meas), np.inf, [], float(row[3])))
            if r == period.DEFERRED:
                self._deferred = (t, meas, self._work[1], self._work[2], self._work[3])
        return out

    def _fast_command(self, t: float, tau: np.ndarray) -> bool:
        """A command through ``period.command_step``; False if it did not take it (the Python
        below then does)."""
        if not (self.steps_compiled and self.initialised and self.fault is None and not self.time_pending
                and len(self._pending) < MAX_PENDING_COMMANDS and not t - self.t > self.cfg.timing.max_future):
            return False
        if self._held is None and self._deferred is None:
            return False  # nothing waits for it: the Python below only queues it (cheaper than a call)
        waiting, meas, work = period.TAKEN, self._row[:0], self._work
        if self._held is not None:
            waiting, meas = period.HELD, self._held[1][self.imu.axes]
            if not np.all(np.isfinite(meas)):
                return False
        elif self._deferred is not None:
            _, meas, prior, tau_before, a_before = self._deferred
            waiting, work = period.DEFERRED, (work[0], prior, tau_before, a_before)
        cmd, ctl = self._kernel_control(1, self._t_decide)
        row = self._row
        done = self._pin(period.command_step)(self.mech.arrays, self.model.fixed, self._proc, self._state(), cmd, ctl,
                                              self._timing, self.evidence, self._imu_bundle,
                                              self.gate(len(meas)) if len(meas) else np.inf, float(t), tau, waiting,
                                              meas, work, self._save, row)
        if not done:
            return False
        self._take_control(cmd, ctl)
        st = self.stats["command"]
        st.accepted += 1
        st.consecutive_rejections = 0
        if waiting == period.HELD:
            t_held = self._held[0]
            self._held = None
            self.released.append(self._after("imu", t_held, float(row[1]), 0, len(meas), np.inf, [], float(row[3])))
        self._deferred = None
        return True

    def update_branch_forces(self, t: float, names, force) -> UpdateResult | None:
        """Measured branch forces (strain gauges), by branch name."""
        self.released = []
        if self.branch is None:
            return None
        return self._branch_update(t, list(names), force)

    def _branch_update(self, t, names, force) -> UpdateResult:
        late = self._sync(t, "branch_forces")
        if late is not None:
            return late
        x = self.x()
        s = self.branch.sample(names, np.asarray(force, dtype=float), x, self.nx)
        if s is None:
            return UpdateResult("branch_forces", t, False, reason="empty")
        return self._correct(s, t)

    # ------------------------------------------------------------------ correction
    def _correct(self, s: Sample, t: float) -> UpdateResult:
        st = self.stats[s.sensor]
        st.nan += len(s.dropped)
        if s.r.size == 0:
            st.last_reason = "NaN: " + ", ".join(s.dropped)
            return UpdateResult(s.sensor, t, False, reason="nan", dropped=s.dropped)
        gate = self.gate(s.r.size)
        nis, status, logdet = self._pin(kernels.correct)(self.mech.arrays, self._state(), np.ascontiguousarray(s.H),
                                                         s.R, s.r, gate)
        return self._after(s.sensor, t, nis, status, s.r.size, gate, s.dropped, logdet)

    def _after(self, sensor: str, t: float, nis: float, status: int, dof: int, gate: float,
               dropped: list[str], logdet: float = float("nan")) -> UpdateResult:
        st = self.stats[sensor]
        st.last_nis = nis
        if status == 1:
            st.rejected += 1
            st.consecutive_rejections += 1
            st.nll += nll_term(min(nis, gate), logdet, dof)
            st.last_reason = f"gated out at t = {t:.6f} s: NIS {nis:.3g} > {gate:.3g} ({dof} dof)"
            return UpdateResult(sensor, t, False, nis, dof, "gate", dropped, logdet)
        if status == 2:
            self._fail(f"a {sensor} correction left the closure unsolvable at t = {t:.6f} s")
        if status == 3:
            self._fail(f"covariance lost positive definiteness in a {sensor} correction at t = {t:.6f} s")
        if status == 4:
            self._fail(f"singular configuration in the {sensor} model at t = {t:.6f} s")
        st.accepted += 1
        st.consecutive_rejections = 0
        st.nll += nll_term(nis, logdet, dof)
        st.nis_sum += nis
        st.window.append((nis, dof))
        if len(st.window) > self.cfg.gating.nis_window:
            st.window.popleft()
        return UpdateResult(sensor, t, True, nis, dof, "", dropped, logdet)

    def _accepted_many(self, sensor: str, nis: list[float], dof: int, logdet: list[float]) -> None:
        """The statistics of :meth:`_after` for consecutive accepted samples (the offline fast
        path; the same sums in the same order)."""
        if not nis:
            return
        st = self.stats[sensor]
        st.last_nis = nis[-1]
        nll, nis_sum = st.nll, st.nis_sum
        for v, ld in zip(nis, logdet, strict=True):
            nll += nll_term(v, ld, dof)
            nis_sum += v
        st.nll, st.nis_sum = nll, nis_sum
        st.accepted += len(nis)
        st.consecutive_rejections = 0
        keep = self.cfg.gating.nis_window
        w = st.window
        w.extend((v, dof) for v in nis[-keep - 1:])
        while len(w) > keep:
            w.popleft()

    # ------------------------------------------------------------------ outputs
    def x(self) -> np.ndarray:
        return np.concatenate([self.q[self.ae], self.qd[self.ae], self.z])

    def disturbance(self) -> np.ndarray:
        """Estimated disturbance torques d = Lz z on ``dist_idx`` joints."""
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

    # ------------------------------------------------------------------ diagnostics
    def health(self) -> tuple[int, str]:
        """(level OK/WARN/ERROR, one line) for /diagnostics."""
        if self.fault is not None:
            return ERROR, f"fault: {self.fault}; reset needed"
        if not self.initialised:
            return WARN, "waiting for a joint state with every motor position"
        findings = list(self.nis_findings().values())  # a sensor far off, with its likely cause
        limit = self.cfg.gating.max_consecutive_rejections
        for name, st in self.stats.items():
            if st.consecutive_rejections >= limit:
                return ERROR, "; ".join([f"{name}: {st.consecutive_rejections} consecutive samples gated out "
                                         f"(last: {st.last_reason}); the estimate has diverged, reset needed",
                                         *findings])
        if findings:
            return WARN, "; ".join(findings)
        return OK, "tracking"

    def nis_findings(self) -> dict[str, str]:
        """Sensors whose windowed NIS is far off (or that are mostly gated out), each with one line
        naming its likely cause (:mod:`~elastic_pm_dyn.observer.schedule.consistency`)."""
        return consistency.findings(self, TIMING_SWITCH_EVIDENCE)

    def nis_band(self, sensor: str, p: float = 0.95) -> tuple[float, float, float]:
        """Two-sided p band of the windowed mean NIS and its value (NaN if no samples)."""
        w = self.stats[sensor].window
        if len(w) < 10:
            return float("nan"), float("nan"), float("nan")
        total = sum(n for n, _ in w)
        dof = sum(d for _, d in w)
        lo, hi = chi2.ppf((1 - p) / 2, dof) / len(w), chi2.ppf((1 + p) / 2, dof) / len(w)
        return float(lo), float(hi), float(total / len(w))

    def diagnostics(self) -> dict[str, str]:
        """Key/value pairs for diagnostic_msgs/KeyValue: counts and NIS statistics per sensor."""
        out = {"time": f"{self.t:.6f}"}
        for name, st in self.stats.items():
            out[f"{name}.accepted"] = str(st.accepted)
            out[f"{name}.rejected"] = str(st.rejected)
            out[f"{name}.late"] = str(st.late)
            out[f"{name}.future"] = str(st.future)
            out[f"{name}.nan_entries"] = str(st.nan)
            if st.recoveries:
                out[f"{name}.recoveries"] = str(st.recoveries)
            if st.window:
                lo, hi, mean = self.nis_band(name)
                out[f"{name}.nis_last"] = f"{st.last_nis:.4g}"
                out[f"{name}.nis_mean"] = f"{mean:.4g}"
                out[f"{name}.nis_band95"] = f"[{lo:.4g}, {hi:.4g}]"
            if st.last_reason:
                out[f"{name}.last_rejection"] = st.last_reason
        for name, text in self.nis_findings().items():
            out[f"{name}.nis_diagnosis"] = text
        if self.imu is not None:
            out["imu.sample_timing"] = self.sample_timing()
            d = self.timing_last
            if d is not None:
                out["imu.sample_timing_check"] = d.text()
        if self.recoveries:
            out["recovery_last"] = self.recoveries[-1].text()
        out["command_delay"] = f"{self.delay:g}"
        out["process.dt_in_use"] = f"{self.dt:g}"
        return out

    def observability(self, horizon: float | None = None):
        """Observability of the states at the current state; see :mod:`.observability`."""
        from elastic_pm_dyn.observer.core.observability import analyse
        return analyse(self, horizon)
