"""The plant stepper: the simulated machine behind the plant node, one control period at a time.

The node validates messages and calls these methods, so the stepping, the reset and the
set-state logic run (and are tested) without ROS. Time is an integer count of control
periods, t = k * period, so it never drifts and equals offline sample times.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from elastic_pm_dyn.errors import AssemblyError, InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose, solve_velocity
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque


@dataclass
class BranchState:
    """Per branch (model order): axial force [N], deflection u [m], rate du/dt [m/s]."""

    names: list[str]
    force: np.ndarray
    deflection: np.ndarray
    rate: np.ndarray


class Plant:
    """Tree state (q, qd) of an elastic mechanism under zero-order-held motor torques."""

    def __init__(self, mech: Mechanism, options: SimulationOptions, period: float):
        if not (np.isfinite(period) and period > 0):
            raise InputError(f"control period must be a positive number of seconds, got {period!r}")
        options.validate()
        self.mech = mech
        self.options = options
        self.period = period
        self.q0 = initial_state(mech)
        self.q = self.q0.copy()
        self.qd = np.zeros(mech.n)
        self.k = 0  # control periods done
        self.tau = np.zeros(len(mech.active))  # torque applied over the last period
        self.fault: str | None = None  # why integration stopped (singular configuration)
        self._sim = Simulator(mech, options)
        # Compile (or load) the integrator now, not inside the first control period; a
        # throwaway simulator keeps the real one's state as offline runs start it.
        Simulator(mech, options).advance(self.q0.copy(), np.zeros(mech.n), ConstantTorque(self.tau), 0.0, period)
        self._branch_names = [b.name for b in mech.model.branches]

    @property
    def t(self) -> float:
        """Simulated time [s] of the current state."""
        return self.k * self.period

    # ----------------------------------------------------------------- stepping
    def step(self, tau: np.ndarray) -> None:
        """Advance one period with ``tau`` (active order) held constant (ZOH).

        On a singular configuration ``fault`` is set, the state stays at the last good
        RK4 step and the time does not advance; :meth:`reset` or :meth:`set_state` recover.
        """
        if self.fault is not None:
            raise SingularConfigurationError(self.fault)
        t0 = self.t
        try:
            self._sim.advance(self.q, self.qd, ConstantTorque(tau), t0, t0 + self.period)
        except SingularConfigurationError as err:
            self.fault = str(err)
            raise
        self.tau = np.array(tau, dtype=float)
        self.k += 1

    def reset(self) -> None:
        """Back to the model's initial state at rest (see :meth:`_restart` for the time)."""
        self._restart(self.q0.copy(), np.zeros(self.mech.n))

    def set_state(self, names: Sequence[str], position: Sequence[float], velocity: Sequence[float]) -> str:
        """Set named joints; the closure fixes the passive ones. Returns a one-line summary.

        Unnamed active/elastic joints keep their current position; passive positions
        (named ones are the Newton guess) come from assembly. Velocity: empty = at rest,
        else given for the named joints, zero for the other active/elastic ones, passive
        from the closure. Raises InputError (state unchanged) when it cannot be done.
        """
        mech = self.mech
        names = list(names)
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
        idx = np.array([mech.joint_names.index(n) for n in names], dtype=int)
        q = self.q.copy()
        q[idx] = pos
        qd = np.zeros(mech.n)
        if len(vel):
            qd[idx] = vel
        try:
            if mech.m:
                q = solve_pose(mech, q, mech.passive)
                qd = solve_velocity(mech, q, mech.passive, qd)
        except (AssemblyError, SingularConfigurationError) as err:
            raise InputError(f"state not reachable: {err}") from None
        self._restart(q, qd)
        return f"state set at t = {self.t:.6g} s (closure gap {mech.gap(q):.3g} m)"

    def _restart(self, q: np.ndarray, qd: np.ndarray) -> None:
        """Continue from (q, qd) one period later: time never runs back, and the new state gets a
        time stamp of its own (a lockstep controller that answers each new stamp resumes)."""
        self.q, self.qd = q, qd
        self.k += 1
        self.tau = np.zeros(len(self.mech.active))
        self.fault = None
        # A fresh simulator: the one-pass SCDD variant keeps the last accelerations.
        self._sim = Simulator(self.mech, self.options)

    # ------------------------------------------------------------------ outputs
    def efforts(self) -> np.ndarray:
        """Per tree joint: applied motor torque (active), spring force c u + d du/dt (elastic), 0 (passive)."""
        out = np.zeros(self.mech.n)
        out[self.mech.active] = self.tau
        out[self.mech.elastic] = self.mech.spring_forces(self.q, self.qd)[self.mech.elastic]
        return out

    def branches(self, efforts: np.ndarray | None = None) -> BranchState:
        """Branch force = its spring joint's force c u + d du/dt (pass :meth:`efforts` to reuse it)."""
        j = self.mech.branch_joints
        force = (self.efforts() if efforts is None else efforts)[j]
        return BranchState(self._branch_names, force, self.q[j] - self.mech.rest[j], self.qd[j].copy())

    def end_effector(self) -> np.ndarray:
        return self.mech.end_effector(self.q)

    def gap(self) -> float:
        return self.mech.gap(self.q)
