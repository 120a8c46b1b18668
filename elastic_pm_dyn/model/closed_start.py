"""A robot file whose start pose no motor setting of its own can close: the nearest closed pose.

A URDF has no motor positions: its zero pose is a convention, and a Stewart-like leg may not
close with every linear motor at zero (Gepetto's WL-16-like leg: its rods are too short there).
Gepetto's tools then solve the closure over all joints from that pose. So does the loader, when
the passive joints alone cannot close the loops but all joints together can: the motors start
where that solve puts them (said in a warning with the largest move), the file's other
numbers untouched. A start pose the file states (a sidecar's ``initial_state.active`` or
``end_effector``) is never moved.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from elastic_pm_dyn.model.description import ACTIVE, PASSIVE, Model
from elastic_pm_dyn.model.free_motions import closes_from_start


def motors_to_a_closed_pose(model: Model) -> Model:
    """``model`` starting at the closed pose nearest its file's pose when its motors must move
    to close the loops; the same model when the passive joints close them, nothing closes them,
    or the file states the motors' start."""
    init = model.initial
    if model.closure is None or not model.closure.pairs or init.active is not None or init.end_effector is not None:
        return model
    passive = [i for i, j in enumerate(model.joints) if j.role == PASSIVE]
    if closes_from_start(model, passive) is not None:
        return model
    q = closes_from_start(model, list(range(len(model.joints))))
    if q is None:
        return model  # the counts (or the loops that miss) are named by the caller's checks
    start = np.array([init.guess.get(j.name, j.rest) for j in model.joints], dtype=float)
    motors = [i for i, j in enumerate(model.joints) if j.role == ACTIVE]
    if not motors:
        return model
    k = max(motors, key=lambda i: abs(q[i] - start[i]))
    names = model.joint_names
    warnings.warn(f"{model.source}: the loops do not close with the motors where the file puts them; the nearest "
                  f"closed pose moves them (most: {names[k]} by {q[k] - start[k]:+.6g}): started there",
                  stacklevel=3)
    return replace(model, initial=replace(init, guess={name: float(v) for name, v in zip(names, q, strict=True)}))
