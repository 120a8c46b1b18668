"""The plant stepper: the simulated machine behind the plant node, one control period at a time.

The node validates messages and calls these methods, so the stepping, the reset and the
set-state logic run (and are tested) without ROS. Time is an integer count of control
periods, t = k * period, so it never drifts and equals offline sample times.

Besides the commanded torque the motors may feel an unknown disturbance (the truth an
observer has to estimate): a smooth function of time d(t) (``disturbance``, e.g. a
:class:`~elastic_pm_dyn.sim.disturbances.SpectrumDisturbance`) integrated as such (refitted
per step, as offline recordings do), plus a held value given with each period's command.

An external wrench on the end effector (``wrench``, :class:`~elastic_pm_dyn.sim.wrench.ExternalWrench`:
steps, ramps, a wall, a held value) depends on the state (a wall pushes by how far the tool is
in): it is evaluated at the start of every integrator step and held over it (tree forces
J^T w, :class:`~elastic_pm_dyn.sim.wrench.WrenchMap`); :attr:`Plant.true_wrench` is its value at
the current state, the truth an observer's wrench estimate is held against. Without a wrench
the stepping is exactly what it was.

A fault (a singular configuration, or a state that diverged) never leaves garbage: the
state stays the last good one, at the start of the period that failed, until
:meth:`Plant.reset` or :meth:`Plant.set_state`, which recover from any fault.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.dynamics.statics import rest_state
from elastic_pm_dyn.errors import AssemblyError, InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose, solve_velocity
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.sim import kernels
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.stopped import integration_error
from elastic_pm_dyn.sim.torque import ConstantTorque, HeldPlusSmooth, input_bounds
from elastic_pm_dyn.sim.wrench import WRENCH_SIZE, ExternalWrench, WrenchMap

# [rad or m] a requested position beyond this is a mistake: float spacing there exceeds 1e-10
START_STATES = ("relaxed", "static")  # Plant(start=...): springs unloaded, or deflected by gravity
MAX_POSITION = 1.0e6
SET_TOLERANCE = 1e-6  # set_state: a named passive joint where the closure puts it, to this (relative beyond 1)


@dataclass
class BranchState:
    """Per branch (model order): axial force [N], deflection u [m], rate du/dt [m/s]."""

    names: list[str]
    force: np.ndarray
    deflection: np.ndarray
    rate: np.ndarray


class Plant:
    """Tree state (q, qd) of an elastic mechanism under zero-order-held motor torques."""

    def __init__(self, mech: Mechanism, options: SimulationOptions, period: float,
                 disturbance: Callable[[float], np.ndarray] | None = None, start: str = "relaxed",
                 wrench: ExternalWrench | None = None):
        """``start``: ``relaxed`` begins at the model's initial pose with every spring unloaded (as
        ``simulate`` does); ``static`` with the springs deflected by gravity, the motors held there
        (a machine standing at rest, as the observer assumes at its start)."""
        if not (np.isfinite(period) and period > 0):
            raise InputError(f"control period must be a positive number of seconds, got {period!r}")
        options.validate()
        self.mech = mech
        self.options = options
        self.period = period
        if start not in START_STATES:
            raise InputError(f"start must be one of {', '.join(START_STATES)}, got {start!r}")
        self.q0 = rest_state(mech) if start == "static" and len(mech.elastic) else initial_state(mech)
        self.q = self.q0.copy()
        self.qd = np.zeros(mech.n)
        self.k = 0  # control periods done
        self.tau = np.zeros(len(mech.active))  # torque applied over the last period
        self._bounds = input_bounds(mech)  # the motors' input ranges (MJCF servos' ctrlrange), None if none
        # Unknown torques on the motors (truth): a smooth d(t), and a held part per period (the last one's)
        self.disturbance = disturbance
        self.held_disturbance = np.zeros(len(mech.active))
        self._d_last: tuple[float | None, np.ndarray] = (None, self.held_disturbance)  # (t, d(t)) last asked
        self.fault: str | None = None  # why integration stopped (singular configuration, diverged state)
        self.fault_error: SingularConfigurationError | None = None
        self._sim = Simulator(mech, options)
        self._coef = np.zeros((3, mech.n))  # the held torque as RK4's polynomial (constant)
        self._no_rows = np.zeros((0, mech.n))  # _smooth_steps records no samples
        # Compile (or load) the integrator now, not inside the first control period; a
        # throwaway simulator keeps the real one's state as offline runs start it.
        Simulator(mech, options).advance(self.q0.copy(), np.zeros(mech.n), ConstantTorque(self.tau), 0.0, period)
        self._branch_names = [b.name for b in mech.model.branches]
        # the external wrench on the end effector (truth), and where it acts
        self.wrench = wrench
        self.wrench_map = WrenchMap(mech) if wrench is not None else None
        self.true_wrench = np.zeros(WRENCH_SIZE)
        self._update_true_wrench()

    @property
    def t(self) -> float:
        """Simulated time [s] of the current state."""
        return self.k * self.period

    # ----------------------------------------------------------------- stepping
    def step(self, tau: np.ndarray, held_disturbance: np.ndarray | None = None) -> None:
        """Advance one period with ``tau`` (active order) held constant (ZOH), plus the unknown
        torque: ``held_disturbance`` held over the period (None: zero) and :attr:`disturbance` d(t).

        On a singular configuration or a diverged state (SingularConfigurationError, or its
        DivergedStateError) ``fault`` is set, the state stays the one at the start of the
        period (the last good one) and the time does not advance; :meth:`reset` or
        :meth:`set_state` recover. A torque that is not n_a finite numbers: InputError.
        """
        if self.fault_error is not None:
            raise self.fault_error
        tau = np.asarray(tau, dtype=float)
        if tau.shape != self.tau.shape or not np.isfinite(tau.sum()):  # one check: NaN, Inf or overflow
            raise InputError(f"torque must be {len(self.tau)} finite numbers, got {tau!r}")
        held = np.zeros(len(self.tau)) if held_disturbance is None else np.asarray(held_disturbance, dtype=float)
        if held.shape != self.tau.shape or not np.isfinite(held.sum()):
            raise InputError(f"disturbance torque must be {len(self.tau)} finite numbers, got {held!r}")
        if self._bounds is not None:  # a servo's ctrl within its ctrlrange, as MuJoCo clamps it
            tau = np.clip(tau, *self._bounds)
        # Without a disturbance the torque is tau itself: the arithmetic of plants without one is unchanged.
        acting = tau if held_disturbance is None else tau + held
        t0 = self.t
        t1 = t0 + self.period
        q, qd = self.q.copy(), self.qd.copy()  # the stepping works on copies: a fault keeps the last good state
        try:
            fixed_step = self._sim.integrator.fixed_step
            if self.wrench is not None:
                self._wrench_steps(q, qd, acting, t0, t1)
            elif self.disturbance is not None:  # a function of time: refitted per step (as offline simulate)
                if fixed_step and hasattr(self.disturbance, "on_grid"):
                    self._smooth_steps(q, qd, acting, t0, t1)
                else:
                    self._sim.advance(q, qd, HeldPlusSmooth(acting, self.disturbance), t0, t1)
            elif fixed_step:
                self._fixed_step(q, qd, acting, t0, t1)
            else:
                self._sim.advance(q, qd, ConstantTorque(acting), t0, t1)
            if not (np.isfinite(q.sum()) and np.isfinite(qd.sum())):  # the adaptive path has no check of its own
                raise integration_error(kernels.DIVERGED, self.options.formulation, t0, np.array([0.0, np.inf, np.nan]))
        except SingularConfigurationError as err:
            self.fault, self.fault_error = str(err), err
            raise
        self.q, self.qd = q, qd
        self.tau = tau.copy()
        self.held_disturbance = held.copy()
        self.k += 1
        self._update_true_wrench()

    def _update_true_wrench(self) -> None:
        if self.wrench is not None:
            p, v = self.wrench_map.point_state(self.q, self.qd)
            self.true_wrench = self.wrench(self.t, p, v)

    def _wrench_steps(self, q: np.ndarray, qd: np.ndarray, acting: np.ndarray, t0: float, t1: float) -> None:
        """The fixed-step integrator one step at a time, the wrench's tree forces J^T w evaluated at
        each step's start and held over it (a wall's force follows the tool in), the smooth
        disturbance at the step's middle. The step is the plant's dt: a 1e4 N/m wall against the
        end effector's mass rings far below 1 / dt."""
        o, sim, wm = self.options, self._sim, self.wrench_map
        if not sim.integrator.fixed_step:
            raise InputError("an external wrench needs a fixed-step integrator (rk4 or etd2)")
        n_steps = max(1, int(np.ceil((t1 - t0) / o.dt - 1e-9)))
        h = (t1 - t0) / n_steps
        coef = np.zeros((3, self.mech.n))
        for k in range(n_steps):
            t = t0 + k * h
            u = acting + (self.disturbance(t + 0.5 * h) if self.disturbance is not None else 0.0)
            self.mech.split_tau(u, out=coef[0])
            p, v = wm.point_state(q, qd)
            coef[0] += wm.tree_forces(q, self.wrench(t, p, v))
            status = sim.fixed_steps(q, qd, coef, h, 1)
            if status != kernels.OK:
                raise integration_error(status, o.formulation, t + sim.info[0] * h, sim.info)

    def _fixed_step(self, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, t0: float, t1: float) -> None:
        """The simulator's fixed-step method (RK4 or ETD2) over one torque piece (the same steps, so
        the same arithmetic as offline ``simulate``), with the kernel's status turned into the
        error that says why."""
        o, sim = self.options, self._sim
        n_steps = max(1, int(np.ceil((t1 - t0) / o.dt - 1e-9)))
        h = (t1 - t0) / n_steps
        self.mech.split_tau(tau, out=self._coef[0])  # in place, every period
        status = sim.fixed_steps(q, qd, self._coef, h, n_steps)
        if status != kernels.OK:
            raise integration_error(status, o.formulation, t0 + sim.info[0] * h, sim.info)

    def _smooth_steps(self, q: np.ndarray, qd: np.ndarray, held: np.ndarray, t0: float, t1: float) -> None:
        """:meth:`Simulator.advance` of ``HeldPlusSmooth(held, disturbance)`` (one quadratic per step
        through its values at the step's start, middle and end) with the disturbance evaluated at
        all the period's stage times in one vectorised pass and the steps in one compiled call
        (Simulator.run_pieces): 0.25 instead of 0.85 ms per 1 ms period on the five-bar at dt = 1e-4 s
        (measured 2026-11-27 on the 2-core dev machine; bench/benchmarks/bench_plant.py)."""
        o, sim = self.options, self._sim
        n_steps = max(1, int(np.ceil((t1 - t0) / o.dt - 1e-9)))
        h = (t1 - t0) / n_steps
        starts = t0 + np.arange(n_steps) * h
        f = held + self.disturbance.on_grid(t0, 0.5 * h, 2 * n_steps + 1)  # each step's start, middle, end
        f0, f1, f2 = f[0:-1:2], f[1::2], f[2::2]
        coefs = np.stack([f0, (4 * f1 - 3 * f0 - f2) / h, 2 * (f0 - 2 * f1 + f2) / h ** 2], axis=1)
        status, done, _ = sim.run_pieces(q, qd, coefs, np.full(n_steps, h), np.ones(n_steps, dtype=np.int64),
                                         np.zeros(n_steps, dtype=bool), self._no_rows, self._no_rows, 0)
        if status != kernels.OK:
            raise integration_error(status, o.formulation, starts[min(done, n_steps - 1)] + sim.info[0] * h, sim.info)

    def reset(self) -> None:
        """Back to the model's initial state at rest (see :meth:`_restart` for the time)."""
        self._restart(self.q0.copy(), np.zeros(self.mech.n))

    def set_state(self, names: Sequence[str], position: Sequence[float], velocity: Sequence[float]) -> str:
        """Set named joints; the closure fixes the passive ones. Returns a one-line summary.

        Unnamed active/elastic joints keep their current position (after a fault: the
        elastic ones go back to rest, as the last good state led to the fault); passive
        positions come from assembly, a named one the Newton guess that must also be where the
        closure puts it (to SET_TOLERANCE). Velocity: empty = at rest, else given for the named
        joints, zero for the other active/elastic ones, passive from the closure (a named one
        must match it alike). Raises InputError (state unchanged) when it cannot be done: an
        empty request, or a state the closure does not allow.
        """
        mech = self.mech
        names = [str(n) for n in names]
        if not names:
            raise InputError("an empty request: name the joints to set (state.name) and give their positions "
                             "(state.position)")
        unknown = [n for n in names if n not in mech.joint_names]
        if unknown:
            raise InputError(f"unknown joint(s) {', '.join(unknown)} (joints: {', '.join(mech.joint_names)})")
        if len(set(names)) != len(names):
            raise InputError("a joint is named twice")
        if len(position) != len(names) or (len(velocity) and len(velocity) != len(names)):
            raise InputError(f"{len(names)} names need as many positions (got {len(position)}) "
                             f"and velocities (got {len(velocity)}, or none for rest)")
        pos, vel = np.asarray(position, dtype=float), np.asarray(velocity, dtype=float)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel))):
            raise InputError("NaN or Inf in the requested state")
        max_rate = kernels.MAX_STEP_MOTION / self.options.dt  # faster diverges in the first step
        if np.any(np.abs(pos) > MAX_POSITION) or np.any(np.abs(vel) > max_rate):
            raise InputError(f"positions must lie within +-{MAX_POSITION:g} (rad or m) and velocities within "
                             f"+-{max_rate:g} (rad/s or m/s, one step of dt = {self.options.dt:g} s)")
        idx = np.array([mech.joint_names.index(n) for n in names], dtype=int)
        q = self.q.copy()
        if self.fault is not None:
            q[mech.elastic] = mech.rest[mech.elastic]
        q[idx] = pos
        qd = np.zeros(mech.n)
        if len(vel):
            qd[idx] = vel
        q, qd = self._assemble(q, qd, idx)
        for what, want, got in (("at", pos, q[idx]), ("moving at", vel, qd[idx]) if len(vel) else ("", (), ())):
            off = np.abs(np.asarray(got) - want) > SET_TOLERANCE * np.maximum(1.0, np.abs(want))
            if np.any(off):  # a named passive joint the closure puts elsewhere (the rest are set as named)
                k = int(np.argmax(off))
                raise InputError(f"state not reachable: the closure puts {mech.joint_names[idx[k]]} {what} "
                                 f"{got[k]:.6g}, not {want[k]:.6g} (with the other joints as named); name the motors "
                                 "(and springs) alone to let the closure place the passive joints")
        self._restart(q, qd)
        return f"state set at t = {self.t:.6g} s (closure gap {mech.gap(q):.3g} m)"

    def _assemble(self, q: np.ndarray, qd: np.ndarray, named: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Passive positions and velocities from the closure; from the start pose's passive
        joints as a second guess (the current ones may lie in another assembly branch)."""
        mech = self.mech
        if not mech.m:
            return q, qd
        guesses = [q]
        unnamed_passive = np.setdiff1d(mech.passive, named)
        if len(unnamed_passive):
            second = q.copy()
            second[unnamed_passive] = self.q0[unnamed_passive]
            guesses.append(second)
        reason = ""
        for guess in guesses:
            try:
                pose = solve_pose(mech, guess, mech.passive)
                return pose, solve_velocity(mech, pose, mech.passive, qd)
            except (AssemblyError, SingularConfigurationError, np.linalg.LinAlgError, FloatingPointError) as err:
                reason = reason or str(err)
        raise InputError(f"state not reachable: {reason}")

    def _restart(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Continue from (q, qd) one period later: time never runs back, and the new state gets a
        time stamp of its own (a lockstep controller that answers each new stamp resumes)."""
        self.q, self.qd = q, qd
        self.k += 1
        self.tau = np.zeros(len(self.mech.active))
        self.held_disturbance = np.zeros(len(self.mech.active))
        self.fault = self.fault_error = None
        self._update_true_wrench()
        # A fresh simulator: the one-pass SCDD variant keeps the last accelerations.
        self._sim = Simulator(self.mech, self.options)

    # ------------------------------------------------------------------ outputs
    def efforts(self, out: np.ndarray | None = None, springs: np.ndarray | None = None,
                work: np.ndarray | None = None) -> np.ndarray:
        """Per tree joint: applied motor torque (active: B u on the motor's joint), spring force
        c u + d du/dt (elastic), 0 (passive); into ``out`` without allocating where ``out``,
        ``springs`` and ``work`` (scratch of the tree's size) are given (the plant node's publishing, every period)."""
        mech = self.mech
        out = np.empty(mech.n) if out is None else out
        springs = mech.spring_forces(self.q, self.qd, springs, work)
        out[:] = 0.0
        # a spread motor (a tendon): what its input does on its own joint
        out[mech.active] = mech.split_tau(self.tau)[mech.active] if mech.spread else self.tau
        out[mech.elastic] = springs[mech.elastic]
        return out

    def branches(self, efforts: np.ndarray | None = None) -> BranchState:
        """Branch force = its spring joint's force c u + d du/dt (pass :meth:`efforts` to reuse it)."""
        j = self.mech.branch_joints
        force = (self.efforts() if efforts is None else efforts)[j]
        return BranchState(self._branch_names, force, self.q[j] - self.mech.rest[j], self.qd[j].copy())

    def motor_torque(self, tau: np.ndarray | None = None, held: np.ndarray | None = None) -> np.ndarray:
        """The total torque on the motors at the current state's time t_k: the command ``tau`` plus
        the disturbance (``held`` + d(t_k)). By default the last period's command and held part:
        the torque just before t_k (what a(t_k-) feels); the next period's give a(t_k+)."""
        return (self.tau if tau is None else np.asarray(tau, dtype=float)) + self.disturbance_at(self.t, held)

    def disturbance_at(self, t: float, held: np.ndarray | None = None) -> np.ndarray:
        """The unknown motor torque at ``t``: d(t) plus ``held`` (default: the last period's held part)."""
        out = (self.held_disturbance if held is None else held).copy()
        if self.disturbance is not None:
            if self._d_last[0] != t:  # asked for the same t_k by the truth topic and the accelerometer
                self._d_last = (t, self.disturbance(t))
            out += self._d_last[1]
        return out

    def wrench_tree_forces(self) -> np.ndarray | None:
        """The tree forces J^T w of :attr:`true_wrench` at the current state (None without a wrench):
        what an accelerometer sample of this state feels besides the motor torques."""
        if self.wrench is None:
            return None
        return self.wrench_map.tree_forces(self.q, self.true_wrench)

    def end_effector(self) -> np.ndarray:
        return self.mech.end_effector(self.q)

    def gap(self) -> float:
        return self.mech.gap(self.q)
