"""Bad run input: a clear one-line error, nothing lost."""

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.errors import AssemblyError, InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque, TorqueTable, load_torque_csv

CONFIG = Path(__file__).resolve().parent.parent / "config"
FIVE_BAR = str(CONFIG / "five_bar.yaml")
NAMES = ["left_motor", "right_motor"]


def _csv(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "tau.csv"
    p.write_text(text)
    return p


def test_unknown_joint_in_torque_csv(tmp_path: Path) -> None:
    p = _csv(tmp_path, "t,left_motor,middle_motor\n0,1,2\n")
    with pytest.raises(InputError, match=r"line 1: unknown joint.*middle_motor.*active joints: left_motor"):
        load_torque_csv(p, NAMES)


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf"])
def test_nan_or_inf_torque_names_line_and_column(tmp_path: Path, bad: str) -> None:
    p = _csv(tmp_path, f"t,left_motor,right_motor\n0,1,2\n0.001,{bad},2\n")
    with pytest.raises(InputError, match=r"line 3: NaN or Inf in column.*left_motor"):
        load_torque_csv(p, NAMES)


def test_columns_may_come_in_any_order(tmp_path: Path) -> None:
    table = load_torque_csv(_csv(tmp_path, "t,right_motor,left_motor\n0,2,1\n"), NAMES)
    assert np.all(table.values[0] == [1, 2])


@pytest.mark.parametrize(("text", "words"), [
    ("t,left_motor\n0,1\n", "missing column.*right_motor"),
    ("time,left_motor,right_motor\n0,1,2\n", "first column must be 't'"),
    ("t,left_motor,right_motor\n0,1\n", "line 2: expected 3 values"),
    ("t,left_motor,right_motor\n0,1,x\n", "line 2"),
    ("t,left_motor,right_motor\n0,1,2\n0,1,2\n", "increase strictly"),
])
def test_other_torque_table_mistakes(tmp_path: Path, text: str, words: str) -> None:
    with pytest.raises(InputError, match=words):
        load_torque_csv(_csv(tmp_path, text), NAMES)


def test_zero_order_hold_sample_acts_until_the_next() -> None:
    table = TorqueTable(np.array([0.0, 0.001]), np.array([[1.0, 0.0], [2.0, 0.0]]))
    assert table.value(0.0)[0] == 1.0 and table.value(0.000999)[0] == 1.0 and table.value(0.001)[0] == 2.0
    with pytest.raises(InputError, match="NaN or Inf"):
        TorqueTable(np.array([0.0]), np.array([[np.nan, 0.0]]))


def test_unreachable_start_pose() -> None:
    text = (CONFIG / "five_bar.yaml").read_text().replace("end_effector: [-0.05, 0.35]", "end_effector: [0.0, 0.9]")
    mech = Mechanism(parse_model(YamlSource(text, "far.yaml")))
    with pytest.raises(AssemblyError, match="cannot assemble the end-effector target: residual"):
        initial_state(mech)


def test_wrong_assembly_mode_is_an_error() -> None:
    text = (CONFIG / "five_bar.yaml").read_text().replace(
        "assembly_mode: {left_elbow: negative", "assembly_mode: {left_elbow: positive")
    with pytest.raises(AssemblyError, match="wrong assembly mode: left_elbow"):
        initial_state(Mechanism(parse_model(YamlSource(text, "mode.yaml"))))


def test_singular_configuration_reached_in_a_run_keeps_the_partial_output(five_bar) -> None:
    """Motor torques pull the forearms into line (the rigid machine's parallel singularity):
    L-D'A, which inverts dh/dq_p, stops with time and residual; the samples so far are kept.
    The elastic machine itself passes there: SCDD integrates through."""
    torque = ConstantTorque(np.array([1.0, -1.0]))
    with pytest.raises(SingularConfigurationError) as exc:
        Simulator(five_bar, SimulationOptions(formulation="lda", sample=0.005)).run(torque, 1.0)
    err = exc.value
    assert 0.3 < err.time < 1.0 and err.residual is not None
    assert f"t = {err.time:.6g} s" in str(err) and "dh/dq_p" in str(err)
    assert err.partial is not None and err.partial.t[-1] <= err.time and len(err.partial.t) > 50
    assert err.partial.gap.max() <= 1e-12  # what was kept is good
    r = Simulator(five_bar, SimulationOptions(formulation="scdd", sample=0.005)).run(torque, 1.0)
    assert r.gap.max() <= 1e-12


def test_cli_reports_user_errors_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    p = _csv(tmp_path, "t,left_motor,middle_motor\n0,1,2\n")
    code = main(["simulate", "--model", FIVE_BAR, "--torques", str(p), "--duration", "0.1",
                 "--out", str(tmp_path / "o.csv")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err and "middle_motor" in err
    code = main(["simulate", "--model", str(tmp_path / "nope.yaml"), "--torques", str(p), "--duration", "0.1",
                 "--out", str(tmp_path / "o.csv")])
    assert code == 2 and "cannot read file" in capsys.readouterr().err
    assert main(["check", str(tmp_path / "nope.yaml")]) == 2


def test_cli_singular_run_writes_partial_csv(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    p = _csv(tmp_path, "t,left_motor,right_motor\n0,1.0,-1.0\n")
    out = tmp_path / "run.csv"
    code = main(["simulate", "--model", FIVE_BAR, "--torques", str(p), "--duration", "1.0", "--method", "lda",
                 "--out", str(out)])
    assert code == 1
    assert "singular configuration" in capsys.readouterr().err
    rows = out.read_text().splitlines()
    assert rows[0].startswith("t,left_motor,left_spring") and len(rows) > 100


def test_cli_blow_up_is_named_as_such_not_as_a_singularity(tmp_path) -> None:
    """1e6 N m on the reference five-bar: the CLI says the state diverged (|qdd|, step or torque),
    never 'singular configuration', keeps the rows before it and exits 1 (a failed run)."""
    import subprocess
    import sys
    csv = tmp_path / "big.csv"
    csv.write_text("t,left_motor,right_motor\n0,1e6,-1e6\n1,1e6,-1e6\n")
    out = tmp_path / "run.csv"
    p = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "simulate", "--model", str(CONFIG / "five_bar.yaml"),
                        "--torques", str(csv), "--duration", "0.2", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 1, p.stderr
    assert "state diverged at t = " in p.stderr and "step too large or torque too high" in p.stderr
    assert "singular" not in p.stderr and "Traceback" not in p.stderr
    assert out.exists()
