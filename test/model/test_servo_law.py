"""MuJoCo's actuator law in the machine: a servo file loads as published, its inputs the servos'
ctrl (force = gain ctrl + bias0 + bias1 L + bias2 dL/dt, ctrl clamped to ctrlrange), checked
against MuJoCo running the same file under the same ctrl table: a Menagerie-style arm with a
<position>, a <velocity> and a <general> servo, and the Robotiq 2F-85 as published (a <general>
servo on a fixed tendon, two four-bars, a joint equality)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulate import simulate
from elastic_pm_dyn.sim.torque import TorqueTable

mujoco = pytest.importorskip("mujoco")

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
ARM = ROBOTS / "menagerie_style" / "arm.xml"
ROBOTIQ = ROBOTS / "third_party" / "robotiq_2f85_v4.xml"
SAMPLE = 0.01


def _quiet_load(path: Path, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_model(path, **kwargs)


def _arm_without_friction(tmp_path: Path) -> Path:
    """The arm with MuJoCo's own friction loss, limits and contacts off (what this test is not about:
    test_friction_loss.py has the friction) and no force range (not applied: a line says so)."""
    text = ARM.read_text().replace('<option gravity="0 0 -9.81" timestep="0.002"/>',
                                   '<option gravity="0 0 -9.81"><flag frictionloss="disable" limit="disable" '
                                   'contact="disable"/></option>')
    text = text.replace(' forcerange="-8 8"', "").replace(' forcerange="-3 3"', "")
    path = tmp_path / "arm.xml"
    path.write_text(text)
    return path


def _mujoco_run(path: Path, names: list[str], q0: np.ndarray, table: TorqueTable, samples: int,
                solref: float | None = None) -> tuple[np.ndarray, float]:
    """MuJoCo (RK4, 1e-5 s) from q0 at rest under the ctrl table held per sample; joint positions at
    each sample, and the largest |actuator force| met."""
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    if solref is not None:
        m.eq_solref[:] = (solref, 1.0)
        m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in names]
    d.qpos[adr] = q0
    out, force = [d.qpos[adr].copy()], 0.0
    for k in range(samples - 1):
        d.ctrl[:] = table.values[min(k, len(table.values) - 1)]
        for _ in range(round(SAMPLE / m.opt.timestep)):
            mujoco.mj_step(m, d)
            force = max(force, float(np.abs(d.actuator_force).max()))
        out.append(d.qpos[adr].copy())
    return np.array(out), force


def test_servos_load_as_published_with_their_law():
    model = _quiet_load(ARM)
    joints = {j.name: j for j in model.joints}
    assert model.active_names == ["shoulder", "elbow", "wrist"]
    assert joints["shoulder"].stiffness == 20.0 and joints["elbow"].stiffness == 0.0  # kp; a velocity servo has none
    assert joints["wrist"].stiffness == 5.0 and joints["wrist"].rest == pytest.approx(0.2 / 5.0)  # bias0 / -bias1
    assert joints["elbow"].friction == pytest.approx(0.1 + 2.0)  # the joint's damping + kv
    assert dict(model.transmissions) == {"shoulder": (("shoulder", 20.0),), "elbow": (("elbow", 2.0),),
                                         "wrist": (("wrist", 5.0),)}
    assert model.input_ranges == (("shoulder", -1.5, 1.5), ("elbow", -3.0, 3.0), ("wrist", -2.0, 2.0))


def test_servos_as_motors_keeps_torques_as_inputs():
    model = _quiet_load(ARM, servos_as_motors=True)
    assert model.transmissions == () and model.input_ranges == ()
    assert all(j.stiffness == 0.0 for j in model.joints)


def test_the_arm_follows_its_servos_as_mujoco_does(tmp_path):
    """A ctrl table at 100 Hz that steps past the ctrl ranges (clamped by both): 0.2 s under gravity."""
    path = _arm_without_friction(tmp_path)
    mech = Mechanism(_quiet_load(path))
    t = np.arange(0.0, 0.2, SAMPLE)
    ctrl = np.column_stack([1.0 + 0.8 * np.sin(20 * t), 4.0 * np.cos(15 * t), -2.5 + 3 * t])  # beyond each range
    table = TorqueTable(t, ctrl)
    q0 = initial_state(mech)
    run = simulate(mech, table, 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    peer, _ = _mujoco_run(path, mech.joint_names, q0, table, len(run.t))
    moved = float(np.abs(run.q - q0).max())
    err = float(np.abs(peer - run.q).max())
    print(f"servo arm against MuJoCo: moved {moved:.3g} rad, max |q - q_mujoco| {err:.2e} rad")
    assert np.all(run.tau <= [1.5, 3.0, 2.0]) and np.all(run.tau >= [-1.5, -3.0, -2.0])  # the inputs clamped
    assert moved > 0.3
    assert err < 1e-6


def test_force_ranges_clamp_the_servos_as_mujoco_does(tmp_path):
    """The arm with its force ranges kept (the shoulder's 8 N m, the wrist's 3 N m): its servos
    saturate under the same ctrl table (checked), and the run follows MuJoCo's."""
    text = ARM.read_text().replace('<option gravity="0 0 -9.81" timestep="0.002"/>',
                                   '<option gravity="0 0 -9.81"><flag frictionloss="disable" limit="disable" '
                                   'contact="disable"/></option>')
    path = tmp_path / "arm.xml"
    path.write_text(text)
    mech = Mechanism(_quiet_load(path))
    assert mech.model.joints[0].force_range is not None and mech.model.joints[1].force_range is None
    t = np.arange(0.0, 0.2, SAMPLE)
    ctrl = np.column_stack([1.0 + 0.8 * np.sin(20 * t), 4.0 * np.cos(15 * t), -2.5 + 3 * t])
    table = TorqueTable(t, ctrl)
    q0 = initial_state(mech)
    run = simulate(mech, table, 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    peer, force = _mujoco_run(path, mech.joint_names, q0, table, len(run.t))
    err = float(np.abs(peer - run.q).max())
    print(f"servo arm with force ranges against MuJoCo: largest |force| {force:.3g}, max |q - q_mujoco| {err:.2e} rad")
    assert force == pytest.approx(8.0)  # the shoulder saturated
    assert err < 1e-6


@pytest.mark.parametrize(("first", "then", "saturates"), [(12.0, 6.0, False), (255.0, 255.0, True)],
                         ids=["gentle", "full_grip"])
def test_the_robotiq_gripper_as_published_closes_as_mujoco_does(tmp_path, first, then, saturates):
    """No flag: its <general> servo on the tendon 'split' (gain 0.3137, bias -100 L - 10 dL/dt) takes
    ctrl 0..255; a gentle grip keeps the force inside its 5 N range, a full one saturates it."""
    mech = Mechanism(_quiet_load(ROBOTIQ))
    assert mech.active_names == ["right_driver_joint"]
    t = np.arange(0.0, 0.2, SAMPLE)
    table = TorqueTable(t, np.where(t < 0.1, first, then)[:, None])
    q0 = initial_state(mech)
    run = simulate(mech, table, 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    text = ROBOTIQ.read_text().replace('<option cone="elliptic" impratio="10"/>',
                                       '<option cone="elliptic" impratio="10"><flag limit="disable" '
                                       'contact="disable"/></option>')
    peer_file = tmp_path / "robotiq.xml"
    peer_file.write_text(text)  # MuJoCo's limits and contacts off: ours has neither (lines say so)
    peer, force = _mujoco_run(peer_file, mech.joint_names, q0, table, len(run.t), solref=2e-5)
    moved = float(np.abs(run.q - q0).max())
    err = float(np.abs(peer - run.q).max())
    print(f"Robotiq 2F-85 as published against MuJoCo (tightened), ctrl {first:g} then {then:g}: moved {moved:.3g} "
          f"rad, max |q - q_mujoco| {err:.2e} rad, largest actuator force {force:.3g} N")
    assert (force == pytest.approx(5.0)) if saturates else force < 5.0
    assert moved > 0.02  # the servo's spring (100 N per unit L) holds it near L = 0.3137 ctrl / 100, or 5 N
    assert err < 1e-6


def test_two_servos_on_one_joint_need_the_flag(tmp_path):
    text = ARM.read_text().replace('<velocity name="elbow_servo" joint="elbow"',
                                   '<velocity name="shoulder_damper" joint="shoulder" kv="1"/>\n    '
                                   '<velocity name="elbow_servo" joint="elbow"').replace('ctrl="0.5 0.5 -0.3"',
                                                                                         'ctrl="0.5 0 0.5 -0.3"')
    path = tmp_path / "arm.xml"
    path.write_text(text)
    with pytest.raises(ModelError, match=r"several actuators \(shoulder_servo, shoulder_damper\) on one joint"):
        _quiet_load(path)
    assert _quiet_load(path, servos_as_motors=True).active_names == ["shoulder", "elbow", "wrist"]


def test_the_plant_clamps_a_servo_command(tmp_path):
    from elastic_pm_dyn.sim.plant import Plant
    from elastic_pm_dyn.sim.simulator import SimulationOptions
    mech = Mechanism(_quiet_load(_arm_without_friction(tmp_path)))
    plant = Plant(mech, SimulationOptions(integrator="rk4", dt=1e-4), 1e-3)
    plant.step(np.array([9.0, -9.0, 0.0]))
    assert plant.tau.tolist() == [1.5, -3.0, 0.0]


def test_a_plain_motors_ranges_clamp_its_torque_as_mujoco_does(tmp_path):
    """A <motor> with gear 2, ctrlrange +-1 and forcerange +-1.5: its input, the torque gear ctrl,
    is clamped to +-2 and to 2 * 1.5; asked for 5 N m it gives 2, as MuJoCo under ctrl 2.5 gives."""
    text = ARM.read_text().replace('<option gravity="0 0 -9.81" timestep="0.002"/>',
                                   '<option gravity="0 0 -9.81"><flag frictionloss="disable" limit="disable" '
                                   'contact="disable"/></option>')
    text = text.replace('<velocity name="elbow_servo" joint="elbow" kv="2" ctrlrange="-3 3"/>',
                        '<motor name="elbow_motor" joint="elbow" gear="2" ctrlrange="-1 1" forcerange="-1.5 1.5"/>')
    path = tmp_path / "arm.xml"
    path.write_text(text)
    model = _quiet_load(path)
    assert ("elbow", -2.0, 2.0) in model.input_ranges
    mech = Mechanism(model)
    t = np.arange(0.0, 0.2, SAMPLE)
    ours = np.column_stack([np.full_like(t, 0.5), np.full_like(t, 5.0), np.full_like(t, -0.3)])
    run = simulate(mech, TorqueTable(t, ours), 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    ctrl = ours.copy()
    ctrl[:, 1] = 2.5  # MuJoCo's ctrl: the torque over the gear, past its range too
    peer, _ = _mujoco_run(path, mech.joint_names, initial_state(mech), TorqueTable(t, ctrl), len(run.t))
    err = float(np.abs(peer - run.q).max())
    print(f"arm with a geared, ranged motor against MuJoCo: max |q - q_mujoco| {err:.2e} rad")
    assert np.all(run.tau[:, 1] == 2.0) and err < 1e-6
