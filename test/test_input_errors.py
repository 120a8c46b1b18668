"""User mistakes in model files, torque CSVs and simulate's values: one line, exit 2, nothing
written; Ctrl-C in a run keeps the samples so far."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from ros_harness import domain_id, require

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.errors import ModelError, RunInterrupted
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import FunctionTorque

CONFIG = Path(__file__).resolve().parent.parent / "config"
FIVE_BAR = CONFIG / "five_bar.yaml"
TEXT = FIVE_BAR.read_text()
TORQUES = "t,left_motor,right_motor\n0,0.02,-0.01\n0.01,0,0\n"


def _line_of(text: str, fragment: str) -> int:
    """1-based line of the first line holding ``fragment``."""
    return next(i for i, s in enumerate(text.splitlines(), start=1) if fragment in s)


def _one_error_line(capsys: pytest.CaptureFixture) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.endswith("\n"), err[:2000]
    assert "Traceback" not in err
    return err


def _check(tmp_path: Path, capsys: pytest.CaptureFixture, content: bytes, name: str = "m.yaml") -> str:
    """``check`` of a model file with ``content``: exit 2, one line, which is returned."""
    p = tmp_path / name
    p.write_bytes(content)
    assert main(["check", str(p)]) == 2
    return _one_error_line(capsys)


# ---------------------------------------------------------------- model files
TAGGED = TEXT.replace("mass: 0.6", "mass: !kg 0.6", 1)
BAD_FLOAT = TEXT.replace("mass: 0.6", "mass: !!float abc", 1)
MASS_LINE = _line_of(TEXT, "mass: 0.6")
MASS_KEY = "chains[0].joints[0].body.mass"


@pytest.mark.parametrize(("content", "where", "words"), [
    (b"name: x\n", "m.yaml:1: chains: ", "missing"),
    (b"", "m.yaml: ", "empty"),
    (b"# only a comment\n", "m.yaml: ", "empty"),
    (TAGGED.encode(), f"m.yaml:{MASS_LINE}: {MASS_KEY}: ", "'!kg'"),
    (BAD_FLOAT.encode(), f"m.yaml:{MASS_LINE}: {MASS_KEY}: ", "'abc'"),
    (b"a: &a [*a]\n", "m.yaml:1: ", "recursive alias"),
    (b"chains: &c\n  - *c\n", "m.yaml:2: ", "recursive alias"),
    (TEXT.encode() + b"# caf\xe9\n", f"m.yaml:{TEXT.count(chr(10)) + 1}: ", "UTF-8"),
    (bytes(range(256)) * 4, "m.yaml:", "UTF-8"),
    (TEXT.replace("planar: true", 'planar: "no"').encode(), f"m.yaml:{_line_of(TEXT, 'planar: true')}: planar: ",
     "true or false"),
    (TEXT.replace("planar: true", "planar: no").encode(), f"m.yaml:{_line_of(TEXT, 'planar: true')}: planar: ",
     "true or false"),
    ((TEXT + "elastic_dof_per_chain: 1.5\n").encode(), f"m.yaml:{TEXT.count(chr(10)) + 1}: elastic_dof_per_chain: ",
     "1.5"),
    (TEXT.replace("{name: right, joint: right_spring}", "{name: left, joint: right_spring}").encode(),
     f"m.yaml:{_line_of(TEXT, '{name: right, joint: right_spring}')}: branches[1].name: ", "twice"),
    (TEXT.replace("  - name: right\n", "  - name: left\n").encode(),
     f"m.yaml:{_line_of(TEXT, '  - name: right')}: chains[1].name: ", "twice"),
    (TEXT.replace("name: right_spring", "name: left_spring").encode(), "m.yaml:", "twice"),
    (b"[" * 100_000 + b"]" * 100_000, "m.yaml:1: ", "nest"),  # ours ("nested") or ruamel >= 0.19 ("nesting depth")
    ((TEXT + "---\nname: second\n").encode(), "m.yaml:", "document"),
], ids=["no-chains", "empty", "comment-only", "unknown-tag", "float-abc", "recursive-alias", "recursive-chains",
        "latin-1", "binary", "planar-quoted-no", "planar-no", "dof-1.5", "duplicate-branch", "duplicate-chain",
        "duplicate-joint", "deep-nesting", "two-documents"])
def test_model_file_mistake_is_one_line_naming_file_line_and_key(tmp_path, capsys, content, where, words) -> None:
    err = _check(tmp_path, capsys, content)
    assert err.startswith(f"elastic-pm-dyn: error: {tmp_path / where}"), err
    assert words in err


def test_model_size_is_checked_before_parsing(tmp_path, capsys) -> None:
    """A 50 MB file is refused at once, with its size and the limit; the shipped models load."""
    p = tmp_path / "huge.yaml"
    with p.open("wb") as fh:
        fh.write(TEXT.encode())
        fh.truncate(50 * 10**6)  # sparse: no time spent writing it
    start = time.monotonic()
    assert main(["check", str(p)]) == 2
    err = _one_error_line(capsys)
    assert time.monotonic() - start < 2.0
    assert "50000000 bytes" in err and "MiB" in err and "more than" in err
    for name in ("five_bar", "five_bar_vertical", "triglide", "hexa"):
        load_model(CONFIG / f"{name}.yaml")


def test_a_big_model_file_gets_its_error_in_linear_time(tmp_path) -> None:
    """~2 MB: 12 000 one-joint chains joined by a point closure, a branch per joint, the last
    branch naming a missing joint. Every check that compares names must cost O(1)."""
    n = 12_000
    chains = "".join(f"  - name: c{i}\n    joints:\n      - {{name: j{i}, type: prismatic, role: elastic, "
                     f"stiffness: 1.0, body: {{mass: 1.0}}}}\n" for i in range(n))
    branches = "".join(f"  - {{name: b{i}, joint: j{i}}}\n" for i in range(n - 1)) + "  - {name: bad, joint: nowhere}\n"
    closure = "closure: {chains: [" + ", ".join(f"c{i}" for i in range(n)) + "]}\n"
    text = "chains:\n" + chains + closure + "branches:\n" + branches
    p = tmp_path / "big.yaml"
    p.write_text(text)
    assert len(text) > 1.5e6
    start = time.monotonic()
    with pytest.raises(ModelError) as exc:
        load_model(p)
    elapsed = time.monotonic() - start
    assert f"big.yaml:{text.count(chr(10))}: branches[{n - 1}].joint: unknown joint 'nowhere'" in str(exc.value)
    assert elapsed < 12.0, f"{elapsed:.1f} s for {len(text) / 1e6:.1f} MB"


def test_plant_node_with_a_binary_model_prints_one_line_and_exits_2(tmp_path) -> None:
    require("rclpy")
    p = tmp_path / "garbage.yaml"
    p.write_bytes(bytes(range(256)) * 4)
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain_id(20))}
    proc = subprocess.run([sys.executable, "-m", "elastic_pm_dyn.ros.plant.node", "--ros-args", "-p", f"model:={p}"],
                          capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("plant_node: error: ") and "garbage.yaml" in proc.stderr


# ---------------------------------------------------------------- torque CSVs
def _simulate(tmp_path: Path, torques: bytes | str, *extra: str) -> tuple[int, Path]:
    tau = tmp_path / "tau.csv"
    tau.write_bytes(torques if isinstance(torques, bytes) else torques.encode())
    out = tmp_path / "run.csv"
    code = main(["simulate", "--model", str(FIVE_BAR), "--torques", str(tau), "--out", str(out), *extra])
    return code, out


@pytest.mark.parametrize(("torques", "words"), [
    (bytes(range(256)) * 8, "UTF-8"),
    (b"t,left_motor,right_motor\n0,0,0\x00\n", "line 2"),
    ("t,left_motor,right_motor,left_motor\n0,0.1,0,5\n", "line 1: column 'left_motor' appears twice"),
    ("t,left_motor,right_motor\n# ramp\n0,0,0\n\n0.1,0,0\n0.05,0,0\n", "line 6: t = 0.05"),
], ids=["binary", "nul-byte", "duplicate-column", "time-goes-back"])
def test_torque_csv_mistake_is_one_line_naming_the_file(tmp_path, capsys, torques, words) -> None:
    code, out = _simulate(tmp_path, torques, "--duration", "0.01")
    err = _one_error_line(capsys)
    assert code == 2 and f"{tmp_path / 'tau.csv'}: " in err and words in err, err
    assert not out.exists()


# ---------------------------------------------------------------- simulate's values
@pytest.mark.parametrize(("extra", "words"), [
    (("--duration", "1e7"), ("--duration", "--sample", "rows", "limit")),
    (("--duration", "0.01", "--sample", "1e-15"), ("--sample", "rows", "limit")),
    (("--duration", "0.01", "--dt", "1e-300"), ("--dt", "steps", "limit")),
    (("--duration", "1e300", "--integrator", "dop853", "--sample", "1e300"), ("--duration",)),
    (("--duration", "0.01", "--dt", "nan"), ("--dt",)),
    (("--duration", "0.01", "--dt", "-1e-4"), ("--dt",)),
    (("--duration", "0.01", "--sample", "inf"), ("--sample",)),
    (("--duration", "0.01", "--dt", "fast"), ("--dt", "'fast'")),
], ids=["duration-1e7", "sample-1e-15", "dt-1e-300", "dop853-1e300", "dt-nan", "dt-negative", "sample-inf", "dt-text"])
def test_simulate_refuses_impossible_sizes_at_once(tmp_path, capsys, extra, words) -> None:
    start = time.monotonic()
    try:
        code, out = _simulate(tmp_path, TORQUES, *extra)
    except SystemExit as exc:  # argparse
        code, out = exc.code, tmp_path / "run.csv"
    err = _one_error_line(capsys)
    assert code == 2 and time.monotonic() - start < 10.0
    assert all(w in err for w in words), err
    assert not out.exists()


def test_ctrl_c_in_a_run_keeps_the_samples_so_far() -> None:
    """The library: RunInterrupted (a KeyboardInterrupt) carries the rows up to the interrupt,
    equal to an uninterrupted run's."""
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    mech = Mechanism(load_model(FIVE_BAR))
    options = SimulationOptions(sample=0.002)

    def torque(t: float) -> np.ndarray:
        if t > 0.0101:
            raise KeyboardInterrupt
        return np.array([0.02, -0.01])

    full = Simulator(mech, options).run(FunctionTorque(lambda t: np.array([0.02, -0.01])), 0.02)
    with pytest.raises(KeyboardInterrupt) as exc:
        Simulator(mech, options).run(FunctionTorque(torque), 0.02)
    stop = exc.value
    assert isinstance(stop, RunInterrupted)
    part = stop.partial
    assert 4 <= len(part.t) < len(full.t) and stop.time == part.t[-1] <= 0.0101
    assert np.array_equal(part.table(), full.table()[:len(part.t)])


