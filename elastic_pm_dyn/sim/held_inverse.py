"""Discrete-time inverse of the held elastic machine: torque samples for a zero-order hold.

The plant holds each command sample u_k over [t_k, t_k + h) (h = 1 / rate). The continuous
elastic inverse (:mod:`~elastic_pm_dyn.motion.elastic_inverse`) sampled, even as each period's mean, is not an
inverse of that machine: the staircase differs from the smooth torque by O(h), so the end
effector leaves the path between and at the samples and, above all, the machine ends the move
with a small velocity left in its free motors (a double integrator, or with gravity a slow
pendulum), which the hold turns into drift. Here the samples are chosen for the held machine
itself (the lifted formulation of iterative learning control, run on the model):

    minimise  sum_s |y(t_s) - y_d(t_s)|^2                     (t_s: POINTS points per period)
    subject to x(T) = x_rest,   u_k = u_rest for t_k >= T

with y the task coordinates (:class:`~elastic_pm_dyn.motion.task.Task`), y_d the path,
x = (q_ae, qd_ae) the minimal state (eqs 12, 17-18) and x_rest, u_rest the elastic machine at
rest on the path's end (the springs loaded, :func:`rest_state`); T is the move's end plus a
few periods in which the torques may still settle the springs (post-actuation on the held
grid). Gauss-Newton: each pass simulates the nonlinear machine under the samples (compiled
RK4, steps that end on the hold's edges) and corrects them by the lifted sensitivity
dY / dU, built from the machine linearised about the simulated motion (eq 17 projected onto
q_ae, by finite differences of SCDD's accelerations, eqs 33-41) and discretised exactly
over each sub-interval (the matrix exponential of the frozen linear system with the held
input, as an ETD step does). The residual is always the nonlinear simulation's, so the
linearisation only sets the rate of convergence, not the answer (each correction carries a
tiny Tikhonov term, RHO). A pass that does not lower the error ends the passes and the best
samples so far are kept: where a mode is nearly uncontrollable through the hold (the
Triglide's 976 Hz mode under a 1 kHz hold) that is the first guess itself. A long horizon is
solved in overlapping windows (:func:`solve_held`).

Why not a per-sample inverse: matching y at t_{k+1} alone with u_k (one sample ahead) inverts
the sampled system's zeros, among them the hold's sampling zeros near -1 (relative degree
two from torque to position), and the samples alternate without bound. The points between
the samples and the whole horizon at once (a non-causal, bounded solution) avoid it, and
non-minimum-phase zero dynamics of the elastic coordinates are handled the same way (the
least-squares solution over the horizon is the stable inversion: it acts before the effect,
within the horizon, which starts with the continuous inverse's pre-actuation where it has
one). The continuous inverse's period means are the first guess.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.assembly import solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.motion.elastic_inverse import Path
from elastic_pm_dyn.motion.task import Task
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable

POINTS = 4  # output points per hold period (its end included): the ripple between samples counts
MAX_STEP = 1e-5  # [s] RK4 step of the model runs: 0.06 rad of the Triglide's 976 Hz mode (DOP853 agrees to ~1e-10 m)
SETTLE = 10  # periods after the move in which the samples may still settle the machine
MAX_PASSES = 8
TOLERANCE = 1e-12  # [task units] output error at which the passes stop
DRIFT_SPAN = 0.3  # [s] the end state's velocity error counts as the distance it drifts in this time
STALL = 0.7  # a pass that leaves more than this part of the best error so far ends the passes
LINEARISE = 5e-3  # [s] between the points the machine is linearised at (interpolated between)
WINDOW = 400  # periods kept from one solve: the lifted matrices hold ~(4 n_y + 1) ((WINDOW + OVERLAP) n_a)^2 numbers
OVERLAP = 100  # periods a window's solve reaches into the next one
RHO = 1e-9  # Tikhonov weight on the correction, relative to the sensitivity's largest column norm^2


@dataclass
class HeldInverse:
    """Torque samples for a zero-order hold and how well the model follows them."""

    times: np.ndarray  # (N,) t_k = k / rate
    torques: np.ndarray  # (N, n_a)
    q0: np.ndarray  # tree position the plant starts from, at rest (springs loaded)
    passes: int
    path_error: float  # largest model output error at the points of the last pass [task units]
    rest_error: np.ndarray  # (2 n_ae,) x(T) - x_rest after the last pass


def rest_state(mech: Mechanism, task: Task, y: np.ndarray, q_guess: np.ndarray, passes: int = 8
               ) -> tuple[np.ndarray, np.ndarray]:
    """The elastic machine at rest with task coordinates y: the deflections balance the
    springs' rows of eq 17 (W_e^T h_t = B_e u) by Newton, the motors' rows give u.
    Returns (tree position, motor inputs)."""
    e = mech.elastic
    q = task.pose(q_guess, y)

    def rows(qq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = mech.terms(qq)
        W, _ = mech.passive_map(t)
        return mech.motor_inputs(W.T @ t.h)

    for _ in range(passes if len(e) else 0):
        r = rows(q)[1]
        jac = np.empty((len(e), len(e)))
        for i in range(len(e)):
            d = 1e-9 * max(1.0, abs(q[e[i]]))
            qp, qm = q.copy(), q.copy()
            qp[e[i]] += d
            qm[e[i]] -= d
            jac[:, i] = (rows(task.pose(qp, y))[1] - rows(task.pose(qm, y))[1]) / (2 * d)
        step = np.linalg.solve(jac, r)
        q = q.copy()
        q[e] -= step
        q = task.pose(q, y)
        if np.max(np.abs(step)) <= 1e-15 * max(1.0, float(np.max(np.abs(q[e])))):
            break  # round-off: the springs balance
    return q, rows(q)[0]


class _Linearisation:
    """x' = A x + B u of the machine in x = (q_ae, qd_ae) about a tree state (finite differences)."""

    def __init__(self, mech: Mechanism):
        self.mech = mech
        self.dyn = Dynamics(mech)
        n_a, n_e = len(mech.active), len(mech.elastic)
        # motors' angles vs the springs' small deflections; rates enter quadratically (central: exact)
        self.dq = np.concatenate([np.full(n_a, 1e-7), np.full(n_e, 1e-9)])
        self.dqd = 1e-4

    def _acc(self, q: np.ndarray, q_ae: np.ndarray, qd_ae: np.ndarray, u: np.ndarray) -> np.ndarray:
        mech = self.mech
        qq = q.copy()
        qq[mech.ae] = q_ae
        qq = solve_pose(mech, qq, mech.passive)
        W, _ = mech.passive_map(mech.terms(qq))
        return self.dyn.accelerations(qq, W @ qd_ae, u)[mech.ae]

    def __call__(self, q: np.ndarray, qd: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mech = self.mech
        ae = mech.ae
        n = len(ae)
        q_ae, qd_ae = q[ae], qd[ae]
        A = np.zeros((2 * n, 2 * n))
        A[:n, n:] = np.eye(n)
        for i in range(n):
            d = np.zeros(n)
            d[i] = self.dq[i]
            A[n:, i] = (self._acc(q, q_ae + d, qd_ae, u) - self._acc(q, q_ae - d, qd_ae, u)) / (2 * d[i])
            d[i] = self.dqd
            A[n:, n + i] = (self._acc(q, q_ae, qd_ae + d, u) - self._acc(q, q_ae, qd_ae - d, u)) / (2 * d[i])
        base = self._acc(q, q_ae, qd_ae, u)
        B = np.zeros((2 * n, len(u)))
        for i in range(len(u)):  # affine in u
            du = np.zeros(len(u))
            du[i] = 1.0
            B[n:, i] = self._acc(q, q_ae, qd_ae, u + du) - base
        return A, B


def _output_map(mech: Mechanism, task: Task, q: np.ndarray) -> np.ndarray:
    """dy / dq_ae at a tree position (the task coordinates through W, eq 18)."""
    t = mech.terms(q)
    W, _ = mech.passive_map(t)
    if task.kind == "platform":
        return W[task.joints]
    J_ee, _ = mech.end_effector_jacobian(t)
    return J_ee @ W


def _discretise(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of x' = A x + B u with u held over h: (e^{hA}, int_0^h e^{sA} ds B)."""
    n, m = B.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = A, B
    E = scipy.linalg.expm(big * h)
    return E[:n, :n], E[:n, n:]


def solve_held(mech: Mechanism, path: Path, rate: float, horizon: float, u_first: np.ndarray,
               q0: np.ndarray, u_rest: np.ndarray, q_rest: np.ndarray, offset: float = 0.0,
               task: Task | None = None, through: Callable[[float], np.ndarray] | None = None) -> HeldInverse:
    """Samples u_k, k < n_h (n_h = ceil(horizon * rate)), held at ``rate``, by Gauss-Newton
    from ``u_first`` ((n_h, n_a)), the plant starting at rest at ``q0``; u_rest after them.
    The table's t = 0 is the path's t = -``offset`` (pre-actuation).

    A horizon longer than :data:`WINDOW` periods is solved window by window (the lifted
    matrices grow with its square): each window starts where the last one's simulated machine
    is and ends in ``through``'s state (path time -> x = (q_ae, qd_ae): the continuous
    inverse's, on the path), the last one at rest."""
    task = Task(mech) if task is None else task
    h = 1.0 / rate
    n_h = int(np.ceil(horizon * rate - 1e-9))
    U = np.array(u_first[:n_h], dtype=float)
    if U.shape != (n_h, len(mech.active)):
        raise InputError(f"held inverse: {n_h} first samples of {len(mech.active)} motors needed")
    n = len(mech.ae)
    windows = max(1, int(np.ceil(n_h / WINDOW)))
    if windows > 1 and through is None:
        raise InputError(f"held inverse: a horizon of {n_h} periods needs the path's states between its windows")
    edges = np.linspace(0, n_h, windows + 1).round().astype(int)
    dt = h / POINTS
    sim = Simulator(mech, SimulationOptions(integrator="rk4", dt=dt / np.ceil(dt / MAX_STEP - 1e-9), sample=dt))
    lin = _Linearisation(mech)
    q, qd = np.array(q0, dtype=float), np.zeros(mech.n)
    passes, err = 0, 0.0
    for k0, k1 in itertools.pairwise(edges):
        # each window reaches OVERLAP periods into the next (receding horizon): where it is cut,
        # the samples were not forced to a state, the end of the longer solve was
        reach = min(k1 + OVERLAP, n_h) if k1 < n_h else n_h
        last = reach == n_h
        x_end = (np.concatenate([q_rest[mech.ae], np.zeros(n)]) if last
                 else np.asarray(through(reach * h - offset), dtype=float))
        U_w, w_err, e_T, w_passes, (Q, Qd) = _solve_window(
            mech, task, sim, lin, path, rate, k0, U[k0:reach], u_rest if last else U[reach], q, qd, x_end, offset)
        U[k0:k1] = U_w[:k1 - k0]
        q, qd = Q[(k1 - k0) * POINTS - 1], Qd[(k1 - k0) * POINTS - 1]  # the machine where the next window starts
        passes, err = max(passes, w_passes), max(err, w_err)
    return HeldInverse(np.arange(n_h + 1) * h, np.vstack([U, u_rest]), np.array(q0, dtype=float), passes, err, e_T)


def _solve_window(mech: Mechanism, task: Task, sim: Simulator, lin: _Linearisation, path: Path, rate: float,
                  k0: int, U: np.ndarray, u_next: np.ndarray, q: np.ndarray, qd: np.ndarray, x_end: np.ndarray,
                  offset: float) -> tuple[np.ndarray, float, np.ndarray, int, tuple[np.ndarray, np.ndarray]]:
    """Gauss-Newton on the samples of periods k0 .. k0 + len(U) from the tree state (q, qd):
    (samples, largest output error, end-state error, passes, the simulated tree states at the points)."""
    h = 1.0 / rate
    n_w, n_a = U.shape
    n = len(mech.ae)
    dt = h / POINTS
    t0 = k0 * h
    t_pts = t0 + dt * np.arange(1, n_w * POINTS + 1)
    y_d = np.array([path(float(t) - offset)[0] for t in t_pts])
    times = t0 + np.arange(n_w + 1) * h
    U = U.copy()
    solver = None
    best = None
    for passes in range(1, MAX_PASSES + 1):
        run = sim.run(TorqueTable(times, np.vstack([U, u_next])), n_w * h, q0=q, qd0=qd, t0=t0)
        Q, Qd = run.q[1:], run.qd[1:]  # the points t_pts (the run also records its start)
        e_y = np.array([task.coordinates(x) for x in Q]) - y_d
        e_T = np.concatenate([Q[-1][mech.ae], Qd[-1][mech.ae]]) - x_end
        err = float(np.max(np.abs(e_y)))
        # the output error, or the end state's: its position and what its velocity drifts over a while
        score = max(err, float(np.max(np.abs(e_T[:n])) + DRIFT_SPAN * np.max(np.abs(e_T[n:]))))
        if best is not None and score > STALL * best[4]:
            break  # what is left is the staircase's own ripple (the least-squares optimum), or a pass made it worse
        if best is None or score < best[4]:
            best = (U.copy(), err, e_T, passes, score, (Q, Qd))
        if score <= TOLERANCE:
            break
        if solver is None:  # linearised once, about the first pass's motion (a pass is then one simulation)
            solver = _Correction(*_lifted(mech, task, lin, Q, Qd, U, n_w, dt, max(1, round(LINEARISE * rate))))
        U = U + solver(e_y.ravel(), e_T).reshape(n_w, n_a)
    U, err, e_T, passes, _, end = best
    return U, err, e_T, passes, end


def _lifted(mech: Mechanism, task: Task, lin: _Linearisation, Q: np.ndarray, Qd: np.ndarray, U: np.ndarray,
            n_h: int, dt: float, every: int) -> tuple[np.ndarray, np.ndarray]:
    """dY / dU (outputs at every point) and dx(T) / dU: the machine linearised about the
    middle of every ``every``-th period, discretised exactly over a point's interval, the
    periods between interpolated (the machine's configuration changes little in a few ms; an
    error here only slows the passes), all inputs propagated at once."""
    n, n_a = len(mech.ae), U.shape[1]
    mid = POINTS // 2 - 1  # the point at the period's middle (index within the period)
    knots = np.unique(np.append(np.arange(0, n_h, every), n_h - 1))
    maps = [_discretise(*lin(Q[k * POINTS + mid], Qd[k * POINTS + mid], U[k]), dt) for k in knots]
    X = np.zeros((2 * n, n_h * n_a))  # d x(t_s) / dU
    n_y = task.size
    G = np.empty((n_h * POINTS * n_y, n_h * n_a))
    for k in range(n_h):
        j = min(int(np.searchsorted(knots, k, side="right")) - 1, len(knots) - 2) if len(knots) > 1 else 0
        w = 0.0 if len(knots) == 1 else (k - knots[j]) / (knots[j + 1] - knots[j])
        Ad, Bd = maps[j] if w == 0.0 else ((1 - w) * maps[j][0] + w * maps[j + 1][0],
                                             (1 - w) * maps[j][1] + w * maps[j + 1][1])
        cols = slice(k * n_a, (k + 1) * n_a)
        for p in range(POINTS):
            s = k * POINTS + p
            X[:, : (k + 1) * n_a] = Ad @ X[:, : (k + 1) * n_a]
            X[:, cols] += Bd
            G[s * n_y:(s + 1) * n_y] = _output_map(mech, task, Q[s]) @ X[:n]
    return G, X.copy()


class _Correction:
    """dU = argmin |e_y + G dU|^2 + rho |dU|^2 subject to e_T + E dU = 0: the KKT system,
    factorised once (the sensitivity stays that of the first pass)."""

    def __init__(self, G: np.ndarray, E: np.ndarray):
        H = G.T @ G
        rho = RHO * float(np.max(np.diag(H)))
        self.scale = 1.0 / np.maximum(np.linalg.norm(E, axis=1), 1e-300)  # rows of unit norm: rad vs rad/s
        Es = E * self.scale[:, None]
        m = len(E)
        self.G, self.n = G, len(H)
        self.lu = scipy.linalg.lu_factor(np.block([[H + rho * np.eye(len(H)), Es.T], [Es, np.zeros((m, m))]]))

    def __call__(self, e_y: np.ndarray, e_T: np.ndarray) -> np.ndarray:
        rhs = np.concatenate([-self.G.T @ e_y, -e_T * self.scale])
        return scipy.linalg.lu_solve(self.lu, rhs)[:self.n]
