"""How long an item may run before its worker is taken for hung and killed.

The default is generous (hangs are rare; killing a slow but sound item costs a re-run):
``BASE_S`` plus ``PER_PASS_SECOND`` for every second of the item's recording (torque table,
study motion) and every pass over it (a tune item's ``max_evaluations``; a simulation's
steps below 0.1 ms). Measured costs are 0.4 s (observe) and 0.1 s per pass (tune) per
recording second on one core, so the margin is some 75x. ``--item-timeout`` replaces it.
Reading a recording's length costs a few hundred microseconds (``metadata.yaml``, or the
file size for a bare ``.mcap``).
"""

from __future__ import annotations

import re
from pathlib import Path

from elastic_pm_dyn.fleet.items import BAG_SUFFIXES, Item

BASE_S = 120.0  # a worker's first item loads kernels: seconds on a loaded machine
PER_PASS_SECOND = 30.0
BYTES_PER_SECOND = 50_000.0  # a bag without metadata: assume a sparse recording (a long timeout)
DEFAULT_EVALUATIONS = 160  # elastic-pm-dyn tune --max-evaluations
DEFAULT_DT = 1e-4  # elastic-pm-dyn simulate --dt
_DURATION = re.compile(r"^  duration:\s*\n\s+nanoseconds:\s*(\d+)", re.MULTILINE)


def recording_seconds(item: Item) -> float:
    """The length of the item's input [s]; 1 s when it cannot be read (the item says why)."""
    if item.study:
        p = dict(item.study)
        return float(p.get("move", 0.3)) + float(p.get("hold", 0.2))
    path = Path(item.source)
    try:
        if item.kind == "simulate":
            return _table_seconds(path)
        meta = path / "metadata.yaml"
        if meta.is_file():
            found = _DURATION.search(meta.read_text(errors="replace")[:65536])
            if found:
                return int(found[1]) * 1e-9
        files = [path] if path.is_file() else [f for f in path.iterdir() if f.suffix in BAG_SUFFIXES]
        return sum(f.stat().st_size for f in files) / BYTES_PER_SECOND
    except (OSError, ValueError):
        return 1.0


def _table_seconds(path: Path) -> float:
    """A torque table's last time: the first number of its last line."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        f.seek(max(0, f.tell() - 4096))
        last = f.read().decode(errors="replace").strip().splitlines()[-1]
    return float(last.split(",")[0])


def passes(item: Item) -> float:
    """How many times the item goes over its recording (or a simulation's extra steps)."""
    options = dict(item.options)
    try:
        if item.kind == "tune":
            return float(options.get("max_evaluations", DEFAULT_EVALUATIONS))
        if item.kind == "simulate":
            dt = float(dict(item.study).get("dt", options.get("dt", DEFAULT_DT)))
            return max(1.0, DEFAULT_DT / dt)
    except (TypeError, ValueError):  # a bad value: the item fails with its reason
        pass
    return 1.0


def item_timeout(item: Item, given: float | None = None) -> float:
    """Seconds the item may run: ``given`` (the user's) or the default of the module docstring."""
    if given is not None:
        return float(given)
    return BASE_S + PER_PASS_SECOND * recording_seconds(item) * passes(item)