def test_ctrl_c_in_simulate_writes_the_csv_and_exits_130(tmp_path, capsys) -> None:
    """SIGINT while one output interval takes 1e7 RK4 steps: the compiled loop runs in
    chunks, so the run stops within seconds and writes the rows so far."""
    code, full = _simulate(tmp_path, TORQUES, "--duration", "0.01")  # warm up, and the format
    assert code == 0
    header = full.read_text().splitlines()[0]
    capsys.readouterr()
    out = tmp_path / "stopped.csv"
    (tmp_path / "tau.csv").write_text(TORQUES)
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT))
    start = time.monotonic()
    timer.start()
    try:
        code = main(["simulate", "--model", str(FIVE_BAR), "--torques", str(tmp_path / "tau.csv"),
                     "--duration", "5000", "--sample", "1000", "--out", str(out)])
    except KeyboardInterrupt:
        pytest.fail("KeyboardInterrupt escaped from simulate")
    finally:
        timer.cancel()
    elapsed = time.monotonic() - start
    err = _one_error_line(capsys)
    assert code == 130 and "interrupted at t = 0 s" in err and str(out) in err
    rows = out.read_text().splitlines()
    assert rows[0] == header and len(rows) == 2
    assert rows[1] == full.read_text().splitlines()[1]  # the start, as in any run
    assert elapsed < 10.0  # the whole run would take minutes


