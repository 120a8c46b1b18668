"""The CLI takes every model format the loader does: --closures for a URDF's sidecar, the
`urdf` command, and simulate's --elastic-dof-per-chain."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.model.loader import load_model

ROOT = Path(__file__).resolve().parents[1].parent
ROBOTS = Path(__file__).resolve().parents[1] / "robots"


def test_urdf_command_writes_a_urdf_with_every_tree_joint(tmp_path, capsys) -> None:
    out = tmp_path / "five_bar.urdf"
    assert main(["urdf", str(ROOT / "config" / "five_bar.yaml"), "--out", str(out)]) == 0
    robot = ET.parse(out).getroot()
    names = {j.get("name") for j in robot.iter("joint")}
    model = load_model(ROOT / "config" / "five_bar.yaml")
    assert {j.name for j in model.joints} <= names


def test_a_sidecar_named_with_closures_is_used(tmp_path, capsys) -> None:
    """The URDF copied away from its robot.yaml: without --closures no loop, with it the five-bar."""
    urdf = tmp_path / "elsewhere" / "five_bar.urdf"
    urdf.parent.mkdir()
    shutil.copy(ROBOTS / "five_bar_urdf" / "robot.urdf", urdf)
    sidecar = tmp_path / "loops.yaml"
    shutil.copy(ROBOTS / "five_bar_urdf" / "robot.yaml", sidecar)
    assert main(["check", str(urdf), "--closures", str(sidecar)]) == 0
    text = capsys.readouterr().out
    assert "closure equations 2" in text and "closure residual" in text


def test_simulate_takes_elastic_dof_per_chain(tmp_path, capsys) -> None:
    model = load_model(ROOT / "config" / "triglide.yaml")
    active = [j.name for j in model.joints if j.role == "active"]
    torques = tmp_path / "tau.csv"
    torques.write_text("t," + ",".join(active) + "\n0," + ",".join("0" for _ in active) + "\n")
    cols = {}
    for dof in (1, 2):
        out = tmp_path / f"run{dof}.csv"
        assert main(["simulate", "--model", str(ROOT / "config" / "triglide.yaml"), "--torques", str(torques),
                     "--duration", "0.002", "--out", str(out), "--elastic-dof-per-chain", str(dof)]) == 0
        cols[dof] = out.read_text().splitlines()[0].split(",")
    assert len(cols[2]) > len(cols[1])  # more elastic joints, more columns
    assert np.isfinite(np.loadtxt(tmp_path / "run2.csv", delimiter=",", skiprows=1)).all()
