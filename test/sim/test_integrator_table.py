"""One integrator vocabulary: sim/integrators.py's METHODS table serves simulations, the plant and
the observer's mean, and code asks a row, never compares names (nothing here compiles)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer import config as observer_config
from elastic_pm_dyn.sim import integrators
from elastic_pm_dyn.sim.integrators import DOP853, ETD2, METHODS, RK4
from elastic_pm_dyn.sim.simulator import INTEGRATORS, SimulationOptions, Simulator

PACKAGE = Path(__file__).resolve().parents[1].parent / "elastic_pm_dyn"
CONFIG = Path(__file__).resolve().parents[1].parent / "config"


def test_every_integrator_is_a_row_of_the_table() -> None:
    assert set(INTEGRATORS) == {name for name, row in METHODS.items() if row.offered} == {"rk4", "etd2", "dop853"}
    assert {name: row.method for name, row in METHODS.items()} == {
        "rk4": RK4, "etd2": ETD2, "etd2rk": ETD2, "impulse": ETD2, "dop853": DOP853}
    assert [name for name, row in METHODS.items() if not row.fixed_step] == ["dop853"]
    assert [name for name, row in METHODS.items() if row.exponential] == ["etd2", "etd2rk", "impulse"]
    # the observer's mean takes the plant's fixed-step integrators, by the same names
    assert all(METHODS[name].fixed_step for name in observer_config.INTEGRATORS)


def test_the_simulator_steps_by_the_row() -> None:
    mech = Mechanism(load_model(CONFIG / "five_bar.yaml"))
    for name, row in METHODS.items():
        sim = Simulator(mech, SimulationOptions(integrator=name))
        assert sim.integrator == row and sim.method == row.kernel
        assert sim._advance_piece == (sim._advance_fixed if row.fixed_step else sim._advance_adaptive), name
    with pytest.raises(InputError, match="unknown integrator 'euler' \\(expected one of: rk4, dop853, etd2\\)"):
        SimulationOptions(integrator="euler").validate()
    with pytest.raises(InputError, match="needs a tree formulation"):
        SimulationOptions(integrator="etd2", formulation="lda").validate()


def _name_comparisons(path: Path) -> list[str]:
    names = set(METHODS)
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Compare):
            consts = {n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
            if consts & names:
                out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}: {ast.unparse(node)}")
    return out


def test_no_integrator_name_is_compared_outside_the_table() -> None:
    """The simulator, the plant and the observer dispatch on a row of METHODS. (The observer's
    test recordings check the truth's integrator against the two they support.)"""
    allowed = {PACKAGE / "observer" / "testing" / "recordings.py"}
    found = [hit for folder in ("sim", "observer") for path in sorted((PACKAGE / folder).rglob("*.py"))
             if path not in allowed for hit in _name_comparisons(path)]
    assert not found, "\n".join(found)
    assert integrators.OFFERED == INTEGRATORS
