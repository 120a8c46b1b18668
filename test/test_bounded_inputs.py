"""Every input bounded before it is read (issue #23 item 2).

Devices and FIFOs are refused where a file is expected (they never end, or block); YAML
that would expand without end (alias bombs), nest thousands deep or give a key twice is
refused before a value is built; values no machine has (gravity of 1e308, a stiffness of
1e300, a keyframe missing coordinates, a move shorter than a control period, a delay of
years, zero threads) each get one line. Every case ends with exit 2 and one line.
"""

from __future__ import annotations

import contextlib
import os
import signal
from pathlib import Path

import pytest
from bag_factory import run_messages, synthetic_run, write_bag

from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.typestore import make_typestore
from elastic_pm_dyn.cli import MAX_MESSAGE, main
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model import yaml12

CONFIG = Path(__file__).resolve().parents[1] / "config"
ROBOTS = Path(__file__).resolve().parent / "robots"
FIVE_BAR = CONFIG / "five_bar.yaml"


def _one_line(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("elastic-pm-dyn: error:") and len(err[0]) <= MAX_MESSAGE + 40, err
    return err[0]


def _bomb(levels: int = 9) -> str:
    """A YAML alias bomb of ~1 kB: 9 ** levels values once expanded."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for k in range(1, levels):
        lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "model.yaml"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("device", ["/dev/zero", "fifo"])
def test_a_model_that_is_a_device_or_fifo_is_refused(capsys, fifo: Path, device: str) -> None:
    path = fifo if device == "fifo" else Path(device)
    line = _one_line(capsys, ["check", str(path)])
    assert str(path) in line and "not a regular file" in line


def test_an_observer_config_that_is_a_device_is_refused(capsys) -> None:
    line = _one_line(capsys, ["observe", "--model", str(FIVE_BAR), "--bag", "none", "--out", "x",
                              "--config", "/dev/zero"])
    assert "/dev/zero" in line and "not a regular file" in line


def test_a_bag_that_is_a_fifo_or_holds_one_is_refused(tmp_path: Path, fifo: Path) -> None:
    with pytest.raises(BagError, match="not a bag"), open_bag(fifo):
        pass
    bag = tmp_path / "bag"
    write_bag(bag, run_messages(synthetic_run(), make_typestore())[:50], "mcap")
    storage = next(bag.glob("*.mcap"))
    storage.unlink()
    os.mkfifo(storage)
    with pytest.raises(BagError, match="not a regular file"), open_bag(bag):
        pass


def test_a_huge_metadata_yaml_is_refused_before_it_is_read(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_bag(bag, run_messages(synthetic_run(), make_typestore())[:50], "mcap")
    with (bag / "metadata.yaml").open("a") as fh:
        fh.truncate(17 * 2**20)  # sparse: 17 MiB of NUL bytes after the real content
    with pytest.raises(BagError, match="more than the 16 MiB"), open_bag(bag):
        pass


@pytest.mark.parametrize(("text", "words"), [
    (_bomb(), "aliases are expanded"),
    ("x: " + "[" * 80 + "]" * 80, "levels deep"),
    ("a: &a [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]\n"
     "b: [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[*a]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]", "expanded"),
    ("x: " + "[" * 5000 + "]" * 5000, "depth"),  # libyaml's own limit: a YAMLError too
    ("&a [*a]", "recursive alias"),
    ("a: 1\nb: 2\na: 3\n", "key 'a' given twice"),
])
def test_yaml_beyond_its_limits_is_refused_before_it_is_built(text: str, words: str) -> None:
    with pytest.raises(yaml12.yaml.YAMLError, match=words):
        yaml12.load(text)


def test_ordinary_parameter_yaml_still_loads() -> None:
    assert yaml12.load("a: &x [1, 2.5, 5e-5]\nb: *x\nc: {d: .inf, e: off}\n") == {
        "a": [1, 2.5, 5e-5], "b": [1, 2.5, 5e-5], "c": {"d": float("inf"), "e": False}}


def test_an_alias_bomb_as_observer_config_is_one_line_naming_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bomb.yaml"
    path.write_text("observer:\n  ros__parameters:\n    observer:\n" + "".join("      " + ln + "\n"
                                                                               for ln in _bomb().splitlines()))
    with pytest.raises(InputError, match=rf"{path}:\d+: more than .* values"):
        yaml12.load_file(path)


@pytest.mark.parametrize(("setting", "words"), [
    ("process.dt=" + "[" * 5000 + "1" + "]" * 5000, "not a valid YAML value"),
    ("process.dt=" + "[" * 70 + "1" + "]" * 70, "levels deep"),
    ("process.dt=1e-12", "below"),
    ("command_delay=1e9", "actuation latency"),
    ("process.max_interval=1e300", "prediction piece"),
    ("process.dt=-1", "with --set process.dt"),  # the user's --set named, not the shipped file alone
])
def test_observe_set_values_are_bounded(capsys, setting: str, words: str) -> None:
    line = _one_line(capsys, ["observe", "--model", str(FIVE_BAR), "--bag", "none", "--out", "x", "--set", setting])
    assert words in line


def test_observe_step_count_is_checked_before_work(capsys, tmp_path: Path) -> None:
    messages = run_messages(synthetic_run(), make_typestore())[:40]
    topic, msgtype, t_ns, msg = messages[-1]
    bag = tmp_path / "bag"
    write_bag(bag, [*messages, (topic, msgtype, t_ns + 20 * 10**9, msg)], "mcap")  # a bag spanning 20 s
    line = _one_line(capsys, ["observe", "--model", str(FIVE_BAR), "--bag", str(bag), "--out", str(tmp_path / "o"),
                              "--set", "process.dt=1e-7"])
    assert "2e+08 prediction steps" in line and str(bag) in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(("args", "words"), [
    (["--threads", "0"], "--threads must be 1 to"),
    (["--threads", "1000"], "--threads must be 1 to"),
    (["--seconds", "1e-9"], "at least"),
    (["--max-evaluations", "1000000000"], "--max-evaluations"),
])
def test_tune_sizes_are_checked_before_work(capsys, args: list[str], words: str) -> None:
    line = _one_line(capsys, ["tune", "--model", str(FIVE_BAR), "--bag", "none", "--out", "x.yaml", *args])
    assert words in line


def test_model_values_no_machine_has(tmp_path: Path, capsys) -> None:
    text = FIVE_BAR.read_text()
    gravity = tmp_path / "gravity.yaml"
    gravity.write_text(text.replace("gravity: [0.0, 0.0, 0.0]", "gravity: [1e308, 1e308, 0]", 1))
    assert "gravity" in _one_line(capsys, ["check", str(gravity)])
    stiff = tmp_path / "stiff.yaml"
    stiff.write_text(text.replace("stiffness: 5.464e6", "stiffness: 1e300", 1))
    assert "stiffness" in _one_line(capsys, ["check", str(stiff)])


def test_an_mjcf_keyframe_missing_coordinates_is_refused(tmp_path: Path, capsys) -> None:
    pytest.importorskip("mujoco")
    short = tmp_path / "five_bar.xml"
    short.write_text((ROBOTS / "five_bar.xml").read_text().replace('qpos="2.6 0 -1.9 0.87 0 1.8"', 'qpos="2.6 0"'))
    line = _one_line(capsys, ["check", str(short)])
    assert "keyframe" in line and "2 values" in line


def test_feedforward_move_and_analyze_hold_start(capsys, tmp_path: Path) -> None:
    assert "--move" in _one_line(capsys, ["feedforward", "--model", str(FIVE_BAR), "--move", "1e-12",
                                          "--out", str(tmp_path / "t.csv")])
    assert not (tmp_path / "t.csv").exists()
    # a rate too low for the default move to hold ten samples (a NaN/LinAlgError traceback before)
    assert "control periods" in _one_line(capsys, ["feedforward", "--model", str(FIVE_BAR), "--rate", "1e-300",
                                                   "--out", str(tmp_path / "t.csv")])
    assert not (tmp_path / "t.csv").exists()
    assert "--hold-start" in _one_line(capsys, ["analyze", "none", "--hold-start", "nan", "--out",
                                                str(tmp_path / "a")])


@contextlib.contextmanager
def _never_blocks(seconds: float = 60.0):
    """Fail (instead of hanging) if the block waits, e.g. in open() of a FIFO without a writer."""
    def expired(_signum, _frame):
        raise TimeoutError(f"blocked for {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_a_model_fifo_without_a_suffix_is_refused_at_once(capsys, tmp_path: Path) -> None:
    """The format of a file without a known suffix is read from its head: a FIFO is refused there,
    not opened (it blocked until a writer came)."""
    fifo = tmp_path / "machine"
    os.mkfifo(fifo)
    with _never_blocks():
        line = _one_line(capsys, ["check", str(fifo)])
    assert str(fifo) in line and "not a regular file (a FIFO)" in line


@pytest.mark.parametrize(("waypoints", "words"), [
    ("/dev/zero", "not a regular file (a device)"),
    ("fifo", "not a regular file (a FIFO)"),
    ("dir", "not a regular file (a directory)"),
    ("rows", "10001 rows, more than the 10000"),
    ("big", "more than the 4 MiB a waypoint file may have"),
    ("long", "samples, more than the limit of 1e+06"),
])
def test_feedforward_waypoint_files_are_bounded_before_work(capsys, tmp_path: Path, waypoints: str,
                                                            words: str) -> None:
    path = {"/dev/zero": Path("/dev/zero"), "fifo": tmp_path / "poses", "dir": tmp_path}.get(waypoints,
                                                                                         tmp_path / "poses.csv")
    if waypoints == "fifo":
        os.mkfifo(path)
    elif waypoints == "rows":
        path.write_text("t,x,y\n" + "".join(f"{k * 1e-3},-0.05,0.35\n" for k in range(10001)))
    elif waypoints == "big":
        with path.open("w") as fh:
            fh.write("t,x,y\n0,-0.05,0.35\n1,-0.05,0.36\n")
            fh.truncate(5 * 2**20)  # sparse
    elif waypoints == "long":  # two poses 2000 s apart: 2e6 samples at 1 kHz
        path.write_text("t,x,y\n0,-0.05,0.35\n2000,-0.05,0.36\n")
    out = tmp_path / "tau.csv"
    with _never_blocks():
        line = _one_line(capsys, ["feedforward", "--model", str(FIVE_BAR), "--waypoints", str(path),
                                  "--out", str(out)])
    assert words in line and not out.exists()


@pytest.mark.parametrize("method", ["rigid", "elastic"])
def test_feedforward_rate_is_bounded_before_work(capsys, tmp_path: Path, method: str) -> None:
    out = tmp_path / "tau.csv"
    line = _one_line(capsys, ["feedforward", "--model", str(FIVE_BAR), "--method", method, "--rate", "1e7",
                              "--out", str(out)])
    assert "--rate 1e+07 Hz is more than the 100000 Hz" in line and not out.exists()
