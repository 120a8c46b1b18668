"""Point numba's on-disk cache at a directory keyed by a hash of this package's source.

numba checks a cached function against its own file only: after an edit to a kernel in
another file, a cached caller would keep the old machine code inlined. Keying the whole
cache on the content of every file with compiled code means any change to one of them
compiles afresh (once); edits elsewhere (nodes, analysis) keep the cache.
A user's own NUMBA_CACHE_DIR is respected.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path


def source_hash() -> str:
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        text = path.read_bytes()
        if b"njit" in text:  # only compiled code ends up in the cache
            h.update(str(path.relative_to(root)).encode())
            h.update(text)
    return h.hexdigest()[:16]


def configure() -> None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    directory = str(base / "elastic_pm_dyn" / f"numba-{source_hash()}")
    if "numba" in sys.modules:  # already configured from the environment: set it directly
        import numba
        numba.config.CACHE_DIR = directory
    else:
        os.environ["NUMBA_CACHE_DIR"] = directory
