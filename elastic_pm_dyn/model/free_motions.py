"""Passive motions the closures leave free: a rod between two ball joints spins about its
own axis, whatever the motors do (Gepetto's legged robots close every rod this way, a 6d
weld between two half rods each hung on a ball). The closures then give fewer equations
than there are passive joints, and no choice of dependent joints fixes them all.

Such a motion is a degree of freedom of its own, unactuated and unsprung: it becomes an
independent coordinate, an elastic joint of zero stiffness (its damping the file's joint
damping), as Pinocchio integrates it. Which joints stay dependent is chosen from the
closure Jacobian at an assembled pose (reached from the file's zero pose) by QR with
column pivoting (the best-conditioned set); the others are the free ones.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import scipy.linalg
from scipy.spatial.transform import Rotation

from elastic_pm_dyn.model.description import ELASTIC, PASSIVE, Closure, Model

RANK_TOL = 1e-9  # relative to the largest pivot: below it a column adds nothing new
CLOSED = 1e-10  # [m, rad] closure residual taken as assembled for choosing the free joints
SNAP = 1e-12  # a direction's component below it is round-off of a zero (an axis of the file)


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _forward(model: Model, q: np.ndarray) -> tuple[list, list, list, list]:
    """World origin and axis of each joint, world pose of each body, tree order."""
    joints = model.joints
    p_joint, R_body, p_body, axes = [], [], [], []
    for k, (j, par) in enumerate(zip(joints, model.parents(), strict=True)):
        R0, p0 = (R_body[par], p_body[par]) if par >= 0 else (np.eye(3), np.zeros(3))
        Rj = R0 @ j.origin_rotation()
        pj = p0 + R0 @ np.asarray(j.origin_xyz, dtype=float)
        a = np.asarray(j.axis, dtype=float)
        p_joint.append(pj)
        axes.append(Rj @ a)
        if j.type == "revolute":
            R_body.append(Rj @ _axis_rotation(a / np.linalg.norm(a), q[k]))
            p_body.append(pj)
        else:
            R_body.append(Rj)
            p_body.append(pj + axes[k] * q[k])
    return p_joint, axes, R_body, p_body


def forward_poses(model: Model, q: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each body's world rotation and origin at tree coordinates q, in tree order."""
    _, _, R_body, p_body = _forward(model, q)
    return R_body, p_body


def _ancestors(parents: list[int], b: int) -> list[int]:
    out = []
    while b >= 0:
        out.append(b)
        b = parents[b]
    return out


def _velocity_rows(model: Model, p_joint, axes, x: np.ndarray, b: int) -> np.ndarray:
    """d(x)/dq for a point x on body b (6 rows: linear, then angular)."""
    J = np.zeros((6, len(axes)))
    for k in _ancestors(model.parents(), b):
        if model.joints[k].type == "revolute":
            J[:3, k] = np.cross(axes[k], x - p_joint[k])
            J[3:, k] = axes[k]
        else:
            J[:3, k] = axes[k]
    return J


