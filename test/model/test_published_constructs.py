"""Constructs public robot files carry (issue #26), each checked against an engine we did not
write on the same file: a motor on a sprung joint and a spring preloaded away from its rest
(MJCF, against MuJoCo with its constraints tightened), Gepetto's UJOINT_* joint types and a
parallel spring on a sidecar's motor (against Pinocchio), and the start pose: assembled from
the file's zero pose, its passive angles wrapped, a loop that cannot close named in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import AssemblyError
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
DURATION, SAMPLE = 0.2, 1e-3  # [s]

# A five-bar in the x-y plane under gravity: the left crank's motor acts beside a spring
# (MuJoCo stiffness on the motor's joint, springref 0.3), the right crank is a spring whose
# springref (0.5) is away from the file's pose (qpos0 = 0): it starts preloaded, as in MuJoCo.
FIVE_BAR = (ROBOTS / "published_constructs" / "five_bar.xml").read_text()


def _write(tmp_path: Path, text: str, name: str = "robot.xml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _mujoco_run(path: Path, names: list[str], q0: np.ndarray, samples: int) -> np.ndarray:
    """MuJoCo from our start pose, motors off, constraints tightened (solref at its floor of 2 dt,
    solimp 0.9999), RK4 at 1e-5 s: joint positions at each sample."""
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.eq_solref[:] = (2e-5, 1.0)
    m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in names]
    d.qpos[adr] = q0
    steps = round(SAMPLE / m.opt.timestep)
    out = [d.qpos[adr].copy()]
    for _ in range(samples - 1):
        mujoco.mj_step(m, d, nstep=steps)
        out.append(d.qpos[adr].copy())
    return np.array(out)


def test_motor_with_a_spring_and_a_preloaded_spring_match_mujoco(tmp_path):
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    path = _write(tmp_path, FIVE_BAR)
    mech = Mechanism(load_model(path))
    joints = {j.name: j for j in mech.model.joints}
    assert mech.active_names == ["left"] and joints["left"].stiffness == 2.0 and joints["left"].rest == 0.3
    assert joints["right"].role == "elastic" and joints["right"].rest == -0.5
    q0 = initial_state(mech)
    # assembled where the file puts it (qpos0), not with the right spring at its springref
    np.testing.assert_allclose(q0, np.zeros(4), atol=1e-12)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque([0.0]), DURATION)
    peer = _mujoco_run(path, mech.joint_names, q0, len(run.t))
    moved = float(np.abs(run.q - q0).max())
    err = float(np.abs(peer - run.q).max())
    print(f"sprung five-bar against MuJoCo (tightened): moved {moved:.3g} rad, max |q - q_mujoco| {err:.2e} rad")
    assert moved > 0.05  # the preloaded spring and gravity move it
    assert err < 1e-6


def test_keyframe_places_a_preloaded_spring(tmp_path):
    """A keyframe's value for a spring is its start (MuJoCo starts there), not its springref."""
    text = FIVE_BAR.replace("</mujoco>", '  <keyframe><key qpos="0.1 0 -0.2 0"/></keyframe>\n</mujoco>')
    mech = Mechanism(load_model(_write(tmp_path, text)))
    q0 = initial_state(mech)
    names = mech.joint_names
    assert q0[names.index("left")] == 0.1 and q0[names.index("right")] == -0.2
    assert mech.gap(q0) < 1e-12


def _pin_machine(urdf: Path, model):
    pytest.importorskip("pinocchio")
    from pinocchio_urdf import PinocchioMachine
    return PinocchioMachine(urdf, model)


