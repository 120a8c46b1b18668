"""No element of a robot file that acts on the motion is dropped without a line: each kind the
machine leaves out (joint limits, tendon ranges, friction loss, servo laws, control and force
ranges, actuator dynamics, gravity compensation, fluid forces, contacts, inactive equalities;
URDF limits, dry friction, transmissions, <gazebo>) is one warning line naming its elements, and
a kind the file itself disables in MuJoCo gets none. A tight fixed-tendon range is a coupling,
checked against MuJoCo holding the same tendon by an equality."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

mujoco = pytest.importorskip("mujoco")

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
ARM = ROBOTS / "menagerie_style" / "arm.xml"
WAIST = ROBOTS / "menagerie_style" / "waist.xml"


def _lines(path: Path, **kwargs) -> list[str]:
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        load_model(path, **kwargs)
    out = [str(w.message) for w in seen]
    assert all("\n" not in line for line in out)
    return out


def _one(lines: list[str], words: str) -> str:
    found = [line for line in lines if words in line]
    assert len(found) == 1, (words, lines)
    return found[0]


def test_menagerie_style_arm_says_each_kind_it_leaves_out_once():
    lines = _lines(ARM, servos_as_motors=True)
    assert "shoulder [-1.57, 1.57], elbow [-2.5, 2.5], wrist [-3, 3]" in _one(lines, "joint limits are not enforced")
    assert "shoulder 0.05, elbow 0.03, wrist 0.01" in _one(lines, "friction loss")
    assert "shoulder_servo, elbow_servo, wrist_servo" in _one(lines, "servos' law")
    assert "wrist_servo [-2, 2]" in _one(lines, "control ranges")
    assert "shoulder_servo [-8, 8], wrist_servo [-3, 3]" in _one(lines, "force ranges")
    assert "floor-fingertip" in _one(lines, "contacts are not simulated")
    assert len(lines) == 6


def test_every_other_kind_has_its_line(tmp_path):
    text = ARM.read_text()
    text = text.replace('<option gravity="0 0 -9.81" timestep="0.002"/>',
                        '<option gravity="0 0 -9.81" timestep="0.002" density="1.2" wind="0 1 0"/>')
    text = text.replace('<body name="forearm" pos="0.25 0 0">', '<body name="forearm" pos="0.25 0 0" gravcomp="1">')
    text = text.replace('<velocity name="elbow_servo"', '<general name="filtered" joint="elbow" dyntype="filter" '
                        'dynprm="0.05"/>\n    <velocity name="elbow_servo"')
    text = text.replace("<actuator>", '<tendon><fixed name="loose" limited="true" range="-1 1"><joint joint="elbow" '
                        'coef="1"/><joint joint="wrist" coef="1"/></fixed></tendon>\n  <equality><connect body1="hand" '
                        'body2="upper_arm" anchor="0 0 0" active="false"/></equality>\n  <actuator>')
    text = text.replace('ctrl="0.5 0.5 -0.3"', 'ctrl="0.5 0 0.5 -0.3"')
    path = tmp_path / "arm.xml"
    path.write_text(text)
    lines = _lines(path, servos_as_motors=True)
    assert "forearm 1" in _one(lines, "gravity compensation")
    assert "density 1.2" in _one(lines, "fluid forces") and "wind [0.0, 1.0, 0.0]" in _one(lines, "fluid forces")
    assert "filtered" in _one(lines, "actuator dynamics")
    assert "loose [-1, 1]" in _one(lines, "tendon ranges are not enforced")
    assert "#0" in _one(lines, "inactive equalities")


def test_kinds_the_file_disables_get_no_line(tmp_path):
    """MuJoCo itself leaves out what <flag> disables: nothing is dropped, nothing said."""
    text = ARM.read_text().replace('<option gravity="0 0 -9.81" timestep="0.002"/>',
                                   '<option gravity="0 0 -9.81"><flag contact="disable" limit="disable" '
                                   'frictionloss="disable" clampctrl="disable"/></option>')
    path = tmp_path / "arm.xml"
    path.write_text(text)
    lines = _lines(path, servos_as_motors=True)
    assert not [line for line in lines if "limits" in line or "friction" in line or "contacts" in line
                or "control ranges" in line]


URDF = """<robot name="limited">
  <link name="base"/>
  <link name="a"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01"/></inertial></link>
  <link name="b"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="5" velocity="2"/><dynamics damping="0.1" friction="0.2"/></joint>
  <joint name="j2" type="continuous"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0"/>
    <dynamics friction="0"/><safety_controller soft_lower_limit="-1" soft_upper_limit="1" k_velocity="1"/></joint>
  <transmission name="t1"><type>transmission_interface/SimpleTransmission</type>
    <joint name="j1"/><actuator name="m1"><mechanicalReduction>50</mechanicalReduction></actuator></transmission>
  <gazebo reference="a"><mu1>0.5</mu1></gazebo>
