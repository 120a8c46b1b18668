"""Closure rows that repeat other loops' rows (issue #26): a body closed twice is reduced
exactly, as rows that hold by themselves are, and the machine matches MuJoCo (constraints
tightened) on the same file. Here the welded-knees leg of test_published_constructs with its
first knee's rocker also joined to its top by a <connect> at a point off the weld: the
connect's rows repeat the weld's (pos + turn x offset)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_published_constructs import DURATION, SAMPLE, WELD_LEG, _mujoco_run

from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

CLOSED_TWICE = WELD_LEG.replace(
    '<weld body1="rocker2_top" body2="rocker2"/>',
    '<weld body1="rocker2_top" body2="rocker2"/>\n'
    '    <connect body1="rocker_top" body2="rocker" anchor="-0.03 0.02 0.01"/>')


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "robot.xml"
    path.write_text(text)
    return path


# the same knee welded twice (the second weld written rocker to rocker_top): its three rows that
# do not hold by themselves (the two positions across the hinges, the turn about them) repeat the
# first weld's
WELDED_TWICE = CLOSED_TWICE.replace('<connect body1="rocker_top" body2="rocker" anchor="-0.03 0.02 0.01"/>',
                                    '<weld body1="rocker" body2="rocker_top"/>')


@pytest.mark.parametrize(("text", "repeated"), [(CLOSED_TWICE, 0b011), (WELDED_TWICE, 0b100011)],
                         ids=["weld-and-connect", "two-welds"])
def test_a_body_closed_twice_is_reduced_and_matches_mujoco(tmp_path, text, repeated):
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    path = _write(tmp_path, text)
    mech = Mechanism(load_model(path))
    closure = mech.model.closure
    # pair 3's rows that do not hold by themselves all repeat the first weld's
    assert len(closure.pairs) == 3 and dict(closure.repeated) == {2: repeated}
    assert mech.m == 6 and len(mech.passive) == 6  # 6 + 6 + 3 rows in the file, 6 kept
    q0 = initial_state(mech)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque([0.0, 0.0, 0.0]), DURATION)
    assert float(np.abs(run.gap).max()) < 1e-9
    peer = _mujoco_run(path, mech.joint_names, q0, len(run.t))
    roll = mech.joint_names.index("roll")
    err = float(np.abs(peer - run.q).max())
    print(f"\nknee closed twice ({bin(repeated)} repeated) against MuJoCo (tightened): roll moved "
          f"{abs(run.q[-1, roll] - q0[roll]):.3g} rad, "
          f"max |q - q_mujoco| {err:.2e} rad")
    assert abs(run.q[-1, roll] - q0[roll]) > 0.05
    assert err < 1e-6


def test_check_says_which_rows_repeat_other_loops(tmp_path):
    path = _write(tmp_path, CLOSED_TWICE)
    out = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "check", str(path)], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    dropped = [line for line in out.stdout.splitlines() if line.strip().startswith("dropped")]
    again = [line for line in dropped if "repeat rows of the other closures" in line]
    assert len(again) == 1 and "closure 3" in again[0], out.stdout
    assert any("holds by itself" in line and "closure 3" in line for line in dropped), out.stdout


def test_a_weld_that_contradicts_another_is_still_refused_in_one_line(tmp_path):
    """Two welds of one body pair at different turns: no pose holds both (inconsistent, not repeated)."""
    from elastic_pm_dyn.errors import ModelError
    text = CLOSED_TWICE.replace('<connect body1="rocker_top" body2="rocker" anchor="-0.03 0.02 0.01"/>',
                                '<weld body1="rocker_top" body2="rocker" relpose="0 0 0 0.9 0.4 0 0"/>')
    with pytest.raises(ModelError) as err:
        load_model(_write(tmp_path, text))
    message = str(err.value)
    assert "\n" not in message and "robot.xml" in message and "cannot all hold" in message
    lines = [n for n, row in enumerate(text.splitlines(), 1) if "<weld body1=\"rocker_top\"" in row]
    assert all(f"(line {n})" in message for n in lines), message  # both welds of the pair, by line
