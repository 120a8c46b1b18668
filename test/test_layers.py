"""The package's layering, written once: data flows one way and only ``ros/`` talks to ROS.

A module may import from its own package and from packages on LOWER layers; packages on one
layer are siblings and do not import each other. Function-level and ``TYPE_CHECKING``
imports count too: a lazy import still ties the lower layer to the upper one. Inside a
package the modules import each other without a circle.

``python test/test_layers.py`` prints the package graph (Mermaid) for a drawing.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

PACKAGE = "elastic_pm_dyn"
ROOT = Path(__file__).resolve().parent.parent / PACKAGE

# Bottom to top. The package's own __init__ (the public face) is "<public>".
LAYERS: list[set[str]] = [
    {"errors", "small_linalg", "_numba_cache", "text_file", "interrupts", "pinned_kernels"},
    {"output_files", "csv_text"},
    {"bags", "model"},
    {"kinematics"},
    {"dynamics"},
    {"motion"},
    {"sim"},
    {"observer", "analysis"},
    {"demo", "fleet", "calibration"},
    {"ros"},
    {"cli"},
    {"entry"},
    {"__main__", "<public>"},
]
LEVEL = {unit: k for k, layer in enumerate(LAYERS) for unit in layer}
ROS_ONLY = ("rclpy", "elastic_pm_dyn_msgs", "launch", "launch_ros", "rosidl_runtime_py")


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def unit_of(module: str) -> str:
    """The layering unit of a package module: its first sub-package or top-level module."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "<public>"


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def imports(path: Path, known: set[str], root: Path = ROOT) -> set[str]:
    """Every module ``path`` imports (absolute names), at any depth of the file."""
    me = module_name(path, root)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            # `from pkg import sub` imports the submodule pkg.sub when there is one.
            subs = {f"{source}.{a.name}" for a in node.names} & known
            found.update(subs or {source})
    return found


def edges() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {m: imports(p, known) for m, p in mods.items()}


def test_every_unit_has_a_layer() -> None:
    units = {unit_of(m) for m in modules()}
    missing = sorted(units - set(LEVEL))
    assert not missing, f"modules on no layer (add them to LAYERS): {missing}"


def test_no_module_imports_from_a_layer_above_or_beside_its_own() -> None:
    bad = []
    for mod, targets in edges().items():
        for target in targets:
            if target.split(".")[0] != PACKAGE:
                continue
            a, b = unit_of(mod), unit_of(target)
            if a == b or a not in LEVEL or b not in LEVEL:  # units on no layer: test_every_unit_has_a_layer
                continue
            if LEVEL[b] >= LEVEL[a]:
                bad.append(f"{mod} ({a}, layer {LEVEL[a]}) imports {target} ({b}, layer {LEVEL[b]})")
    assert not bad, "upward or sideways imports:\n" + "\n".join(sorted(bad))


def test_only_ros_imports_rclpy_and_our_messages() -> None:
    bad = sorted(f"{mod} imports {t}" for mod, targets in edges().items() if unit_of(mod) != "ros"
                 for t in targets if t.split(".")[0] in ROS_ONLY)
    assert not bad, "\n".join(bad)


# Inside the observer, bottom to top: the configuration, the filter core (kernels, the per-period
# step, models), the scheduler (Observer: delays, sample timing, recovery), the drivers (stream,
# bags, event filter, pipeline), whole-recording passes (tune, smoother), the `observe` and
# `tune` commands, and the test data.
OBSERVER_LAYERS: list[set[str]] = [{"config"}, {"core"}, {"schedule"}, {"drivers"}, {"tuning"}, {"offline"}, {"cli"},
                                   {"testing"}]
OBSERVER_LEVEL = {unit: k for k, layer in enumerate(OBSERVER_LAYERS) for unit in layer}


def observer_unit(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "observer" else None


def test_observer_sub_packages_import_only_downwards() -> None:
    bad, missing = [], set()
    for mod, targets in edges().items():
        a = observer_unit(mod)
        if a is None:
            continue
        if a not in OBSERVER_LEVEL:
            missing.add(a)
            continue
        for target in targets:
            b = observer_unit(target)
            if b is None or b == a:
                continue
            if b not in OBSERVER_LEVEL:
                missing.add(b)
            elif OBSERVER_LEVEL[b] >= OBSERVER_LEVEL[a]:
                bad.append(f"{mod} ({a}) imports {target} ({b})")
    assert not missing, f"observer modules on no layer (add them to OBSERVER_LAYERS): {sorted(missing)}"
    assert not bad, "upward or sideways imports inside the observer:\n" + "\n".join(sorted(bad))


# The observer's test data and scores against truth (observer.testing) stay out of the product's
# path: only the demo that shows estimate against truth uses them.
TESTING = f"{PACKAGE}.observer.testing"
USES_TESTING = {f"{PACKAGE}.ros.demos.loop_demo"}


def test_the_product_does_not_import_the_observers_test_data() -> None:
    bad = sorted(f"{mod} imports {t}" for mod, targets in edges().items()
                 if not mod.startswith(TESTING) and mod not in USES_TESTING
                 for t in targets if t.startswith(TESTING))
    assert not bad, "\n".join(bad)


def test_modules_of_a_package_import_each_other_without_a_circle() -> None:
    known = set(modules())
    graph = {m: {t for t in ts if t in known and t != m} for m, ts in edges().items()}
    cycles = [c for c in strongly_connected(graph) if len(c) > 1]
    assert not cycles, f"import circles: {cycles}"


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative: no recursion limit)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        top = stack.pop()
                        on_stack.discard(top)
                        comp.append(top)
                        if top == node:
                            break
                    out.append(sorted(comp))
            elif child not in index:
                index[child] = low[child] = len(index)
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph.get(child, ())))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return out


def test_the_checker_sees_an_upward_import_and_a_circle(tmp_path: Path) -> None:
    """The checks above must be able to fail: a planted upward import and a planted circle."""
    pkg = tmp_path / PACKAGE
    (pkg / "model").mkdir(parents=True)
    (pkg / "model" / "__init__.py").write_text("")
    (pkg / "model" / "a.py").write_text("from elastic_pm_dyn.model import b\nfrom elastic_pm_dyn.ros import x\n")
    (pkg / "model" / "b.py").write_text("def f():\n    from . import a\n")
    known = {"elastic_pm_dyn.model.a", "elastic_pm_dyn.model.b"}
    found = imports(pkg / "model" / "a.py", known, pkg)
    back = imports(pkg / "model" / "b.py", known, pkg)
    assert found == {"elastic_pm_dyn.model.b", "elastic_pm_dyn.ros"}
    assert LEVEL[unit_of("elastic_pm_dyn.ros")] > LEVEL[unit_of("elastic_pm_dyn.model.a")]
    graph = {"elastic_pm_dyn.model.a": found & known, "elastic_pm_dyn.model.b": back}
    assert strongly_connected(graph) == [["elastic_pm_dyn.model.a", "elastic_pm_dyn.model.b"]]


def mermaid() -> str:
    """The package graph, one arrow per importing unit -> imported unit."""
    arrows: dict[str, set[str]] = defaultdict(set)
    for mod, targets in edges().items():
        for t in targets:
            if t.split(".")[0] == PACKAGE and unit_of(t) != unit_of(mod):
                arrows[unit_of(mod)].add(unit_of(t))
    lines = ["graph TD"]  # importer above imported: the lowest layer at the bottom
    lines += [f"    {a.strip('<>_')} --> {b.strip('<>_')}" for a in sorted(arrows) for b in sorted(arrows[a])]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.stdout.write(mermaid() + "\n")
