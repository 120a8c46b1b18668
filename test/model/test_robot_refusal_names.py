"""Refusal lines that name what is wrong: the motors a loop locks or ties, and for a misspelt
name in a closure sidecar the nearest name the file has."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.loader import load_model

RSSR = Path(__file__).resolve().parents[1] / "robots" / "rssr_misspelt"


def _refusal(path: Path, **kwargs) -> tuple[str, list[str]]:
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with pytest.raises(ModelError) as err:
            load_model(path, **kwargs)
    line = str(err.value)
    assert "\n" not in line
    return line, [str(w.message) for w in seen]


def test_a_misspelt_ball_locks_the_motor_and_the_line_says_so_and_what_was_meant():
    line, said = _refusal(RSSR / "robot.urdf")
    assert "the loops lock motor crank_motor" in line
    assert "the sidecar re-types no joint 'sherical_crank' (nearest: 'spherical_crank')" in line
    assert any("no joint 'sherical_crank'" in w and "(nearest: 'spherical_crank')" in w for w in said)


def test_the_sidecar_spelt_right_loads(tmp_path):
    text = (RSSR / "robot.yaml").read_text().replace("sherical_crank", "spherical_crank")
    (tmp_path / "robot.yaml").write_text(text)
    model = load_model(RSSR / "robot.urdf", closures=tmp_path / "robot.yaml")
    assert model.active_names == ["crank_motor"]


@pytest.mark.parametrize(("key", "wrong", "right"), [("name_mot", "crank_motr", "crank_motor"),
                                                     ("closed_loop", "roker_end", "rocker_end")])
def test_a_misspelt_sidecar_name_is_refused_with_the_nearest(tmp_path, key, wrong, right):
    text = (RSSR / "robot.yaml").read_text().replace("sherical_crank", "spherical_crank")
    text = text.replace(right, wrong)
    (tmp_path / "robot.yaml").write_text(text)
    line, _ = _refusal(RSSR / "robot.urdf", closures=tmp_path / "robot.yaml")
    assert f"{wrong!r}" in line and f"(nearest: {right!r})" in line


FOUR_BAR_TWO_MOTORS = """<mujoco model="four_bar_two_motors">
  <compiler angle="radian"/>
  <worldbody>
    <body name="crank">
      <joint name="crank" axis="0 0 1"/>
      <inertial pos="0.05 0 0" mass="0.2" diaginertia="1e-5 2e-4 2e-4"/>
      <body name="coupler" pos="0.1 0 0" euler="0 0 1.2">
        <joint name="coupler" axis="0 0 1"/>
        <inertial pos="0.15 0 0" mass="0.3" diaginertia="1e-5 2e-3 2e-3"/>
      </body>
    </body>
    <body name="rocker" pos="0.3 0 0" euler="0 0 1.9">
      <joint name="rocker" axis="0 0 1"/>
      <inertial pos="0.1 0 0" mass="0.2" diaginertia="1e-5 6e-4 6e-4"/>
    </body>
  </worldbody>
  <equality><connect body1="coupler" body2="rocker" anchor="0.3 0 0"/></equality>
  <actuator><motor joint="crank"/><motor joint="rocker"/></actuator>
</mujoco>
"""


def test_two_motors_on_one_four_bar_are_named_as_tied(tmp_path):
    """MuJoCo's connect closes at qpos0 (its anchor in body2 is taken there): a one-DOF four-bar
    with a motor on its crank and one on its rocker."""
    path = tmp_path / "four_bar.xml"
    path.write_text(FOUR_BAR_TWO_MOTORS)
    line, _ = _refusal(path)
    assert "the loops tie motors crank, rocker (they move only together" in line


def test_a_joint_nothing_holds_is_named_at_its_own_line(tmp_path):
    """ToddlerBot's waist as published nests the gear motors in the pelvis; with its roll
    tendon's range widened past a coupling's, beside a four-bar, the roll joint is held by
    nothing: the line points at it, not at the four-bar's connect."""
    import re
    waist = Path(__file__).resolve().parents[1] / "robots" / "menagerie_style" / "waist.xml"
    text = waist.read_text().replace('range="0 0.001"', 'range="-0.5 0.5"')
    gears = re.findall(r'    <body name="gear_\d".*?</body>\n', text, flags=re.S)
    for gear in gears:
        text = text.replace(gear, "")
    torso = '<inertial pos="0.01 0.02 0.08" mass="0.6" diaginertia="2e-3 2e-3 1e-3"/>\n'
    text = text.replace(torso, torso + "".join(gears))  # the gears ride on the torso, as ToddlerBot's
    four_bar = FOUR_BAR_TWO_MOTORS.split("<worldbody>")[1].split("</worldbody>")[0]
    text = text.replace("  </worldbody>", four_bar + '  </worldbody>\n  <equality><connect body1="coupler" '
                        'body2="rocker" anchor="0.3 0 0"/></equality>')
    text = text.replace('<motor name="waist_act_2" joint="waist_act_2"/>',
                        '<motor name="waist_act_2" joint="waist_act_2"/>\n    <motor joint="crank"/>')
    text = text.replace('<key qpos="0.2 -0.1 0 0"/>', '<key qpos="0 0 0.2 -0.1 0 0 0"/>')
    path = tmp_path / "waist.xml"
    path.write_text(text)
    line, _ = _refusal(path)
    joint_line = text.splitlines().index('        <joint name="waist_roll" axis="1 0 0"/>') + 1
    assert line.startswith(f"{path}:{joint_line}: joint 'waist_roll': under-actuated"), line
    assert "held waist_roll (on no loop" in line
