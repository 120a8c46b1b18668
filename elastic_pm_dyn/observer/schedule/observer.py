"""The observer: time-stamped messages in, the filter's predictions and corrections at their stamps, estimates out.

:class:`Observer` is the scheduler over the filter (:class:`~elastic_pm_dyn.observer.core.ekf.Ekf`,
its base: state, predict, correct, the estimate row). It holds the commands
(:mod:`.commands`: delays, the queue, the timeout), the accelerometer's sample timing
(:mod:`.sample_timing`: the hypotheses, held and deferred samples), the fall-back from
divergence (:mod:`.recovery`) and the sensors' statistics (:mod:`.sensor_stats`: results, health,
diagnostics), and decides per message what the filter does. Every prediction runs the compiled
``advance`` of :mod:`~elastic_pm_dyn.observer.core.period`, whose steps (the samples of a stamp,
its command) ``observe`` runs for many periods in one call; with :attr:`Observer.steps_compiled`
each message runs one step, and what a step does not take (gated, late, simultaneous or
non-finite samples, timing decisions, recoveries, faults) the Python here takes, with the same
numbers.

Time: float seconds of the message stamps since an integer-ns origin (the stream's,
:mod:`~elastic_pm_dyn.observer.drivers.stream`: epoch stamps keep their nanoseconds). A sample
stamped t_k is compared with the state at t_k. Correction is sequential per message. Samples
stamped before the filter's time are late and dropped (the filter never rewinds); a stamp ahead
of it is first predicted to, unless more than ``timing.max_future`` ahead (an outlier: not used,
counted as ``future``, the time stays). Missing samples just mean longer predictions;
``reset()`` without a time restarts the clock at the next stamp.

Typical use (live node or offline)::

    obs = Observer(mech, load_config("config/observer.yaml"))
    obs.command(t, tau)                          # torque_command
    obs.update_joint_states(t, names, position)  # measured_joint_states
    obs.update_imu(t, accel)                     # ee_imu
    est = obs.estimate()                         # joint states, branch forces, std devs
"""

from __future__ import annotations

from operator import attrgetter

import numpy as np

from elastic_pm_dyn.dynamics.statics import static_deflection
from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.kinematics.assembly import solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import ACTIVE
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.core import kernels, period
from elastic_pm_dyn.observer.core.ekf import Ekf, ObserverFault
from elastic_pm_dyn.observer.core.observer_model import ObserverModel
from elastic_pm_dyn.observer.core.sensors import FastEncoderPlan, Sample, motor_positions
from elastic_pm_dyn.observer.schedule import sensor_stats
from elastic_pm_dyn.observer.schedule.commands import MAX_PENDING_COMMANDS, CommandQueue
from elastic_pm_dyn.observer.schedule.recovery import EncoderRecovery
from elastic_pm_dyn.observer.schedule.sample_timing import AUTO, DeferredSample, HeldSample, SampleTiming
from elastic_pm_dyn.observer.schedule.sensor_stats import UpdateResult

# a correction's status (correction.correct, imu_correct) that is a fault
CORRECTION_FAULTS = {2: "a {sensor} correction left the closure unsolvable at t = {t:.6f} s",
                     3: "covariance lost positive definiteness in a {sensor} correction at t = {t:.6f} s",
                     4: "singular configuration in the {sensor} model at t = {t:.6f} s"}