@pytest.mark.parametrize("kind, axes", [("UJOINT_YZ", "YZ"), ("UJOINT_ZY", "ZY"), ("UJOINT_XY", "XY")])
def test_gepetto_ujoint_types_match_pinocchio(tmp_path, kind, axes):
    """UJOINT_AB: two revolutes about the joint frame's A then B (<joint>_A, <joint>_B), as
    Gepetto's loader builds them; on the crank's ball it stops the rod's spin."""
    from consistent_states import consistent_states

    from elastic_pm_dyn.dynamics.direct import Dynamics
    src = ROBOTS / "split_rod" / "robot.urdf"
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(src.read_text())
    (tmp_path / "robot.yaml").write_text(
        "closed_loop: [['closedloop1_A', 'closedloop1_B']]\ntype: ['6d']\nname_mot: ['motor_crank']\n"
        f"joint_name: ['spherical_crank', 'spherical_rocker']\njoint_type: ['{kind}', 'SPHERICAL']\n")
    model = load_model(urdf)
    joints = {j.name: j for j in model.joints}
    unit = {"X": [1.0, 0, 0], "Y": [0, 1.0, 0], "Z": [0, 0, 1.0]}
    np.testing.assert_array_equal(joints[f"spherical_crank_{axes[0]}"].axis, unit[axes[0]])
    np.testing.assert_array_equal(joints[f"spherical_crank_{axes[1]}"].axis, unit[axes[1]])
    mech = Mechanism(model)
    assert len(mech.elastic) == 0 and len(mech.passive) == 6
    peer = _pin_machine(urdf, model)
    for q, qd, tau in consistent_states(mech, np.random.default_rng(7), 4):
        a = peer.accelerations(q, qd, tau)
        qdd = Dynamics(mech, "scdd").accelerations(q, qd, tau[mech.active])
        assert np.abs(a - qdd).max() <= 1e-9 * np.abs(a).max()


def test_sidecar_spring_on_a_motor_is_a_parallel_spring_matching_pinocchio(tmp_path):
    from consistent_states import consistent_states

    from elastic_pm_dyn.dynamics.direct import Dynamics
    src = ROBOTS / "five_bar_urdf"
    urdf = tmp_path / "robot.urdf"
    urdf.write_text((src / "robot.urdf").read_text())
    side = (src / "robot.yaml").read_text().replace(
        "elastic:\n", "elastic:\n  left_motor: {stiffness: 3.0, damping: 0.05, rest: 0.4}\n")
    (tmp_path / "robot.yaml").write_text(side)
    model = load_model(urdf)
    mech = Mechanism(model)
    left = model.joints[model.joint_index("left_motor")]
    assert left.role == "active" and left.stiffness == 3.0 and left.rest == 0.4
    peer = _pin_machine(urdf, model)
    for q, qd, tau in consistent_states(mech, np.random.default_rng(3), 4):
        a = peer.accelerations(q, qd, tau)
        qdd = Dynamics(mech, "scdd").accelerations(q, qd, tau[mech.active])
        assert np.abs(a - qdd).max() <= 1e-9 * np.abs(a).max()


def test_passive_angles_come_back_wrapped(tmp_path):
    """Whole turns on the passive joints' guess: the same pose, its angles in (-pi, pi]."""
    mech = Mechanism(load_model(_write(tmp_path, FIVE_BAR)))
    q0 = initial_state(mech)
    guess = q0.copy()
    guess[mech.passive] += np.array([4 * np.pi, -6 * np.pi]) + 0.01
    q = solve_pose(mech, guess, mech.passive, robust=True)
    assert np.all(np.abs(q[mech.passive]) <= np.pi)
    along = solve_pose(mech, guess, mech.passive)  # a pose solved along a motion keeps its branch
    np.testing.assert_allclose(along[mech.passive], q0[mech.passive] + np.array([4 * np.pi, -6 * np.pi]), atol=1e-9)
    np.testing.assert_allclose(q, q0, atol=1e-10)


