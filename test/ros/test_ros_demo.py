"""``elastic-pm-dyn ros-demo``: three node processes, a bag, plots; equal to offline simulate."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from ros_harness import domain_id, require

from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES


def _demo(out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "ros-demo", "--out", str(out),
                           "--domain-id", str(domain_id(62)), "--timeout", "90", *extra],
                          capture_output=True, text=True, timeout=150)


def test_ros_demo_lockstep(tmp_path: Path) -> None:
    require("rclpy")
    require("rosbags")
    from rosbags.highlevel import AnyReader
    out = tmp_path / "demo"
    proc = _demo(out)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["states_in_manoeuvre"] == 501
    assert summary["offline_compared_samples"] == 501
    assert summary["max_joint_position_difference_vs_offline"] <= 1e-9
    assert summary["max_joint_velocity_difference_vs_offline"] <= 1e-9
    assert summary["max_gap_m"] < 1e-12
    for name in ("path", "branch_forces", "gap", "torques"):
        assert (out / f"{name}.png").stat().st_size > 10_000
    with AnyReader([out / "bag"]) as reader:  # definitions from the bag itself
        conns = [c for c in reader.connections if c.topic == "/branch_forces"]
        assert [c.msgtype for c in conns] == [BRANCH_FORCES]
        stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                  for c, _, raw in reader.messages(connections=conns) for m in [reader.deserialize(raw, c.msgtype)]]
        # 501 states; the first may come again while the plant waits for its first command
        assert len(set(stamps)) == 501 and all(s == stamps[0] for s in stamps[:len(stamps) - 500])
    for log in ("plant", "feedforward", "recorder"):
        assert (out / "logs" / f"{log}.log").is_file()
    assert "Traceback" not in "".join(p.read_text() for p in (out / "logs").glob("*.log"))


def test_ros_demo_reports_a_node_that_cannot_start(tmp_path: Path) -> None:
    require("rclpy")
    proc = _demo(tmp_path / "demo", "--model", str(tmp_path / "missing.yaml"))
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("elastic-pm-dyn: error: ")
    assert "exited with status 2" in lines[0] and "no such file" in lines[0]


def test_ros_demo_domain_is_the_option_else_ros_domain_id_else_private(monkeypatch: pytest.MonkeyPatch) -> None:
    from elastic_pm_dyn.errors import InputError
    from elastic_pm_dyn.ros.demos.local_nodes import run_domain_id
    from elastic_pm_dyn.ros.demos.processes import private_domain_id

    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert run_domain_id() == private_domain_id()
    assert run_domain_id(0) == 0  # --domain-id 0 is domain 0, not "unset"
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert run_domain_id() == 42
    assert run_domain_id(7) == 7  # --domain-id wins
    monkeypatch.setenv("ROS_DOMAIN_ID", "0")
    assert run_domain_id() == 0
    monkeypatch.setenv("ROS_DOMAIN_ID", " ")  # set but empty: unset, as for every ROS 2 tool
    assert run_domain_id() == private_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", "abc")
    with pytest.raises(InputError, match="ROS_DOMAIN_ID must be a whole number 0-232, got 'abc'"):
        run_domain_id()
    with pytest.raises(InputError, match="domain id must be a whole number 0-232, got 300"):
        run_domain_id(300)


def test_launch_file_uses_installed_executables_and_configs() -> None:
    """The launch file cannot run without a full ROS install; check what it refers to."""
    import ast
    import re
    repo = Path(__file__).resolve().parents[2]
    tree = ast.parse((repo / "launch" / "five_bar_demo.launch.py").read_text())
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    scripts = set(re.findall(r'"(\w+) = elastic_pm_dyn\.', (repo / "setup.py").read_text()))
    assert {"plant_node", "feedforward_node", "recorder_node"} <= scripts & strings
    for name in ("plant.yaml", "feedforward.yaml", "recorder.yaml"):
        assert name in strings and (repo / "config" / name).is_file()
