"""Dry (Coulomb) friction: MJCF frictionloss and URDF <dynamics friction> act in the machine by
Coulomb's law by default (a joint at rest sticks while the force it needs is within F, slides
against -F sign(qd) otherwise; dynamics/dry_friction.py), or as F tanh(qd / v_s) with a slip speed
v_s > 0 given. Checked against MuJoCo's friction loss, a soft constraint tightened here to
solref 2e-5 and solimp 0.9999 (its stick then creeps 1.2e-8 rad over 0.2 s under the sticking
pendulum's load; at its default solimp 1.3e-5). The errors measured are printed (-s) and listed
in docs/robot_files.md, "Dry friction"."""

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
            solref: float = 2e-5, solimp: float = 0.9999, qd0: np.ndarray | None = None) -> np.ndarray:
    """MuJoCo (RK4, 1e-5 s), its friction loss tightened to ``solref`` and ``solimp`` (its
    equalities to solref 2e-4, solimp 0.9999), ctrl held per sample."""
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.dof_solref[:] = (solref, 1.0)
    m.dof_solimp[:] = (solimp, solimp, 0.001, 0.5, 2.0)
    m.eq_solref[:] = (2e-4, 1.0)
    m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in names]
    dof = [m.jnt_dofadr[m.joint(name).id] for name in names]
    d.qpos[adr] = q0
    if qd0 is not None:
        d.qvel[dof] = qd0
    out = [d.qpos[adr].copy()]
    for k in range(samples - 1):
        d.ctrl[:] = ctrl[min(k, len(ctrl) - 1)]
        mujoco.mj_step(m, d, nstep=round(SAMPLE / m.opt.timestep))
        out.append(d.qpos[adr].copy())
    return np.array(out)


