"""Inverse dynamics of the elastic machine along a path of its task coordinates.

The servo-constraint problem: find the tree motion q(t) and motor torques tau(t) with

    M_t qdd + h_t = tau_t + A^T lambda       (eqs 4, 11: tree dynamics with the closure forces)
    h(q) = 0                                 (eq 8: closure)
    task(q) = y(t)                           (the path: end-effector point or platform coordinates)

Projected with W = dq_t/dq_ae (eq 18) this is W^T (M_t qdd + h_t) = B_ae u (eq 17; B_ae =
[I; 0] for motors on their own joints): the motor rows B_a u give the inputs, the elastic rows
W_e^T (M_t qdd + h_t) - B_e u = 0 (B_e: a tendon motor's share on a spring coordinate, else
none) are the equations that fix the deflections. Given y(t) and q_e(t)
the closure fixes every other coordinate (:class:`~elastic_pm_dyn.motion.task.Task`), so the
unknown is q_e(t) alone. The spring term K_e (q_e - q_rest) sits in h_t, hence the fixed point

    q_e  <-  q_e - K_e^-1 W_e^T (M_t qdd + h_t)       (all along the path at once)

whose first pass is the quasi-static deflection under the rigid machine's inertia forces
(the branch forces of the path, eqs 27-32, over the springs), and whose later passes add the
deflections' own inertia. It converges at a rate of about (f_path / f_zero)^2, f_zero the
internal (zero-dynamics) frequencies of the machine held at its output, and yields the
solution without the internal oscillation: the stable inverse's low-frequency series, for a
rest-to-rest path at rest before and after the move. Where the zero dynamics are unstable
(non-minimum phase: real exponents +-a, :func:`zero_dynamics`) and slow enough for the grid
(a step < 1), that series stalls: those modes get their bounded, non-causal solution
instead (:func:`_noncausal_step`), and the grid, the motion and the torques extend 10 / a
before the move (pre-actuation) and after it (post-actuation). Faster unstable modes (the
Triglide's and the Hexa's, 1 / a <= 0.15 ms) keep the quasi-static step. It
needs the path's second derivative and the deflections' second derivative, so the torques
contain the path's fourth: a C^4 time law (``Line(order=4)``) makes them continuous. A move
too fast for the internal dynamics makes the iteration diverge: refused with one line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline, make_lsq_spline
from scipy.linalg import solve_banded

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.motion.task import Task

Path = Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]]  # t -> (y, yd, ydd)
TOLERANCE = 1e-6  # relative change of the deflections left (estimated) at which the fixed point has converged
MAX_PASSES = 30
KNOT = 5e-3  # [s] knot spacing of the deflections' spline (see _smooth)
RESIDUAL_LIMIT = 1e-3  # unbalanced spring force over the spring forces beyond which the answer is refused
CLOSURE_TOLERANCE = 1e-11  # [m] closure error of a predicted position below which no Newton runs
PAD = 6  # grid points at rest before and after the move: the spline's ends see a flat signal
TAIL = 10.0  # pre- and post-actuation last TAIL / a (a the slowest unstable zero-dynamics exponent): e^-10 left
RESOLVED = 1.0  # a * step below which an unstable zero-dynamics mode's tails span grid points: inverted non-causally


@dataclass
class InverseMotion:
    """The elastic (or rigid) tree motion along the path and its motor torques, on a time grid."""

    t: np.ndarray  # (N,)
    q: np.ndarray  # (N, n_t)
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray  # (N, n_a) motor torques [N m or N], active order
    passes: int  # fixed-point passes (1 for a rigid model)
    residual: float  # largest elastic-row force left [N or N m]
    pre: float = 0.0  # [s] pre-actuation: the torques start this long before the move (non-minimum phase)
    post: float = 0.0  # [s] post-actuation: they settle this long after it

    def torque(self) -> Callable[[float], np.ndarray]:
        """tau(t) between the grid points: an interpolating quintic spline over the move (its
        ends, where the path's fifth derivative jumps, are the spline's ends), the rest values outside."""
        inside = (self.t >= self.t[PAD] - 1e-12) & (self.t <= self.t[-1 - PAD] + 1e-12)
        t, tau = self.t[inside], self.tau[inside]
        return _Torque(make_interp_spline(t, tau, k=5 if len(t) > 5 else 1, axis=0), t[0], t[-1], tau[0], tau[-1])


class _Torque:
    """tau(t) of :meth:`InverseMotion.torque` (a class, not a closure: a reference made in a
    worker process comes back pickled)."""

    def __init__(self, spline, lo: float, hi: float, first: np.ndarray, last: np.ndarray):
        self.spline, self.lo, self.hi, self.first, self.last = spline, lo, hi, first, last

    def __call__(self, x: float) -> np.ndarray:
        if x <= self.lo:
            return self.first.copy()
        if x >= self.hi:
            return self.last.copy()
        return np.asarray(self.spline(x))


def solve(mech: Mechanism, path: Path, move: float, step: float, q_start: np.ndarray,
          task: Task | None = None) -> InverseMotion:
    """Inverse dynamics along ``path`` on a grid of ``step`` over [0, move] (plus rest on both sides).

    ``q_start`` is a tree position near the path's start (warm start; it selects the assembly
    mode). Elastic joints need a stiffness. Raises :class:`InputError` (one line) if the
    fixed point diverges.
    """
    task = Task(mech) if task is None else task
    if not (step > 0 and move > 0):
        raise InputError(f"grid step and move time must be > 0 (got {step}, {move})")
    e = mech.elastic
    k_e = mech.stiffness[e]
    if len(e) and not np.all(k_e > 0):
        raise InputError("the elastic inverse needs a stiffness > 0 on every elastic joint")
    # unstable (non-minimum-phase) zero dynamics slow enough for the grid: inverted non-causally
    modes = zero_dynamics(mech, task, path, q_start) if len(e) else None
    unstable = None if modes is None else (modes[0] < 0) & (np.sqrt(np.abs(modes[0])) * step < RESOLVED)
    n_tail = 0
    if unstable is not None and np.any(unstable):
        n_tail = int(np.ceil(TAIL / np.sqrt(-modes[0][unstable].max()) / step))
    # the grid k * step (the control instants when step = 1 / rate), past the move's end
    n = int(np.ceil(move / step - 1e-9))
    t = np.arange(-PAD - n_tail, n + n_tail + PAD + 1) * step
    span = (-n_tail * step, move + n_tail * step)
    ys = [path(float(tk)) for tk in t]
    q_guess = np.array(q_start, dtype=float)
    qe = np.tile(q_guess[e], (len(t), 1))
    Q = np.empty((len(t), mech.n))
    last_change, previous, previous_pass = np.inf, None, None
    for passes in range(1, MAX_PASSES + 1):
        qe, qed, qedd = _smooth(t, qe, 0.0, move, span)
        # converged when the deflections (in the spline's band) stop changing; the raw
        # residual keeps the part of the exact deflections the band cannot hold
        size = np.inf if previous is None else (float(np.max(np.abs(qe - previous)))
                                                / max(float(np.max(np.abs(qe - mech.rest[e]))), 1e-300))
        if passes > 2 and size > 0.5 * last_change and size > TOLERANCE:
            raise InputError(f"the elastic inverse does not converge (pass {passes}: change {size:.3g}, before "
                             f"{last_change:.3g}): the move is too fast for the machine's internal dynamics; "
                             "give it more time")
        Q, Qd, Qdd, F, previous_pass = _pass(mech, task, ys, qe, qed, qedd, previous_pass, q_guess, t)
        if not len(e):
            return InverseMotion(t, Q, Qd, Qdd, mech.motor_inputs(F)[0], 1, 0.0)
        U, r = mech.motor_inputs(F)  # the motors' rows through their transmission; the elastic rows' rest
        # the change still to come, from the contraction seen so far (geometric): its torques'
        # error is that small a part of the springs' share
        if size <= TOLERANCE or (np.isfinite(last_change) and size * size / last_change <= TOLERANCE):
            # what the band could not hold, against the spring forces: a move the grid and knots
            # resolve leaves ~1e-6; a move faster than they (or the internal dynamics) allow, much more
            residual = float(np.max(np.abs(r)))
            spring = max(float(np.max(np.abs(k_e * (qe - mech.rest[e])))), 1e-300)
            if residual > RESIDUAL_LIMIT * spring:
                raise InputError(f"the elastic inverse leaves {residual / spring:.2g} of the spring forces "
                                 f"unbalanced: the move ({move:g} s) is too fast for its grid ({step:g} s) or the "
                                 "machine's internal dynamics; give it more time")
            return InverseMotion(t, Q, Qd, Qdd, U, passes, residual, n_tail * step, n_tail * step)
        last_change, previous = size, qe
        qe = qe - r / k_e if not n_tail else qe + _noncausal_step(r, modes, unstable, step)
    raise InputError(f"the elastic inverse did not converge in {MAX_PASSES} passes")


def zero_dynamics(mech: Mechanism, task: Task, path: Path, q_start: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The machine's internal dynamics at the path's start, held at its task coordinates:
    the elastic rows linearised, K_z dq_e + M_z dq_e'' (finite differences of :func:`_pass`),
    as (eigenvalues of M_z^-1 K_z, their eigenvectors V, M_z^-1). An eigenvalue w^2 > 0 is an
    oscillation at w; -a^2 < 0 a pair of real exponents +-a: non-minimum phase, whose bounded
    inverse is non-causal (pre- and post-actuation of time constant 1 / a). None if complex or
    if M_z is singular (the x-y stage's springs carry only the tip, which the path holds)."""
    e = mech.elastic
    n_e = len(e)
    y0 = np.asarray(path(0.0)[0], dtype=float)
    rest = np.zeros_like(y0)
    zeros = np.zeros((1, n_e))

    def rows(qe: np.ndarray, qedd: np.ndarray) -> np.ndarray:
        F = _pass(mech, task, [(y0, rest, rest)], qe[None], zeros, qedd[None], None, q_start, np.zeros(1))[3]
        return mech.motor_inputs(F)[1][0]

    base = np.asarray(q_start, dtype=float)[e]
    r0 = rows(base, np.zeros(n_e))
    K, M = np.empty((n_e, n_e)), np.empty((n_e, n_e))
    for i in range(n_e):
        d = np.zeros(n_e)
        d[i] = 1e-7 * max(1.0, abs(base[i]))
        K[:, i] = (rows(base + d, zeros[0]) - rows(base - d, zeros[0])) / (2 * d[i])
        M[:, i] = rows(base, np.eye(n_e)[i]) - r0
    if np.linalg.cond(M) > 1e12:  # a deflection that moves no mass at the fixed output: no dynamics to invert
        return None
    m_inv = np.linalg.inv(M)
    lam, V = np.linalg.eig(m_inv @ K)
    if np.any(np.abs(lam.imag) > 1e-6 * np.abs(lam)):
        return None
    return lam.real, V.real, m_inv


