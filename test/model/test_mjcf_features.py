"""MJCF features met in public third-party models (bench/studies/third_party_mjcf.py): a joint
``ref``, a body weld's relative pose, a floating base fixed on request, redundant closures.

Each is checked against MuJoCo itself: our assembled start pose, handed to MuJoCo as qpos
(our joint coordinates are MuJoCo's), must close MuJoCo's own constraints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

ROBOTS = Path(__file__).resolve().parents[1] / "robots"  # the test models

mujoco = pytest.importorskip("mujoco")

# A slider-crank in the x-y plane: the rod's hinge and the slider written at a 'ref' (MuJoCo
# puts the body there at qpos = ref), the crank started away from the file's pose.
SLIDER_CRANK = (ROBOTS / "mjcf_features" / "slider_crank.xml").read_text()

# Two arms joined by a weld between bodies whose frames are turned 0.7 rad apart: MuJoCo
# keeps that relative pose (taken at qpos0), not aligned frames.
WELD_ARMS = (ROBOTS / "mjcf_features" / "weld_arms.xml").read_text()


def _write(tmp_path: Path, text: str, name: str = "robot.xml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _mujoco_residual(path: Path, mech: Mechanism, q: np.ndarray, fix_base: bool = False) -> float:
    """MuJoCo's equality-constraint violation at our tree coordinates (hinges and slides only)."""
    from elastic_pm_dyn.model.mjcf import compile_mjcf
    m = compile_mjcf(path, fix_base)
    d = mujoco.MjData(m)
    for name, value in zip(mech.joint_names, q, strict=True):
        d.qpos[m.jnt_qposadr[m.joint(name).id]] = value
    mujoco.mj_forward(m, d)
    rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    return float(np.abs(d.efc_pos[rows]).max())


@pytest.mark.parametrize("text", [SLIDER_CRANK, WELD_ARMS], ids=["joint ref", "turned weld"])
def test_assembled_pose_closes_mujocos_constraints(tmp_path, text):
    path = _write(tmp_path, text)
    mech = Mechanism(load_model(path))
    q = initial_state(mech)
    from elastic_pm_dyn.model.mjcf import compile_mjcf
    key = compile_mjcf(path).key_qpos[0]
    assert mech.gap(q) < 1e-12
    assert q[0] == key[0]  # the motor where the keyframe puts it ...
    assert np.abs(q - key).max() > 0.05  # ... the rest assembled away from the file's pose
    assert _mujoco_residual(path, mech, q) < 1e-10


def test_ref_keeps_mujocos_coordinate(tmp_path):
    """At the file's own pose (qpos = ref) the loop is closed, and our coordinates read ref."""
    path = _write(tmp_path, SLIDER_CRANK.replace('<key qpos="0.5 0.3 0.05"/>', '<key qpos="0 0.3 0.05"/>'))
    mech = Mechanism(load_model(path))
    q = initial_state(mech)
    np.testing.assert_allclose(q, [0.0, 0.3, 0.05], atol=1e-9)


FLOATING = SLIDER_CRANK.replace('<body name="crank">', '<body name="frame" pos="0 0 0.5">\n      <freejoint/>\n'
                                '      <inertial pos="0 0 0" mass="2" diaginertia="1e-2 1e-2 1e-2"/>\n'
                                '    <body name="crank">') \
    .replace('    <body name="slider"', '    </body>\n    <body name="slider"') \
    .replace('<key qpos="0.5 0.3 0.05"/>', '<key qpos="0 0 0.5 1 0 0 0 0.5 0.3 0.05"/>')
FLOATING = FLOATING.replace('<body name="slider" pos="0.35 0.0 0"', '<body name="slider" pos="0.35 0.0 0.5"')


def test_free_joint_is_refused_with_its_line_unless_the_base_is_fixed(tmp_path):
    path = _write(tmp_path, FLOATING)
    with pytest.raises(ModelError) as err:
        load_model(path)
    line = FLOATING.splitlines().index("      <freejoint/>") + 1
    assert str(err.value).startswith(f"{path}:{line}: joint of body 'frame': a free joint"), str(err.value)
    assert "--fix-base" in str(err.value)
    mech = Mechanism(load_model(path, fix_base=True))
    q = initial_state(mech)
    assert sorted(mech.joint_names) == ["crank", "rod", "slider"]
    assert q[mech.joint_names.index("crank")] == 0.5  # the keyframe read past the free joint's seven entries
    assert _mujoco_residual(path, mech, q, fix_base=True) < 1e-10
    with pytest.raises(ModelError, match="fixing the base is for an MJCF"):
        load_model(Path(__file__).resolve().parents[1] / "robots" / "five_bar_urdf" / "robot.urdf", fix_base=True)


# Cassie's planar four-bar closed by a 3-D connect (a row that holds by itself): test_redundant_rows.py.


FOUR_BAR_XY = (ROBOTS / "mjcf_features" / "four_bar_xy.xml").read_text()


def test_planar_machine_in_the_y_z_plane_moves_as_in_x_y(tmp_path):
    """The same four-bar turned a quarter about y (hinges along x; gravity along y stays):
    planar in y-z, its joints move exactly as in x-y."""
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    runs = []
    options = SimulationOptions(integrator="rk4", dt=1e-4, sample=1e-3)
    for name, turn in (("xy.xml", ""), ("yz.xml", ' euler="0 1.5707963267948966 0"')):
        path = _write(tmp_path, FOUR_BAR_XY.replace('<body name="mount">', f'<body name="mount"{turn}>'), name)
        mech = Mechanism(load_model(path, servos_as_motors=True))
        assert mech.model.planar and mech.active_names == ["crank"]
        run = Simulator(mech, options).run(ConstantTorque([0.0]), 0.05)
        runs.append((mech, run))
    (m_xy, r_xy), (m_yz, r_yz) = runs
    assert tuple(m_xy.model.ee_names) == ("x", "y") and tuple(m_yz.model.ee_names) == ("y", "z")
    assert np.abs(r_xy.q - r_xy.q[0]).max() > 1e-3  # it falls
    np.testing.assert_allclose(r_yz.q, r_xy.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r_yz.ee[:, 0], r_xy.ee[:, 1], rtol=0, atol=1e-12)  # world y is y in both
    assert [h for h in r_yz.header() if h.startswith("ee_")] == ["ee_y", "ee_z"]


def test_servo_loads_with_its_law_and_a_law_not_kept_is_refused_unless_taken_for_a_motor(tmp_path):
    """A <position> servo keeps MuJoCo's law (test_servo_law.py checks it against MuJoCo); a gain
    that is not fixed is refused in one line that names the flag taking it for a motor."""
    path = _write(tmp_path, FOUR_BAR_XY)
    assert dict(load_model(path).transmissions) == {"crank": (("crank", 50.0),)}  # kp: the file default class
    text = FOUR_BAR_XY.replace('<position name="crank" joint="crank"/>',
                               '<general name="crank" joint="crank" gaintype="affine" gainprm="1 2 0"/>')
    path = _write(tmp_path, text)
    with pytest.raises(ModelError) as err:
        load_model(path)
    line = text.splitlines().index('    <general name="crank" joint="crank" gaintype="affine" gainprm="1 2 0"/>') + 1
    assert str(err.value).startswith(f"{path}:{line}: actuator 'crank': not supported yet"), str(err.value)
    assert "--servos-as-motors" in str(err.value)
    assert load_model(path, servos_as_motors=True).active_names == ["crank"]
