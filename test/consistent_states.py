"""Random consistent states of a closed-loop machine, for the cross-checks against peer engines."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism


def consistent_states(mech: Mechanism, rng: np.random.Generator, n: int) -> Iterator[tuple]:
    """``n`` (q, qd, tau) near the start pose: motors +-0.2 rad, springs +-0.1 mm, motor rates
    +-2 rad/s, spring rates +-5 cm/s, motor torques +-2 N m; passive joints assembled, tree
    velocities on the constraint."""
    q0 = initial_state(mech)
    for _ in range(n):
        q = q0.copy()
        q[mech.active] += rng.uniform(-0.2, 0.2, len(mech.active))
        q[mech.elastic] += rng.uniform(-1e-4, 1e-4, len(mech.elastic))
        q = solve_pose(mech, q, mech.passive)
        qd_ae = np.concatenate([rng.uniform(-2.0, 2.0, len(mech.active)),
                                rng.uniform(-0.05, 0.05, len(mech.elastic))])
        qd = mech.tree_velocity(q, qd_ae)
        tau = mech.split_tau(rng.uniform(-2.0, 2.0, len(mech.active)))
        yield q, qd, tau