def test_a_loop_that_cannot_close_names_file_and_loop(tmp_path):
    """The right arm too short to reach at any pose: one line with the file, the loop and the
    residual, and what to do."""
    text = FIVE_BAR.replace('<body name="r1" pos="0.2 0 0"', '<body name="r1" pos="0.9 0 0"')
    text = text.replace('<connect body1="l2" body2="r2" anchor="0.2 0 0"/>',
                        '<connect body1="l2" body2="r2" anchor="0.2 0 0"/>')
    path = _write(tmp_path, text)
    model = load_model(path)
    # the file closes its loop at qpos0 (MuJoCo computes body2's anchor there): move the base
    # point of the right crank away in our model to make the loop unreachable
    from dataclasses import replace
    chains = list(model.chains)
    right = chains[1]
    first = replace(right.joints[0], origin_xyz=np.array([2.0, 0.0, 0.0]))
    chains[1] = replace(right, joints=(first, *right.joints[1:]))
    mech = Mechanism(replace(model, chains=tuple(chains)))
    with pytest.raises(AssemblyError) as err:
        initial_state(mech)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: cannot assemble closure 1 ("), message
    assert "residual" in message and "initial_state.guess" in message


# A gripper as MJCF grippers are written (Robotiq's 2F-85 in MuJoCo Menagerie: a motor on a
# fixed tendon over both drivers, a <joint> equality tying them): the right finger a four-bar
# (a <connect>), the left driver tied to the right one by q_left = 0.1 - 1.5 q_right (violated
# at qpos0: the assembly closes it), the tendon over both with coefficients 1 and -0.4.
GRIPPER = (ROBOTS / "published_constructs" / "gripper.xml").read_text()
TENDON_GAIN = 1.0 + (-0.4) * (-1.5)  # d(tendon)/d(right_driver) through the equality: 1.6


def _gripper(tmp_path: Path) -> tuple[Path, Mechanism]:
    path = _write(tmp_path, GRIPPER)
    return path, Mechanism(load_model(path))


def test_tendon_gripper_loads_with_its_couplings(tmp_path):
    _, mech = _gripper(tmp_path)
    assert mech.active_names == ["right_driver"]
    # the input is the tendon's force: through the equality it does 1.6 times its work on right_driver
    expected = np.zeros((mech.n, 1))
    expected[mech.joint_names.index("right_driver"), 0] = TENDON_GAIN
    np.testing.assert_allclose(mech.transmission, expected, rtol=1e-12, atol=1e-15)
    assert sorted(mech.joint_names[i] for i in mech.passive) == ["left_driver", "right_coupler", "right_follower"]
    assert mech.m == 3 and len(mech.model.closure.couplings) == 1  # the connect's two rows, the equality
    q0 = initial_state(mech)
    names = mech.joint_names
    assert abs(q0[names.index("left_driver")] - (0.1 - 1.5 * q0[names.index("right_driver")])) < 1e-13
    assert mech.gap(q0) < 1e-12


def test_tendon_gripper_matches_mujoco(tmp_path):
    """A constant grip command for 0.2 s: our motor's input is the tendon force, as MuJoCo's ctrl."""
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    mujoco = pytest.importorskip("mujoco")
    path, mech = _gripper(tmp_path)
    q0 = initial_state(mech)
    force = 0.02  # [N m] the tendon's "force" (its coordinate is an angle combination)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque([force]), DURATION)
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.eq_solref[:] = (2e-5, 1.0)
    m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in mech.joint_names]
    d.qpos[adr] = q0
    d.ctrl[0] = force
    out = [d.qpos[adr].copy()]
    for _ in range(len(run.t) - 1):
        mujoco.mj_step(m, d, nstep=round(SAMPLE / m.opt.timestep))
        out.append(d.qpos[adr].copy())
    moved = float(np.abs(run.q - q0).max())
    err = float(np.abs(np.array(out) - run.q).max())
    print(f"tendon gripper against MuJoCo (tightened): moved {moved:.3g} rad, max |q - q_mujoco| {err:.2e} rad")
    assert moved > 0.05
    assert err < 1e-6
    left, right = mech.joint_names.index("left_driver"), mech.joint_names.index("right_driver")
    assert np.abs(run.q[:, left] - (0.1 - 1.5 * run.q[:, right])).max() < 1e-9  # the coupling held


def test_under_actuated_tendon_is_refused_in_one_line(tmp_path):
    """Without the equality the tendon drives two fingers with one motor."""
    text = GRIPPER.replace('    <joint name="mirror" joint1="left_driver" joint2="right_driver" '
                           'polycoef="0.1 -1.5 0 0 0"/>\n', '')
    path = _write(tmp_path, text)
    from elastic_pm_dyn.errors import ModelError
    with pytest.raises(ModelError) as err:
        load_model(path)
    message = str(err.value)
    line = text.splitlines().index('    <motor name="grip" tendon="split"/>') + 1
    assert message.startswith(f"{path}:{line}: actuator 'grip': not supported yet"), message
    assert "under-actuated" in message and "\n" not in message


def test_nonlinear_joint_equality_is_refused_in_one_line(tmp_path):
    text = GRIPPER.replace('polycoef="0.1 -1.5 0 0 0"', 'polycoef="0.1 -1.5 0.2 0 0"')
    path = _write(tmp_path, text)
    from elastic_pm_dyn.errors import ModelError
    with pytest.raises(ModelError) as err:
        load_model(path)
    line = next(k for k, s in enumerate(text.splitlines(), 1) if 'name="mirror"' in s)
    assert str(err.value).startswith(f"{path}:{line}: joint equality 'mirror': not supported yet: a polycoef"), \
        str(err.value)


