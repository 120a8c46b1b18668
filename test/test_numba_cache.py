"""The compiled-code cache is keyed on the package source (stale kernels are never reused)."""

import ast
from pathlib import Path

import numba
import pytest

from elastic_pm_dyn import _numba_cache


def test_cache_directory_follows_the_source_hash(monkeypatch: pytest.MonkeyPatch) -> None:
    h = _numba_cache.source_hash()
    assert h == _numba_cache.source_hash() and len(h) == 16
    assert numba.config.CACHE_DIR.endswith(f"numba-{h}")  # set when the package was imported
    monkeypatch.setenv("NUMBA_CACHE_DIR", "/somewhere/else")  # a user's own choice wins
    before = numba.config.CACHE_DIR
    _numba_cache.configure()
    assert before == numba.config.CACHE_DIR


def test_a_parent_copys_directory_is_not_inherited(tmp_path) -> None:
    """A child process that imports this copy of the package, started by a process of another
    copy (which exported its own cache directory), compiles into this copy's directory; a
    user's own NUMBA_CACHE_DIR still wins."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(_numba_cache.__file__).resolve().parents[1]
    code = "import elastic_pm_dyn, numba; print(numba.config.CACHE_DIR)"
    env = {**os.environ, "PYTHONPATH": str(root), "NUMBA_CACHE_DIR": str(tmp_path / "parent"),
           _numba_cache.MARK: str(tmp_path / "parent")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip().endswith(f"numba-{_numba_cache.source_hash()}")
    env.pop(_numba_cache.MARK)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == str(tmp_path / "parent")


# ---------------------------------------------------------------- one specialisation per kernel
def _is_njit(decorator: ast.expr) -> bool:
    d = decorator.func if isinstance(decorator, ast.Call) else decorator
    return (isinstance(d, ast.Name) and d.id == "njit") or (isinstance(d, ast.Attribute) and d.attr == "njit")


def _argument_kinds() -> dict[tuple[str, int], dict[str, list[str]]]:
    """For every compiled kernel of the package and argument position: how its callers pass it,
    ``literal <value>`` (a bool or int constant, or a module constant such as SCDD, inside
    compiled code) or ``typed`` (a variable, an expression, or any call from Python), with where."""
    root = Path(_numba_cache.__file__).resolve().parent
    trees = {p: ast.parse(p.read_text()) for p in sorted(root.rglob("*.py"))}
    kernels, constants = set(), {}
    for tree in trees.values():
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and any(_is_njit(d) for d in node.decorator_list):
                kernels.add(node.name)
            elif (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                  and node.targets[0].id.isupper() and isinstance(node.value, ast.Constant)
                  and type(node.value.value) in (int, bool)):
                constants[node.targets[0].id] = node.value.value
    kinds: dict[tuple[str, int], dict[str, list[str]]] = {}
    for path, tree in trees.items():
        compiled = {id(n) for f in tree.body if isinstance(f, ast.FunctionDef)
                    and any(_is_njit(d) for d in f.decorator_list) for n in ast.walk(f) if isinstance(n, ast.Call)}
        for call in ast.walk(tree):
            if not isinstance(call, ast.Call):
                continue
            name = getattr(call.func, "id", None) or getattr(call.func, "attr", None)
            if name not in kernels:
                continue
            for k, arg in enumerate(call.args):
                kind = "typed"
                if id(call) in compiled:
                    if isinstance(arg, ast.Constant) and type(arg.value) in (int, bool):
                        kind = f"literal {arg.value!r}"
                    elif isinstance(arg, ast.Name) and arg.id in constants:
                        kind = f"literal {constants[arg.id]!r}"
                where = f"{path.relative_to(root.parent)}:{call.lineno}"
                kinds.setdefault((name, k), {}).setdefault(kind, []).append(where)
    return kinds


# Small helpers whose literal arguments are meant (offsets into a row, solved columns): each
# specialisation costs a fraction of a second.
SMALL = {"row3", "row9", "cholesky_solve_rows", "_closure_at"}


def test_no_kernel_is_compiled_twice_for_a_literal_argument() -> None:
    """numba types a constant passed from one kernel to another (``True``, ``0``, a module constant
    such as ``SCDD``) as a Literal and compiles the callee again for it, beside the signature the
    other callers use: the observer's step and the simulator's integrators were each compiled twice
    (a second sample_step alone: 4.4 MB of machine code). A call passes ``np.int64(c)`` or
    ``np.bool_(c)`` instead, unless every caller passes the same constant."""
    mixed = [f"{name}, argument {k}: " + "; ".join(f"{kind} at {', '.join(at)}" for kind, at in by_kind.items())
             for (name, k), by_kind in sorted(_argument_kinds().items())
             if len(by_kind) > 1 and any(kind.startswith("literal") for kind in by_kind) and name not in SMALL]
    assert not mixed, "\n".join(mixed)
