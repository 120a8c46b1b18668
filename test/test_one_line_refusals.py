"""Inputs that were accepted silently, or refused over two lines, end in one clear line (#38 item 5).

An observer configuration is read as a node reads it: no ``ros__parameters`` section, an
integer list for a list of floats, or a file cut in the middle of a line that leaves
parameters at their defaults is refused. An MJCF ``<include>`` of a directory or a FIFO, and a
NaN attribute, are one line at their element (MuJoCo's own warning no longer printed on a line
of its own). ``observe`` on a bag whose stamps of one topic are shuffled says so before any
filtering, instead of diverging into covariance faults.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.cli import MAX_MESSAGE, main

CONFIG = Path(__file__).resolve().parents[1] / "config"
ROBOTS = Path(__file__).resolve().parent / "robots"
FIVE_BAR = CONFIG / "five_bar.yaml"


def _one_line(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("elastic-pm-dyn: error:") and len(err[0]) <= MAX_MESSAGE + 40, err
    return err[0]


def _observe(config: Path) -> list[str]:
    return ["observe", "--model", str(FIVE_BAR), "--bag", "none", "--out", "x", "--config", str(config)]


@pytest.mark.parametrize(("edit", "words"), [
    ("cut", "ends in the middle of a line and leaves"),
    ("plain", "no ros__parameters section"),
    ("int_list", "observer.imu.stddev: [2] holds integers"),
    ("int", "observer.process.dt: 0 is an integer"),
    ("scalar_list", "observer.imu.stddev: a list parameter takes a list"),
])
def test_an_observer_config_a_node_would_refuse_is_one_line(capsys, tmp_path: Path, edit: str, words: str) -> None:
    text = (CONFIG / "observer.yaml").read_text()
    if edit == "cut":
        text = text[:len(text) // 2].rstrip("\n")
        text = text[:text.rindex("#") + 3]  # within a comment: valid YAML, the rest of the file lost
    elif edit == "plain":
        text = "observer:\n  sensors: [encoders]\n  imu:\n    stddev: [0.02]\n"
    elif edit == "int_list":
        assert "stddev: [0.02]" in text
        text = text.replace("stddev: [0.02]", "stddev: [2]", 1)
    elif edit == "int":
        assert "dt: 0.0 " in text
        text = text.replace("dt: 0.0 ", "dt: 0 ", 1)
    else:
        text = text.replace("stddev: [0.02]", "stddev: 0.02", 1)
    path = tmp_path / "observer config.yaml"
    path.write_text(text)
    line = _one_line(capsys, _observe(path))
    assert words in line and str(path) in line


def test_a_whole_observer_config_without_its_last_newline_and_a_partial_one_load(tmp_path: Path) -> None:
    from elastic_pm_dyn.observer.config import load_config
    whole = tmp_path / "whole.yaml"
    whole.write_text((CONFIG / "observer.yaml").read_text().rstrip("\n"))  # every parameter: nothing lost
    assert load_config(whole).parameters == load_config(CONFIG / "observer.yaml").parameters
    partial = tmp_path / "partial.yaml"
    partial.write_text("/**:\n  ros__parameters:\n    observer:\n      sensors: [encoders]\n")
    assert load_config(partial).sensors == ["encoders"]


@pytest.fixture
def mjcf(tmp_path: Path) -> Path:
    pytest.importorskip("mujoco")
    return tmp_path / "robot.xml"


def _with_include(source: str, name: str) -> str:
    assert '<mujoco model="five_bar">' in source
    return source.replace('<mujoco model="five_bar">', f'<mujoco model="five_bar">\n  <include file="{name}"/>', 1)


@pytest.mark.parametrize(("kind", "words"), [("dir", "not a regular file (a directory)"),
                                             ("fifo", "not a regular file (a FIFO)")])
def test_an_mjcf_include_that_is_no_file_is_one_line(capsys, mjcf: Path, kind: str, words: str) -> None:
    target = mjcf.parent / "parts"
    if kind == "dir":
        target.mkdir()
    else:
        os.mkfifo(target)  # MuJoCo would block opening it
    source = (ROBOTS / "five_bar.xml").read_text()
    mjcf.write_text(_with_include(source, "parts"))
    line = _one_line(capsys, ["check", str(mjcf)])
    assert f"{mjcf}:" in line and "include: file 'parts'" in line and words in line


def test_an_mjcf_nan_mass_is_one_line(capsys, mjcf: Path) -> None:
    source = (ROBOTS / "five_bar.xml").read_text()
    assert 'mass="0.6"' in source
    mjcf.write_text(source.replace('mass="0.6"', 'mass="nan"', 1))
    line = _one_line(capsys, ["check", str(mjcf)])
    assert "inertial: mass='nan': NaN" in line


def test_mujoco_warnings_join_the_error_line(mjcf: Path) -> None:
    """A compile error after a MuJoCo warning: both in one line (MuJoCo printed the warning itself)."""
    from elastic_pm_dyn.errors import ModelError
    from elastic_pm_dyn.model.mjcf import compile_mjcf
    source = (ROBOTS / "five_bar.xml").read_text()
    mjcf.write_text(source.replace('mass="0.6"', 'mass="nan"', 1))  # past our own check: MuJoCo's compile
    with pytest.raises(ModelError) as err:
        compile_mjcf(mjcf)
    assert "MuJoCo warned: XML contains a 'NaN'" in str(err.value) and "\n" not in str(err.value)


def test_observe_on_a_bag_with_shuffled_stamps_says_what_is_wrong(capsys, tmp_path: Path) -> None:
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer

    from elastic_pm_dyn.bags.typestore import make_typestore
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer.testing.recordings import EPOCH, RecordingSpec, generate, write_bag
    rec = generate(Mechanism(load_model(FIVE_BAR)), RecordingSpec(duration=0.1, disturbance_rms=0.02, t0=EPOCH,
                                                                  seed=8))
    write_bag(rec, tmp_path / "good", "mcap")
    ts = make_typestore()
    with Reader(tmp_path / "good") as reader:
        messages = [(c.topic, c.msgtype, t, ts.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]
    joint = [m for m in messages if m[0] == "/measured_joint_states"]
    stamps = [(m[3].header.stamp.sec, m[3].header.stamp.nanosec) for m in joint]
    for (_, _, _, msg), k in zip(joint, np.random.default_rng(1).permutation(len(joint)), strict=True):
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamps[k]  # the samples' stamps shuffled
    bag = tmp_path / "shuffled"
    writer = Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    conns: dict = {}
    for topic, msgtype, t_ns, msg in messages:
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
        writer.write(conns[topic], t_ns, ts.serialize_cdr(msg, msgtype))
    writer.close()
    out = tmp_path / "estimates"
    line = _one_line(capsys, ["observe", "--model", str(FIVE_BAR), "--bag", str(bag), "--out", str(out)])
    assert f"{bag}: /measured_joint_states: header stamps go back in time" in line and "shuffled" in line
    assert not out.exists()
    assert main(["observe", "--model", str(FIVE_BAR), "--bag", str(tmp_path / "good"), "--out", str(out),
                 "--no-bag"]) == 0  # the same bag in order: estimates
