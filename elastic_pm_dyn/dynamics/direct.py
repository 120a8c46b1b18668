"""Direct dynamics behind one interface: ``Dynamics(mech, "scdd").accelerations(...)``."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, SCDD_ONE_PASS, SINGULAR_TOL, accelerations
from elastic_pm_dyn.dynamics.one_pass import check_one_pass, one_pass_convergence_factor
from elastic_pm_dyn.errors import InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.pinned_kernels import KernelPins

__all__ = ["FORMULATIONS", "Dynamics", "one_pass_convergence_factor"]

FORMULATIONS = tuple(FORMULATION_CODES)


class Dynamics:
    """Direct dynamics of a mechanism by one formulation.

    ``scdd`` (exact, default; reduced onto the platform where the model has one),
    ``scdd_stacked`` (exact, all cut forces stacked), ``lda`` (compact
    Lagrange-D'Alembert), ``multipliers`` (Lagrange equations of the first kind) or
    ``scdd_one_pass`` (the paper's variant; stateful: it remembers the last accelerations
    it returned; refused with :class:`~elastic_pm_dyn.errors.OnePassDivergenceError` at a pose
    where its iteration diverges, dynamics/one_pass.py).
    """

    def __init__(self, mech: Mechanism, formulation: str = "scdd", singular_tol: float = SINGULAR_TOL):
        if formulation not in FORMULATION_CODES:
            raise InputError(f"unknown formulation {formulation!r} (expected one of: {', '.join(FORMULATIONS)})")
        self.mech = mech
        self.formulation = formulation
        self.code = FORMULATION_CODES[formulation]
        self.singular_tol = singular_tol
        self.qdd_prev = np.zeros(mech.n)
        self.cut_force = np.zeros(mech.m)
        self._checked_q: np.ndarray | None = None  # the last pose the one-pass factor was checked at
        self._pin = KernelPins()  # accelerations without numba's type dispatch (pinned_kernels.py)

    def tree_forces(self, tau_active: np.ndarray, ee_force: np.ndarray | None = None,
                    q: np.ndarray | None = None) -> np.ndarray:
        """Tree generalised forces: motor torques, plus J_ee^T f for an end-effector force."""
        tau = self.mech.split_tau(tau_active)
        if ee_force is not None:
            if q is None:
                raise InputError("an end-effector force needs the configuration q")
            J_ee, _ = self.mech.end_effector_jacobian(self.mech.terms(q))
            tau += J_ee.T @ np.asarray(ee_force, dtype=float)
        return tau

    def accelerations(self, q: np.ndarray, qd: np.ndarray, tau_active: np.ndarray,
                      ee_force: np.ndarray | None = None, baumgarte: tuple[float, float] = (0.0, 0.0),
                      extra_tree: np.ndarray | None = None) -> np.ndarray:
        """Tree accelerations qdd_t at (q_t, qd_t) under motor torques tau_active (plus tree forces
        ``extra_tree``: an external wrench's J^T w).

        The cut forces (multipliers lambda of the closure rows) are left in ``cut_force``
        (zero for L-D'A, which never forms them).
        """
        n = self.mech.n
        q, qd = state_vector(q, n, "q"), state_vector(qd, n, "qd")
        if self.code == SCDD_ONE_PASS and (self._checked_q is None or not np.array_equal(q, self._checked_q)):
            check_one_pass(self.mech, q)  # before its lag can make a wrong answer
            self._checked_q = q.copy()
        tau = self.tree_forces(tau_active, ee_force, q)
        if extra_tree is not None:
            tau = tau + extra_tree
        qdd = np.empty(n)
        lam = np.zeros(self.mech.m)
        cond, gap = self._pin(accelerations)(self.code, self.mech.arrays, q, qd, tau, float(baumgarte[0]),
                                             float(baumgarte[1]), self.qdd_prev, qdd, lam)
        if cond < self.singular_tol:
            raise SingularConfigurationError(
                f"singular configuration for {self.formulation}: conditioning {cond:.3g} "
                f"< {self.singular_tol:g} (closure residual {gap:.3g} m)", residual=gap)
        if self.code == SCDD_ONE_PASS:
            self.qdd_prev[:] = qdd
        self.cut_force = lam
        return qdd

    def reset(self) -> None:
        self.qdd_prev[:] = 0.0


def state_vector(x: np.ndarray, n: int, name: str) -> np.ndarray:
    """``x`` as the writeable, contiguous float64 vector of n entries a pinned kernel reads
    (pinned_kernels.py: its entry point does not check types; x itself when it already is one)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    if x.shape != (n,):
        raise InputError(f"{name} must have {n} tree coordinates, got shape {x.shape}")
    return x if x.flags.writeable else x.copy()