# A leg as Gepetto's and Menagerie's legged robots close their knees: on a hip that rolls about
# x (a motor, unpowered: it swings under gravity, so the loop's plane turns), a four-bar of
# hinges parallel to (0, 0.6, 0.8) cut inside its rocker, the two halves joined by a 6-D
# <weld>: six rows of which three (the position along the hinges, the turns across them) hold
# by themselves; and a second such knee on the same hip, so 12 weld rows for 6 passive joints.
HINGE = "0 0.6 0.8"
WELD_LEG = f"""<mujoco model="welded_knees">
  <compiler angle="radian"/>
  <worldbody>
    <body name="hip">
      <joint name="roll" type="hinge" axis="1 0 0"/>
      <inertial pos="0 0.05 -0.02" mass="1" diaginertia="1e-2 1e-2 1e-2"/>
      <body name="crank">
        <joint name="crank" type="hinge" axis="{HINGE}"/>
        <inertial pos="0.05 0 0" mass="0.5" diaginertia="1e-4 1e-3 1e-3"/>
        <body name="coupler" pos="0.1 0.04 -0.03" axisangle="{HINGE} 1.2">
          <joint name="coupler" type="hinge" axis="{HINGE}"/>
          <inertial pos="0.1 0 0" mass="0.3" diaginertia="1e-5 1e-3 1e-3"/>
          <body name="rocker_top" pos="0.2 0 0">
            <joint name="rocker_top" type="hinge" axis="{HINGE}"/>
            <inertial pos="-0.02 0 0" mass="0.05" diaginertia="1e-6 1e-5 1e-5"/>
          </body>
        </body>
      </body>
      <body name="rocker" pos="0.3 0 0" axisangle="{HINGE} 1.9">
        <joint name="rocker" type="hinge" axis="{HINGE}"/>
        <inertial pos="0.1 0 0" mass="0.3" diaginertia="1e-5 1e-3 1e-3"/>
      </body>
      <body name="crank2" pos="0 -0.2 0">
        <joint name="crank2" type="hinge" axis="{HINGE}"/>
        <inertial pos="0.05 0 0" mass="0.5" diaginertia="1e-4 1e-3 1e-3"/>
        <body name="coupler2" pos="0.1 0.04 -0.03" axisangle="{HINGE} 1.0">
          <joint name="coupler2" type="hinge" axis="{HINGE}"/>
          <inertial pos="0.1 0 0" mass="0.3" diaginertia="1e-5 1e-3 1e-3"/>
          <body name="rocker2_top" pos="0.2 0 0">
            <joint name="rocker2_top" type="hinge" axis="{HINGE}"/>
            <inertial pos="-0.02 0 0" mass="0.05" diaginertia="1e-6 1e-5 1e-5"/>
          </body>
        </body>
      </body>
      <body name="rocker2" pos="0.3 -0.2 0" axisangle="{HINGE} 1.7">
        <joint name="rocker2" type="hinge" axis="{HINGE}"/>
        <inertial pos="0.1 0 0" mass="0.3" diaginertia="1e-5 1e-3 1e-3"/>
      </body>
    </body>
  </worldbody>
  <equality>
    <weld body1="rocker_top" body2="rocker"/>
    <weld body1="rocker2_top" body2="rocker2"/>
  </equality>
  <actuator>
    <motor name="roll" joint="roll"/>
    <motor name="crank" joint="crank"/>
    <motor name="crank2" joint="crank2"/>
  </actuator>
</mujoco>
"""


def leg_against_mujoco(path: Path, mech: Mechanism) -> tuple[float, float]:
    """The welded leg falling unpowered for DURATION, ours (DOP853, tight tolerances, the closure
    held to 1e-9) against MuJoCo's run of the same file: (how far its roll joint turned, max |q - q_mujoco|)."""
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import ConstantTorque
    q0 = initial_state(mech)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque([0.0, 0.0, 0.0]), DURATION)
    assert float(np.abs(run.gap).max()) < 1e-9
    peer = _mujoco_run(path, mech.joint_names, q0, len(run.t))
    roll = mech.joint_names.index("roll")
    return float(abs(run.q[-1, roll] - q0[roll])), float(np.abs(peer - run.q).max())


def dropped_lines(path: Path) -> list[str]:
    """The lines of ``elastic-pm-dyn check`` that say which closure rows were dropped."""
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "check", str(path)], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return [line for line in out.stdout.splitlines() if line.strip().startswith("dropped")]


