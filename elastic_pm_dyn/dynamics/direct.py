"""Direct dynamics behind one interface: ``Dynamics(mech, "scdd").accelerations(...)``."""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, SCDD_ONE_PASS, SINGULAR_TOL, accelerations
from elastic_pm_dyn.errors import InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.pinned_kernels import KernelPins

FORMULATIONS = tuple(FORMULATION_CODES)


class Dynamics:
    """Direct dynamics of a mechanism by one formulation.

    ``scdd`` (exact, default; reduced onto the platform where the model has one),
    ``scdd_stacked`` (exact, all cut forces stacked), ``lda`` (compact
    Lagrange-D'Alembert), ``multipliers`` (Lagrange equations of the first kind) or
    ``scdd_one_pass`` (the paper's variant; stateful: it remembers the last accelerations
    it returned).
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
                      ) -> np.ndarray:
        """Tree accelerations qdd_t at (q_t, qd_t) under motor torques tau_active.

        The cut forces (multipliers lambda of the closure rows) are left in ``cut_force``
        (zero for L-D'A, which never forms them).
        """
        n = self.mech.n
        q, qd = state_vector(q, n, "q"), state_vector(qd, n, "qd")
        tau = self.tree_forces(tau_active, ee_force, q)
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


def one_pass_convergence_factor(mech: Mechanism, q: np.ndarray) -> float:
    """Spectral radius of the paper's calculation loop (eqs 34-39) as an iteration.

    One pass maps the previous q_ae accelerations to new ones linearly:
    qdd_ae <- G qdd_ae + const with G = [M^-1 A^T]_ae (dh/dq_p)^-T M_p W. Closed once
    per evaluation with last step's accelerations (``scdd_one_pass``), the lag only
    shrinks where rho(G) < 1; where rho(G) >= 1 successive evaluations amplify it and the
    run diverges. Exact SCDD solves the loop instead and has no such limit.
    """
    t = mech.terms(q)
    W, _ = mech.passive_map(t)
    Y = np.linalg.solve(t.M, t.A.T)
    A_p = t.A[:, mech.passive]
    G = Y[mech.ae] @ np.linalg.solve(A_p.T, t.M[mech.passive] @ W)
    return float(np.max(np.abs(np.linalg.eigvals(G))))
