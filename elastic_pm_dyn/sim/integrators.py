"""Every integrator in one table, :data:`METHODS` (as scipy's ``solve_ivp`` keeps its solvers), one compiled dispatch.

A row names an integrator's method (the compiled fixed-step RK4, the exponential ETD2 whose
springs are integrated exactly, or scipy's adaptive DOP853), ETD2's scheme, and whether users
are offered it. Simulations, the plant and the observer's mean (``process.integrator``) look an
integrator up here and ask its row (:attr:`Integrator.fixed_step`, :attr:`Integrator.exponential`);
none compares names. :func:`fixed_steps_ws` is the only place that picks a compiled kernel, used
by the stepping from Python (:func:`fixed_steps`: ``Simulator.fixed_steps``, the plant), by the
compiled offline run of many pieces (:func:`elastic_pm_dyn.sim.batch.run_pieces`) and by the
observer's prediction (``observer.core.kernels.predict``).
"""

from typing import NamedTuple

from numba import njit

from elastic_pm_dyn.sim.exponential import AVERAGED, ETD2RK, IMPULSE, etd2_workspace, exponential_steps_ws
from elastic_pm_dyn.sim.kernels import rk4_steps

RK4 = 0  # compiled, fixed steps of dt: the classical Runge-Kutta
ETD2 = 1  # compiled, fixed steps of dt: exponential, the springs exact (sim/exponential.py)
DOP853 = 2  # scipy's solve_ivp, adaptive (rtol, atol): not compiled, no dt


class Integrator(NamedTuple):
    """One row of :data:`METHODS`."""

    method: int  # RK4 | ETD2 | DOP853
    scheme: int  # ETD2's exponential scheme (sim/exponential.py; the others ignore it)
    offered: bool  # a user's choice (command line, plant parameter); else the comparison bench's only

    @property
    def fixed_step(self) -> bool:
        """Compiled steps of dt (:func:`fixed_steps`); else scipy's adaptive DOP853."""
        return self.method != DOP853

    @property
    def exponential(self) -> bool:
        """The springs integrated exactly: its step follows their coupling with the motion, not their stability."""
        return self.method == ETD2

    @property
    def kernel(self) -> tuple[int, int]:
        """(method, scheme): the compiled kernels' first two arguments."""
        return self.method, self.scheme


# integrator name -> its row. "etd2rk" and "impulse" are ETD2's variants the comparison in
# bench/benchmarks/bench_integrators.py measures against it: SimulationOptions takes them, the
# command line does not offer them.
METHODS = {"rk4": Integrator(RK4, AVERAGED, True), "dop853": Integrator(DOP853, AVERAGED, True),
           "etd2": Integrator(ETD2, AVERAGED, True), "etd2rk": Integrator(ETD2, ETD2RK, False),
           "impulse": Integrator(ETD2, IMPULSE, False)}
OFFERED = tuple(name for name, row in METHODS.items() if row.offered)  # the command line's choices


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
