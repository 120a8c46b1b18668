"""Assembly: find tree coordinates that satisfy the closure (and an end-effector target).

Newton-Raphson on the chosen free joints with a backtracking line search, so a rough
guess converges to the assembly mode it lies in (the guess selects the mode; the sign
check in :func:`initial_state` makes a wrong mode an error, not a surprise). A start pose
(:func:`initial_state`) that Newton does not close is tried further: Levenberg-Marquardt,
continuation from the guess and several seeded starts about it, the closed pose nearest
the guess kept.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from elastic_pm_dyn.errors import AssemblyError
from elastic_pm_dyn.kinematics.mechanism import Mechanism

TOLERANCE = 1e-13  # [m]: a few ulps of the link lengths
# Newton that ends this close (residual [m]) with a Jacobian this ill-conditioned (smallest over
# largest singular value) stalled beside a singular configuration, not short of an unreachable pose.
NEAR_RESIDUAL = 1e-6
SINGULAR_RATIO = 1e-4


def _weld_angles(mech: Mechanism, terms) -> np.ndarray:
    """The closure residual with each weld's orientation rows as the rotation vector of
    E = R_a R_b^T (angle times axis) instead of the kernels' vee(E - E^T) / 2 = sin(angle)
    axis: the two agree to first order at E = I, but the sine vanishes again at a half
    turn, where Newton from a far guess (an exported zero pose with a rod flipped) would stall."""
    res = terms.residual.copy()
    ma = mech.arrays
    pairs = ma.closure_pairs
    if not len(pairs) or not np.any(pairs[:, 2] == 1):
        return res
    closure = mech.model.closure
    axes = closure.weld_axes  # the normal alone on a planar machine
    r = int(np.sum(pairs[:, 2] != 2)) * len(ma.closure_axes)  # after the point rows
    for a, b, kind in pairs:
        if kind != 1:
            continue
        Ra = terms.p_tip[a, 3:12].reshape(3, 3)
        Rb = terms.p_tip[b, 3:12].reshape(3, 3)
        phi = Rotation.from_matrix(Ra @ Rb.T).as_rotvec()
        res[r:r + len(axes)] = axes @ phi
        r += len(axes)
    return res


def _residual(mech: Mechanism, q: np.ndarray, target: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    t = mech.terms(q)
    r, jac = [_weld_angles(mech, t)], [t.A]
    if target is not None:
        J_ee, _ = mech.end_effector_jacobian(t)
        r.append(mech.end_effector(q) - target)
        jac.append(J_ee)
    return np.concatenate(r), np.vstack(jac)


def _newton(mech: Mechanism, q: np.ndarray, free: np.ndarray, target: np.ndarray | None, max_iter: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton (least-squares steps) with backtracking from q: (q, residual, Jacobian) where it stops."""
    q = np.array(q, dtype=float)
    r, jac = _residual(mech, q, target)
    for _ in range(max_iter):
        norm = float(np.linalg.norm(r))
        if norm <= TOLERANCE:
            break
        step, *_ = np.linalg.lstsq(jac[:, free], r, rcond=None)
        lam = 1.0
        while lam > 1e-6:
            trial = q.copy()
            trial[free] -= lam * step
            r_new, jac_new = _residual(mech, trial, target)
            if np.linalg.norm(r_new) < norm:
                break
            lam *= 0.5
        else:
            break
        q, r, jac = trial, r_new, jac_new
    return q, r, jac


def _levenberg_marquardt(mech: Mechanism, q: np.ndarray, free: np.ndarray, target: np.ndarray | None
                         ) -> np.ndarray:
    """A damped least-squares solve from q (MINPACK's Levenberg-Marquardt; a trust region where
    there are fewer rows than free joints): it walks down the residual where Newton's full
    steps overshoot, from a pose far from closing (a file's zero pose with its rods flipped)."""
    base = np.array(q, dtype=float)

    def fun(x: np.ndarray) -> np.ndarray:
        trial = base.copy()
        trial[free] = x
        return _residual(mech, trial, target)[0]

    def jac(x: np.ndarray) -> np.ndarray:
        trial = base.copy()
        trial[free] = x
        return _residual(mech, trial, target)[1][:, free]

    rows = len(fun(base[free]))
    method = "lm" if rows >= len(free) else "trf"
    with np.errstate(all="ignore"):
        from scipy.optimize import least_squares  # here: only this fallback needs it, not every start-up
        sol = least_squares(fun, base[free], jac=jac, method=method, xtol=1e-15, ftol=1e-15, gtol=1e-15,
                            max_nfev=200 * max(1, len(free)))
    base[free] = sol.x
    return base


def _continuation(mech: Mechanism, q: np.ndarray, free: np.ndarray, target: np.ndarray | None,
                  steps: int = 20) -> np.ndarray:
    """Newton along the homotopy r(q) = (1 - s) r(q_guess), s from 0 to 1: a path of poses from
    the guess (where it holds) to a closed one, the assembly mode the guess lies in."""
    q = np.array(q, dtype=float)
    r0 = _residual(mech, q, target)[0]
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        for _ in range(20):
            r, jac = _residual(mech, q, target)
            shifted = r - (1.0 - s) * r0
            if np.linalg.norm(shifted) <= TOLERANCE * 10:
                break
            step, *_ = np.linalg.lstsq(jac[:, free], shifted, rcond=None)
            q[free] -= step
    return q


