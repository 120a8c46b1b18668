"""Repeated closure rows of truly 3-D machines (issue #26): a spatial parallelogram platform and a
model YAML ``type: point`` closure, both checked by physics as test_repeated_planar.py checks the
planar ones (the residual of every row of the file, dropped ones too, over a simulated motion;
energy; the accelerations of all the file's rows by a least-squares KKT solve; MuJoCo with its
constraints tightened on the same machine).

The platform: a body on three slides (it only translates) hung from three rods, each on a
universal joint (two hinges) at a base right above its platform point, the points spread in 3-D
(not in a plane with the bases). As in a Delta robot's parallelogram, every rod then keeps the
direction of the first, so the platform moves on a sphere (2 DOF, the first rod's two motors)
and each further rod's row along itself (its length) repeats the first rod's: 9 rows, 7 passive
joints. The third rod's universal joint is turned 45 degrees about the vertical, so its angles
differ from the first rod's while its direction does not.

The point closure: a carriage on three slides (a passive gantry) whose point two rods from one
pivot hold (a link doubled for stiffness), the second's universal joint turned 45 degrees: 6 rows,
5 passive joints; the second rod's length repeats the first's (rows in the carriage's frame: the
vertical one is dropped, the two across kept).
"""

from __future__ import annotations

import numpy as np
from test_published_constructs import _mujoco_run, _write
from test_repeated_planar import _physics

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

C = 0.7071067811865476  # cos 45 degrees: the turned universal joints' axes


def _rod(name: str, role: str, base: str, axes: tuple[str, str], mass: float) -> str:
    """A rod of 0.3 m on a universal joint (hinge about axes[0], then axes[1]) at ``base``, hanging along -z."""
    return f"""  - name: {name}
    joints:
      - {{name: {name}_a, type: revolute, role: {role}, axis: {axes[0]}, origin: {{xyz: {base}}}}}
      - name: {name}_b
        type: revolute
        role: {role}
        axis: {axes[1]}
        body: {{mass: {mass}, com: [0.0, 0.0, -0.15], inertia: {{ixx: 1.5e-3, iyy: 1.5e-3, izz: 1.0e-5}}}}
    end: {{xyz: [0.0, 0.0, -0.3]}}
"""


def _mj_rod(name: str, base: str, axes: tuple[str, str], mass: float, tip: str) -> str:
    return f"""    <body name="{name}" pos="{base}">
      <joint name="{name}_a" type="hinge" axis="{axes[0]}"/>
      <joint name="{name}_b" type="hinge" axis="{axes[1]}"/>
      <inertial pos="0 0 -0.15" mass="{mass}" diaginertia="1.5e-3 1.5e-3 1e-5"/>
      <site name="{tip}" pos="0 0 -0.3"/>
    </body>
"""


STRAIGHT = ("[1, 0, 0]", "[0, 1, 0]")
TURNED = (f"[{C}, {C}, 0]", f"[-{C}, {C}, 0]")
MJ_STRAIGHT = ("1 0 0", "0 1 0")
MJ_TURNED = (f"{C} {C} 0", f"-{C} {C} 0")
POINTS = {"a1": (0.0, 0.0, 0.0), "a2": (0.3, 0.0, 0.05), "a3": (0.1, 0.25, -0.05)}  # on the platform


def _base(point: str, sep: str = ", ") -> str:
    x, y, z = POINTS[point]
    text = sep.join(f"{v:g}" for v in (x, y, z + 0.3))
    return f"[{text}]" if sep == ", " else text


SLIDES = """      - {{name: {p}_x, type: prismatic, role: passive, axis: [1, 0, 0]}}
      - {{name: {p}_y, type: prismatic, role: passive, axis: [0, 1, 0]}}
      - name: {p}_z
        type: prismatic
        role: passive
        axis: [0, 0, 1]
        body: {{mass: {mass}, com: {com}, inertia: {{ixx: 2.0e-3, iyy: 3.0e-3, izz: 4.0e-3}}}}
"""

