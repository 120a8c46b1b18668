"""The one module every bench script may import (beside the helpers in bench/tools/): where the
repository and the results are, what a benchmark writes (its numbers as JSON and its table as
Markdown in bench/results/, git-ignored; the table also printed) and the commit it measured.

A script in bench/<kind>/ finds it with
``sys.path.insert(0, str(Path(__file__).resolve().parents[1]))``; no script imports another.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
RESULTS = BENCH / "results"


def commit() -> str:
    """The short hash of the checked-out commit (what a figure was measured on)."""
    return subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()


def write(out: Path, stem: str, data: Any, markdown: str) -> None:
    """``out/stem.json`` (``data``, indented) and ``out/stem.md`` (``markdown``); prints the table."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.json").write_text(json.dumps(data, indent=2))
    (out / f"{stem}.md").write_text(markdown + "\n")
    print(markdown)
