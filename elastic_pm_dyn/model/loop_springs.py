"""Springs on joints a loop fixes: a gripper's spring link in a four-bar its driver moves.

A file joint with a spring (MJCF ``stiffness``, a sidecar's ``elastic``) is taken as an
elastic joint, an independent coordinate. Inside a loop whose other joints are too few to
close it, the loop fixes that joint instead (the Robotiq 2F-85 v4 and xArm grippers: driver,
spring link and follower form a four-bar of one degree of freedom, the driver's): it is a
passive joint still carrying its spring, as MuJoCo simulates it. Which springs become passive
is read off the closure Jacobian at a closed pose: those whose columns add rank to the
passive joints' until these span every independent row; the others stay elastic.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from elastic_pm_dyn.model.description import ELASTIC, PASSIVE, Model
from elastic_pm_dyn.model.free_motions import RANK_TOL, closes_from_start, closure_terms


def _rank(X: np.ndarray, scale: float) -> int:
    """The rank of X against ``scale`` (the whole Jacobian's largest singular value): a
    column block shares the tolerance of the matrix it comes from."""
    if X.size == 0:
        return 0
    return int(np.sum(np.linalg.svd(X, compute_uv=False) > RANK_TOL * scale))


def springs_fixed_by_loops(model: Model) -> Model:
    """``model`` with the sprung elastic joints its loops fix made passive (springs kept), with
    a warning naming them; the same model when the passive joints already span every
    independent closure row, or no closed pose is found (the counts then name the problem)."""
    c = model.closure
    if c is None:
        return model
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    sprung = [i for i, j in enumerate(model.joints) if j.role == ELASTIC and j.stiffness > 0.0]
    if not sprung:
        return model
    q = closes_from_start(model, passive + sprung)
    if q is None:
        return model
    A = closure_terms(model, q)[1]
    scale = float(np.linalg.norm(A, 2)) if A.size else 0.0
    if scale == 0.0:
        return model
    need = _rank(A, scale)  # rows that hold by themselves or repeat others do not count
    cols = list(passive)
    have = _rank(A[:, cols], scale)
    fixed = []
    for i in sprung:
        if have >= need:
            break
        grown = _rank(A[:, cols + [i]], scale)
        if grown > have:
            cols.append(i)
            fixed.append(i)
            have = grown
    if not fixed:
        return model
    names = [model.joints[i].name for i in fixed]
    warnings.warn(f"{model.source}: joint{'s' if len(names) > 1 else ''} {', '.join(repr(n) for n in names)}: "
                  f"{'their springs sit' if len(names) > 1 else 'its spring sits'} on a loop that fixes "
                  f"{'them' if len(names) > 1 else 'it'} (the loop has no other joint left to close it): "
                  "passive, the spring kept", stacklevel=3)
    chains, start = [], 0
    for ch in model.chains:
        joints = tuple(replace(j, role=PASSIVE) if start + k in fixed else j for k, j in enumerate(ch.joints))
        chains.append(replace(ch, joints=joints))
        start += len(ch.joints)
    return replace(model, chains=tuple(chains),
                   branches=tuple(b for b in model.branches if b.joint not in names))