def test_redundant_weld_rows_are_dropped_and_the_leg_matches_mujoco(tmp_path):
    path = _write(tmp_path, WELD_LEG)
    mech = Mechanism(load_model(path))
    closure = mech.model.closure
    assert len(closure.welds) == 2 and len(closure.projected) == 2
    assert all(mask == 0b100011 for _, _, mask in closure.projected)  # two positions across, the turn about
    for _, frame, _ in closure.projected:  # the hinge direction, in the weld's frame
        n = np.asarray(frame)[:, 2]
        assert abs(abs(n @ np.array([0.0, 0.6, 0.8])) - 1.0) < 1e-9
    assert mech.m == 6 and len(mech.passive) == 6
    moved, err = leg_against_mujoco(path, mech)
    print(f"welded knees against MuJoCo (tightened): roll moved {moved:.3g} rad, max |q - q_mujoco| {err:.2e} rad")
    assert moved > 0.05  # the loops' plane turned in the world
    assert err < 1e-6


def test_check_says_how_many_weld_rows_were_dropped(tmp_path):
    dropped = dropped_lines(_write(tmp_path, WELD_LEG))
    assert len(dropped) == 2, dropped
    assert all("dropped  3 rows of weld" in line and "3 rows kept" in line for line in dropped), dropped


def test_robust_assembly_closes_where_newton_stalls(tmp_path):
    """From a guess Newton does not close (the knees' passive joints far off), the start-pose
    solve (Levenberg-Marquardt, continuation, several starts) does; MuJoCo agrees it is closed."""
    mujoco = pytest.importorskip("mujoco")
    path = _write(tmp_path, WELD_LEG)
    mech = Mechanism(load_model(path))
    guess = np.array([0.0, 0.0, -1.07, 1.812, -1.237, 0.0, -0.292, -2.299, -0.609])
    with pytest.raises(AssemblyError):
        solve_pose(mech, guess, mech.passive)
    q = solve_pose(mech, guess, mech.passive, robust=True)
    assert mech.gap(q) < 1e-12
    assert np.all(np.abs(q[mech.passive]) <= np.pi)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    d.qpos[[m.jnt_qposadr[m.joint(name).id] for name in mech.joint_names]] = q
    mujoco.mj_forward(m, d)
    rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert float(np.abs(d.efc_pos[rows]).max()) < 1e-10


MIMIC_ARM = """<?xml version="1.0"?>
<robot name="mimic_arm">
  <link name="base"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="upper"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="10" velocity="10"/>
  </joint>
  <link name="upper">
    <inertial><origin xyz="0.15 0 0.01"/><mass value="0.8"/>
      <inertia ixx="1e-3" ixy="0" ixz="0" iyy="6e-3" iyz="0" izz="6e-3"/></inertial>
  </link>
  <joint name="elbow" type="revolute">
    <parent link="upper"/><child link="fore"/>
    <origin xyz="0.3 0 0" rpy="0 0.2 0"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="10" velocity="10"/>
    <mimic joint="shoulder" multiplier="-0.6" offset="0.25"/>
  </joint>
  <link name="fore">
    <inertial><origin xyz="0.1 0.02 0"/><mass value="0.4"/>
      <inertia ixx="5e-4" ixy="0" ixz="0" iyy="3e-3" iyz="0" izz="3e-3"/></inertial>
  </link>
  <joint name="wrist" type="revolute">
    <parent link="fore"/><child link="hand"/>
    <origin xyz="0.2 0 0"/>
    <axis xyz="0 0.6 0.8"/><limit lower="-3" upper="3" effort="10" velocity="10"/>
  </joint>
  <link name="hand">
    <inertial><origin xyz="0.05 0 0.02"/><mass value="0.2"/>
      <inertia ixx="1e-4" ixy="0" ixz="0" iyy="2e-4" iyz="0" izz="2e-4"/></inertial>
  </link>
</robot>
"""


