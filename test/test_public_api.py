"""The public face, ``import elastic_pm_dyn as epd``: every name resolves, lazily.

Every ``import elastic_pm_dyn.<module>`` runs the package's ``__init__`` first, so the names
are loaded on first use: importing the errors (or the package) must not import numba or
scipy.
"""

from __future__ import annotations

import ast
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

import elastic_pm_dyn as epd

INIT = Path(epd.__file__)
HEAVY = ("numba", "scipy", "elastic_pm_dyn.sim", "elastic_pm_dyn.dynamics", "rclpy")


@pytest.mark.parametrize("name", epd.__all__)
def test_every_public_name_resolves(name: str) -> None:
    module, attribute = epd._EXPORTS[name]
    assert getattr(epd, name) is getattr(importlib.import_module(module), attribute)


def test_all_lists_exactly_the_lazy_names() -> None:
    assert sorted(epd.__all__) == sorted(epd._EXPORTS)
    assert len(set(epd.__all__)) == len(epd.__all__)


def test_type_checking_imports_match_all() -> None:
    """What IDEs see (the ``if TYPE_CHECKING:`` imports) is what ``__getattr__`` loads."""
    tree = ast.parse(INIT.read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If) and getattr(n.test, "id", "") == "TYPE_CHECKING")
    seen = {}
    for node in block.body:
        assert isinstance(node, ast.ImportFrom)
        for alias in node.names:
            seen[alias.asname or alias.name] = (node.module, alias.name)
    assert seen == epd._EXPORTS


def test_dir_lists_the_public_names_and_nothing_else() -> None:
    """dir(epd) is __all__ plus dunders, whatever has been imported before: not the helpers this
    file imports, nor the internal modules Python binds on the package when they are loaded."""
    import elastic_pm_dyn.errors  # binds epd.errors, as any loaded submodule is bound
    import elastic_pm_dyn.small_linalg
    import elastic_pm_dyn.text_file
    listed = dir(epd)
    assert "__version__" in listed and isinstance(epd.__version__, str)
    assert {name for name in listed if not name.startswith("__")} == set(epd.__all__)
    assert not {"Any", "importlib", "TYPE_CHECKING", "ModuleType", "annotations", "errors", "small_linalg",
                "text_file", "pinned_kernels", "sim"} & set(listed)
    assert epd.errors is elastic_pm_dyn.errors  # still reachable as an attribute


def test_mapped_names_are_the_library_objects() -> None:
    from elastic_pm_dyn.analysis.report import analyze
    from elastic_pm_dyn.observer.config import load_config
    from elastic_pm_dyn.observer.offline import observe_bag
    assert epd.observe is observe_bag
    assert epd.load_observer_config is load_config
    assert epd.analyze is analyze
    assert issubclass(epd.InputError, epd.ElasticPmDynError)
    assert issubclass(epd.SingularConfigurationError, epd.ElasticPmDynError)


def test_unknown_name_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        epd.no_such_name  # noqa: B018
    assert not hasattr(epd, "no_such_name")


def _modules_after(statement: str) -> list[str]:
    code = f"{statement}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    return json.loads(proc.stdout)


@pytest.mark.parametrize("statement", ["import elastic_pm_dyn.errors", "import elastic_pm_dyn"])
def test_importing_the_package_or_its_errors_stays_light(statement: str) -> None:
    loaded = _modules_after(statement)
    heavy = [m for m in loaded if any(m == h or m.startswith(h + ".") for h in HEAVY)]
    assert heavy == []


def test_first_use_of_a_name_loads_only_its_module() -> None:
    loaded = _modules_after("import elastic_pm_dyn as epd\nepd.InputError")
    assert "numba" not in loaded and "scipy" not in loaded
    loaded = _modules_after("import elastic_pm_dyn as epd\nepd.Mechanism")
    assert "elastic_pm_dyn.kinematics.mechanism" in loaded and "elastic_pm_dyn.sim.simulator" not in loaded


def test_observe_and_analyze_take_the_robot_and_config_in_the_same_forms(tmp_path: Path) -> None:
    """A model file, a Model or a Mechanism; a config file, an ObserverConfig or None: the same results."""
    pytest.importorskip("rosbags")
    from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag
    from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

    repo = Path(__file__).resolve().parents[1]
    model_file, config_file = repo / "config" / "five_bar.yaml", repo / "config" / "observer.yaml"
    model = epd.load_model(model_file)
    mech = epd.Mechanism(model)
    recording_to_bag(manoeuvre_recording(mech, seed=5, duration=0.03), tmp_path / "bag")
    quiet = {"log": lambda line: None}
    by_objects = epd.observe(mech, epd.load_observer_config(config_file), tmp_path / "bag", tmp_path / "a", **quiet)
    by_files = epd.observe(model_file, config_file, tmp_path / "bag", tmp_path / "b", **quiet)
    by_model = epd.observe(model, None, tmp_path / "bag", tmp_path / "c", **quiet)
    assert (tmp_path / "a" / "estimates.csv").read_bytes() == (tmp_path / "b" / "estimates.csv").read_bytes()
    assert by_objects.summary.rows == by_files.summary.rows == by_model.summary.rows > 0
    bags = [tmp_path / "a" / "estimates"]
    from_file = epd.analyze(model_file, bags, tmp_path / "r1", plots_on=False)
    from_mech = epd.analyze(mech, bags, tmp_path / "r2", plots_on=False)
    assert from_file.runs["estimates"]  # the same figures, NaN where a figure has no data
    runs = [json.dumps(r.to_dict()["runs"], sort_keys=True) for r in (from_file, from_mech)]
    assert runs[0] == runs[1]
    with pytest.raises(epd.ModelError, match=r"missing\.yaml"):
        epd.observe(tmp_path / "missing.yaml", None, tmp_path / "bag", None, **quiet)
