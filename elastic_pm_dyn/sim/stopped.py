"""Why a compiled integration stopped, as the package's errors (one line each).

The kernels return a status and ``info`` (see :func:`elastic_pm_dyn.sim.kernels.rk4_steps`);
a singular configuration and a blow-up are different faults with different cures, so they
get different errors and messages.
"""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.errors import DivergedStateError, SingularConfigurationError
from elastic_pm_dyn.sim import kernels

# What breaks down at a singular configuration, per formulation.
SINGULAR_MATRIX = {
    "lda": "dh/dq_p is singular or Newton cannot solve the passive joints: a parallel singularity",
    "scdd_one_pass": "dh/dq_p is singular: a parallel singularity",
    "scdd": "the cut-force Schur complement (or a leg's end-point inertia) is singular",
    "scdd_stacked": "the cut-force Schur complement is singular",
    "multipliers": "the KKT matrix is singular",
}


def integration_error(status: int, formulation: str, t_fail: float, info: np.ndarray) -> SingularConfigurationError:
    """The error for a kernel ``status`` other than OK, stopped at ``t_fail`` with ``info``."""
    if status == kernels.DIVERGED:
        return DivergedStateError(
            f"state diverged at t = {t_fail:.6g} s: |qdd| = {info[1]:.3g}; step too large or torque too high",
            time=t_fail, residual=float(info[2]))
    return SingularConfigurationError(
        f"singular configuration ({SINGULAR_MATRIX[formulation]}) at t = {t_fail:.6g} s "
        f"(conditioning {info[1]:.3g}, closure residual {info[2]:.3g} m)", time=t_fail, residual=float(info[2]))