@pytest.mark.parametrize("extra, words", [(("--rate", "1e300"), "Hz a torque table may have"),
                                          (("--move", "1e300"), "samples, more than the limit")],
                         ids=["rate-1e300", "move-1e300"])
def test_feedforward_refuses_an_impossible_table_at_once(tmp_path, capsys, extra, words) -> None:
    out = tmp_path / "ff.csv"
    assert main(["feedforward", "--model", str(FIVE_BAR), "--out", str(out), *extra]) == 2
    err = _one_error_line(capsys)
    assert extra[0] in err and words in err
    assert not out.exists()


@pytest.mark.parametrize("content, words", [
    (b"/**:\n  ros__parameters:\n    observer:\n      sensors: [\xe9ncoders]\n", [":4: not UTF-8 text"]),
    (b"\x00\xff\xfe garbage \x81", ["not UTF-8 text"]),
    (b"/**:\n  ros__parameters:\n    observer:\n      sensors: &a [*a]\n", ["recursive alias"]),
    (b"a: [1, 2\n", [":2: not valid YAML"]),
])
@pytest.mark.parametrize("command", ["observe", "tune"])
def test_observer_parameter_file_mistake_is_one_line(tmp_path, capsys, content, words, command) -> None:
    """The observer's parameter files (observe/tune --config) get the model files' treatment:
    bad bytes, recursive aliases and malformed YAML are one line naming the file, exit 2."""
    cfg = tmp_path / "observer.yaml"
    cfg.write_bytes(content)
    out = ["--out", str(tmp_path / ("out" if command == "observe" else "tuned.yaml"))]
    code = main([command, "--model", str(FIVE_BAR), "--bag", str(tmp_path / "no_bag"), *out, "--config", str(cfg)])
    assert code == 2
    line = _one_error_line(capsys)
    assert str(cfg) in line and all(w in line for w in words), line
    assert not (tmp_path / "out").exists() and not (tmp_path / "tuned.yaml").exists()


@pytest.mark.parametrize("extra, words", [((), ["--line is needed", "3 coordinates", "XA YA ZA XB YB ZB"]),
                                          (("--line", "0", "0", "1", "1"), ["--line", "give 6 numbers", "got 4"])],
                         ids=["no-line", "planar-line"])
def test_feedforward_on_a_spatial_machine_asks_for_its_line(tmp_path, capsys, extra, words) -> None:
    """The default line is the planar five-bar's: a spatial machine gets one line, not a traceback."""
    out = tmp_path / "ff.csv"
    assert main(["feedforward", "--model", str(FIVE_BAR.parent / "triglide.yaml"), "--out", str(out), *extra]) == 2
    err = _one_error_line(capsys)
    assert all(w in err for w in words), err
    assert not out.exists()
