"""Bad URDF, sidecar and MJCF files: each mistake is one ModelError line naming file, element and line."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.loader import load_model

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
URDF = (ROBOTS / "five_bar_urdf" / "robot.urdf").read_text()
SIDECAR = (ROBOTS / "five_bar_urdf" / "robot.yaml").read_text()
MJCF = (ROBOTS / "five_bar.xml").read_text()
# The same five-bar with rigid rods. With the rods' springs a weld's extra row (the turn about z)
# is taken up by a spring the loop then fixes (model/loop_springs.py), as MuJoCo would simulate it;
# without them the weld locks the motors: a file that cannot load.
RIGID_URDF = URDF.replace('name="left_spring" type="prismatic"', 'name="left_spring" type="fixed"').replace(
    'name="right_spring" type="prismatic"', 'name="right_spring" type="fixed"')
RIGID_SIDECAR = re.sub(r"(elastic|branches):\n(  .*\n)+", "", SIDECAR)
RIGID_MJCF = re.sub(r'\s*<joint name="(left|right)_spring"[^>]*/>', "", MJCF).replace(
    'qpos="2.6 0 -1.9 0.87 0 1.8"', 'qpos="2.6 -1.9 0.87 1.8"')


def _line_of(text: str, needle: str) -> int:
    return text[:text.index(needle)].count("\n") + 1


def _error(tmp_path: Path, urdf: str = URDF, sidecar: str | None = SIDECAR, name: str = "robot.urdf") -> str:
    (tmp_path / name).write_text(urdf)
    if sidecar is not None:
        (tmp_path / "robot.yaml").write_text(sidecar)
    with pytest.raises(ModelError) as exc:
        load_model(tmp_path / name)
    message = str(exc.value)
    assert "\n" not in message and message.startswith(str(tmp_path))
    return message


URDF_CASES = [
    ("floating", URDF.replace('name="left_motor" type="revolute"', 'name="left_motor" type="floating"'),
     'name="left_motor" type="floating"', "floating joint is not supported"),
    ("unknown type", URDF.replace('name="left_elbow" type="continuous"', 'name="left_elbow" type="screw"'),
     'name="left_elbow" type="screw"', "unknown joint type 'screw'"),
    ("missing link", URDF.replace('<child link="left_forearm"/>', '<child link="left_forarm"/>'),
     '<child link="left_forarm"/>', "missing link 'left_forarm'"),
    ("bad number", URDF.replace('<origin xyz="-0.10 0 0" rpy="0 0 0"/>', '<origin xyz="-0.10 0" rpy="0 0 0"/>'),
     '<origin xyz="-0.10 0"', "xyz: expected 3 numbers, got 2"),
    ("negative mass", URDF.replace('<mass value="0.6"/>', '<mass value="-0.6"/>', 1),
     '<mass value="-0.6"/>', "mass must be >= 0"),
    ("bad inertia", URDF.replace('iyy="3.125e-3" iyz="0" izz="3.125e-3"', 'iyy="-3.125e-3" iyz="0" izz="3.125e-3"', 1),
     'iyy="-3.125e-3"', "not positive semi-definite"),
    ("mimic", URDF.replace('<axis xyz="0 0 1"/>\n  </joint>', '<axis xyz="0 0 1"/>\n    <mimic joint="rigth_elbow"/>\n'
                           '  </joint>', 1), '<mimic joint=', "<mimic> names a missing joint 'rigth_elbow'"),
    ("malformed", URDF.replace("</robot>", "</robt>"), "</robt>", "malformed XML"),
    ("doctype", '<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY a "aaaa">]>\n' + URDF.split("?>", 1)[1],
     "<!DOCTYPE", "DOCTYPE"),
    ("joint cycle", URDF.replace("</robot>", '  <joint name="back" type="revolute"><parent link="left_forearm"/>'
                                 '<child link="left_upper_arm"/><axis xyz="0 0 1"/></joint>\n</robot>'),
     '<joint name="back"', "already has a parent joint"),
    ("two parents", URDF.replace("</robot>", '  <joint name="extra" type="fixed"><parent link="base_link"/>'
                                 '<child link="closure_right"/></joint>\n</robot>'),
     '<joint name="extra"', "already has a parent joint"),
]


@pytest.mark.parametrize("urdf, needle, expected", [c[1:] for c in URDF_CASES], ids=[c[0] for c in URDF_CASES])
def test_bad_urdf_is_one_line_with_file_and_line(tmp_path, urdf, needle, expected):
    message = _error(tmp_path, urdf)
    assert expected in message
    assert message.startswith(f"{tmp_path / 'robot.urdf'}:{_line_of(urdf, needle)}:"), message


SIDECAR_CASES = [
    ("unknown frame", SIDECAR.replace("['closure_left', 'closure_right']", "['closure_left', 'closure_rigth']"),
     "closed_loop:", "no frame (link or joint) 'closure_rigth'"),
    ("6d", RIGID_SIDECAR.replace("type: ['3d']", "type: ['6d']"), "closed_loop:",
     "the closures give 3 equations but the legs have 2 passive joints"),  # planar: a weld adds the turn about z
    ("unknown motor", SIDECAR.replace("name_mot: ['left_motor', 'right_motor']", "name_mot: ['left_motor', 'rmotor']"),
     "name_mot:", "no joint 'rmotor'"),
    ("same body", SIDECAR.replace("['closure_left', 'closure_right']", "['closure_left', 'left_forearm']"),
     "closed_loop:", "are both on one body of leg 'left_upper_arm': no joint between them, so the closure makes "
     "no loop"),
    ("unknown key", SIDECAR + "stifness: 3\n", "stifness", "unknown key"),
    ("counts", SIDECAR.replace("name_mot: ['left_motor', 'right_motor']", "name_mot: ['left_motor']"),
     "closed_loop:", "the closures give 2 equations but the legs have 3 passive joints"),
]


@pytest.mark.parametrize("sidecar, needle, expected", [c[1:] for c in SIDECAR_CASES], ids=[c[0] for c in SIDECAR_CASES])
def test_bad_sidecar_is_one_line_with_its_line(tmp_path, sidecar, needle, expected):
    urdf = URDF if "elastic:" in sidecar else RIGID_URDF  # a sidecar without springs goes with rigid rods
    message = _error(tmp_path, urdf, sidecar)
    assert expected in message
    assert message.startswith(f"{tmp_path / 'robot.yaml'}:{_line_of(sidecar, needle)}:"), message


def test_closure_between_two_base_frames_makes_no_loop(tmp_path):
    urdf = URDF.replace("</robot>", '  <joint name="mark_frame" type="fixed"><parent link="base_link"/>'
                        '<child link="mark"/><origin xyz="0.1 0 0" rpy="0 0 0"/></joint>\n'
                        '  <link name="mark"/>\n</robot>')
    sidecar = SIDECAR.replace("['closure_left', 'closure_right']", "['base_link', 'mark']")
    message = _error(tmp_path, urdf, sidecar)
    assert "frames 'base_link' and 'mark' are both on the fixed base: no joint between them" in message
    assert message.startswith(f"{tmp_path / 'robot.yaml'}:{_line_of(sidecar, 'closed_loop:')}:"), message


def test_urdf_without_sidecar(tmp_path):
    message = _error(tmp_path, sidecar=None)
    assert "robot.yaml next to it" in message


def test_planar_true_with_an_axis_off_the_plane(tmp_path):
    urdf = URDF.replace('<axis xyz="0 0 1"/>', '<axis xyz="0 1 0"/>', 1)  # the left motor now turns about y
    message = _error(tmp_path, urdf, SIDECAR + "planar: true\n")
    assert "planar: true, but joint" in message and "does not move in the plane normal to" in message


MJCF_CASES = [
    ("free joint", MJCF.replace('<joint name="left_motor" type="hinge"', '<joint name="left_motor" type="free"')
     .replace(' axis="0 0 1" armature="1e-4"/>', ' armature="1e-4"/>', 1).replace(
         '<motor name="left" joint="left_motor"/>', ''), '<joint name="left_motor" type="free"', "free joint"),
    ("weld", RIGID_MJCF.replace('<connect site1="closure_left" site2="closure_right"',
                                '<weld name="w" site1="closure_left" site2="closure_right"'),
     '<weld name="w"', "the loops lock motors left_motor, right_motor"),  # 3 equations for 2 passive joints
    ("compiler", MJCF.replace('stiffness="5.464e6"', 'stifness="5.464e6"', 1), 'stifness=', "MuJoCo:"),
    ("servo", MJCF.replace('<motor name="right" joint="right_motor"/>',
                           '<general name="right" joint="right_motor" gaintype="affine" gainprm="1 2 0"/>'),
     '<general name="right"', "not supported yet: an actuator whose gain is not fixed"),
]


@pytest.mark.parametrize("mjcf, needle, expected", [c[1:] for c in MJCF_CASES], ids=[c[0] for c in MJCF_CASES])
def test_bad_mjcf_is_one_line_with_file_and_line(tmp_path, mjcf, needle, expected):
    pytest.importorskip("mujoco")
    message = _error(tmp_path, mjcf, sidecar=None, name="robot.xml")
    assert expected in message
    assert message.startswith(f"{tmp_path / 'robot.xml'}:{_line_of(mjcf, needle)}:"), message


def test_what_was_not_supported_loads_now(tmp_path):
    """A branch inside a leg (a tool on the upper arm, sprung), a closure frame on a leg's inner
    body and a closure to the fixed base load as subtrees: the counts decide, as for any file."""
    tool = URDF.replace("</robot>", '  <joint name="tool" type="revolute"><parent link="left_upper_arm"/>'
                        '<child link="tool_link"/><axis xyz="0 0 1"/></joint>\n'
                        '  <link name="tool_link"><inertial><mass value="0.1"/>'
                        '<inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial></link>\n'
                        '</robot>')
    sprung = SIDECAR.replace("elastic:", "elastic:\n  tool: {stiffness: 10.0}")
    for urdf, sidecar, check in (
            (tool, sprung, lambda m: m.chains[0].parents and m.joint_names[:4] == ["left_motor", "left_spring",
                                                                                  "left_elbow", "tool"]),
            (URDF, SIDECAR.replace("['closure_left', 'closure_right']", "['left_elbow_housing', 'closure_right']"),
             lambda m: m.chains[0].end_body == 1),
            (URDF, SIDECAR.replace("['closure_left', 'closure_right']", "['base_link', 'closure_right']"),
             lambda m: len(m.fixed_points) == 1)):
        (tmp_path / "robot.urdf").write_text(urdf)
        (tmp_path / "robot.yaml").write_text(sidecar)
        assert check(load_model(tmp_path / "robot.urdf"))
