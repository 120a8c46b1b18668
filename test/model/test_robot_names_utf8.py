"""Joint names outside Latin-1 (Gepetto's ``left_sĥerical_free_foot``, Greek, CJK) through every
command that reads a robot file: the files written hold them in UTF-8 and read back, and a
terminal that cannot show them gets them escaped, never a UnicodeEncodeError traceback."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from elastic_pm_dyn.cli import main

REPO = Path(__file__).resolve().parents[1].parent
ROBOTS = REPO / "test" / "robots"
NAMES = {"left_motor": "left_sĥerical_free_foot", "right_motor": "δεξιός_κινητήρας", "left_elbow": "左肘",
         "right_spring": "ressort_droit_é"}


def _renamed(text: str) -> str:
    for old, new in NAMES.items():
        text = re.sub(rf"(?<!\w){old}(?!\w)", new, text)
    return text


@pytest.fixture
def mjcf(tmp_path: Path) -> Path:
    path = tmp_path / "fünf_stäbe.xml"
    path.write_text(_renamed((ROBOTS / "five_bar.xml").read_text(encoding="utf-8")), encoding="utf-8")
    return path


@pytest.fixture
def urdf(tmp_path: Path) -> Path:
    folder = tmp_path / "urdf"
    folder.mkdir()
    for name in ("robot.urdf", "robot.yaml"):
        text = (ROBOTS / "five_bar_urdf" / name).read_text(encoding="utf-8")
        (folder / name).write_text(_renamed(text), encoding="utf-8")
    return folder / "robot.urdf"


def _header(path: Path) -> list[str]:
    return path.read_bytes().decode("utf-8").splitlines()[0].split(",")


@pytest.mark.parametrize("kind", ["mjcf", "urdf"])
def test_names_go_through_check_feedforward_simulate_and_urdf(kind, mjcf, urdf, tmp_path, capsys):
    model = mjcf if kind == "mjcf" else urdf
    assert main(["check", str(model)]) == 0
    shown = capsys.readouterr().out
    assert "left_sĥerical_free_foot" in shown and "δεξιός_κινητήρας" in shown and "左肘" in shown
    torques = tmp_path / "τ.csv"
    assert main(["feedforward", "--model", str(model), "--out", str(torques), "--move", "0.02", "--hold", "0"]) == 0
    assert _header(torques) == ["t", "left_sĥerical_free_foot", "δεξιός_κινητήρας"]
    out = tmp_path / "运动.csv"
    assert main(["simulate", "--model", str(model), "--torques", str(torques), "--duration", "0.005",
                 "--out", str(out)]) == 0  # the feedforward's table read back by its names
    header = _header(out)
    for name in ("left_sĥerical_free_foot", "左肘_vel", "F_ressort_droit_é" if kind == "mjcf" else "左肘",
                 "tau_δεξιός_κινητήρας"):
        assert name in header
    written = tmp_path / "robot_out.urdf"
    assert main(["urdf", str(model), "--out", str(written)]) == 0
    assert "左肘" in written.read_text(encoding="utf-8")


def test_a_terminal_that_cannot_show_a_name_gets_it_escaped(mjcf):
    """A Latin-1 (or ASCII) console: the line is printed with the name escaped, exit 0."""
    env = dict(os.environ, PYTHONIOENCODING="latin-1", PYTHONPATH=str(REPO))
    run = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "check", str(mjcf)], env=env, capture_output=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr.decode("latin-1")[-400:]
    out = run.stdout.decode("latin-1")
    assert "\\u5de6\\u8098" in out  # 左肘, escaped
    assert "left_s\\u0125erical_free_foot" in out
    assert "Traceback" not in run.stderr.decode("latin-1")


def test_a_refusal_names_the_joint_as_written(tmp_path, capsys):
    """An error line that quotes a non-Latin name (a torque column no motor has) keeps it readable."""
    model = tmp_path / "m.xml"
    model.write_text(_renamed((ROBOTS / "five_bar.xml").read_text(encoding="utf-8")), encoding="utf-8")
    torques = tmp_path / "t.csv"
    torques.write_text("t,left_sĥerical_free_foot,δεξιός_κινητήρα\n0,0,0\n", encoding="utf-8")
    assert main(["simulate", "--model", str(model), "--torques", str(torques), "--duration", "0.001",
                 "--out", str(tmp_path / "o.csv")]) == 2
    assert "δεξιός_κινητήρα" in capsys.readouterr().err


def test_names_go_through_a_bag_and_its_csv_export(tmp_path):
    """A joint state with the names, written by the package's bag writer, read back and
    exported: the names are the same strings, the CSV header UTF-8."""
    from bag_factory import Messages

    from elastic_pm_dyn.analysis.export import export_bag
    from elastic_pm_dyn.bags.msgtypes import JOINT_STATE
    from elastic_pm_dyn.bags.reader import open_bag
    from elastic_pm_dyn.bags.typestore import make_typestore
    from elastic_pm_dyn.bags.writer import BagWriter
    names = list(NAMES.values())
    ts = make_typestore()
    bag = tmp_path / "バッグ"
    with BagWriter(bag, "mcap", ts) as w:
        conn = w.add_connection("/joint_states", JOINT_STATE)
        for k in range(3):
            w.write_message(conn, 10**9 + k * 10**6, Messages(ts).joint_state(k * 1e-3, names, [0.1 * k] * 4))
    with open_bag(bag) as reader:
        read = [msg.name for _, _, msg in reader.decoded([c for c in reader.connections])]
    assert read == [names] * 3
    exported = export_bag(bag, tmp_path / "csv")
    header = exported[0].file.read_bytes().decode("utf-8").splitlines()[0]
    assert "position.左肘" in header and "position.left_sĥerical_free_foot" in header


def test_the_written_urdf_and_sidecar_hold_the_names_as_written(mjcf, tmp_path):
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.model.urdf_writer import closure_sidecar, model_to_urdf
    model = load_model(mjcf)
    (tmp_path / "robot.urdf").write_text(model_to_urdf(model), encoding="utf-8")
    (tmp_path / "robot.yaml").write_text(closure_sidecar(model), encoding="utf-8")
    assert "left_sĥerical_free_foot" in (tmp_path / "robot.yaml").read_text(encoding="utf-8")  # not \u escapes
    assert load_model(tmp_path / "robot.urdf").joint_names == model.joint_names
