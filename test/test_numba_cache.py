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
