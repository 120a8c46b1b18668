"""Run a mechanism forward in time under a torque source."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from elastic_pm_dyn.dynamics.direct import state_vector
from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, LDA, SCDD_ONE_PASS, SINGULAR_TOL, accelerations
from elastic_pm_dyn.dynamics.one_pass import check_one_pass, one_pass_convergence_factor, one_pass_refusal
from elastic_pm_dyn.errors import InputError, OnePassDivergenceError, RunInterrupted, SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.pinned_kernels import KernelPins
from elastic_pm_dyn.sim import batch, exponential, integrators, kernels
from elastic_pm_dyn.sim.coulomb_events import (
    coulomb_joints,
    frozen_slip,
    segment_events,
    settle_at_rest,
    settle_stops,
)
from elastic_pm_dyn.sim.result import SimulationResult
from elastic_pm_dyn.sim.stopped import integration_error
from elastic_pm_dyn.sim.torque import TorqueSource

# The integrators (sim/integrators.py's METHODS): the compiled fixed-step RK4 on everything and
# the exponential ETD2, whose springs are integrated on sub-steps of a frozen linear system
# (sim/exponential.py), both taking dt; scipy's adaptive DOP853 (rtol, atol); ETD2's variants of
# the comparison bench.
INTEGRATORS = integrators.OFFERED  # offered to users (the command line's choices)
STABILIZATIONS = {"none": 0, "baumgarte": kernels.STAB_BAUMGARTE, "projection": kernels.STAB_PROJECTION,
                  "both": kernels.STAB_BAUMGARTE | kernels.STAB_PROJECTION}

# Bounds of one run, checked before anything is allocated: the samples kept in memory
# (about 3 copies of each output row on the way to the CSV) and the RK4 steps (at tens of
# microseconds each, 1e9 steps are days of computing).
MEMORY_BUDGET = 2 * 2**30  # [bytes]
MAX_STEPS = 1e9
MAX_DURATION = 1e6  # [s] of simulated time, also for DOP853, whose steps are not known ahead
# RK4 steps per compiled call: a Ctrl-C is seen between calls (within ~0.1 s of simulated
# time at the default dt), and the call overhead stays far below 1 %.
STEPS_PER_CALL = 1000
# Intervals between output samples and torque breakpoints planned at once by an offline run
# (a few arrays of this length): bounds its memory on long runs.
INTERVALS_PER_BLOCK = 2**16
# DOP853 segments (between Coulomb friction's stops and breakaways) per interval of a run
MAX_SEGMENTS = 10000

@dataclass
class SimulationOptions:
    formulation: str = "scdd"
    integrator: str = "rk4"
    dt: float = 1e-4  # [s] RK4 / ETD2 step; shortened so steps end on samples and torque steps
    rtol: float = 1e-10  # adaptive integrator
    atol: float = 1e-12
    stabilization: str = "projection"  # none | baumgarte | projection | both
    baumgarte_alpha: float = 200.0  # [1/s]: hdd + 2 alpha hd + beta^2 h = 0
    baumgarte_beta: float = 200.0
    sample: float = 1e-3  # output interval [s]
    closure_tol: float = 1e-14  # [m] Newton / projection target
    singular_tol: float = SINGULAR_TOL  # conditioning below which the run stops
    phase_step: float = exponential.DEFAULT_PHASE_STEP  # etd2 sub-step [rad of the fastest spring mode]

    def validate(self) -> None:
        if self.formulation not in FORMULATION_CODES:
            raise InputError(f"unknown formulation {self.formulation!r} "
                             f"(expected one of: {', '.join(FORMULATION_CODES)})")
        method = integrators.METHODS.get(self.integrator)
        if method is None:
            raise InputError(f"unknown integrator {self.integrator!r} (expected one of: {', '.join(INTEGRATORS)})")
        if method.exponential and self.formulation == "lda":
            raise InputError(f"integrator {self.integrator} needs a tree formulation (scdd, multipliers, "
                             "scdd_one_pass, scdd_stacked); L-D'A integrates q_ae: use rk4 or dop853 with it")
        if self.stabilization not in STABILIZATIONS:
            raise InputError(f"unknown stabilization {self.stabilization!r} "
                             f"(expected one of: {', '.join(STABILIZATIONS)})")
        for name in ("dt", "rtol", "atol", "sample", "phase_step"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"{name} must be a positive number, got {value!r}")

    def step_settings(self) -> integrators.StepSettings:
        """The settings of the compiled fixed-step kernels (read at every call: a plant's
        options may change between periods)."""
        stab = STABILIZATIONS[self.stabilization]
        return integrators.StepSettings(stab, float(self.baumgarte_alpha), float(self.baumgarte_beta),
                                        float(self.closure_tol), float(self.singular_tol), float(self.phase_step))


class Simulator:
    """Integrates the tree state; see :mod:`elastic_pm_dyn.sim.kernels` for the methods."""

    def __init__(self, mech: Mechanism, options: SimulationOptions | None = None):
        self.mech = mech
        self.options = options or SimulationOptions()
        self.options.validate()
        self.code = FORMULATION_CODES[self.options.formulation]
        self.stab = STABILIZATIONS[self.options.stabilization]
        self.qdd_prev = np.zeros(mech.n)
        self.lam = np.zeros(mech.m)
        # Reused by every advance(): a plant node calls it once per control period.
        self._coef = np.zeros((3, mech.n))
        self.info = np.zeros(3)
        self._transmission = np.ascontiguousarray(mech.transmission, dtype=np.float64)  # B (n_t, n_a)
        # the compiled calls per chunk, period or DOP853 stage, without numba's type dispatch
        # (pinned_kernels.py): every argument keeps its type from call to call
        self._pin = KernelPins()
        self.integrator = integrators.METHODS[self.options.integrator]  # its row (sim/integrators.py)
        self.method = self.integrator.kernel  # (method, exponential scheme) of the compiled kernels
        # one piece of a run: compiled fixed steps, or scipy's adaptive DOP853
        self._advance_piece = self._advance_fixed if self.integrator.fixed_step else self._advance_adaptive
        self._coulomb = coulomb_joints(mech.arrays.jf)  # joints whose stops DOP853 finds as events

    # ------------------------------------------------------------------ stepping
    def advance(self, q: np.ndarray, qd: np.ndarray, torque: TorqueSource, t0: float, t1: float) -> None:
        """Integrate (q, qd) in place from t0 to t1, which must lie inside one torque piece.

        Raises SingularConfigurationError (state left at the last good step).
        """
        if self.code == SCDD_ONE_PASS:  # each call (a plant's period, a run's interval) starts where it converges
            check_one_pass(self.mech, q, f"at t = {t0:.6g} s", t0)
        self._advance_piece(q, qd, torque, t0, t1)

    def _advance_fixed(self, q: np.ndarray, qd: np.ndarray, torque: TorqueSource, t0: float, t1: float) -> None:
        """:meth:`advance` by the compiled fixed-step integrator: steps of at most dt."""
        o = self.options
        n_steps = max(1, int(np.ceil((t1 - t0) / o.dt - 1e-9)))
        h = (t1 - t0) / n_steps
        info, coef = self.info, self._coef
        # A table's piece is one polynomial over the whole call; a function is refitted
        # through the stage times of every step.
        calls = ([(t0 + k * h, 1) for k in range(n_steps)] if torque.smooth else
                 [(t0 + k * h, min(STEPS_PER_CALL, n_steps - k)) for k in range(0, n_steps, STEPS_PER_CALL)])
        for start, steps in calls:
            self.mech.split_tau(torque.coefficients(start, steps * h), out=coef)
            status = self.fixed_steps(q, qd, coef, h, steps)
            if status != kernels.OK:  # a singular configuration or a blow-up, told apart
                raise integration_error(status, o.formulation, start + info[0] * h, info)

    def fixed_steps(self, q: np.ndarray, qd: np.ndarray, coef: np.ndarray, h: float, steps: int) -> int:
        """``steps`` compiled steps of h of the fixed-step integrator on (q, qd) in place, under the
        tree torque polynomial ``coef`` (3, n_t); the kernel's status."""
        n = self.mech.n
        qw, qdw = self._state(q, qd)
        coef = np.ascontiguousarray(coef, dtype=np.float64)
        if coef.shape != (3, n):
            raise InputError(f"torque polynomial must have shape (3, {n}), got {coef.shape}")
        status = self._pin(integrators.fixed_steps)(*self.method, self.code, self.mech.arrays, qw, qdw, coef, float(h),
                                                    int(steps), self.options.step_settings(), self.qdd_prev, self.lam,
                                                    self.info)
        _write_back(q, qd, qw, qdw)
        return status

    def run_pieces(self, q: np.ndarray, qd: np.ndarray, coefs: np.ndarray, hs: np.ndarray, steps: np.ndarray,
                   record: np.ndarray, q_out: np.ndarray, qd_out: np.ndarray, row: int) -> tuple[int, int, int]:
        """:func:`elastic_pm_dyn.sim.batch.run_pieces` of this simulator's integrator on (q, qd) in
        place (float64 vectors of n_t): coefs (pieces, 3, n_a) of the active joints' torque, the
        pieces' steps hs and step counts, which of them end on a sample row of q_out, qd_out
        (float64, (rows, n_t)) from ``row`` on. Returns (status, pieces done, next row)."""
        n, n_a = self.mech.n, self._transmission.shape[1]
        qw, qdw = self._state(q, qd)
        coefs = np.ascontiguousarray(coefs, dtype=np.float64)
        hs = np.ascontiguousarray(hs, dtype=np.float64)
        steps = np.ascontiguousarray(steps, dtype=np.int64)
        record = np.ascontiguousarray(record, dtype=np.bool_)
        pieces = len(hs)
        if coefs.shape != (pieces, 3, n_a) or hs.shape != (pieces,) or steps.shape != hs.shape \
                or record.shape != hs.shape:
            raise InputError(f"{pieces} pieces need coefs of shape ({pieces}, 3, {n_a}) and as many steps and "
                             f"record flags, got {coefs.shape}, {steps.shape}, {record.shape}")
        last = row + int(np.count_nonzero(record))  # the compiled code writes rows unchecked
        for out in (q_out, qd_out):
            if not (out.dtype == np.float64 and out.ndim == 2 and out.shape[1] == n and out.flags.c_contiguous
                    and out.flags.writeable and row >= 0 and last <= out.shape[0]):
                raise InputError(f"output rows {row} to {last} need writeable contiguous float64 arrays of shape "
                                 f"(at least {last}, {n})")
        status, done, row = self._pin(batch.run_pieces)(
            *self.method, self.code, self.mech.arrays, self._transmission, qw, qdw, coefs, hs, steps, record, q_out,
            qd_out, int(row), self.options.step_settings(), self.qdd_prev, self.lam, self.info)
        _write_back(q, qd, qw, qdw)
        return int(status), int(done), int(row)

    def _state(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, qd) as the vectors a compiled call steps in place (themselves when they already are)."""
        n = self.mech.n
        return state_vector(q, n, "q"), state_vector(qd, n, "qd")

    def _advance_adaptive(self, q: np.ndarray, qd: np.ndarray, torque: TorqueSource, t0: float, t1: float) -> None:
        """:meth:`advance` by scipy's DOP853 (rtol, atol)."""
        o, mech, n = self.options, self.mech, self.mech.n
        a = float(o.baumgarte_alpha) if self.stab & kernels.STAB_BAUMGARTE else 0.0
        b = float(o.baumgarte_beta) if self.stab & kernels.STAB_BAUMGARTE else 0.0
        evaluate_kernel = self._pin(accelerations)
        coef = None if torque.smooth else torque.coefficients(t0, t1 - t0)
        tau = np.zeros(n)
        qdd = np.empty(n)
        law = [mech.arrays, None]  # a segment's arrays and friction force of its sliding joints (frozen_slip)

        def evaluate(t: float, y: np.ndarray, qdd_prev: np.ndarray) -> tuple[float, np.ndarray]:
            qq, vv = y[:n].copy(), y[n:].copy()
            if self.code == LDA:
                kernels.partition(mech.arrays, qq, vv, o.closure_tol, 4)
            s = t - t0
            mech.split_tau(torque.value(t) if coef is None else coef[0] + s * (coef[1] + s * coef[2]), out=tau)
            if law[1] is not None:
                tau[:] += law[1]
            cond, _ = evaluate_kernel(self.code, law[0], qq, vv, tau, a, b, qdd_prev, qdd, self.lam)
            return cond, vv

        def rhs(t: float, y: np.ndarray) -> np.ndarray:
            _, vv = evaluate(t, y, self.qdd_prev)
            self.qdd_prev[:] = qdd
            return np.concatenate([vv, qdd])

        y, t = np.concatenate([q, qd]), t0
        for _ in range(MAX_SEGMENTS):  # segments between Coulomb friction's events (sim/coulomb_events.py)
            events = None
            if len(self._coulomb):  # the segment's law: its sliding joints' friction frozen
                law[:] = frozen_slip(mech.arrays, self._coulomb, y[n:])
                events = segment_events(self._coulomb, n, y)
            sol = solve_ivp(rhs, (t, t1), y, method="DOP853", rtol=o.rtol, atol=o.atol, events=events)
            # The conditioning where the solution went (its accepted steps), not at the stages of
            # the steps it tried and rejected: those probe states far off the path (the Triglide at
            # n_ek = 4 under a 1 kHz-sampled chirp "failed" at 5e-9 on a path whose conditioning
            # stays at 0.65 for RK4 and ETD2)
            worst = min((evaluate(float(s), yy, self.qdd_prev.copy())[0] for s, yy in zip(sol.t[1:], sol.y.T[1:],
                                                                                          strict=True)), default=1.0)
            if not sol.success or worst < o.singular_tol:
                raise SingularConfigurationError(
                    f"adaptive integration failed between t = {t0:.6g} and {t1:.6g} s "
                    f"(conditioning {worst:.3g}; {sol.message})", time=t0, residual=mech.gap(q))
            end = sol.y[:, -1].copy()
            settle_at_rest(self._coulomb, end[n:])
            if sol.status != 1:  # reached t1
                y = end
                break
            settle_stops(self._coulomb, n, y, [len(te) > 0 for te in sol.t_events], end)
            y, t = end, float(sol.t[-1])
        else:
            raise SingularConfigurationError(
                f"adaptive integration between t = {t0:.6g} and {t1:.6g} s stopped at {t:.6g} s: more than "
                f"{MAX_SEGMENTS} stops and breakaways of joints with Coulomb friction", time=t, residual=mech.gap(q))
        q[:], qd[:] = y[:n], y[n:]
        if self.code == LDA:
            kernels.partition(mech.arrays, q, qd, o.closure_tol, 4)
        elif self.stab & kernels.STAB_PROJECTION:
            kernels.project(mech.arrays, q, qd, o.closure_tol, 3)

    # ------------------------------------------------------------------ runs
    def run_size(self, duration: float) -> tuple[float, float]:
        """(output rows, RK4 steps) a run of ``duration`` takes, as floats (they may be
        astronomical); steps 0 with DOP853."""
        o = self.options
        rows = math.floor(duration / o.sample + 1e-9) + 2.0 if duration / o.sample < 2**52 else duration / o.sample
        steps = duration / o.dt if self.integrator.fixed_step else 0.0
        return rows, steps

    def max_rows(self) -> int:
        """Output rows that fit in :data:`MEMORY_BUDGET`."""
        columns = 1 + 2 * self.mech.n + len(self.mech.ee_components) + len(self.mech.model.branches) + 1 \
            + len(self.mech.active)
        per_row = 3 * 112 + 4 * 8 * columns + 25 * columns  # arrays kept per sample, numbers, CSV text
        return MEMORY_BUDGET // per_row

    def check_run_size(self, duration: float, prefix: str = "") -> None:
        """InputError naming the settings (``prefix`` + option name, e.g. ``--sample``) if a
        run of ``duration`` would keep more rows than fit in memory or take more than
        :data:`MAX_STEPS` steps."""
        o = self.options
        if not (math.isfinite(duration) and duration > 0):
            raise InputError(f"{prefix}duration must be a positive number of seconds, got {duration!r}")
        rows, steps = self.run_size(duration)
        limit = self.max_rows()
        if rows > limit:
            raise InputError(f"{prefix}duration {duration:g} s at {prefix}sample {o.sample:g} s means {rows:.4g} "
                             f"output rows, more than the limit of {limit} (the rows of a run must fit in "
                             f"{MEMORY_BUDGET / 2**30:g} GiB): raise {prefix}sample or shorten {prefix}duration")
        if steps > MAX_STEPS:
            raise InputError(f"{prefix}duration {duration:g} s at {prefix}dt {o.dt:g} s means {steps:.4g} "
                             f"{o.integrator.upper()} steps, "
                             f"more than the limit of {MAX_STEPS:.0e}: raise {prefix}dt or shorten {prefix}duration")
        if duration > MAX_DURATION:
            raise InputError(f"{prefix}duration {duration:g} s is more than the {MAX_DURATION:g} s a run may simulate")

    def run(self, torque: TorqueSource, duration: float, q0: np.ndarray | None = None,
            qd0: np.ndarray | None = None, t0: float = 0.0) -> SimulationResult:
        """Simulate ``duration`` seconds; samples every ``options.sample`` from t0.

        Starts from the model's initial state at rest unless q0/qd0 are given. On a
        singular configuration the error carries the samples so far as ``partial``; on
        Ctrl-C (KeyboardInterrupt) a :class:`RunInterrupted` does.
        """
        self.check_run_size(duration)
        mech = self.mech
        q = initial_state(mech) if q0 is None else np.array(q0, dtype=float)
        qd = np.zeros(mech.n) if qd0 is None else np.array(qd0, dtype=float)
        if q.shape != (mech.n,) or qd.shape != (mech.n,):
            raise InputError(f"initial state must have {mech.n} tree coordinates")
        self.qdd_prev[:] = 0.0
        if self.code == SCDD_ONE_PASS:  # refused before anything is computed, not after
            check_one_pass(mech, q, "at the start pose", t0)
        o = self.options
        t_end = t0 + duration
        n_out = int(np.floor(duration / o.sample + 1e-9))
        out_times = np.append(t0 + o.sample * np.arange(n_out + 1), t_end)  # the end is always recorded
        brk = torque.breakpoints()
        grid = np.unique(np.concatenate([out_times, brk[(brk > t0) & (brk < t_end)]]))
        grid = grid[np.concatenate([[True], np.diff(grid) > 1e-12])]
        is_out = np.isin(np.round(grid / 1e-12), np.round(out_times / 1e-12))

        if self.integrator.fixed_step and not torque.smooth:
            # a function's fits cost more than the loop (3 Python calls a step): it stays below,
            # called in time order as each step needs it
            return self._run_pieces(torque, grid, is_out, q, qd, t_end)
        samples: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []

        def record(t: float) -> None:
            # one append: an interrupt never leaves a half-recorded sample
            samples.append((t, q.copy(), qd.copy(), torque.value(t)))

        try:
            record(grid[0])
            for a, b, out in zip(grid[:-1], grid[1:], is_out[1:], strict=True):
                self.advance(q, qd, torque, a, b)
                if out:
                    record(b)
        except SingularConfigurationError as err:
            err.partial = self._result(samples)
            raise
        except KeyboardInterrupt:
            partial = self._result(samples)
            t_last = float(partial.t[-1]) if len(partial.t) else t0
            raise RunInterrupted(f"interrupted at t = {t_last:.6g} s of {t_end:.6g} s", t_last, partial) from None
        return self._result(samples)

    def _run_pieces(self, torque: TorqueSource, grid: np.ndarray, is_out: np.ndarray, q: np.ndarray,
                    qd: np.ndarray, t_end: float) -> SimulationResult:
        """:meth:`run` of a fixed-step integrator: the pieces :meth:`advance` would integrate one
        call at a time (the grid's intervals, split as it splits them), integrated chunk by chunk
        in compiled code (sim/batch.py) with the samples written into preallocated rows.
        Bit-identical to the per-interval loop; a Ctrl-C is seen between chunks."""
        o, mech = self.options, self.mech
        rows = 1 + int(np.count_nonzero(is_out[1:]))
        t_out = np.concatenate([grid[:1], grid[1:][is_out[1:]]])
        q_out, qd_out = np.empty((rows, mech.n)), np.empty((rows, mech.n))
        q_out[0], qd_out[0] = q, qd
        row = 1

        def result(n_rows: int) -> SimulationResult:
            t = t_out[:n_rows]
            return SimulationResult(mech, t, q_out[:n_rows], qd_out[:n_rows],
                                    torque.values_at(t).reshape(n_rows, len(mech.active)), o.formulation,
                                    {"integrator": o.integrator, "dt": o.dt, "stabilization": o.stabilization})

        try:
            for i0 in range(0, len(grid) - 1, INTERVALS_PER_BLOCK):
                i1 = min(i0 + INTERVALS_PER_BLOCK, len(grid) - 1)
                starts, hs, steps, record = self._calls(grid[i0:i1 + 1], is_out[i0 + 1:i1 + 1])
                # chunks of about STEPS_PER_CALL steps (at least one call each)
                marks = STEPS_PER_CALL * np.arange(1, steps.sum() // STEPS_PER_CALL + 1)
                ends = np.searchsorted(np.cumsum(steps), marks, side="right")
                for c0, c1 in itertools.pairwise(np.unique(np.concatenate([[0], ends, [len(hs)]]))):
                    coefs = torque.coefficients_many(starts[c0:c1], steps[c0:c1] * hs[c0:c1])
                    first = row
                    status, done, row = self.run_pieces(q, qd, coefs, hs[c0:c1], steps[c0:c1], record[c0:c1], q_out,
                                                        qd_out, row)
                    if self.code == SCDD_ONE_PASS:
                        self._check_one_pass_rows(q_out, t_out, first, row, result)
                    if status != kernels.OK:  # a singular configuration or a blow-up, told apart
                        p = c0 + done
                        t_fail = starts[p] + self.info[0] * hs[p]
                        err = integration_error(status, o.formulation, t_fail, self.info)
                        if self.code == SCDD_ONE_PASS:  # a blow-up of the iteration, not of the machine?
                            rho = one_pass_convergence_factor(mech, q)
                            if not rho < 1.0:
                                err = OnePassDivergenceError(one_pass_refusal(rho, f"at t = {t_fail:.6g} s"), rho,
                                                             t_fail, float(self.info[2]))
                        err.partial = result(row)
                        raise err
        except KeyboardInterrupt:
            partial = result(row)
            t_last = float(partial.t[-1])
            raise RunInterrupted(f"interrupted at t = {t_last:.6g} s of {t_end:.6g} s", t_last, partial) from None
        return result(row)

    def _check_one_pass_rows(self, q_out: np.ndarray, t_out: np.ndarray, first: int, last: int,
                             result) -> None:
        """The one-pass SCDD's convergence factor at the samples ``first:last`` a compiled chunk
        just wrote: at the first where it is >= 1 the run stops, keeping the samples before it."""
        for k in range(first, last):
            try:
                check_one_pass(self.mech, q_out[k], f"at t = {t_out[k]:.6g} s", float(t_out[k]))
            except OnePassDivergenceError as err:
                err.partial = result(k)
                raise

    def _calls(self, grid: np.ndarray, out: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The compiled calls :meth:`advance` makes over the intervals of ``grid`` for a torque
        that is not a function (STEPS_PER_CALL steps at most): their start times, steps h,
        step counts, and whether the state after them is a sample (``out``: per interval)."""
        a, b = grid[:-1], grid[1:]
        n_steps = np.maximum(1, np.ceil((b - a) / self.options.dt - 1e-9).astype(np.int64))
        h = (b - a) / n_steps
        per_call = STEPS_PER_CALL
        n_calls = -(-n_steps // per_call)
        interval = np.repeat(np.arange(len(a)), n_calls)
        last = np.cumsum(n_calls) - 1
        k = (np.arange(len(interval)) - (last - n_calls + 1)[interval]) * per_call
        record = np.zeros(len(interval), dtype=bool)
        record[last] = out
        return a[interval] + k * h[interval], h[interval], np.minimum(per_call, n_steps[interval] - k), record

    def _result(self, samples: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]) -> SimulationResult:
        n, n_a = self.mech.n, len(self.mech.active)
        return SimulationResult(self.mech, np.array([s[0] for s in samples]),
                                np.array([s[1] for s in samples]).reshape(-1, n),
                                np.array([s[2] for s in samples]).reshape(-1, n),
                                np.array([s[3] for s in samples]).reshape(-1, n_a),
                                self.options.formulation,
                                {"integrator": self.options.integrator, "dt": self.options.dt,
                                 "stabilization": self.options.stabilization})


def _write_back(q: np.ndarray, qd: np.ndarray, qw: np.ndarray, qdw: np.ndarray) -> None:
    """After a compiled call stepped (qw, qdw): where those were copies, the caller's arrays get the state."""
    if qw is not q:
        q[:] = qw
    if qdw is not qd:
        qd[:] = qdw