def test_urdf_mimic_is_a_coupling_matching_pinocchio(tmp_path):
    """<mimic multiplier offset>: elbow = -0.6 shoulder + 0.25 as a closure row. The peer:
    Pinocchio's mass matrix and bias of the same URDF (its mimic joints are not in all of its
    algorithms), the coupling elbow + 0.6 shoulder = 0.25 written from the file by hand, the
    constrained accelerations from their KKT system."""
    pin = pytest.importorskip("pinocchio")
    from elastic_pm_dyn.dynamics.direct import Dynamics
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(MIMIC_ARM)
    (tmp_path / "robot.yaml").write_text("name_mot: ['shoulder', 'wrist']\n")
    mech = Mechanism(load_model(urdf))
    assert mech.active_names == ["shoulder", "wrist"] and [mech.joint_names[i] for i in mech.passive] == ["elbow"]
    q0 = initial_state(mech)
    assert abs(q0[1] - 0.25) < 1e-14  # the mimic's offset, the shoulder at 0
    pm = pin.buildModelFromUrdf(str(urdf))
    data = pm.createData()
    assert list(pm.names)[1:] == mech.joint_names
    G = np.array([[0.6, 1.0, 0.0]])  # d/dt of elbow + 0.6 shoulder
    rng = np.random.default_rng(11)
    for _ in range(5):
        qs, qw, vs, vw, ts, tw = rng.uniform(-1, 1, 6)
        q = np.array([qs, -0.6 * qs + 0.25, qw])
        qd = np.array([vs, -0.6 * vs, vw])
        M = pin.crba(pm, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        kkt = np.block([[M, G.T], [G, np.zeros((1, 1))]])
        rhs = np.concatenate([np.array([ts, 0.0, tw]) - pin.nonLinearEffects(pm, data, q, qd), [0.0]])
        theirs = np.linalg.solve(kkt, rhs)[:3]
        ours = Dynamics(mech, "scdd").accelerations(q, qd, np.array([ts, tw]))
        assert np.abs(ours - theirs).max() <= 1e-9 * np.abs(theirs).max()


def test_written_urdf_and_sidecar_load_as_the_same_machine(tmp_path):
    """`urdf` + closure_sidecar of a machine with couplings and a sprung motor: the sidecar's
    `couplings` and `elastic` keys bring both back."""
    from elastic_pm_dyn.model.urdf_writer import closure_sidecar, model_to_urdf
    _, mech = _gripper(tmp_path)
    text = FIVE_BAR
    five = Mechanism(load_model(_write(tmp_path, text, "five.xml")))
    for m in (mech, five):
        out = tmp_path / m.model.name
        out.mkdir()
        (out / "robot.urdf").write_text(model_to_urdf(m.model))
        if m is mech:  # the tendon's gain on its motor has no sidecar key: said
            with pytest.warns(UserWarning, match="transmissions of motor.s. right_driver .fixed tendons. are not in"):
                (out / "robot.yaml").write_text(closure_sidecar(m.model))
        else:
            (out / "robot.yaml").write_text(closure_sidecar(m.model))
        back = load_model(out / "robot.urdf")
        assert back.closure.couplings == m.model.closure.couplings
        assert [(j.name, j.role, j.stiffness, j.rest) for j in back.joints] == \
            [(j.name, j.role, j.stiffness, j.rest) for j in m.model.joints]
        q0 = initial_state(m)
        np.testing.assert_allclose(initial_state(Mechanism(back)), q0, atol=1e-12)


def test_position_and_velocity_servo_on_one_joint_are_one_motor(tmp_path):
    """As Menagerie arms write a PD servo: a <position> and a <velocity> on one joint."""
    text = FIVE_BAR.replace('<motor name="left" joint="left"/>',
                            '<position name="left_kp" joint="left" kp="10"/>\n'
                            '    <velocity name="left_kv" joint="left" kv="1"/>')
    mech = Mechanism(load_model(_write(tmp_path, text), servos_as_motors=True))
    assert mech.active_names == ["left"]


def test_a_tendon_with_its_own_spring_is_refused_in_one_line(tmp_path):
    from elastic_pm_dyn.errors import ModelError
    text = GRIPPER.replace('<fixed name="split">', '<fixed name="split" stiffness="3">')
    path = _write(tmp_path, text)
    with pytest.raises(ModelError) as err:
        load_model(path)
    line = next(k for k, s in enumerate(text.splitlines(), 1) if '<fixed name="split"' in s)
    assert str(err.value).startswith(f"{path}:{line}: fixed 'split': not supported yet: a tendon with stiffness"), \
        str(err.value)


def test_rigid_model_locks_a_preloaded_spring_where_the_file_puts_it(tmp_path):
    """The rigid machine (springs locked) of a file whose spring starts away from its rest: locked
    at the start pose, the machine stands where the elastic one starts."""
    mech = Mechanism(load_model(_write(tmp_path, FIVE_BAR)))
    rigid = Mechanism(mech.model.locked())
    assert rigid.joint_names == ["left", "left_elbow", "right_elbow"]
    q = initial_state(rigid)
    np.testing.assert_allclose(rigid.end_effector(q), mech.end_effector(initial_state(mech)), rtol=0, atol=1e-12)
