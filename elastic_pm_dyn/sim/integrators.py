"""The fixed-step integrators behind one table and one compiled dispatch.

``FIXED_STEP`` names them; :func:`fixed_steps_ws` is the only place that picks the kernel, used
by the stepping from Python (:func:`fixed_steps`: ``Simulator.fixed_steps``, the plant) and by
the compiled offline run of many pieces (:func:`elastic_pm_dyn.sim.batch.run_pieces`).
"""

from typing import NamedTuple

from numba import njit

from elastic_pm_dyn.sim.exponential import AVERAGED, ETD2RK, IMPULSE, etd2_workspace, exponential_steps_ws
from elastic_pm_dyn.sim.kernels import rk4_steps

RK4 = 0
ETD2 = 1

# integrator name -> (method, exponential scheme; RK4 ignores the scheme). "etd2rk" and
# "impulse" are ETD2's variants the comparison in bench/benchmarks/bench_integrators.py
# measures against it: SimulationOptions takes them, the command line does not offer them.
FIXED_STEP = {"rk4": (RK4, AVERAGED), "etd2": (ETD2, AVERAGED), "etd2rk": (ETD2, ETD2RK),
              "impulse": (ETD2, IMPULSE)}


class StepSettings(NamedTuple):
    """The settings of a fixed-step run in the form the compiled kernels take (one argument
    instead of six: numba unboxes a tuple of scalars for about what the scalars cost)."""

    stab: int  # stabilisation bits (kernels.STAB_BAUMGARTE | kernels.STAB_PROJECTION)
    alpha: float  # [1/s] Baumgarte: hdd + 2 alpha hd + beta^2 h = 0
    beta: float  # [1/s]
    tol: float  # [m] closure target of the Newton / projection corrections
    singular_tol: float  # conditioning below which a run stops (SINGULAR)
    phase_step: float  # [rad] ETD2 sub-step against its fastest spring mode


@njit(cache=True)
def fixed_steps_ws(method, scheme, form, ma, q, qd, tau_coef, dt, n_steps, settings, qdd_prev, lam, info, ew):
    """Advance (q, qd) in place by n_steps steps of dt of the integrator ``method`` (RK4 or
    ETD2 with ``scheme``), with the contract of :func:`elastic_pm_dyn.sim.kernels.rk4_steps`
    (tau_coef (3, n_t), info, the status). ``ew``: ETD2's work arrays
    (:func:`elastic_pm_dyn.sim.exponential.etd2_workspace`), made once for many calls."""
    s = settings
    if method == ETD2:
        return exponential_steps_ws(scheme, form, ma, q, qd, tau_coef, dt, n_steps, s.stab, s.alpha, s.beta, s.tol,
                                    s.singular_tol, s.phase_step, qdd_prev, lam, info, ew)
    return rk4_steps(form, ma, q, qd, tau_coef, dt, n_steps, s.stab, s.alpha, s.beta, s.tol, s.singular_tol,
                     qdd_prev, lam, info)


@njit(cache=True)
def fixed_steps(method, scheme, form, ma, q, qd, tau_coef, dt, n_steps, settings, qdd_prev, lam, info):
    """:func:`fixed_steps_ws` for calls from Python: ETD2's work arrays are made here (RK4 makes
    its own, smaller, ones), so a call does not unbox a workspace of some fifty arrays."""
    if method == ETD2:
        return fixed_steps_ws(method, scheme, form, ma, q, qd, tau_coef, dt, n_steps, settings, qdd_prev, lam, info,
                              etd2_workspace(ma))
    return rk4_steps(form, ma, q, qd, tau_coef, dt, n_steps, settings.stab, settings.alpha, settings.beta,
                     settings.tol, settings.singular_tol, qdd_prev, lam, info)