def closure_terms(model: Model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closure residual and Jacobian d/dq at tree coordinates q: point rows (eq 8's
    S (p_a - p_b)), then each weld's orientation rows (the rotation vector of R_a R_b^T),
    in the order of :attr:`Closure.size`. Plain forward kinematics: the model layer's own,
    for choosing roles before the model is compiled."""
    c = model.closure
    p_joint, axes, R_body, p_body = _forward(model, q)
    n = len(axes)
    points = model.point_list()
    bodies = model.point_bodies()

    def point(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        b = bodies[i]
        xyz = np.asarray(points[i][1], dtype=float)
        J = np.zeros((6, n))
        if b < 0:
            return xyz, np.eye(3), J  # on the base, in the world
        x = p_body[b] + R_body[b] @ xyz
        return x, R_body[b], _velocity_rows(model, p_joint, axes, x, b)

    res, rows = [], []
    S, S_weld = c.axes, c.weld_axes  # in the plane and about its normal if planar
    reduced = set(c.reduced_pairs) | set(c.projected_pairs)
    for k, (a, b) in enumerate(c.pairs):
        if k in reduced:
            continue
        (xa, _, Ja), (xb, _, Jb) = point(a), point(b)
        res.append(S @ (xa - xb))
        rows.append(S @ (Ja - Jb)[:3])
    for (a, b), (Ra, Rb) in zip(c.welds, c.weld_rotations, strict=True):
        if c.pairs.index((a, b)) in reduced:
            continue
        (_, Rba, Ja), (_, Rbb, Jb) = point(a), point(b)
        phi = Rotation.from_matrix((Rba @ Ra) @ (Rbb @ Rb).T).as_rotvec()
        res.append(S_weld @ phi)
        rows.append(S_weld @ (Ja - Jb)[3:])
    for k, frame in c.reduced:  # along the first two directions of point a's frame, as its body turns them
        a, b = c.pairs[k]
        (xa, Rba, Ja), (xb, _, Jb) = point(a), point(b)
        U = (Rba @ np.asarray(frame, dtype=float))[:, :2].T
        res.append(U @ (xa - xb))
        rows.append(U @ (Ja - Jb)[:3])
    rotations = dict(zip(c.welds, c.weld_rotations, strict=True))
    for k, frame, mask in c.projected:  # the masked rows along a's frame (a weld's: its frame R_a F)
        a, b = c.pairs[k]
        (xa, Rba, Ja), (xb, Rbb, Jb) = point(a), point(b)
        F = np.asarray(frame, dtype=float)
        U = (Rba @ rotations[(a, b)][0] @ F if (a, b) in rotations else Rba @ F).T
        keep = [i for i in range(3) if mask & (1 << i)]
        res.append(U[keep] @ (xa - xb))
        rows.append(U[keep] @ (Ja - Jb)[:3])
        turn = [i for i in range(3) if mask & (8 << i)]
        if turn:
            Ra, Rb = rotations[(a, b)]
            phi = Rotation.from_matrix((Rba @ Ra) @ (Rbb @ Rb).T).as_rotvec()
            res.append(U[turn] @ phi)
            rows.append(U[turn] @ (Ja - Jb)[3:])
    if c.couplings:  # linear rows: C q = constant
        C = c.coupling_matrix(model.joint_names)
        res.append(C[:, :-1] @ q - C[:, -1])
        rows.append(C[:, :-1])
    if not rows:
        return np.zeros(0), np.zeros((0, n))
    return np.concatenate(res), np.vstack(rows)


def _assembled(model: Model, free: list[int], start: np.ndarray | None = None) -> np.ndarray | None:
    """Tree coordinates closing the loops, moving ``free`` from ``start`` (default: the file's
    start pose); None if that fails. Least-squares Newton (there may be more free joints than
    equations), and where it stalls a trust-region least-squares solve from the same start
    before Newton again: a zero pose with rods folded far from closing (Gepetto's legs)."""
    q = np.array([model.initial.guess.get(j.name, j.rest) for j in model.joints], dtype=float) \
        if start is None else np.array(start, dtype=float)
    closed = _newton(model, free, q)
    if closed is not None or not free:
        return closed
    x0 = q[free]

    def fun(x: np.ndarray) -> np.ndarray:
        trial = q.copy()
        trial[free] = x
        return closure_terms(model, trial)[0]

    def jac(x: np.ndarray) -> np.ndarray:
        trial = q.copy()
        trial[free] = x
        return closure_terms(model, trial)[1][:, free]

    with np.errstate(all="ignore"):
        import scipy.optimize  # here: scipy.optimize costs every start-up ~0.1-0.3 s
        sol = scipy.optimize.least_squares(fun, x0, jac=jac, method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                                           max_nfev=100 * len(free))
    if not np.all(np.isfinite(sol.x)):
        return None
    q = q.copy()
    q[free] = sol.x
    return _newton(model, free, q)


def closes_from_start(model: Model, free: list[int]) -> np.ndarray | None:
    """A closed pose reached from the file's start pose moving ``free``, None if none is found."""
    return _assembled(model, free)


def _newton(model: Model, free: list[int], q: np.ndarray) -> np.ndarray | None:
    """Least-squares Newton with backtracking from q; None where it stalls."""
    r, J = closure_terms(model, q)
    for _ in range(100):
        norm = float(np.linalg.norm(r))
        if norm < CLOSED:
            return q
        step = np.linalg.lstsq(J[:, free], r, rcond=None)[0]
        lam = 1.0
        while lam > 1e-6:
            trial = q.copy()
            trial[free] -= lam * step
            r_new, J_new = closure_terms(model, trial)
            if np.linalg.norm(r_new) < norm:
                break
            lam *= 0.5
        else:
            return None
        q, r, J = trial, r_new, J_new
    return q if float(np.linalg.norm(r)) < CLOSED else None


def _only_spins(model: Model, q: np.ndarray, passive: list[int], Jp: np.ndarray) -> bool:
    """Whether every passive motion the closures allow (motors and springs held) moves no
    joint origin: a part spinning about the line through its two balls (its closure point
    may be off that line: Gepetto's half rods meet at a bend), not a mechanism short of a
    motor, whose joints would move."""
    null = scipy.linalg.null_space(Jp, rcond=RANK_TOL)
    if null.shape[1] == 0:
        return True
    p_joint, axes, _, _ = _forward(model, q)
    parents = model.parents()
    rows = [_velocity_rows(model, p_joint, axes, p_joint[k], parents[k])[:3] for k in range(len(axes))
            if parents[k] >= 0]
    V = np.vstack(rows)[:, passive] @ null
    return float(np.abs(V).max()) < 1e-9 * max(1.0, float(np.abs(Jp).max()))


def free_passive_motions(model: Model) -> Model:
    """``model`` with the passive joints the closures cannot fix made independent
    (elastic, zero stiffness); the same model when there are none or the closures are
    redundant (the counts then name the problem)."""
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    m = model.closure.size if model.closure is not None else 0
    if len(passive) <= m or m == 0:
        return model
    # At an assembled pose: away from it the rod halves are not in line, and their spins
    # look independent.
    q = _assembled(model, passive)
    if q is None:
        return model  # _check_counts names the counts
    Jp = closure_terms(model, q)[1][:, passive]
    if not _only_spins(model, q, passive, Jp):
        return model  # a motion that moves the machine (a motor missing?): _check_counts names it
    rank, piv = _pivoted_rank(Jp)
    if rank < m:
        return model  # redundant closures: not a free motion, _check_counts says so
    free = {passive[k] for k in piv[m:]}
    chains = []
    start = 0
    for ch in model.chains:
        joints = tuple(replace(j, role=ELASTIC, stiffness=0.0, damping=j.friction, rest=0.0, friction=0.0)
                       if start + k in free else j for k, j in enumerate(ch.joints))
        chains.append(replace(ch, joints=joints))
        start += len(ch.joints)
    return replace(model, chains=tuple(chains))


def _across(n: np.ndarray) -> np.ndarray:
    """A rotation whose third column is the unit vector n, its first two spanning the plane
    across n: base axes where n is one (the same numbers in every row, no products)."""
    for i in range(3):
        if abs(abs(n[i]) - 1.0) < SNAP:
            e = np.eye(3)[[(i + 1) % 3, (i + 2) % 3, i]].T  # x, y, z cyclic: right-handed
            return e if n[i] > 0 else e @ np.diag([1.0, -1.0, -1.0])
    e = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = e - (e @ n) * n
    u /= np.linalg.norm(u)
    return np.column_stack([u, np.cross(n, u), n])


def _pair_rows(model: Model, q: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Every pair's three point rows at q in all joints (world directions; (n_pairs, 3, n_t)),
    and the orientation of the body carrying each pair's point a (the identity on the base):
    one forward kinematics for all."""
    c = model.closure
    probe = replace(model, closure=replace(c, components=(0, 1, 2), welds=(), weld_rotations=(), reduced=(),
                                           basis=Closure.basis, couplings=()))
    _, J = closure_terms(probe, q)
    R_body = _forward(model, q)[2]
    bodies = model.point_bodies()
    return J.reshape(len(c.pairs), 3, -1), [R_body[bodies[a]] if bodies[a] >= 0 else np.eye(3) for a, _ in c.pairs]


def _pivoted_rank(X: np.ndarray) -> tuple[int, np.ndarray]:
    """The rank of X by QR with column pivoting (relative tolerance :data:`RANK_TOL`) and the
    pivot order of its columns: the leading ``rank`` columns are independent."""
    _, r, piv = scipy.linalg.qr(X, pivoting=True, mode="economic")
    diag = np.abs(np.diag(r))
    if not len(diag):
        return 0, piv
    return int(np.sum(diag > RANK_TOL * max(diag[0], 1e-300))), piv


def _nearby_poses(model: Model, q: np.ndarray, passive: list[int], tries: int):
    """Assembled poses the non-passive joints reach from q, each moved by up to 0.1 (seeded:
    the same poses every load); a try whose loop does not close yields nothing."""
    others = [i for i in range(len(model.joints)) if i not in passive]
    rng = np.random.default_rng(0)
    for _ in range(tries):
        start = q.copy()
        start[others] += rng.uniform(-0.1, 0.1, len(others))
        moved = _assembled(model, passive, start)
        if moved is not None:
            yield moved


def _full_rank(J: np.ndarray) -> bool:
    """Whether the rows of J are independent (as the free joints are chosen)."""
    return J.shape[0] <= J.shape[1] and J.shape[0] > 0 and _pivoted_rank(J.T)[0] == J.shape[0]


def drop_still_rows(model: Model) -> tuple[Model, bool]:
    """``model`` with each point pair whose row along one direction holds by itself reduced to
    the two rows across it (:attr:`Closure.reduced`; the same model when there is none), and
    whether the closure rows were found independent in the passive joints at the assembled
    pose (then nothing repeats, and :func:`repeated_rows` need not look).

    A loop whose hinges are all parallel, closed by a 3-D point: every joint, in the loop or
    before it, moves the two points alike along the hinges, so that row of the pair's Jacobian
    is zero in all joints, and the passive block loses rank. Found at an assembled pose (from
    the file's zero pose) by the pair's singular values, and confirmed at poses the other
    joints reach from it (a pose folded onto a singularity may zero a row that is not zero
    nearby). The direction is fixed in the body of the pair's point a, not in the world: the
    loop's plane turns with the joints before it (Cassie's hips)."""
    c = model.closure
    if c is None or c.hub >= 0:
        return model, False
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    q = _assembled(model, passive)
    if q is None:
        return model, False
    if _full_rank(closure_terms(model, q)[1][:, passive]):
        return model, True  # a row that holds by itself would be a zero row
    if tuple(c.components) != (0, 1, 2) or not c.pairs:
        return model, False  # planar: the rows along the normal are gone already; or couplings alone
    welded = set(c.welds)
    found: list[tuple[int, np.ndarray]] = []
    rows, R = _pair_rows(model, q)
    for k, pair in enumerate(c.pairs):
        if pair in welded:
            continue  # a weld's position with its turn: not a point closure
        u, sv, _ = np.linalg.svd(rows[k])
        if sv[0] == 0.0 or sv[1] <= RANK_TOL * sv[0] or sv[2] > RANK_TOL * sv[0]:
            continue  # no row, or none alone: a pair that says nothing along two directions is refused later
        n_body = R[k].T @ u[:, 2]
        n_body = np.where(np.abs(n_body) < SNAP, 0.0, n_body)
        found.append((k, n_body / np.linalg.norm(n_body)))
    # Confirmed at two poses near (at most four tries): none that assembles, and the row is not
    # shown to hold by itself (a locked loop, whose other joints cannot move, is refused).
    confirmed = 0
    for moved in _nearby_poses(model, q, passive, 4 if found else 0):
        rows, R = _pair_rows(model, moved)
        found = [(k, n) for k, n in found
                 if np.abs((R[k] @ n) @ rows[k]).max() <= RANK_TOL * np.linalg.norm(rows[k], 2)]
        confirmed += 1
        if confirmed == 2:
            break
    welds = _still_weld_rows(model, q, passive)
    if (not found and not welds) or (not confirmed and found):
        return model, False
    reduced = tuple((k, _rows(_across(n))) for k, n in found)
    projected = tuple((k, _rows(F), mask) for k, F, mask in welds)
    return replace(model, closure=replace(c, reduced=reduced, projected=projected)), False


def _rows(F: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    return tuple(tuple(float(x) for x in row) for row in F)


def _weld_blocks(model: Model, q: np.ndarray) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """Per weld: (pair index, its three position rows and three orientation rows in all joints,
    expressed in the weld frame of its point a, and that frame's world orientation)."""
    c = model.closure
    p_joint, axes, R_body, p_body = _forward(model, q)
    points = model.point_list()
    bodies = model.point_bodies()

    def point(i: int) -> tuple[np.ndarray, np.ndarray]:
        b = bodies[i]
        if b < 0:
            return np.eye(3), np.zeros((6, len(axes)))
        x = p_body[b] + R_body[b] @ np.asarray(points[i][1], dtype=float)
        return R_body[b], _velocity_rows(model, p_joint, axes, x, b)

    out = []
    for (a, b), (Ra, _) in zip(c.welds, c.weld_rotations, strict=True):
        (R_a, Ja), (_, Jb) = point(a), point(b)
        W = R_a @ np.asarray(Ra, dtype=float)
        D = Ja - Jb
        out.append((c.pairs.index((a, b)), W.T @ D[:3], W.T @ D[3:], W))
    return out


def _still_weld_rows(model: Model, q: np.ndarray, passive: list[int]) -> list[tuple[int, np.ndarray, int]]:
    """Welds some of whose rows hold by themselves, each as (pair index, frame F in its weld
    frame, mask of the rows kept: bit i position along F's column i, bit 3 + i the turn about
    it). A weld closing a loop of hinges parallel to n (Gepetto's legs: a knee four-bar closed
    by a 6-D weld) never parts along n nor turns about the two directions across it: those
    three rows hold by themselves, and the loop's two position rows across n and its turn
    about n are kept, in the weld's frame as the body turns it. Found by each block's singular
    values at q, confirmed at two poses the other joints reach from it."""
    found = []
    for k, P, Om, _ in _weld_blocks(model, q):
        scale = max(np.linalg.norm(P, 2), np.linalg.norm(Om, 2), 1e-300)
        up, sp, _ = np.linalg.svd(P)
        uo, so, _ = np.linalg.svd(Om)
        zp = [up[:, i] for i in range(3) if sp[i] <= RANK_TOL * scale]
        zo = [uo[:, i] for i in range(3) if so[i] <= RANK_TOL * scale]
        if not zp and not zo:
            continue
        if len(zp) > 1 or len(zo) == 3:
            continue  # no simple split: the rank check refuses it, if it repeats
        # the one direction both splits agree on: n, along which position holds (zp) and about
        # which alone the weld turns (zo of two) or does not turn (zo of one)
        n = zp[0] if zp else (uo[:, 0] if len(zo) == 2 else zo[0])
        if len(zo) == 2 and abs(abs(n @ uo[:, 0]) - 1.0) > 1e-9:
            continue
        if len(zo) == 1 and abs(abs(n @ zo[0]) - 1.0) > 1e-9:
            continue
        n = np.where(np.abs(n) < SNAP, 0.0, n)
        n = n / np.linalg.norm(n)
        pos = 0b011 if zp else 0b111
        turn = {0: 0b111, 1: 0b011, 2: 0b100}[len(zo)]
        found.append((k, _across(n), pos | turn << 3))
    if not found:
        return []
    confirmed = 0
    for moved in _nearby_poses(model, q, passive, 4):
        blocks = {k: (P, Om) for k, P, Om, _ in _weld_blocks(model, moved)}
        keep = []
        for k, F, mask in found:
            P, Om = blocks[k]
            scale = max(np.linalg.norm(P, 2), np.linalg.norm(Om, 2), 1e-300)
            dropped = [F[:, i] @ P for i in range(3) if not mask & (1 << i)] + \
                [F[:, i] @ Om for i in range(3) if not mask & (8 << i)]
            if all(np.abs(row).max() <= RANK_TOL * scale for row in dropped):
                keep.append((k, F, mask))
        found = keep
        confirmed += 1
        if confirmed == 2:
            break
    return found if confirmed else []


def repeated_rows(model: Model) -> tuple[list[int], int] | None:
    """Closure rows that repeat the others at an assembled pose, and the rank of all of them in
    the passive joints; None when they are independent (or no pose assembles: the counts or the
    assembly name that). A planar loop closed by a 3-D point makes its out-of-plane row repeat."""
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    m = model.closure.size if model.closure is not None else 0
    if m == 0 or not passive:
        return None
    q = _assembled(model, passive)
    if q is None:
        return None

    def rank_at(q: np.ndarray) -> tuple[int, np.ndarray]:  # of the rows, in the passive joints
        return _pivoted_rank(closure_terms(model, q)[1][:, passive].T)

    rank, piv = rank_at(q)
    if rank == m:
        return None
    # Repeated everywhere, or only at this pose (a zero pose folded onto a singularity)? Look
    # again at poses the other joints reach from it.
    for moved in _nearby_poses(model, q, passive, 2):
        if rank_at(moved)[0] == m:
            return None
    return sorted(int(i) for i in piv[rank:]), rank


_ALL_ROWS = 0b111111  # a weld's three position and three turn rows (bits as Closure.projected)


_PLANAR_ROWS = 0b100011  # on a planar machine: the two positions in the plane, the turn about its normal


def _every_row(model: Model, q: np.ndarray) -> list[tuple[int, np.ndarray, int]]:
    """Every pair as (pair index, frame F, mask) in :attr:`Closure.projected`'s terms, in pair
    order: a plain point pair along its point a's body axes (F = I, three rows), a plain weld
    along its weld frame's (six rows), a reduced or projected pair as it already is. On a
    planar machine a pair's rows are its two in the plane (and a weld's turn about the normal):
    F's third column the plane's normal in the frame of point a (its body's, a weld's frame),
    which its bodies, all turning about that normal, never tilt; found at q."""
    c = model.closure
    welded = set(c.welds)
    reduced = dict(c.reduced)
    projected = {k: (F, mask) for k, F, mask in c.projected}
    planar = tuple(c.components) == (0, 1)
    if planar:
        normal = np.asarray(c.basis, dtype=float)[2]
        R_body = _forward(model, q)[2]
        bodies = model.point_bodies()
        turns = dict(zip(c.welds, c.weld_rotations, strict=True))
    out = []
    for k, pair in enumerate(c.pairs):
        if k in projected:
            F, mask = projected[k]
            out.append((k, np.asarray(F, dtype=float), mask))
        elif k in reduced:
            out.append((k, np.asarray(reduced[k], dtype=float), 0b011))
        elif planar:
            a = pair[0]
            R = R_body[bodies[a]] if bodies[a] >= 0 else np.eye(3)
            if pair in welded:
                R = R @ np.asarray(turns[pair][0], dtype=float)
            n = R.T @ normal
            n = np.where(np.abs(n) < SNAP, 0.0, n)
            out.append((k, _across(n / np.linalg.norm(n)), _PLANAR_ROWS if pair in welded else 0b011))
        else:
            out.append((k, np.eye(3), _ALL_ROWS if pair in welded else 0b111))
    return out


def _row_bits(entries: list[tuple[int, np.ndarray, int]]) -> list[tuple[int, int]]:
    """(pair index, bit) of each row of ``entries`` as projected pairs, in closure_terms' order."""
    return [(k, b) for k, _, mask in entries for b in [0, 1, 2, 3, 4, 5] if mask & (1 << b)]


def drop_repeated_rows(model: Model) -> Model:
    """``model`` with the closure rows that repeat rows of other loops left out (a body closed
    twice, loops sharing joints): every pair's rows in its own frame (point a's body, a weld's
    frame, as :attr:`Closure.projected`), taken in file order and kept where they add rank in
    the passive joints at an assembled pose (from the file's start pose); the rest confirmed
    to repeat the kept ones at two poses the other joints reach from it. The kept rows then fix
    the same motion, exactly as all of them. The same model where nothing repeats, where it is
    not confirmed, or where a coupling row would go (the rank check then refuses the file).
    A planar machine's pairs keep their rows in the plane (a parallelogram's third crank: two
    rows where one is new); a platform's legs as any loop (the platform SCDD then gives way to
    the general one, :func:`elastic_pm_dyn.model.arrays.pack`)."""
    c = model.closure
    if c is None or not c.pairs:
        return model
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    q = _assembled(model, passive)
    if q is None:
        return model
    every = _every_row(model, q)
    probe = replace(model, closure=replace(c, reduced=(), projected=tuple((k, _rows(F), m) for k, F, m in every)))
    bits = _row_bits(every)

    def rows_at(x: np.ndarray) -> np.ndarray:
        return closure_terms(probe, x)[1][:, passive]

    J = rows_at(q)
    if _pivoted_rank(J.T)[0] == J.shape[0]:
        return model
    scale = max(float(np.abs(J).max()), 1e-300)
    kept: list[int] = []
    for i in range(J.shape[0]):  # in file order: a later loop's rows repeat an earlier one's
        trial = kept + [i]
        sv = np.linalg.svd(J[trial], compute_uv=False)  # min(rows, joints) values
        if len(sv) == len(trial) and sv[-1] > RANK_TOL * scale * np.sqrt(len(trial)):
            kept = trial
    if any(i >= len(bits) for i in range(J.shape[0]) if i not in kept):
        return model  # a coupling row repeats: not a loop's row to drop
    confirmed = 0
    # rows zero in every joint hold by themselves (a spatial closure of a machine that moves in a
    # plane, as a model YAML writes it); the others repeat other rows. Both go; check names each.
    still = set(range(J.shape[0])) - set(kept)
    for moved in itertools.chain([q], _nearby_poses(model, q, passive, 4)):
        # repeated in the passive joints and in all of them: a row that only the motors' columns
        # tell apart from the kept ones would hold the motors (a locked loop), not repeat
        Jm = rows_at(moved)
        Jt = closure_terms(probe, moved)[1]
        if _pivoted_rank(Jm.T)[0] != len(kept) or _pivoted_rank(Jm[kept].T)[0] != len(kept) \
                or _pivoted_rank(Jt.T)[0] != _pivoted_rank(Jt[kept].T)[0]:
            return model
        tol = RANK_TOL * max(float(np.abs(Jt).max()), 1e-300)
        still = {i for i in still if float(np.abs(Jt[i]).max()) <= tol}
        confirmed += moved is not q
        if confirmed == 2:
            break
    if not confirmed:
        return model
    dropped: dict[int, int] = {}
    again: dict[int, int] = {}
    for i, (k, b) in enumerate(bits):
        if i not in kept:
            dropped[k] = dropped.get(k, 0) | (1 << b)
            if i not in still:
                again[k] = again.get(k, 0) | (1 << b)
    reduced = tuple((k, F) for k, F in c.reduced if k not in dropped)
    projected = [(k, F, m) for k, F, m in c.projected if k not in dropped]
    projected += [(k, _rows(F), mask & ~dropped[k]) for k, F, mask in every if k in dropped]
    repeated = tuple(sorted(again.items()))
    return replace(model, closure=replace(c, reduced=reduced, projected=tuple(projected), repeated=repeated))


def missed_loops(model: Model) -> list[tuple[int, float]] | None:
    """Where no closed pose is found with the passive joints alone: the loops that still miss
    when every joint may move (motors and springs too, least squares from the file's start
    pose), as (pair index, largest residual [m, rad]), worst first; [] when they all close so
    (the motors' start values are the problem, not the loops); None without a closure."""
    c = model.closure
    if c is None or c.size == 0:
        return None
    every = list(range(len(model.joints)))
    q = _assembled(model, every)
    if q is not None:
        return []
    q0 = np.array([model.initial.guess.get(j.name, j.rest) for j in model.joints], dtype=float)
    with np.errstate(all="ignore"):
        import scipy.optimize  # here: scipy.optimize costs every start-up ~0.1-0.3 s
        sol = scipy.optimize.least_squares(lambda x: closure_terms(model, x)[0], q0,
                                           jac=lambda x: closure_terms(model, x)[1], method="trf",
                                           xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=100 * len(every))
    r = np.abs(closure_terms(model, sol.x)[0])
    worst: dict[int, float] = {}
    for row, k in enumerate(c.row_pairs()):
        worst[k] = max(worst.get(k, 0.0), float(r[row]))
    return sorted(((k, v) for k, v in worst.items() if v > 1e-6), key=lambda kv: -kv[1])


def loose_joints(model: Model) -> list[str]:
    """Passive joints that still move, at an assembled pose with the motors and springs held,
    otherwise than as a rod spinning on its balls (which moves no joint's origin): the bodies
    of a machine short of a motor. [] where none does or no pose closes."""
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    if not passive or model.closure is None:
        return []
    q = _assembled(model, passive)
    if q is None:
        return []
    Jp = closure_terms(model, q)[1][:, passive]
    null = scipy.linalg.null_space(Jp, rcond=RANK_TOL)
    if null.shape[1] == 0:
        return []
    p_joint, axes, _, _ = _forward(model, q)
    parents = model.parents()
    scale = 1e-9 * max(1.0, float(np.abs(Jp).max()))
    out = []
    for k in range(len(axes)):
        par = parents[k]
        if par < 0 or model.joints[par].name in out:
            continue
        V = _velocity_rows(model, p_joint, axes, p_joint[k], par)[:3][:, passive] @ null
        if float(np.abs(V).max()) > scale:
            out.append(model.joints[par].name)
    return out


def loops_of(model: Model, names: list[str]) -> list[int]:
    """Indices into the closure's pairs of the loops through any joint named in ``names``: a
    pair's loop is the joints above one of its points and not above the other."""
    c = model.closure
    if c is None:
        return []
    parents = model.parents()
    bodies = model.point_bodies()
    wanted = {model.joint_names.index(n) for n in names if n in model.joint_names}
    out = []
    for k, (a, b) in enumerate(c.pairs):
        above = [set(_ancestors(parents, bodies[i])) if bodies[i] >= 0 else set() for i in (a, b)]
        if wanted & (above[0] ^ above[1]):
            out.append(k)
    return out
