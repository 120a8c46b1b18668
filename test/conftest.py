"""Shared fixtures: the reference five-bar (horizontal and vertical) and random states."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from elastic_pm_dyn.kinematics.assembly import random_consistent_state as random_state  # noqa: F401 (tests import it from here)
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.model.loader import load_model

CONFIG = Path(__file__).resolve().parent.parent / "config"
# Every call of a pinned kernel checks its argument types against the pinned ones (the nodes
# the tests start inherit it): a pinned call with other types would read its arguments wrongly.
os.environ.setdefault("ELASTIC_PM_DYN_CHECK_PINNED", "1")


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
    """Periods done per call of the observer's compiled fast path (period.run_periods)."""
    from elastic_pm_dyn.observer.core import period

    calls: list[int] = []
    inner = period.run_periods

    def wrapped(*args):
        done = inner(*args)
        calls.append(done)
        return done

    monkeypatch.setattr(period, "run_periods", wrapped)
    return calls


# ---------------------------------------------------------------- fuzz budgets
# The input fuzz suites run a fixed, derandomised example budget by default (the same
# examples every run, seconds in all); `pytest --fuzz-long` (or ELASTIC_PM_DYN_FUZZ=long)
# runs 50x as many new examples each time, for an on-demand hunt.
FUZZ_LONG_FACTOR = 50
_fuzz = {"long": os.environ.get("ELASTIC_PM_DYN_FUZZ") == "long"}
settings.register_profile("fuzz", deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
settings.register_profile("fuzz-long", deadline=None, derandomize=False, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--fuzz-long", action="store_true", default=False,
                     help=f"input fuzz suites: {FUZZ_LONG_FACTOR}x the examples, new ones each run")
    parser.addoption("--fleet-long", action="store_true", default=False,
                     help="test_fleet: also the Dask LocalCluster and the Ctrl-C-then-resume runs (~30 s more; "
                          "or ELASTIC_PM_DYN_FLEET=long)")
    parser.addoption("--loop-soak", action="store_true", default=False,
                     help="test_user_loop: also the realtime loop beside two CPU hogs (~50 s; or "
                          "ELASTIC_PM_DYN_LOOP=soak)")


def pytest_configure(config: pytest.Config) -> None:
    if config.getoption("--fuzz-long"):
        _fuzz["long"] = True


@pytest.fixture
def fleet_long(request: pytest.FixtureRequest) -> None:
    """Skip unless --fleet-long (or ELASTIC_PM_DYN_FLEET=long): the batch tests that start clusters or processes."""
    if not (request.config.getoption("--fleet-long") or os.environ.get("ELASTIC_PM_DYN_FLEET") == "long"):
        pytest.skip("a long batch test: run with --fleet-long")


@pytest.fixture
def loop_soak(request: pytest.FixtureRequest) -> None:
    """Skip unless --loop-soak (or ELASTIC_PM_DYN_LOOP=soak): loops run beside CPU hogs."""
    if not (request.config.getoption("--loop-soak") or os.environ.get("ELASTIC_PM_DYN_LOOP") == "soak"):
        pytest.skip("a soak of the loop under load: run with --loop-soak")


def fuzz_settings(examples: int) -> settings:
    """Hypothesis settings of a fuzz test: ``examples`` derandomised examples, or
    FUZZ_LONG_FACTOR times as many random ones with --fuzz-long."""
    if _fuzz["long"]:
        return settings(settings.get_profile("fuzz-long"), max_examples=examples * FUZZ_LONG_FACTOR)
    return settings(settings.get_profile("fuzz"), max_examples=examples)
