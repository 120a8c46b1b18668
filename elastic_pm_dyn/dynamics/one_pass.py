"""Where the paper's one-pass SCDD (``scdd_one_pass``) may be used: its convergence factor.

The one-pass kernel (:func:`elastic_pm_dyn.dynamics.kernels.scdd_one_pass`) closes the paper's
calculation loop (eqs 34-39) once per evaluation, starting from the accelerations it returned
last. Written out, one pass maps the previous q_ae accelerations x to new ones linearly:

1. passive accelerations from the closure (eq 12 differentiated): qdd = W x + c, with
   W = dq_t/dq_ae and c = [A_p^-1 gamma]_p;
2. the cut forces that make the passive torques vanish (eqs 35-39):
   lambda = A_p^-T (M_p qdd + h_p - tau_p), A_p = dh/dq_p, M_p the passive rows of M;
3. each chain's direct dynamics under them (eq 34): qdd' = M^-1 (tau - h + A^T lambda).

So x' = G x + const with G = [M^-1 A^T]_ae A_p^-T M_p W, whatever tau, qd and gamma are: the
factor depends on the pose alone. Its fixed point is exact SCDD; the error to it is multiplied
by G at every evaluation. Where the spectral radius rho(G) < 1 the lag dies out (geometrically,
by rho per evaluation); where rho(G) >= 1 it grows from evaluation to evaluation and the
accelerations are garbage within a few steps: that pose is refused, never simulated silently.
"""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.errors import OnePassDivergenceError, SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism

ONE_PASS = "scdd_one_pass"


def one_pass_convergence_factor(mech: Mechanism, q: np.ndarray) -> float:
    """Spectral radius rho(G) of the one-pass iteration at pose ``q`` (module docstring):
    below 1 the one-pass SCDD converges to exact SCDD, at or above 1 it diverges. 0 for a
    mechanism without closure rows (nothing to iterate); inf where A_p or M is singular."""
    if mech.m == 0 or len(mech.ae) == 0:
        return 0.0
    t = mech.terms(np.ascontiguousarray(q, dtype=float))
    try:
        W, _ = mech.passive_map(t)
        Y = np.linalg.solve(t.M, t.A.T)
        G = Y[mech.ae] @ np.linalg.solve(t.A[:, mech.passive].T, t.M[mech.passive] @ W)
        rho = float(np.max(np.abs(np.linalg.eigvals(G))))
    except (np.linalg.LinAlgError, SingularConfigurationError):  # A_p or M singular: no iteration at all
        return float("inf")
    return rho if np.isfinite(rho) else float("inf")


def one_pass_refusal(rho: float, where: str) -> str:
    """The one line that refuses the one-pass SCDD at a factor ``rho`` >= 1 (``where``: the pose)."""
    value = f"{rho:.6g} >= 1" if np.isfinite(rho) else "infinite (dh/dq_p or the mass matrix is singular)"
    return (f"{ONE_PASS} diverges {where}: its convergence factor (spectral radius of the one-pass "
            f"iteration, dynamics/one_pass.py) is {value}, so its accelerations would be wrong; "
            "use formulation scdd (the default, exact)")


def check_one_pass(mech: Mechanism, q: np.ndarray, where: str = "at this pose", time: float | None = None) -> float:
    """The convergence factor at ``q``; raises :class:`OnePassDivergenceError` (one line, naming
    the factor and suggesting ``scdd``) where it is >= 1."""
    rho = one_pass_convergence_factor(mech, q)
    if not rho < 1.0:
        raise OnePassDivergenceError(one_pass_refusal(rho, where), factor=rho, time=time, residual=mech.gap(q))
    return rho
