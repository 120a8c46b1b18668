"""The ROS tests' private domains: no two test modules share one (see ros_harness.domain_id)."""

from __future__ import annotations

import re
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent


def test_no_two_test_modules_share_a_domain_offset() -> None:
    users: dict[int, set[str]] = defaultdict(set)
    for path in HERE.rglob("test_*.py"):
        for offset in re.findall(r"domain_id\((\d+)\)", path.read_text()):
            users[int(offset) % 100].add(path.name)
    shared = {k: sorted(v) for k, v in users.items() if len(v) > 1}
    assert users and not shared, shared
