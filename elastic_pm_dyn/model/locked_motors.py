"""Motors that the loops hold still or tie together: a loop with more equations than its
passive joints can meet (a ball joint left a hinge, a sidecar's misspelt re-typing, two motors
on one four-bar) constrains the motors it runs through. Found at a closed pose from the motions
the closures allow: a motor none of them moves is locked; motors whose motions are always in
one ratio are tied (they cannot be driven independently)."""

from __future__ import annotations

import numpy as np
import scipy.linalg

from elastic_pm_dyn.model.description import ACTIVE, PASSIVE, Model
from elastic_pm_dyn.model.free_motions import closes_from_start, closure_terms

LOCK_TOL = 1e-9  # a share of unit null vectors below this is none


def constrained_motors(model: Model) -> tuple[list[str], list[str]]:
    """(locked, tied): the motors no allowed motion moves, and the others the closures tie
    to each other; both empty where no closed pose is reached from the start by the passive joints."""
    if model.closure is None:
        return [], []
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    q = closes_from_start(model, passive)
    if q is None:
        return [], []
    J = closure_terms(model, q)[1]
    scale = max(1.0, float(np.abs(J).max())) if J.size else 1.0
    N = scipy.linalg.null_space(J / scale, rcond=1e-10)  # the motions the closures allow, all joints
    motors = [i for i, j in enumerate(model.joints) if j.role == ACTIVE]
    names = model.joint_names
    if not N.shape[1]:
        return [names[i] for i in motors], []
    locked = [i for i in motors if float(np.abs(N[i]).max()) < LOCK_TOL]
    free = [i for i in motors if i not in locked]
    if not free:
        return [names[i] for i in locked], []
    W = scipy.linalg.null_space(N[free].T, rcond=1e-10)  # motor combinations no allowed motion changes
    tied = [names[i] for k, i in enumerate(free) if W.shape[1] and float(np.abs(W[k]).max()) > LOCK_TOL]
    return [names[i] for i in locked], tied