PLATFORM = ("""name: spatial_parallelogram
gravity: [0.0, 0.0, -9.81]
elastic_dof_per_chain: 0
chains:
""" + _rod("leg1", "active", _base("a1"), STRAIGHT, 0.2) + _rod("leg2", "passive", _base("a2"), STRAIGHT, 0.15)
    + _rod("leg3", "passive", _base("a3"), TURNED, 0.1) + """  - name: platform
    joints:
""" + SLIDES.format(p="platform", mass=0.6, com="[0.12, 0.08, 0.0]") + """    end: {xyz: [0.0, 0.0, 0.0]}
    points:
      a1: [0.0, 0.0, 0.0]
      a2: [0.3, 0.0, 0.05]
      a3: [0.1, 0.25, -0.05]
closure:
  type: platform
  platform: platform
  legs: {leg1: a1, leg2: a2, leg3: a3}
initial_state:
  active: {leg1_a: 0.5, leg1_b: 0.3}
  guess: {leg2_a: 0.5, leg2_b: 0.3, leg3_a: 0.1, leg3_b: 0.6, platform_x: -0.09, platform_y: 0.14, platform_z: 0.05}
""")

PLATFORM_MJCF = ("""<mujoco model="spatial_parallelogram">
  <compiler angle="radian"/>
  <option gravity="0 0 -9.81"/>
  <worldbody>
""" + _mj_rod("leg1", _base("a1", " "), MJ_STRAIGHT, 0.2, "tip1") + _mj_rod("leg2", _base("a2", " "), MJ_STRAIGHT, 0.15,
                                                                          "tip2")
    + _mj_rod("leg3", _base("a3", " "), MJ_TURNED, 0.1, "tip3") + """    <body name="platform">
      <joint name="platform_x" type="slide" axis="1 0 0"/>
      <joint name="platform_y" type="slide" axis="0 1 0"/>
      <joint name="platform_z" type="slide" axis="0 0 1"/>
      <inertial pos="0.12 0.08 0" mass="0.6" diaginertia="2e-3 3e-3 4e-3"/>
      <site name="a1" pos="0 0 0"/>
      <site name="a2" pos="0.3 0 0.05"/>
      <site name="a3" pos="0.1 0.25 -0.05"/>
    </body>
  </worldbody>
  <equality>
    <connect site1="tip1" site2="a1"/>
    <connect site1="tip2" site2="a2"/>
    <connect site1="tip3" site2="a3"/>
  </equality>
  <actuator>
    <motor name="leg1_a" joint="leg1_a"/>
    <motor name="leg1_b" joint="leg1_b"/>
  </actuator>
</mujoco>
""")

POINT = ("""name: doubled_rod_gantry
gravity: [0.0, 0.0, -9.81]
elastic_dof_per_chain: 0
chains:
  - name: carriage
    joints:
""" + SLIDES.format(p="carriage", mass=0.5, com="[0.0, 0.0, 0.0]") + """    end: {xyz: [0.0, 0.0, 0.0]}
""" + _rod("rod1", "active", "[0, 0, 0.3]", STRAIGHT, 0.2) + _rod("rod2", "passive", "[0, 0, 0.3]", TURNED, 0.15)
    + """closure:
  type: point
  chains: [carriage, rod1, rod2]
initial_state:
  active: {rod1_a: 0.5, rod1_b: 0.3}
  guess: {rod2_a: 0.1, rod2_b: 0.6, carriage_x: -0.09, carriage_y: 0.14, carriage_z: 0.05}
""")

