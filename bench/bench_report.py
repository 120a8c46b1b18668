"""What the benchmarks write: their numbers as JSON and their table as Markdown in
bench/results/ (git-ignored), the table also printed; and the commit measured."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


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