def test_frictionloss_is_dry_friction_in_the_machine():
    model = _load(ARM)
    assert {j.name: j.coulomb for j in model.joints} == {"shoulder": 0.05, "elbow": 0.03, "wrist": 0.01}
    assert {j.slip for j in model.joints} == {0.0}  # Coulomb's law, not a regularisation
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
    """Gravity's 0.49 N m against 0.3 N m of friction: it slides from the first instant (default
    settings: Coulomb's law; the regularisation's default of 1e-3 was 2e-4 rad off here)."""
    mjcf = tmp_path / "pendulum.xml"
    mjcf.write_text(PENDULUM.format(F=0.3))
    path = mjcf
    if kind == "urdf":
        path = tmp_path / "robot.urdf"
        path.write_text(URDF.format(F=0.3))
        (tmp_path / "robot.yaml").write_text(SIDECAR)
    mech = Mechanism(_load(path))
    assert mech.model.joints[0].coulomb == 0.3
    q0 = initial_state(mech)
    run = simulate(mech, [0.0], 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    peer = _mujoco(mjcf, mech.joint_names, q0, np.zeros((1, 1)), len(run.t))
    err = float(np.abs(peer - run.q).max())
    print(f"pendulum ({kind}) slipping against MuJoCo: moved {abs(run.q[-1, 0]):.3g} rad, max |q - q_mujoco| "
          f"{err:.2e} rad")
    assert abs(run.q[-1, 0]) > 0.4
    assert err < 1e-6
    rk4 = simulate(mech, [0.0], 0.2, sample=SAMPLE)  # every setting the default: RK4 at 1e-4 s
    err = float(np.abs(peer - rk4.q).max())
    print(f"  the default RK4: max |q - q_mujoco| {err:.2e} rad")
    assert err < 1e-6


def test_a_regularised_stick_creeps(tmp_path):
    """Gravity's 0.49 N m against 0.8 N m of friction, with a slip speed given: the regularised
    stick creeps at v_s atanh(tau / F), MuJoCo's soft constraint too; both far inside a free
    fall's 0.47 rad."""
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
    print(f"MuJoCo (solref 2e-5, solimp 0.9999) moved {peer[-1, 0]:.3g} rad")
    assert abs(peer[-1, 0]) < 2e-8


def test_check_says_the_rk4_step_dry_friction_allows(tmp_path):
    """The sticking pendulum: RK4 at half the step `check` gives follows DOP853 (1e-10 rad); at four
    times it the stiff slip band makes it chatter (8e-5 rad)."""
    from elastic_pm_dyn.dynamics.linear import dry_friction_step
    path = tmp_path / "pendulum.xml"
    path.write_text(PENDULUM.format(F=0.8))
    assert dry_friction_step(Mechanism(_load(path)), np.zeros(1)) is None  # Coulomb's law: no slope
    mech = Mechanism(_load(path, slip_speed=1e-3))
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
    mech = Mechanism(_load(path))  # Coulomb's law: the compensation is F sign(qd)
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


@pytest.mark.parametrize("integrator", ["dop853", "rk4"])
def test_a_joint_that_must_stick_stays_exactly_at_rest(tmp_path, integrator):
    """Gravity's 0.49 N m against 0.8 N m of friction, default settings: not a bit of motion, in
    the adaptive DOP853 and in the default RK4; MuJoCo tightened creeps 1.2e-8 rad."""
    path = tmp_path / "pendulum.xml"
    path.write_text(PENDULUM.format(F=0.8))
    mech = Mechanism(_load(path))
    options = {"rtol": 1e-11, "atol": 1e-13} if integrator == "dop853" else {}
    run = simulate(mech, [0.0], 0.2, integrator=integrator, sample=SAMPLE, **options)
    assert np.all(run.q == 0.0) and np.all(run.qd == 0.0)
    peer = _mujoco(path, ["hinge"], np.zeros(1), np.zeros((1, 1)), len(run.t))
    print(f"pendulum held by its friction ({integrator}): moved {np.abs(run.q).max():.3g} rad; MuJoCo (tightened) "
          f"{np.abs(peer).max():.3g} rad")
    assert np.abs(peer - run.q).max() < 1e-6


TURNTABLE = """<mujoco><option gravity="0 0 -9.81"/>
  <worldbody><body name="link"><joint name="hinge" axis="0 0 1" frictionloss="0.3" armature="0.001"/>
    <inertial pos="0.1 0 0" mass="0.5" diaginertia="1e-4 2e-3 2e-3"/></body></worldbody>
  <actuator><motor name="hinge" joint="hinge"/></actuator></mujoco>"""


def test_sticks_then_slips_under_a_rising_torque(tmp_path):
    """A vertical hinge (no gravity torque) under a motor torque rising by 0.05 N m per 0.01 s:
    held while the torque is within the 0.3 N m of friction, then slipping; as MuJoCo (tightened)."""
    path = tmp_path / "turntable.xml"
    path.write_text(TURNTABLE)
    mech = Mechanism(_load(path))
    t = np.arange(0.0, 0.2, SAMPLE)
    ctrl = (0.05 * np.arange(len(t)))[:, None]
    run = simulate(mech, TorqueTable(t, ctrl), 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    peer = _mujoco(path, ["hinge"], np.zeros(1), ctrl, len(run.t))
    err = float(np.abs(peer - run.q).max())
    held = run.t <= 0.07  # the torque reaches 0.3 N m over [0.06, 0.07) and passes it at 0.07
    print(f"turntable sticking then slipping against MuJoCo: moved {run.q[-1, 0]:.3g} rad, max |q - q_mujoco| "
          f"{err:.2e} rad")
    assert np.all(run.q[held] == 0.0) and run.q[-1, 0] > 0.2
    assert err < 1e-6


@pytest.mark.parametrize("integrator", ["dop853", "rk4"])
def test_slides_then_stops_and_stays(tmp_path, integrator):
    """The vertical hinge thrown at 2 rad/s, 0.1 N m pushing on: friction (0.3 N m) stops it at
    about 0.08 s and holds it, at exactly zero speed from then on; as MuJoCo (tightened)."""
    path = tmp_path / "turntable.xml"
    path.write_text(TURNTABLE)
    mech = Mechanism(_load(path))
    options = {"rtol": 1e-11, "atol": 1e-13} if integrator == "dop853" else {}
    run = simulate(mech, [0.1], 0.2, integrator=integrator, sample=SAMPLE, qd0=np.array([2.0]), **options)
    peer = _mujoco(path, ["hinge"], np.zeros(1), np.full((1, 1), 0.1), len(run.t), qd0=np.array([2.0]))
    err = float(np.abs(peer - run.q).max())
    stopped = run.t >= 0.1
    print(f"turntable sliding to a stop ({integrator}) against MuJoCo: stopped at {run.q[-1, 0]:.6g} rad, "
          f"max |q - q_mujoco| {err:.2e} rad")
    assert np.all(run.qd[stopped] == 0.0) and np.all(run.q[stopped] == run.q[-1])
    assert err < 1e-6


def test_friction_never_adds_energy(tmp_path):
    """The slipping pendulum's energy (MuJoCo's mj_energyPos + mj_energyVel of our states, the
    armature's included) never rises between 1 ms samples, and what it loses is F times the
    distance slid (the work of Coulomb friction against a motion that keeps its sign)."""
    path = tmp_path / "pendulum.xml"
    path.write_text(PENDULUM.format(F=0.3))
    mech = Mechanism(_load(path))
    run = simulate(mech, [0.0], 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=1e-3)
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    d = mujoco.MjData(m)
    energy = []
    for q, qd in zip(run.q, run.qd, strict=True):
        d.qpos[:], d.qvel[:] = q, qd
        mujoco.mj_forward(m, d)
        energy.append(float(d.energy.sum()))
    energy = np.array(energy)
    rise = float(np.diff(energy).max())
    lost = energy[0] - energy[-1]
    slid = abs(run.q[-1, 0] - run.q[0, 0])
    print(f"pendulum slipping: energy lost {lost:.6g} J, F times the distance slid {0.3 * slid:.6g} J, largest rise "
          f"between samples {rise:.2e} J")
    assert rise <= 1e-12
    assert abs(lost - 0.3 * slid) < 1e-9


def _four_bar(tmp_path: Path, frictions: tuple[float, float, float]) -> Path:
    """hinge_two_connects.xml (a four-bar closed by two connects) with its sites agreeing and
    friction loss on its crank, coupler and rocker: dry friction on the joints of one loop."""
    text = (ARM.parent / "hinge_two_connects.xml").read_text().replace("0.16215643", "0.16215639")
    for name, f in zip(("crank", "coupler", "rocker"), frictions, strict=True):
        joint = f'<joint name="{name}" axis="0 0 1"'
        text = text.replace(joint, f'{joint} frictionloss="{f}"')
    path = tmp_path / "four_bar.xml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("torque", "scale"), [(0.05, 1.0), (0.0, 5.0), (0.0, 20.0)])
def test_friction_on_the_joints_of_a_loop_as_mujoco(tmp_path, torque, scale):
    """A four-bar with friction loss on all three joints, from rest: its loop couples their stick
    and slip (Coulomb's law at rest solved on the loop's own response). Driven by 0.05 N m it
    slips, as it does under gravity alone with five times the friction, as MuJoCo (friction
    loss and connects tightened); with twenty times it, its friction holds it, exactly."""
    path = _four_bar(tmp_path, tuple(scale * f for f in (0.02, 0.01, 0.015)))
    mech = Mechanism(_load(path))
    q0 = initial_state(mech)
    run = simulate(mech, [torque], 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)
    peer = _mujoco(path, mech.joint_names, q0, np.full((1, 1), torque), len(run.t))
    err = float(np.abs(peer - run.q).max())
    moved = float(np.abs(run.q - q0).max())
    print(f"four-bar with friction on its loop ({scale:g} x), {torque} N m: moved {moved:.3g} rad, "
          f"max |q - q_mujoco| {err:.2e} rad")
    if scale < 20:
        assert moved > 0.1
    else:
        assert moved == 0.0
    assert err < 1e-6
