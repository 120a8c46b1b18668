"""Whether an item's command, though it returned 0, estimated anything: a recording the model
cannot observe is a failed row with its reason, never a silent ``ok``.

The single-item commands finish on such a recording (a bag of another machine: no joint of
the model in it; a bag without sensor messages; an empty bag) with 0 estimates and a
warning, which is right for a user watching one run and wrong for a fleet's table, where
nobody reads the 38th log. These checks read what the command wrote (``summary.json``, its
printed lines) and name the reason in one line.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

from elastic_pm_dyn.errors import InputError

MAX_WARNINGS = 400  # characters of the table's warnings column
_WARNING = re.compile(r"warning:\s*(.*)")
_TUNE_SAMPLES = re.compile(r"^\s+(\w+): (\d+) samples,", re.MULTILINE)


class UnusableRecording(InputError):
    """The command ran and found nothing of the model in the recording."""


def warnings_of(log: str) -> str:
    """The command's warning lines, in one line ("; " between them), for the results table."""
    found = list(dict.fromkeys(" ".join(m[1].split()) for line in log.splitlines() if (m := _WARNING.search(line))))
    text = "; ".join(found)
    return text if len(text) <= MAX_WARNINGS else text[:MAX_WARNINGS - 3] + "..."


def check_observe(summary: Mapping) -> None:
    """An observe run with no estimate, or with no sensor sample used, is unusable."""
    reason = (summary.get("last_joint_state_problem") or _health(summary) or "").strip()
    if not summary.get("rows"):
        raise UnusableRecording(f"no estimate from this recording{': ' + reason if reason else ''}")
    sensors = {k: v for k, v in (summary.get("sensors") or {}).items() if k != "command" and isinstance(v, Mapping)}
    if sensors and not any(v.get("accepted") for v in sensors.values()):
        counts = ", ".join(f"{k} {v.get('accepted', 0)}" for k, v in sensors.items())
        raise UnusableRecording(f"no sensor sample used ({counts}): the estimates are the commands' prediction only"
                                + (f": {reason}" if reason else ""))


def _health(summary: Mapping) -> str:
    health = summary.get("health")
    return str(health[1]) if isinstance(health, list) and len(health) > 1 and health[0] else ""


def check_tune(log: str) -> None:
    """A tune run whose likelihood had no sensor sample to weigh (0 samples each) is unusable."""
    counts = [(name, int(n)) for name, n in _TUNE_SAMPLES.findall(log)]
    if counts and not any(n for _, n in counts):
        raise UnusableRecording(f"no sensor sample the model can use ({', '.join(f'{k} {n}' for k, n in counts)}): "
                                "a recording of another machine, or without the sensors asked for?")


def check_analyze(summary: Mapping, motors: Sequence[str]) -> None:
    """An analyze run over commands that name none of the model's motors is unusable."""
    runs = summary.get("runs") or {}
    for label, run in runs.items():
        named = list(((run or {}).get("torques") or {}).get("peak_Nm") or {})
        if named and not set(named) & set(motors):
            raise UnusableRecording(f"{label}: the commands name no motor of the model (recording: "
                                    f"{', '.join(named[:4])}; model: {', '.join(motors[:4])}): another machine?")