class Observer(Ekf):
    """EKF of an elastic parallel manipulator, driven by time-stamped messages; see the module docstring.

    ``mech``: the mechanism, or an :class:`~elastic_pm_dyn.observer.core.observer_model.ObserverModel`
    built for it (the fixed part, shared by many observers with configurations of one
    :func:`~elastic_pm_dyn.observer.core.observer_model.model_key`); the observer holds the rest of
    its configuration (disturbance model, noise levels, gates, timing) and the filter's state."""

    # statistics made by reset keep each sample's NLL term (calibration's per-sample scores)
    keep_terms: bool = False
    # the parts' state as the observer's own (read only)
    tau_hold = property(attrgetter("commands.tau_hold"))  # the held command (active joint order)
    t_command = property(attrgetter("commands.t_command"))  # ... acting from here
    _pending = property(attrgetter("commands.pending"))  # delayed commands: (time it acts from, torque)
    delay = property(attrgetter("commands.delay"))  # command_delay [s]
    evidence = property(attrgetter("imu_timing.evidence"))  # sample timing: correction.imu_innovations' sums
    timing_decisions = property(attrgetter("imu_timing.decisions"))  # ... the first choice and every switch
    timing_last = property(attrgetter("imu_timing.last"))  # ... the latest choice or check
    recoveries = property(attrgetter("recovery.done"))  # fall-backs since the last reset

    def __init__(self, mech: Mechanism | ObserverModel, config: ObserverConfig | None = None, t0: float = 0.0,
                 q0: np.ndarray | None = None, qd0: np.ndarray | None = None):
        super().__init__(mech, config)
        cfg = self.cfg
        tol = cfg.timing.stamp_tolerance
        self.commands = CommandQueue(self.mech, cfg)
        self.imu_timing = SampleTiming(cfg.imu.sample_timing, self.imu is not None, cfg.command_delay <= tol, tol)
        self.recovery = EncoderRecovery()
        self.released: list[UpdateResult] = []  # held samples the last call corrected
        # True: each message through one compiled step (period.sample_step / command_step), the
        # Python below only for what a step refuses. The same numbers (test_observer_fastpath),
        # but measured 3-16 % slower per live period than the Python calling the kernels piece
        # by piece (bench_observer_loop): a step per message makes as many calls and adds a
        # snapshot. The speed-up needs one call per period; until then the Python is the default.
        self.steps_compiled = False
        self.wrench_jumps: list[float] = []  # stamps where a gated accelerometer sample made the wrench jump
        self.reset(t0, q0, qd0, initialised=q0 is not None or cfg.initial.source == "model")
        self._timing = self.fast_timing()
        n, na = self.mech.n, len(self.mech.active)
        # the compiled steps' work arrays and snapshot (period.step_work, period.snapshot_buffers)
        self._work = (np.zeros((3, n)), tuple(a.copy() for a in self._state()), np.zeros(n), np.zeros(3))
        self._save = (tuple(a.copy() for a in self._state()), (np.zeros(na), np.zeros(na)), np.zeros(4), np.zeros(9))
        self._row = np.empty(4)
        self._empty_plan = (np.zeros((0, self.nx)), np.zeros(0), np.zeros(0, dtype=np.int64),
                            np.zeros(0, dtype=np.bool_))

    # ------------------------------------------------------------------ set-up
    def reset(self, t: float | None = None, q: np.ndarray | None = None, qd: np.ndarray | None = None,
              P0: np.ndarray | None = None, initialised: bool = True) -> None:
        """Restart at time t from tree state (q, qd); t None: at the stamp of the next sample
        or command (the time an outlier may have left behind is not kept).

        q defaults to the model's initial state, qd to rest; the closure fixes q_p and qd_p
        (q_p from q's values as the Newton guess). Statistics, disturbance estimates and
        a fault are cleared. ``initialised=False`` makes the next joint state (with every
        active joint's position) set the pose instead (``initial.source: measurement``).
        """
        self.t = float(self.t if t is None else t)
        self.time_pending = t is None  # the next stamp sets the time
        self._set_state(q, qd, P0)
        self.tau_last = self.commands.tau_hold.copy()
        self.initialised = initialised
        self.stats = sensor_stats.fresh_stats(self.keep_terms)
        self.recovery.reset()
        self.imu_timing.reset(self.t)
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
        motors = motor_positions(mech, names, position)
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
        self.commands.restart_at(t)  # the held command stays
        self.reset(t, q, qd, P0)
        return True

    # ------------------------------------------------------------------ messages
    def predict(self, tau: np.ndarray, t_to: float) -> None:
        """Integrate from the filter's time to t_to with ``tau`` (active joint order) held;
        ``tau`` stays the held command afterwards."""
        self.commands.tau_hold = self.commands.checked(tau, self.stats["command"])
        self.commands.t_command = self.t
        self._advance(float(t_to))

    def command(self, t: float, tau: np.ndarray) -> bool:
        """A torque command stamped t (active joint order): predict to t with the previous
        command, then hold this one. A command older than the last one is ignored (False)."""
        tau = self.commands.checked(tau, self.stats["command"])
        self.released = []
        if self._fast_command(t, tau):
            return True
        st = self.stats["command"]
        if self.initialised and self._ahead(t, st):
            return False
        tol = self.cfg.timing.stamp_tolerance
        t_act = t + self.commands.delay  # it acts from here
        if t_act < self.commands.newest() - tol:
            st.late += 1
            return False
        if self.initialised:
            if t_act < self.t - tol:
                st.late += 1  # late but newest: applies from now on
            if t >= self.t - tol:
                self._timing_check(t)
                self._advance(t)
        self.commands.add(t_act, tau)
        self.commands.activate_due(self.t if self.initialised else t)
        st.accepted += 1
        st.consecutive_rejections = 0
        self._settle()  # the sample of this stamp waited for it
        return True

    def update_joint_states(self, t: float, names, position=None, velocity=None, effort=None
                            ) -> list[UpdateResult]:
        """Encoder positions/rates (and elastic-joint efforts as branch forces, if so configured)."""
        self.released = []
        efforts = (self.branch is not None and self.branch.source == "joint_state_effort" and effort is not None
                   and len(effort))
        if self.encoders is not None and position is not None and len(position) == len(names) and not efforts:
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
                nis, status, logdet = self._correct_encoders(fast.bundle, np.asarray(position, dtype=float)[idx], gate)
                if status >= 0:
                    out.append(self._after("encoders", t, nis, status, len(idx), gate, [], logdet))
                    fast = True
            if fast is not True:
                W = self._passive_jacobian() if self.encoders.needs_w else None
                s = self.encoders.sample(list(names), position, velocity, self.q, self.qd, W, self.nx)
                if s is not None:
                    out.append(self._correct(s, t))
            if out and out[-1].reason == "gate" and position is not None:
                self.recovery.on_gated(self, t, names, position)
        if efforts:
            if len(effort) != len(names):
                raise InputError(f"joint state: {len(names)} names but {len(effort)} efforts")
            pairs = [(self.branch.by_joint[n], e) for n, e in zip(names, effort, strict=True)
                     if n in self.branch.by_joint]
            if pairs:
                out.append(self._branch_update(t, [p[0] for p in pairs], [p[1] for p in pairs]))
        return out

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
        waiting = self.imu_timing.waits_for_command(t, self.commands.newest(), self.commands.delay)
        if waiting and self.imu_timing.use_after():
            self._settle()  # two samples at one stamp: the first goes now
            self.imu_timing.held = HeldSample(t, acc)
            return None
        return self._imu_update(t, acc, defer=waiting)

    def update_branch_forces(self, t: float, names, force) -> UpdateResult | None:
        """Measured branch forces (strain gauges), by branch name."""
        self.released = []
        if self.branch is None:
            return None
        return self._branch_update(t, list(names), force)

    # ------------------------------------------------------------------ time
    def _sync(self, t: float, sensor: str) -> UpdateResult | None:
        """Bring the filter to stamp t; a result if the sample cannot be used."""
        st = self.stats[sensor]
        if not self.initialised:
            st.other += 1
            return UpdateResult(sensor, t, False, reason="uninitialised")
        if self._ahead(t, st):
            return UpdateResult(sensor, t, False, reason="future")
        if t < self.t - self.cfg.timing.stamp_tolerance:
            st.late += 1
            st.last_reason = f"late by {self.t - t:.6f} s"
            return UpdateResult(sensor, t, False, reason="late")
        self._timing_check(t)
        self._advance(t)
        return None

    def _ahead(self, t: float, st: sensor_stats.SensorStats) -> bool:
        """After ``reset(t=None)`` the filter (and the held command) restart at this stamp; True
        for a stamp more than timing.max_future ahead of the filter: an outlier (counted), the time stays."""
        if self.time_pending:
            self.t = t
            self.commands.restart_clock(t)
            self.time_pending = False
            self.imu_timing.restart(t)
        if not t - self.t > self.cfg.timing.max_future:
            return False
        st.future += 1
        st.consecutive_rejections += 1
        st.last_reason = (f"stamped {t - self.t:.6g} s ahead of the filter's time {self.t:.6f} s "
                          f"(timing.max_future {self.cfg.timing.max_future:g} s)")
        return True

    def _advance(self, t_to: float) -> None:
        """Predict from self.t to t_to with the held command (zero after a timeout): ``period.advance``."""
        if self.fault is not None:
            raise ObserverFault(self.fault)
        tol = self.cfg.timing.stamp_tolerance
        if self.imu_timing.waiting_since() < t_to - tol:
            self._settle()  # the command of its stamp did not come: the torque acting now
        if not t_to - self.t > tol:
            self.commands.activate_due(self.t)  # nothing to predict (what period.advance does then)
            return
        cmd, ctl = self._kernel_control(0, np.inf)
        status = self._predict(cmd, ctl, self._timing, t_to, self._work[0][2])
        self._take_control(cmd, ctl)
        self._check_prediction(status)

    # ------------------------------------------------------------------ sample timing
    def _timing_check(self, t: float) -> None:
        """``auto``: at a stamp from the decision time on, choose (first) or check the choice."""
        if self.imu_timing.due(t):
            self._settle()  # what waits belongs to this window
            self.imu_timing.decide(t)

    def _settle(self) -> None:
        """What waited for the command of its stamp: a deferred weighing (``auto``: the sample's
        prior under both hypotheses, the torque acting now as the after one) and a held sample."""
        timing = self.imu_timing
        d = timing.deferred
        if d is not None:
            timing.deferred = None
            self._weigh_imu(d.prior, d.tau_before, self.mech.split_tau(self.commands.torque_at(self.t)), d.meas,
                            timing.evidence, d.a_before)
        held = timing.held
        if held is not None:
            timing.held = None
            self.released.append(self._imu_update(held.t, held.acc))

    def _imu_update(self, t: float, acc: np.ndarray, defer: bool = False) -> UpdateResult:
        """Correct with an accelerometer sample at the filter's time (stamp t): the torque before
        it is the last prediction piece's, the one after it the torque acting now. ``defer``
        (``auto`` under before_command, the command of t still to come): weigh it then."""
        imu, timing = self.imu, self.imu_timing
        meas = acc[imu.axes]
        tau_before = self.mech.split_tau(self.tau_last)
        tau_after = self.mech.split_tau(self.commands.torque_at(self.t))
        after = timing.use_after()
        if not np.all(np.isfinite(meas)):  # the slow path drops NaN axes and reports them (no evidence)
            a = np.empty(3)
            kernels.point_acceleration(self.mech.arrays, self.q, self.qd, tau_after if after else tau_before,
                                       self.dist_idx, self.disturbance(), self.point, a)
            return self._correct(imu.sample(acc, a, self.Hpt), t)
        gate = self.imu_gate(len(meas))
        if timing.mode == AUTO and not defer:
            nis, status, logdet = self._correct_imu_weighed(tau_before, tau_after, after, meas, gate, timing.evidence)
        else:
            a = np.empty(3)  # the point's acceleration at the prior: a deferred sample's weighing takes it
            if defer:  # (then under before: after would have held the sample)
                self._settle()
                # the sample's prior (the kernels' State bundle; Phi, Qd and info are not read)
                prior = (self.q.copy(), self.qd.copy(), self.z.copy(), self.P.copy(), self.Phi, self.Qd,
                         self.Hpt.copy(), self.info)
                timing.deferred = DeferredSample(t, meas.copy(), prior, tau_before, a)
            nis, status, logdet = self._correct_imu(tau_after if after else tau_before, meas, gate, a)
        if status == 1 and self.nw:
            nis, status, logdet = self._wrench_jump(t, tau_after if after else tau_before, meas,
                                                    self.gate(len(meas)), nis, logdet)
        return self._after("imu", t, nis, status, len(meas), gate, [], logdet)

    def _wrench_jump(self, t: float, tau: np.ndarray, meas: np.ndarray, gate: float, nis: float,
                     logdet: float) -> tuple[float, int, float]:
        """An accelerometer sample beyond :meth:`imu_gate` while the filter carries wrench states: the
        likeliest cause is a wrench that jumped (a contact, a push) faster than its random walk
        allows. The wrench states' variances grow by ``process.wrench_jump_stddev``^2 and the sample
        is tried once more against the full gate ``gate``: taken, the estimate follows the jump
        within the period; gated again, it stays an outlier (the first result is kept, the
        variances grown)."""
        pc = self.cfg.process
        ws = np.arange(self.nx - self.nw, self.nx)
        couple = np.abs(self.model.wrench_axes[:, 3:]).sum(axis=1) > 0
        self.P[ws, ws] += np.where(couple, pc.wrench_jump_torque_stddev, pc.wrench_jump_stddev) ** 2
        again = self._correct_imu(tau, meas, gate, np.empty(3))
        if again[1] == 0:
            self.wrench_jumps.append(t)
            return again
        return nis, 1, logdet

    def sample_timing(self) -> str:
        """The accelerometer sample timing in use: before_command | after_command (auto: ``auto
        (trial)`` until the first choice)."""
        return self.imu_timing.in_use()

    def timing_summary(self) -> dict:
        """The timing settings and, for ``auto``, its choices (for summary.json)."""
        return self.imu_timing.summary(self.cfg.imu.sample_timing, self.commands.delay)

    # ------------------------------------------------------------------ compiled steps
    def fast_timing(self) -> np.ndarray:
        """``period.run_periods``' timing array (fixed for the observer's life)."""
        p, tm = self.cfg.process, self.cfg.timing
        return np.array([p.max_interval, self.dt, tm.stamp_tolerance, p.relinearize_every, tm.command_timeout,
                         self.commands.delay, float(self.imu_timing.mode), float(self.imu_timing.no_delay)])

    def _kernel_control(self, room: int, t_stop: float) -> tuple[tuple, np.ndarray]:
        """The compiled steps' ``cmd`` (copies of the held and last command, the delayed-command
        queue with room for ``room`` more) and control array (module ``period``), stopping at ``t_stop``."""
        tau_hold, pend_t, pend_tau = self.commands.bundle(room)
        ctl = np.array([self.t, float(self._lin_age), self._lin_T, self.commands.t_command, 0.0,
                        float(len(self.commands.pending)), t_stop, float(self.imu_timing.trial),
                        float(self.imu_timing.after)])
        return (tau_hold, self.tau_last.copy(), pend_t, pend_tau), ctl

    def _take_control(self, cmd: tuple, ctl: np.ndarray) -> None:
        """Take back what :meth:`_kernel_control` gave a compiled step."""
        self.t, self._lin_age = float(ctl[period.T_NOW]), int(ctl[period.LIN_AGE])
        self._lin_T = float(ctl[period.LIN_T])
        tau_hold, self.tau_last, pend_t, pend_tau = cmd
        self.commands.take_bundle(tau_hold, float(ctl[period.T_COMMAND]), pend_t, pend_tau, int(ctl[period.HEAD]),
                                  int(ctl[period.TAIL]))

    def fast_state(self, periods: int) -> tuple[tuple, np.ndarray]:
        """``period.run_periods``' ``cmd`` and control array for ``periods`` more periods; a
        sample waiting for its command stops the fast path at once (the per-message API's)."""
        timing = self.imu_timing
        return self._kernel_control(periods, -np.inf if timing.waiting_since() < np.inf else timing.t_decide)

    def _fast_samples(self, t: float, plan: FastEncoderPlan | None, position, acc: np.ndarray | None
                      ) -> list[UpdateResult] | None:
        """The samples of one stamp through ``period.sample_step`` (encoder positions of
        ``plan`` (``Encoders.fast_plan``) and/or an accelerometer sample); None if it did not
        take them (the Python above then does)."""
        tol = self.cfg.timing.stamp_tolerance
        timing = self.imu_timing
        if not (self.steps_compiled and self.initialised and self.fault is None and not self.time_pending
                and timing.held is None and timing.deferred is None and t >= self.t - tol
                and not t - self.t > self.cfg.timing.max_future):
            return None
        has_enc, has_imu = plan is not None, acc is not None
        enc_m = np.asarray(position, dtype=float)[plan.idx] if has_enc else self._row[:0]
        meas = acc[self.imu.axes] if has_imu else self._row[:0]
        if (has_imu and not has_enc and not abs(t - self.t) > tol and t < timing.t_decide - tol
                and timing.waits_for_command(t, self.commands.newest(), self.commands.delay) and timing.use_after()
                and np.all(np.isfinite(meas))):
            # what sample_step would do (HELD: the command of this stamp corrects it), without a call
            timing.held = HeldSample(t, acc)
            return []
        enc = plan.bundle if has_enc else self._empty_plan
        dof_e = len(plan.idx) if has_enc else 0
        cmd, ctl = self._kernel_control(0, timing.t_decide)
        row = self._row
        r = self._pin(period.sample_step)(self.mech.arrays, self.model.fixed, self._proc, self._state(), cmd, ctl,
                                          self._timing, timing.evidence, enc,
                                          self.gate(dof_e) if has_enc else np.inf, self._imu_bundle,
                                          self.imu_gate(len(meas)) if has_imu else np.inf, float(t), has_enc, enc_m,
                                          has_imu, meas, self._work, self._save, row)
        if r == 0:
            return None
        self._take_control(cmd, ctl)
        out = []
        if has_enc:
            out.append(self._after("encoders", t, float(row[0]), 0, dof_e, np.inf, [], float(row[2])))
        if r == period.HELD:
            timing.held = HeldSample(t, acc)
        elif has_imu:
            out.append(self._after("imu", t, float(row[1]), 0, len(meas), np.inf, [], float(row[3])))
            if r == period.DEFERRED:
                timing.deferred = DeferredSample(t, meas, self._work[1], self._work[2], self._work[3])
        return out

    def _fast_command(self, t: float, tau: np.ndarray) -> bool:
        """A command through ``period.command_step``; False if it did not take it (the Python
        above then does)."""
        timing = self.imu_timing
        if not (self.steps_compiled and self.initialised and self.fault is None and not self.time_pending
                and len(self.commands.pending) < MAX_PENDING_COMMANDS
                and not t - self.t > self.cfg.timing.max_future):
            return False
        if timing.held is None and timing.deferred is None:
            return False  # nothing waits for it: the Python above only queues it (cheaper than a call)
        waiting, meas, work = period.TAKEN, self._row[:0], self._work
        if timing.held is not None:
            waiting, meas = period.HELD, timing.held.acc[self.imu.axes]
            if not np.all(np.isfinite(meas)):
                return False
        elif timing.deferred is not None:
            d = timing.deferred
            waiting, meas, work = period.DEFERRED, d.meas, (work[0], d.prior, d.tau_before, d.a_before)
        cmd, ctl = self._kernel_control(1, timing.t_decide)
        row = self._row
        done = self._pin(period.command_step)(self.mech.arrays, self.model.fixed, self._proc, self._state(), cmd, ctl,
                                              self._timing, timing.evidence, self._imu_bundle,
                                              self.imu_gate(len(meas)) if len(meas) else np.inf, float(t), tau,
                                              waiting,
                                              meas, work, self._save, row)
        if not done:
            return False
        self._take_control(cmd, ctl)
        st = self.stats["command"]
        st.accepted += 1
        st.consecutive_rejections = 0
        if waiting == period.HELD:
            t_held = timing.held.t
            timing.held = None
            self.released.append(self._after("imu", t_held, float(row[1]), 0, len(meas), np.inf, [], float(row[3])))
        timing.deferred = None
        return True

    # ------------------------------------------------------------------ corrections and their results
    def _branch_update(self, t, names, force) -> UpdateResult:
        late = self._sync(t, "branch_forces")
        if late is not None:
            return late
        x = self.x()
        s = self.branch.sample(names, np.asarray(force, dtype=float), x, self.nx)
        if s is None:
            return UpdateResult("branch_forces", t, False, reason="empty")
        return self._correct(s, t)

    def _correct(self, s: Sample, t: float) -> UpdateResult:
        st = self.stats[s.sensor]
        st.nan += len(s.dropped)
        if s.r.size == 0:
            st.last_reason = "NaN: " + ", ".join(s.dropped)
            return UpdateResult(s.sensor, t, False, reason="nan", dropped=s.dropped)
        gate = self.gate(s.r.size)
        nis, status, logdet = self._correct_sample(s, gate)
        return self._after(s.sensor, t, nis, status, s.r.size, gate, s.dropped, logdet)

    def _after(self, sensor: str, t: float, nis: float, status: int, dof: int, gate: float,
               dropped: list[str], logdet: float = float("nan")) -> UpdateResult:
        """What a correction's status (0 applied, 1 gated, else a fault) makes of the sample."""
        if status in CORRECTION_FAULTS:
            self.stats[sensor].last_nis = nis
            self._fail(CORRECTION_FAULTS[status].format(sensor=sensor, t=t))
        return sensor_stats.record(self.stats[sensor], sensor, t, nis, status == 1, dof, gate, dropped, logdet,
                             self.cfg.gating.nis_window)

    # ------------------------------------------------------------------ health
    def health(self) -> tuple[int, str]:
        """(level OK/WARN/ERROR, one line) for /diagnostics."""
        return sensor_stats.health(self)

    def nis_findings(self) -> dict[str, str]:
        """Sensors whose windowed NIS is far off (or that are mostly gated out), each with one line
        naming its likely cause (:mod:`~elastic_pm_dyn.observer.schedule.consistency`)."""
        return sensor_stats.nis_findings(self)

    def nis_band(self, sensor: str, p: float = 0.95) -> tuple[float, float, float]:
        """Two-sided p band of the windowed mean NIS and its value (NaN if no samples)."""
        return sensor_stats.nis_band(self.stats[sensor], p)

    def diagnostics(self) -> dict[str, str]:
        """Key/value pairs for diagnostic_msgs/KeyValue: counts and NIS statistics per sensor."""
        return sensor_stats.diagnostics(self)