def _noncausal_step(r: np.ndarray, modes: tuple[np.ndarray, np.ndarray, np.ndarray], unstable: np.ndarray,
                    step: float) -> np.ndarray:
    """The deflections' correction for the elastic rows' forces r (N x n_e) left: K_z d + M_z d'' = -r
    in the zero-dynamics modes. A stable mode takes the fixed point's quasi-static step
    (eta = g / w^2); an unstable one (eta'' - a^2 eta = g) the bounded solution over the whole
    grid, at rest at both its ends (central differences: a banded solve): non-causal, it
    starts before the force that needs it and ends after it."""
    lam, V, m_inv = modes
    g = -np.linalg.solve(V, m_inv @ r.T)  # (n_e, N) modal forces
    eta = g / lam[:, None]
    n = r.shape[0]
    # eta'' by the fourth-order five-point stencil (the three-point one misjudges the band the
    # deflections' spline holds by up to 13 %, and the passes then stall)
    stencil = np.array([-1.0, 16.0, -30.0, 16.0, -1.0]) / (12 * step**2)
    for m in np.flatnonzero(unstable):
        bands = np.zeros((5, n))
        for row, c in enumerate(stencil[::-1]):
            bands[row] = c
        bands[2] += lam[m]
        eta[m] = solve_banded((2, 2), bands, g[m])
    return (V @ eta).T


