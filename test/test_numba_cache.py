"""The compiled-code cache is keyed on the package source (stale kernels are never reused)."""

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