POINT_MJCF = ("""<mujoco model="doubled_rod_gantry">
  <compiler angle="radian"/>
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="carriage">
      <joint name="carriage_x" type="slide" axis="1 0 0"/>
      <joint name="carriage_y" type="slide" axis="0 1 0"/>
      <joint name="carriage_z" type="slide" axis="0 0 1"/>
      <inertial pos="0 0 0" mass="0.5" diaginertia="2e-3 3e-3 4e-3"/>
      <site name="c" pos="0 0 0"/>
    </body>
""" + _mj_rod("rod1", "0 0 0.3", MJ_STRAIGHT, 0.2, "tip1") + _mj_rod("rod2", "0 0 0.3", MJ_TURNED, 0.15, "tip2")
    + """  </worldbody>
  <equality>
    <connect site1="c" site2="tip1"/>
    <connect site1="c" site2="tip2"/>
  </equality>
  <actuator>
    <motor name="rod1_a" joint="rod1_a"/>
    <motor name="rod1_b" joint="rod1_b"/>
  </actuator>
</mujoco>
""")


def _check_and_compare(tmp_path, text: str, name: str, mjcf: str) -> tuple[Mechanism, dict[str, float], float]:
    path = _write(tmp_path, text, name)
    mech = Mechanism(load_model(path))
    run, found = _physics(mech)
    err = float(np.abs(_mujoco_run(_write(tmp_path, mjcf), mech.joint_names, run.q[0], len(run.t)) - run.q).max())
    print(f"\n{name}: moved {found['moved']:.3g}, every row's residual {found['residual']:.2e}, energy drift "
          f"{found['energy']:.2e} of the kinetic, accelerations vs all rows (least squares) "
          f"{found['accelerations']:.2e}, "
          f"max |q - q_mujoco| {err:.2e} (rad, m)")
    return mech, found, err


def _assert_physics(found: dict[str, float], err: float) -> None:
    assert found["moved"] > 0.1  # it swings, 0.34 rad in 0.2 s
    assert found["residual"] < 1e-9  # the dropped rows hold too
    assert found["energy"] < 1e-7
    assert found["accelerations"] < 1e-6
    assert err < 1e-6


def test_spatial_parallelogram_platform_is_reduced_and_matches_mujoco(tmp_path):
    mech, found, err = _check_and_compare(tmp_path, PLATFORM, "platform.yaml", PLATFORM_MJCF)
    closure = mech.model.closure
    assert not mech.model.planar and tuple(closure.components) == (0, 1, 2)
    assert mech.m == 7 and len(mech.passive) == 7  # 9 rows in the file
    # the second and third rods' rows along themselves (body z of each rod, the third's turned frame too)
    assert dict(closure.repeated) == {1: 0b100, 2: 0b100}
    assert [(k, mask) for k, _, mask in closure.projected] == [(1, 0b011), (2, 0b011)]
    _assert_physics(found, err)


def test_point_closure_of_a_doubled_rod_is_reduced_and_matches_mujoco(tmp_path):
    mech, found, err = _check_and_compare(tmp_path, POINT, "point.yaml", POINT_MJCF)
    closure = mech.model.closure
    assert closure.hub == -1 and closure.pairs == ((0, 1), (0, 2))  # type: point, the carriage's end first
    assert mech.m == 5 and len(mech.passive) == 5  # 6 rows in the file
    assert dict(closure.repeated) == {1: 0b100}  # in the carriage's (world-aligned) frame: the vertical row
    assert [(k, mask) for k, _, mask in closure.projected] == [(1, 0b011)]
    _assert_physics(found, err)


def test_check_names_the_repeated_rows(tmp_path, capsys):
    assert main(["check", str(_write(tmp_path, PLATFORM, "platform.yaml"))]) == 0
    dropped = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("dropped")]
    assert len(dropped) == 2, dropped
    for k, line in zip((2, 3), dropped, strict=True):
        assert f"dropped  1 row of closure {k} " in line and "position along [0.0, 0.0, 1.0]" in line, line
        assert "it repeats rows of the other closures" in line and "2 rows kept" in line, line
    assert main(["check", str(_write(tmp_path, POINT, "point.yaml"))]) == 0
    dropped = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("dropped")]
    assert len(dropped) == 1 and "dropped  1 row of closure 2 " in dropped[0], dropped
    assert "it repeats rows of the other closures" in dropped[0], dropped
