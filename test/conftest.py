"""Shared fixtures: the reference five-bar (horizontal and vertical) and random states."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.model.loader import load_model

CONFIG = Path(__file__).resolve().parent.parent / "config"


@pytest.fixture(scope="session")
def five_bar() -> Mechanism:
    return Mechanism(load_model(CONFIG / "five_bar.yaml"))


@pytest.fixture(scope="session")
def five_bar_vertical() -> Mechanism:
    return Mechanism(load_model(CONFIG / "five_bar_vertical.yaml"))


def random_state(mech: Mechanism, rng: np.random.Generator, spread: float = 0.2
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A consistent (q, qd) near the start pose and random motor torques.

    Motors within +-spread (rad or m), elastic joints within +-0.1 mm (or mrad), rates up
    to 2 rad/s and 5 cm/s.
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


def without_damping(model: Model) -> Model:
    chains = tuple(replace(c, joints=tuple(replace(j, damping=0.0, friction=0.0) for j in c.joints))
                   for c in model.chains)
    return replace(model, chains=chains)