def _wrapped(mech: Mechanism, q: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Passive revolute angles (the ones solved for) in (-pi, pi]: a solve that wandered whole
    turns away gives the same pose, and its angles then read as the pose (and assembly-mode
    signs as the file means them). Motors and springs keep their coordinate: it is theirs."""
    q = np.array(q, dtype=float)
    for j in free:
        joint = mech.model.joints[j]
        if joint.type == "revolute" and joint.role == "passive":
            q[j] = q[j] - 2.0 * np.pi * np.round(q[j] / (2.0 * np.pi))
            if q[j] <= -np.pi:
                q[j] += 2.0 * np.pi
    return q


def _worst_loop(mech: Mechanism, r: np.ndarray) -> str:
    """The closure the largest residual row belongs to, as the model names its points."""
    closure = mech.model.closure
    if closure is None or not len(r):
        return "the closure"
    rows = closure.row_pairs()
    k = int(np.argmax(np.abs(r[:len(rows)]))) if len(rows) else 0
    if k >= len(rows):
        return "the closure"
    labels = [label for _, _, label in mech.model.point_list()]
    pair = rows[k]
    if pair >= len(closure.pairs):  # a coupling row (closure.couplings), after the loops' rows
        return f"coupling {pair - len(closure.pairs) + 1}"
    a, b = closure.pairs[pair]
    return f"closure {pair + 1} ({labels[a]} = {labels[b]})"


def solve_pose(mech: Mechanism, q_guess: np.ndarray, free: np.ndarray,
               target: np.ndarray | None = None, max_iter: int = 60, robust: bool = False) -> np.ndarray:
    """Tree coordinates with h(q) = 0 (and end effector = target), moving only ``free``.

    Newton-Raphson from the guess; with ``robust`` (a start pose from a file), where it does
    not close: Levenberg-Marquardt, then continuation from the guess, then several starts
    about it (seeded), each polished by Newton, the closed pose nearest the guess taken, and
    the passive angles come back in (-pi, pi]. Raises :class:`AssemblyError` with the remaining
    residual (naming the file and the loop furthest from closing) if none closes, or if the
    Jacobian is singular there.
    """
    guess = np.array(q_guess, dtype=float)
    q, r, jac = _newton(mech, guess, free, target, max_iter)
    if float(np.linalg.norm(r)) <= TOLERANCE:
        # a start pose's passive angles wrapped; a pose solved along a motion (finite differences,
        # trajectories) keeps its branch of the angle
        return _wrapped(mech, q, free) if robust else q
    best = (q, r, jac)
    if robust:
        found = []
        rng = np.random.default_rng(0)  # the same starts every load
        starts = [lambda: _levenberg_marquardt(mech, guess, free, target),
                  lambda: _continuation(mech, guess, free, target)]
        for spread in (0.3, 0.3, 1.0, 1.0, np.pi, np.pi):
            def shaken(spread: float = spread) -> np.ndarray:
                start = guess.copy()
                start[free] += rng.uniform(-spread, spread, len(free))
                return _levenberg_marquardt(mech, start, free, target)
            starts.append(shaken)
        for start in starts:
            try:
                q_try, r_try, jac_try = _newton(mech, start(), free, target, max_iter)
            except (np.linalg.LinAlgError, ValueError, FloatingPointError):
                continue
            if not np.all(np.isfinite(r_try)):
                continue
            if float(np.linalg.norm(r_try)) <= TOLERANCE:
                found.append(_wrapped(mech, q_try, free))
                if len(found) >= 2:
                    break
            elif float(np.linalg.norm(r_try)) < float(np.linalg.norm(best[1])):
                best = (q_try, r_try, jac_try)
        if found:  # the closed pose nearest the guess (angles compared on the circle)
            def distance(qc: np.ndarray) -> float:
                d = (qc - guess)[free]
                return float(np.linalg.norm(np.arctan2(np.sin(d), np.cos(d))))
            return min(found, key=distance)
    q, r, jac = best
    norm = float(np.linalg.norm(r))
    what = "end-effector target" if target is not None else "closure"
    sv = np.linalg.svd(jac[:, free], compute_uv=False)
    ratio = sv[-1] / sv[0] if len(sv) and sv[0] > 0 else 0.0
    if norm <= NEAR_RESIDUAL and not ratio >= SINGULAR_RATIO:
        # Newton stalls beside a fold of the closure: the pose is there, its free joints are not determined
        raise AssemblyError(f"singular configuration (a parallel singularity): the closure Jacobian in the "
                            f"free joints has condition number {1 / max(ratio, 1e-300):.3g} here, so the "
                            f"{what} is solved only to a residual of {norm:.3g} m")
    if robust and target is None:
        raise AssemblyError(f"{mech.model.source}: cannot assemble {_worst_loop(mech, r)}: residual {norm:.3g} "
                            "(m, rad) after Newton, Levenberg-Marquardt, continuation and 6 more starts from the "
                            "file's start pose; give initial_state.guess (joint angles near a closed pose) in the "
                            "model or sidecar")
    raise AssemblyError(f"cannot assemble the {what}: residual {norm:.3g} m after Newton "
                        "(out of reach, or a singular configuration)")


def solve_velocity(mech: Mechanism, q: np.ndarray, free: np.ndarray, fixed_qd: np.ndarray,
                   ee_velocity: np.ndarray | None = None) -> np.ndarray:
    """Tree velocity with A qd = 0 (and J_ee qd = ee_velocity); qd is fixed_qd off ``free``."""
    t = mech.terms(q)
    jac = t.A
    rhs = np.zeros(mech.m)
    if ee_velocity is not None:
        J_ee, _ = mech.end_effector_jacobian(t)
        jac = np.vstack([jac, J_ee])
        rhs = np.concatenate([rhs, ee_velocity])
    qd = np.array(fixed_qd, dtype=float)
    fixed = np.setdiff1d(np.arange(mech.n), free)
    qd[free] = _solve_square(jac[:, free], rhs - jac[:, fixed] @ qd[fixed])
    return qd


def solve_acceleration(mech: Mechanism, q: np.ndarray, qd: np.ndarray, free: np.ndarray,
                       fixed_qdd: np.ndarray, ee_acceleration: np.ndarray | None = None) -> np.ndarray:
    """Tree acceleration with A qdd = gamma (and J_ee qdd + Jdot_ee qd = ee_acceleration)."""
    t = mech.terms(q, qd)
    jac, rhs = t.A, t.gamma
    if ee_acceleration is not None:
        J_ee, a_ee = mech.end_effector_jacobian(t)
        jac = np.vstack([jac, J_ee])
        rhs = np.concatenate([rhs, ee_acceleration - a_ee])
    qdd = np.array(fixed_qdd, dtype=float)
    fixed = np.setdiff1d(np.arange(mech.n), free)
    qdd[free] = _solve_square(jac[:, free], rhs - jac[:, fixed] @ qdd[fixed])
    return qdd


def _solve_square(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    if a.shape[0] != a.shape[1]:
        raise AssemblyError(f"{a.shape[0]} equations for {a.shape[1]} unknowns: the machine is not "
                            "non-redundant for this task")
    s = np.linalg.svd(a, compute_uv=False)
    if s[-1] <= 1e-10 * max(s[0], 1e-300):
        raise AssemblyError(f"singular configuration (condition number {s[0] / max(s[-1], 1e-300):.3g})")
    return np.linalg.solve(a, b)


def initial_state(mech: Mechanism) -> np.ndarray:
    """Start pose from the model's ``initial_state``, at rest: elastic joints where the guess puts
    them (a robot file's keyframe or zero pose: a spring preloaded there, as in MuJoCo), else at
    their spring's rest."""
    model = mech.model
    init = model.initial
    q = np.zeros(mech.n)
    for j, joint in enumerate(model.joints):
        q[j] = init.guess.get(joint.name, joint.rest)
    if init.active is not None:
        for name, value in init.active.items():
            q[model.joint_index(name)] = value
        q = solve_pose(mech, q, mech.passive, robust=True)
    elif init.end_effector is not None:
        target = np.asarray(init.end_effector, dtype=float)
        if target.shape[0] != len(mech.ee_components):
            raise AssemblyError(f"initial end_effector has {target.shape[0]} coordinates, "
                                f"the model's end effector {len(mech.ee_components)}")
        free = np.sort(np.concatenate([mech.active, mech.passive]))
        q = solve_pose(mech, q, free, target, robust=True)
    else:
        q = solve_pose(mech, q, mech.passive, robust=True)
    check_assembly_mode(mech, q)
    return q


def check_assembly_mode(mech: Mechanism, q: np.ndarray) -> None:
    for name, sign in mech.model.initial.signs.items():
        value = q[mech.model.joint_index(name)]
        if np.sign(np.sin(value)) != sign:
            raise AssemblyError(f"start pose is in the wrong assembly mode: {name} = {value:.4f} rad, "
                                f"expected {'positive' if sign > 0 else 'negative'} (sin)")


def random_consistent_state(mech: Mechanism, rng: np.random.Generator, spread: float = 0.2
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random consistent (q, qd) near the start pose and random motor torques.

    Motors within +-spread (rad or m), elastic joints within +-0.1 mm (or mrad), rates up
    to 2 rad/s and 5 cm/s, torques up to 2 (N m or N): for cross-checks and benchmarks.
    """
    q = initial_state(mech)
    n_a = len(mech.active)
    q[mech.active] += rng.uniform(-spread, spread, n_a)
    q[mech.elastic] += rng.uniform(-1e-4, 1e-4, len(mech.elastic))
    q = solve_pose(mech, q, mech.passive)
    qd_ae = np.concatenate([rng.uniform(-2, 2, n_a), rng.uniform(-0.05, 0.05, len(mech.elastic))])
    qd = mech.tree_velocity(q, qd_ae)
    tau = rng.uniform(-2, 2, n_a)
    return q, qd, tau
