"""Shared fixtures: the reference five-bar (horizontal and vertical) and random states."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from elastic_pm_dyn.kinematics.assembly import random_consistent_state as random_state  # noqa: F401 (tests import it from here)
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


def without_damping(model: Model) -> Model:
    chains = tuple(replace(c, joints=tuple(replace(j, damping=0.0, friction=0.0) for j in c.joints))
                   for c in model.chains)
    return replace(model, chains=chains)


@pytest.fixture
def count_fast(monkeypatch) -> list[int]:
    """Periods done per call of the observer's compiled fast path (kernels.run_periods)."""
    from elastic_pm_dyn.observer import kernels

    calls: list[int] = []
    inner = kernels.run_periods

    def wrapped(*args):
        done = inner(*args)
        calls.append(done)
        return done

    monkeypatch.setattr(kernels, "run_periods", wrapped)
    return calls
