"""Point numba's on-disk cache at a directory keyed by a hash of this package's source.

numba checks a cached function against its own file only: after an edit to a kernel in
another file, a cached caller would keep the old machine code inlined. Keying the whole
cache on the content of every file with compiled code means any change to one of them
compiles afresh (once); edits elsewhere (nodes, analysis) keep the cache.
A user's own NUMBA_CACHE_DIR is respected; one this module set in a parent process is not
(MARK tells them apart): a child running another copy of the package (the console script of
an installed version started by a test or launch of a checkout) would otherwise compile its
kernels into the parent's directory, where the parent's copy later reuses a cached caller with
the child's callee inlined (seen: an ETD2 run with the older sub-step kernel, 85 % of an
undamped Hexa's vibration energy lost in 20 ms).
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


MARK = "ELASTIC_PM_DYN_NUMBA_CACHE_DIR"  # the directory configure() chose (inherited by children)


def configure() -> None:
    chosen = os.environ.get("NUMBA_CACHE_DIR")
    if chosen and chosen != os.environ.get(MARK):
        return  # the user's own
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    directory = str(base / "elastic_pm_dyn" / f"numba-{source_hash()}")
    os.environ[MARK] = directory
    os.environ["NUMBA_CACHE_DIR"] = directory
    if "numba" in sys.modules:  # already configured from the environment: set it directly
        import numba
        numba.config.CACHE_DIR = directory
