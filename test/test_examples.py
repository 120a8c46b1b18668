"""Every script in examples/ runs (in a temporary directory) and does what it says.

Each runs as a user would run it: ``python examples/<name>.py ...`` in a fresh interpreter,
with the current directory elsewhere than the repository; the ROS ones with ``ROS_DOMAIN_ID``
set to the module's private domain, as a ROS user sets it.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from ros_harness import domain_id, require

from elastic_pm_dyn.ros.demos.processes import ros_env  # ROS_DOMAIN_ID set, discovery on this machine

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


# A guard against a hang, not a speed requirement: with numba's cache cold (a fresh machine), the
# first example that runs the observer compiles its kernels first (~5 min on a loaded 2-core machine).
HANG_GUARD = 900.0  # [s]


def run_example(name: str, *args: str | Path, cwd: Path, timeout: float = HANG_GUARD,
                env: dict[str, str] | None = None) -> str:
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


def number_after(text: str, label: str) -> float:
    match = re.search(re.escape(label) + r"\s*(-?[0-9.]+(?:e[-+]?[0-9]+)?)", text)
    assert match, f"{label!r} not in:\n{text}"
    return float(match.group(1))


def test_every_example_is_a_short_plain_script_that_says_how_to_run_it() -> None:
    scripts = sorted(EXAMPLES.glob("*.py"))
    assert {p.stem for p in scripts} >= {"simulate_manoeuvre", "compare_formulations", "observe_bag",
                                         "analyze_bag", "closed_loop", "ros_controller"}
    for path in scripts:
        text = path.read_text()
        assert text.startswith('"""') and f"python examples/{path.name}" in text, path.name
        assert len(text.splitlines()) <= 40 and "argparse" not in text, path.name


def test_simulate_manoeuvre(tmp_path: Path) -> None:
    out = run_example("simulate_manoeuvre.py", cwd=tmp_path)
    lines = (tmp_path / "manoeuvre.csv").read_text().splitlines()
    assert lines[0].startswith("t,") and len(lines) == 3002  # a header, 0.3 s sampled every 0.1 ms
    assert number_after(out, "largest distance from the straight line:") < 100.0  # [um]
    assert number_after(out, "peak force in branch left:") > 1.0  # [N]: the rods are loaded


def test_compare_formulations(tmp_path: Path) -> None:
    out = run_example("compare_formulations.py", cwd=tmp_path)
    for f in ("scdd", "multipliers", "cut forces"):
        assert float(re.search(rf"^{f}\s+(\S+)", out, re.MULTILINE).group(1)) <= 1e-9
    assert "the formulations agree" in out


@pytest.fixture(scope="module")
def observed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    require("rosbags")
    tmp = tmp_path_factory.mktemp("observe")
    return tmp / "observe_out", run_example("observe_bag.py", cwd=tmp)


def test_observe_bag_makes_its_own_recording_and_estimates_the_forces(observed: tuple[Path, str]) -> None:
    out, text = observed
    for item in ("recording/metadata.yaml", "estimates/metadata.yaml", "estimates.csv", "summary.json"):
        assert (out / item).is_file(), item
    assert json.loads((out / "summary.json").read_text())["rows"] == 201  # 0.2 s at 1 kHz
    rms = [number_after(line, "RMS error vs truth") for line in text.splitlines() if "RMS error" in line]
    assert len(rms) == 2 and max(rms) < 0.02, text  # [N], against the simulated truth
    assert "branch_forces: 201 accepted" in text
    # The same recording given as BAG (copied out of the folder the script clears).
    import shutil
    shutil.copytree(out / "recording", out.parent / "given")
    again = run_example("observe_bag.py", out.parent / "given", cwd=out.parent)
    assert "branch_forces: 201 accepted" in again and "RMS error" not in again


def test_analyze_bag(observed: tuple[Path, str], tmp_path: Path) -> None:
    require("rosbags")
    from bag_factory import run_messages, synthetic_run, write_bag

    from elastic_pm_dyn.bags.typestore import make_typestore
    run = synthetic_run()
    bag = write_bag(tmp_path / "synthetic", run_messages(run, make_typestore()))
    text = run_example("analyze_bag.py", bag, observed[0] / "estimates", cwd=tmp_path)
    summary = json.loads((tmp_path / "analyze_out" / "summary.json").read_text())
    fit = summary["runs"]["synthetic"]["vibration"]["left"]
    assert fit["f_d_hz"] == pytest.approx(run.truth["f_d"], rel=1e-3)
    assert f"rings at {run.truth['f_d']:.1f} Hz" in text
    assert "estimates - synthetic:" in text  # the second bag compared with the first
    for name in summary["plots"].values():
        assert (tmp_path / "analyze_out" / name).stat().st_size > 10_000
    assert (tmp_path / "analyze_out" / "summary.md").is_file()


def test_ros_examples_take_their_domain_from_ros_domain_id(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from elastic_pm_dyn.errors import InputError
    from elastic_pm_dyn.ros.demos.local_nodes import LocalNodes

    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert LocalNodes(tmp_path).domain_id == 0  # ROS 2's default
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert LocalNodes(tmp_path).domain_id == 42
    for bad in ("abc", "-1", "233", "1.5"):
        monkeypatch.setenv("ROS_DOMAIN_ID", bad)
        with pytest.raises(InputError, match=f"ROS_DOMAIN_ID must be a whole number 0-232, got '{re.escape(bad)}'"):
            LocalNodes(tmp_path)


def test_ros_controller(tmp_path: Path) -> None:
    require("rclpy")
    text = run_example("ros_controller.py", cwd=tmp_path, env=ros_env(domain_id(14)))
    assert "500 periods of 1 ms in lockstep" in text
    assert number_after(text, "motor angle error: max") < 5.0  # [mrad]
    assert number_after(text, "end-effector error: max") < 1000.0  # [um]
    log = (tmp_path / "ros_controller_out" / "plant.log").read_text()
    assert "lockstep" in log and "Traceback" not in log


def test_lockstep_defaults(tmp_path: Path) -> None:
    require("rclpy")
    text = run_example("lockstep_defaults.py", cwd=tmp_path, env=ros_env(domain_id(11)))
    assert "200 lockstep periods driven with default QoS; last state at t = 0.200 s" in text
    log = (tmp_path / "lockstep_defaults_out" / "plant.log").read_text()
    assert "Traceback" not in log


def test_two_plants(tmp_path: Path) -> None:
    require("rclpy")
    text = run_example("two_plants.py", cwd=tmp_path, env=ros_env(domain_id(8)))
    for ns in ("r1", "r2"):
        lines = [line for line in text.splitlines() if line.startswith(f"/{ns}/clock:")]
        assert len(lines) == 1 and lines[0].endswith("strictly increasing: yes"), text
        assert f"'/{ns}/plant: plant', hardware_id 'five_bar /{ns}/plant'" in text
        assert "Traceback" not in (tmp_path / "two_plants_out" / f"{ns}.log").read_text()


def test_contact_stop(tmp_path: Path) -> None:
    """The move into the wall is stopped within 5 ms of the touch (issue 43's bound), by the wrench estimate."""
    text = run_example("contact_stop.py", cwd=tmp_path)
    assert number_after(text, "touched the wall at") > 0
    assert 0 <= number_after(text, "ms: detected") <= 5, text