def _smooth(t: np.ndarray, x: np.ndarray, lo: float, hi: float, span: tuple[float, float] | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples on a grid as a least-squares quintic spline with a knot every KNOT seconds:
    values, first and second derivatives. Why not interpolate: the update multiplies the
    deflections' second derivative by M / K, which raises a component at frequency f by
    (f / f_zero)^2; the grid's own round-off near its Nyquist frequency (above f_zero) would
    grow pass by pass. The knots keep the deflections to the path's band. Triple knots at the
    move's start ``lo`` and end ``hi``: the deflections follow the path's acceleration, whose
    third derivative (the path's fifth) jumps there under a C^4 law. ``span``: with pre- and
    post-actuation the deflections move before ``lo`` and after ``hi``: knots there too."""
    if x.shape[1] == 0:
        return x.copy(), x.copy(), x.copy()
    # at most KNOT apart, at least 10 intervals over the move, never closer than two grid steps
    step = (hi - lo) / max(1, round((hi - lo) / max(min(KNOT, (hi - lo) / 10), 2 * (t[1] - t[0]))))
    inner = np.arange(lo + step, hi - 0.5 * step, step)
    before = after = np.zeros(0)
    if span is not None and span[0] < lo:
        before = np.arange(lo - step, span[0] - 0.5 * step, -step)[::-1]
        after = np.arange(hi + step, span[1] + 0.5 * step, step)
    knots = np.concatenate([[t[0]] * 6, before, [lo] * 3, inner, [hi] * 3, after, [t[-1]] * 6])
    spline = make_lsq_spline(t, x, knots, k=5, axis=0)
    return spline(t), spline(t, 1), spline(t, 2)


def _pass(mech: Mechanism, task: Task, ys: list, qe: np.ndarray, qed: np.ndarray, qedd: np.ndarray,
          previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None, q_guess: np.ndarray, times: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple]:
    """Tree motion with the task coordinates of the path and the given deflections, and the
    generalised forces W^T (M_t qdd + h_t) on q_ae along it (eq 17).

    ``previous`` (the last pass's positions, deflections and dq/dq_e at fixed task
    coordinates) predicts each position to first order in the deflections' change, so Newton
    runs only where the closure is off by more than the assembly tolerance.
    """
    e, free, fixed = mech.elastic, task.free, task.fixed
    N = len(ys)
    n_task = 0 if task.kind == "platform" else task.size
    Q, Qd, Qdd = np.empty((N, mech.n)), np.empty((N, mech.n)), np.empty((N, mech.n))
    S = np.zeros((N, mech.n, len(e)))
    F = np.empty((N, len(mech.ae)))
    q = q_guess.copy()
    for k, (y, yd, ydd) in enumerate(ys):
        if previous is not None:
            q = previous[0][k] + previous[2][k] @ (qe[k] - previous[1][k])
        elif k:  # first pass: Newton from the last point's second-order Taylor step (one iteration)
            h = times[k] - times[k - 1]
            q = Q[k - 1] + h * Qd[k - 1] + 0.5 * h * h * Qdd[k - 1]
        q[e] = qe[k]
        if task.kind == "platform":
            q[task.joints] = y
        t0 = mech.terms(q)
        if previous is None or np.linalg.norm(t0.residual) > CLOSURE_TOLERANCE or (
                n_task and np.linalg.norm(mech.end_effector(q) - y) > CLOSURE_TOLERANCE):
            q = task.pose(q, y)
            t0 = mech.terms(q)
        jac = task.jacobian(t0)
        a = jac[:, free]
        v = np.zeros(mech.n)
        v[e] = qed[k]
        rhs = np.zeros(len(jac))
        if n_task:
            rhs[-n_task:] = yd
        else:
            v[task.joints] = yd
        # one factorisation: the rates, and each deflection's effect at fixed task coordinates
        sol = np.linalg.solve(a, np.column_stack([rhs - jac[:, fixed] @ v[fixed], -jac[:, e]]))
        qd = v
        qd[free] = sol[:, 0]
        S[k][free] = sol[:, 1:]
        S[k][e, np.arange(len(e))] = 1.0
        t1 = mech.terms(q, qd)
        acc = np.zeros(mech.n)
        acc[e] = qedd[k]
        rhs = task.bias(t1)
        if n_task:
            rhs[-n_task:] += ydd
        else:
            acc[task.joints] = ydd
        acc[free] = np.linalg.solve(a, rhs - jac[:, fixed] @ acc[fixed])
        W, _ = mech.passive_map(t1)
        F[k] = W.T @ (t1.M @ acc + t1.h)
        Q[k], Qd[k], Qdd[k] = q, qd, acc
    return Q, Qd, Qdd, F, (Q, qe.copy(), S)


def zoh_samples(motion: InverseMotion, rate: float, duration: float) -> tuple[np.ndarray, np.ndarray]:
    """Torque samples at t_k = k / rate for a zero-order hold: each the mean of tau over
    [t_k, t_k+1) (Simpson on the spline), so the held staircase has the continuous torque's
    impulse in every period. Point samples would lag it by half a period (a delay the
    elastic machine answers with the vibration the inverse removed). With pre- and
    post-actuation the table starts ``motion.pre`` before the move (t_0 = 0 is then the
    motion's -pre: the move starts at t = pre) and is longer by pre + post."""
    f = motion.torque()
    n = round((duration + motion.pre + motion.post) * rate)
    times = np.arange(n + 1) / rate
    h = 1.0 / rate
    values = np.array([(f(tk) + 4 * f(tk + 0.5 * h) + f(tk + h)) / 6 for tk in times - motion.pre])
    return times, values
