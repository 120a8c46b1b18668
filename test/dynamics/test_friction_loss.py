"""Dry (Coulomb) friction: MJCF frictionloss and URDF <dynamics friction> act in the machine as
F tanh(qd / v_s) (a regularisation over the slip speed v_s, default 1e-3), checked against
MuJoCo's friction loss (a soft constraint, tightened here). The errors measured (printed):
  sliding (the Menagerie-style arm driven by its servos, 2.1 rad of motion, 0.2 s): 2.9e-7 rad at
  v_s = 1e-3 and 2.1e-7 at 1e-4 against MuJoCo at solref 2e-5 (1.5e-5 at solref 2e-3, 2.1e-4
  at MuJoCo's default 0.02: MuJoCo's own softness);
  slipping from rest (a pendulum whose gravity torque exceeds F): 1.2e-6 rad at v_s = 1e-5;
  sticking (gravity below F): a true stick does not move; the regularised one creeps at
  v_s atanh(tau / F) (1.4e-4 rad over 0.2 s at 1e-3, 1.4e-6 at 1e-5), MuJoCo's soft one too
  (1.3e-5 rad at solref 2e-5, 1.2e-2 at its default)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulate import simulate
from elastic_pm_dyn.sim.torque import TorqueTable

mujoco = pytest.importorskip("mujoco")

ARM = Path(__file__).resolve().parents[1] / "robots" / "menagerie_style" / "arm.xml"
SAMPLE = 0.01


def _load(path: Path, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_model(path, **kwargs)


def _mujoco(path: Path, names: list[str], q0: np.ndarray, ctrl: np.ndarray, samples: int,
            solref: float = 2e-5) -> np.ndarray:
    """MuJoCo (RK4, 1e-5 s), its friction loss tightened to ``solref``, ctrl held per sample."""
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.dof_solref[:] = (solref, 1.0)
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in names]
    d.qpos[adr] = q0
    out = [d.qpos[adr].copy()]
    for k in range(samples - 1):
        d.ctrl[:] = ctrl[min(k, len(ctrl) - 1)]
        mujoco.mj_step(m, d, nstep=round(SAMPLE / m.opt.timestep))
        out.append(d.qpos[adr].copy())
    return np.array(out)


def test_frictionloss_is_dry_friction_in_the_machine():
    model = _load(ARM)
    assert {j.name: j.coulomb for j in model.joints} == {"shoulder": 0.05, "elbow": 0.03, "wrist": 0.01}
    assert {j.slip for j in model.joints} == {1e-3}
    assert {j.slip for j in _load(ARM, slip_speed=1e-5).joints} == {1e-5}


def test_the_servo_arm_with_friction_loss_moves_as_mujoco(tmp_path):
    text = ARM.read_text().replace('<option gravity="0 0 -9.81" timestep="0.002"/>',
                                   '<option gravity="0 0 -9.81"><flag limit="disable" contact="disable"/></option>')
    path = tmp_path / "arm.xml"
    path.write_text(text.replace(' forcerange="-8 8"', "").replace(' forcerange="-3 3"', ""))
    mech = Mechanism(_load(path))
    t = np.arange(0.0, 0.2, SAMPLE)
    ctrl = np.column_stack([1.0 + 0.8 * np.sin(20 * t), 4.0 * np.cos(15 * t), -2.5 + 3 * t])
    q0 = initial_state(mech)
    run = simulate(mech, TorqueTable(t, ctrl), 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    peer = _mujoco(path, mech.joint_names, q0, ctrl, len(run.t))
    err = float(np.abs(peer - run.q).max())
    print(f"servo arm with friction loss against MuJoCo (solref 2e-5): moved {np.abs(run.q - q0).max():.3g} rad, "
          f"max |q - q_mujoco| {err:.2e} rad")
    assert err < 1e-6


PENDULUM = """<mujoco><option gravity="0 0 -9.81"/>
  <worldbody><body name="link"><joint name="hinge" axis="0 1 0" frictionloss="{F}" armature="0.001"/>
    <inertial pos="0.1 0 0" mass="0.5" diaginertia="1e-4 2e-3 2e-3"/></body></worldbody>
  <actuator><motor name="hinge" joint="hinge"/></actuator></mujoco>"""
URDF = """<robot name="pendulum"><link name="base"/>
  <link name="link"><inertial><origin xyz="0.1 0 0"/><mass value="0.5"/>
    <inertia ixx="1e-4" iyy="2e-3" izz="2e-3"/></inertial></link>
  <joint name="hinge" type="continuous"><parent link="base"/><child link="link"/><axis xyz="0 1 0"/>
    <dynamics friction="{F}"/></joint></robot>"""
SIDECAR = "name_mot: [hinge]\nrotor_inertia: {hinge: 0.001}\n"


@pytest.mark.parametrize("kind", ["mjcf", "urdf"])
def test_a_pendulum_slips_from_rest_as_mujoco(tmp_path, kind):
    """Gravity's 0.49 N m against 0.3 N m of friction: it slides from the first instant."""
    mjcf = tmp_path / "pendulum.xml"
    mjcf.write_text(PENDULUM.format(F=0.3))
    path = mjcf
    if kind == "urdf":
        path = tmp_path / "robot.urdf"
        path.write_text(URDF.format(F=0.3))
        (tmp_path / "robot.yaml").write_text(SIDECAR)
    mech = Mechanism(_load(path, slip_speed=1e-5))
    assert mech.model.joints[0].coulomb == 0.3
    q0 = initial_state(mech)
    run = simulate(mech, [0.0], 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    peer = _mujoco(mjcf, mech.joint_names, q0, np.zeros((1, 1)), len(run.t))
    err = float(np.abs(peer - run.q).max())
    print(f"pendulum ({kind}) slipping against MuJoCo: moved {abs(run.q[-1, 0]):.3g} rad, max |q - q_mujoco| "
          f"{err:.2e} rad")
    assert abs(run.q[-1, 0]) > 0.4
    assert err < 2e-6


def test_a_pendulum_sticks_within_the_regularisations_creep(tmp_path):
    """Gravity's 0.49 N m against 0.8 N m of friction: a true stick stays; ours creeps at
    v_s atanh(tau / F), MuJoCo's soft constraint too; both far inside a free fall's 0.47 rad."""
    path = tmp_path / "pendulum.xml"
    path.write_text(PENDULUM.format(F=0.8))
    tau = 0.5 * 9.81 * 0.1
    for slip in (1e-3, 1e-4):  # (1e-5 creeps 1.4e-6 rad, its stiff stick 150 s of DOP853 steps)
        mech = Mechanism(_load(path, slip_speed=slip))
        run = simulate(mech, [0.0], 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
        creep = slip * np.arctanh(tau / 0.8) * 0.2
        print(f"pendulum sticking, slip speed {slip:g}: moved {run.q[-1, 0]:.3g} rad (creep bound {creep:.3g})")
        assert abs(run.q[-1, 0]) <= 1.05 * creep
    peer = _mujoco(path, ["hinge"], np.zeros(1), np.zeros((1, 1)), len(run.t))
    print(f"MuJoCo (solref 2e-5) moved {peer[-1, 0]:.3g} rad")
    assert abs(peer[-1, 0]) < 2e-5


def test_check_says_the_rk4_step_dry_friction_allows(tmp_path):
    """The sticking pendulum: RK4 at half the step `check` gives follows DOP853 (1e-10 rad); at four
    times it the stiff slip band makes it chatter (8e-5 rad)."""
    from elastic_pm_dyn.dynamics.linear import dry_friction_step
    path = tmp_path / "pendulum.xml"
    path.write_text(PENDULUM.format(F=0.8))
    mech = Mechanism(_load(path))
    q0 = initial_state(mech)
    limit, joint = dry_friction_step(mech, q0)
    assert joint == "hinge"
    ref = simulate(mech, [0.0], 0.05, integrator="dop853", rtol=1e-11, atol=1e-13, sample=1e-3)
    errors = []
    for factor in (0.5, 4.0):
        dt = 1e-3 / round(1e-3 / (factor * limit))
        run = simulate(mech, [0.0], 0.05, integrator="rk4", dt=dt, sample=1e-3)
        errors.append(float(np.abs(run.q - ref.q).max()))
    print(f"RK4 step limit from dry friction {limit:.3g} s: error at half {errors[0]:.2e}, at 4x {errors[1]:.2e}")
    assert errors[0] < 1e-8 < 1e-5 < errors[1]


def test_the_inverse_dynamics_compensates_friction_as_mujoco_needs(tmp_path):
    """The servo arm with its friction loss on a smooth motion that keeps moving (no stick): the
    inputs our inverse dynamics gives (the servos' ctrl, friction compensated) drive MuJoCo's arm
    (friction loss tightened, the ctrl given at each step's midpoint) along the motion."""
    from elastic_pm_dyn.dynamics.inverse import motor_torques
    text = ARM.read_text().replace('<option gravity="0 0 -9.81" timestep="0.002"/>',
                                   '<option gravity="0 0 -9.81"><flag limit="disable" contact="disable"/></option>')
    text = text.replace(' forcerange="-8 8"', "").replace(' forcerange="-3 3"', "")
    text = text.replace('ctrlrange="-1.5 1.5" ', "").replace(' ctrlrange="-3 3"', "").replace(' ctrlrange="-2 2"', "")
    path = tmp_path / "arm.xml"
    path.write_text(text)
    mech = Mechanism(_load(path, slip_speed=1e-5))
    q0, v0, a = np.array([0.3, -0.6, 0.4]), np.array([0.5, -0.8, 1.0]), np.array([2.0, 3.0, -1.5])

    def motion(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return q0 + v0 * t + 0.5 * a * t * t, v0 + a * t, a  # no velocity crosses zero over 0.2 s

    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.dof_solref[:] = (2e-5, 1.0)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = q0, v0
    worst, compensation = 0.0, 0.0
    for k in range(20000):
        t = (k + 0.5) * m.opt.timestep
        u = motor_torques(mech, *motion(t))
        d.ctrl[:] = u
        mujoco.mj_step(m, d)
        if (k + 1) % 1000 == 0:
            worst = max(worst, float(np.abs(d.qpos - motion((k + 1) * m.opt.timestep)[0]).max()))
    frictionless = Mechanism(_no_friction(mech.model))
    compensation = float(np.abs(motor_torques(mech, *motion(0.1)) - motor_torques(frictionless, *motion(0.1))).max())
    print(f"inverse dynamics with friction driving MuJoCo: max |q_mujoco - q_path| {worst:.2e} rad "
          f"(friction's share of the ctrl {compensation:.3g})")
    assert compensation > 1e-3  # the friction is in the inputs
    assert worst < 1e-6


def _no_friction(model):
    from dataclasses import replace
    return replace(model, chains=tuple(replace(c, joints=tuple(replace(j, coulomb=0.0) for j in c.joints))
                                       for c in model.chains))


def test_the_written_urdf_keeps_the_dry_friction(tmp_path):
    from elastic_pm_dyn.model.urdf_writer import closure_sidecar, model_to_urdf
    model = _load(ARM, servos_as_motors=True)
    (tmp_path / "robot.urdf").write_text(model_to_urdf(model))
    (tmp_path / "robot.yaml").write_text(closure_sidecar(model))
    again = _load(tmp_path / "robot.urdf")
    assert {j.name: j.coulomb for j in again.joints} == {j.name: j.coulomb for j in model.joints}
