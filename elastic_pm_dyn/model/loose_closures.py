"""Loops the published geometry closes only nearly: the nearest pose, and points moved to close it.

A CAD export rounds coordinates: a hinge written as two ``<connect>``s between sites on its axis
(ToddlerBot's neck rods) or a wrist closed at rounded frames (onshape-to-robot) then closes to
1e-8..1e-6 m, and where the loop's rows repeat each other (two connects on one hinge) no pose
closes them exactly. MuJoCo runs such a file (its constraints are soft); the loader would find
no closed pose. So where the nearest pose (least squares over the passive joints from the start,
else over all joints) leaves every closure row within ``tol``, each pair's second point (or its
first, if the second is shared) is moved by its residual so that the loops close exactly there:
the machine differs from the file's by at most ``tol`` in its anchors, said in a warning with
the residual and the pose used. A residual beyond ``tol`` is left to the usual refusal.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from elastic_pm_dyn.model.description import PASSIVE, Chain, Model
from elastic_pm_dyn.model.free_motions import CLOSED, closes_from_start, closure_terms, forward_poses

CLOSURE_TOL = 1e-6  # [m, rad] a loop the file's geometry closes within this loads, its anchors moved


def close_loose_loops(model: Model, tol: float = CLOSURE_TOL) -> Model:
    """``model`` with its closure points moved to close at the nearest pose, started there,
    where the file's loops close only within ``tol``; the same model otherwise."""
    c = model.closure
    if c is None or not c.pairs or tol <= 0:
        return model
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    if closes_from_start(model, passive) is not None:
        return model
    everything = list(range(len(model.joints)))
    for free in (passive, everything):
        q, residual = _nearest(model, free)
        if residual <= CLOSED:
            return model  # it closes: the start pose's own checks take it from here
        if residual <= tol:
            break
    else:
        return model
    moved = _closed_at(model, q)
    if moved is None:
        return model
    shifted, shift = moved
    if closure_terms(shifted, q)[0].size and float(np.abs(closure_terms(shifted, q)[0]).max()) > CLOSED:
        return model  # a coupling row or a shared point stays open: the usual refusal
    names = model.joint_names
    start = np.array([model.initial.guess.get(j.name, j.rest) for j in model.joints], dtype=float)
    moved_joints = sorted((i for i in everything if q[i] != start[i]), key=lambda i: -abs(q[i] - start[i]))
    pose = ", ".join(f"{names[i]} {q[i]:.9g}" for i in moved_joints[:8]) + (", ..." if len(moved_joints) > 8 else "")
    warnings.warn(f"{model.source}: the loops close only to {residual:.3g} (m, rad) in the file's geometry, within "
                  f"the tolerance {tol:g}: their anchors moved by up to {shift:.3g} m to close them exactly at the "
                  f"nearest pose, started there ({pose or 'no joint moved'})", stacklevel=3)
    guess = dict(model.initial.guess) | {name: float(v) for name, v in zip(names, q, strict=True)}
    return replace(shifted, initial=replace(model.initial, guess=guess))


def _nearest(model: Model, free: list[int]) -> tuple[np.ndarray, float]:
    """The pose nearest closing the loops moving ``free`` from the start (least squares), and
    its largest closure row."""
    q0 = np.array([model.initial.guess.get(j.name, j.rest) for j in model.joints], dtype=float)

    def at(x: np.ndarray) -> np.ndarray:
        q = q0.copy()
        q[free] = x
        return q

    with np.errstate(all="ignore"):
        import scipy.optimize  # here: scipy.optimize costs every start-up ~0.1-0.3 s
        sol = scipy.optimize.least_squares(lambda x: closure_terms(model, at(x))[0], q0[free],
                                           jac=lambda x: closure_terms(model, at(x))[1][:, free], method="trf",
                                           xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=100 * max(1, len(free)))
    q = at(sol.x)
    r = closure_terms(model, q)[0]
    return q, float(np.abs(r).max()) if r.size and np.all(np.isfinite(r)) else np.inf


def _closed_at(model: Model, q: np.ndarray) -> tuple[Model, float] | None:
    """``model`` with each pair's point moved (in its body's frame) by the pair's residual at q,
    and each weld's second orientation turned by its own, so that they close exactly at q; the
    largest move. None where both points of an open pair are shared with other pairs."""
    c = model.closure
    R_body, p_body = forward_poses(model, q)
    points = [np.asarray(xyz, dtype=float).copy() for _, xyz, _ in model.point_list()]
    bodies = model.point_bodies()
    uses = np.bincount(np.asarray(c.pairs, dtype=int).ravel(), minlength=len(points))
    S = c.axes
    P = S.T @ S  # the residual's part in the rows (a planar machine's plane)

    def world(i: int) -> tuple[np.ndarray, np.ndarray]:
        b = bodies[i]
        return (np.eye(3), points[i]) if b < 0 else (R_body[b], p_body[b] + R_body[b] @ points[i])

    largest = 0.0
    for a, b in c.pairs:
        (_, xa), (Rb, xb) = world(a), world(b)
        gap = P @ (xa - xb)
        if not np.any(gap):
            continue
        if uses[b] == 1:
            points[b] = points[b] + Rb.T @ gap
        elif uses[a] == 1:
            Ra = world(a)[0]
            points[a] = points[a] - Ra.T @ gap
        else:
            return None
        largest = max(largest, float(np.linalg.norm(gap)))
    rotations = list(c.weld_rotations)
    for k, ((a, b), (Ra, Rb)) in enumerate(zip(c.welds, c.weld_rotations, strict=True)):
        Rba, Rbb = world(a)[0], world(b)[0]
        turned = Rbb.T @ Rba @ np.asarray(Ra, dtype=float)  # (Rba Ra)(Rbb Rb')^T = I
        largest = max(largest, float(np.linalg.norm(Rotation.from_matrix(turned @ np.asarray(Rb).T).as_rotvec())))
        rotations[k] = (Ra, turned)
    return _with_points(model, points, tuple(rotations)), largest


def _with_points(model: Model, points: list[np.ndarray], rotations: tuple) -> Model:
    """``model`` with :meth:`Model.point_list`'s points replaced, in its order."""
    n = len(model.chains)
    chains: list[Chain] = []
    k = n
    for ci, chain in enumerate(model.chains):
        named = tuple((name, points[k + i]) for i, (name, _) in enumerate(chain.points))
        k += len(chain.points)
        chains.append(replace(chain, end_xyz=points[ci], points=named))
    fixed = tuple((name, points[k + i]) for i, (name, _) in enumerate(model.fixed_points))
    return replace(model, chains=tuple(chains), fixed_points=fixed,
                   closure=replace(model.closure, weld_rotations=rotations))