</robot>
"""


def test_urdf_says_each_kind_it_leaves_out_once(tmp_path):
    path = tmp_path / "robot.urdf"
    path.write_text(URDF)
    (tmp_path / "robot.yaml").write_text("name_mot: [j1, j2]\n")
    lines = _lines(path)
    assert "j1 [-1, 1]" in _one(lines, "joint limits are not enforced")
    assert "j1 (effort 5, velocity 2)" in _one(lines, "effort and velocity limits")
    friction = _one(lines, "<dynamics friction>")
    assert "j1 0.2" in friction and "j2" not in friction  # a zero friction is no friction
    assert "t1" in _one(lines, "<transmission>s are not read")
    assert "a" in _one(lines, "<gazebo> elements")
    assert len(lines) == 5  # the safety controller does not act on the motion


def test_tight_tendon_ranges_couple_the_waist_as_mujoco_holds_them():
    """ToddlerBot's waist: the two tendons' tight ranges are couplings; MuJoCo holding the same
    tendons at the same lengths by <tendon> equalities (tightened) moves the same, 0.2 s under
    gravity and two motor torques."""
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    lines = _lines(WAIST)
    assert "taken as a coupling holding its length at 0.001" in _one(lines, "'waist_roll_coupling'")
    assert "at -0.0005" in _one(lines, "'waist_yaw_coupling'")
    assert not [line for line in lines if "not enforced" in line]
    mech = Mechanism(load_model(WAIST))
    assert mech.active_names == ["waist_act_1", "waist_act_2"]
    q0 = initial_state(mech)
    tau = np.array([0.03, -0.01])
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=0.01)) \
        .run(ConstantTorque(tau), 0.2)
    spec = mujoco.MjSpec.from_file(str(WAIST))
    for t, held in zip(spec.tendons, (0.001, -0.0005), strict=True):
        t.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        spec.add_equality(type=mujoco.mjtEq.mjEQ_TENDON, name1=t.name, data=[held, 0, 0, 0, 0] + [0] * 7,
                          solref=[2e-5, 1.0], solimp=[0.9999, 0.9999, 0.001, 0.5, 2.0])
    m = spec.compile()
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in mech.joint_names]
    d.qpos[adr] = q0
    d.ctrl[:] = tau
    peer = [d.qpos[adr].copy()]
    for _ in range(len(run.t) - 1):
        mujoco.mj_step(m, d, nstep=1000)
        peer.append(d.qpos[adr].copy())
    moved = float(np.abs(run.q - q0).max())
    err = float(np.abs(np.array(peer) - run.q).max())
    print(f"waist differential against MuJoCo (tendon equalities, tightened): moved {moved:.3g} rad, "
          f"max |q - q_mujoco| {err:.2e} rad")
    assert moved > 0.05
    assert err < 1e-6


def test_a_geared_motor_says_its_input_is_the_torque(tmp_path):
    text = ARM.read_text().replace('<velocity name="elbow_servo" joint="elbow" kv="2" ctrlrange="-3 3"/>',
                                   '<motor name="elbow_motor" joint="elbow" gear="50"/>')
    path = tmp_path / "arm.xml"
    path.write_text(text)
    assert "elbow_motor 50" in _one(_lines(path), "motors' gear is not applied")
