"""A closure row that holds by itself is dropped (issue #13: Cassie's foot four-bar).

The machine, as one of Cassie's legs: on a yoke that rolls about x (a motor, unpowered here:
the yoke swings under gravity, so the loop's plane turns in the world), a four-bar whose
three hinges are parallel (along (0, 0.6, 0.8), across no base axis) closed by a 3-D
``<connect>``: its row along the hinges holds by itself, every joint moving the two points
alike along them. And a lever held by a rod on a ball, whose spin about its own axis is free.
Loaded, the four-bar's pair keeps the two rows across the hinges in the coupler's frame; the
dynamics then agree with the other formulations, with Pinocchio (which takes the three rows:
its proximal solver copes with the repeated one) and with MuJoCo (its soft connect, tightened).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pinocchio_urdf import PinocchioMachine
from scipy.integrate import solve_ivp

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state, random_consistent_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.model.mjcf import mujoco_qpos
from elastic_pm_dyn.model.urdf_writer import closure_sidecar, model_to_urdf
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

ROBOTS = Path(__file__).resolve().parents[1] / "robots"  # the test models

HINGE = np.array([0.0, 0.6, 0.8])
LEG = (ROBOTS / "redundant_rows" / "leg.xml").read_text()
DURATION, SAMPLE = 0.2, 1e-3  # [s]


@pytest.fixture(scope="module")
def leg(tmp_path_factory) -> tuple[Path, Mechanism]:
    path = tmp_path_factory.mktemp("leg") / "leg.xml"
    path.write_text(LEG)
    return path, Mechanism(load_model(path))


def _export(mech: Mechanism, where: Path) -> Path:
    urdf = where / "robot.urdf"
    urdf.write_text(model_to_urdf(mech.model))
    (where / "robot.yaml").write_text(closure_sidecar(mech.model))
    return urdf


def test_the_still_row_is_dropped_in_the_coupler_frame(leg):
    _, mech = leg
    closure = mech.model.closure
    assert len(closure.reduced) == 1
    k, frame = closure.reduced[0]
    a, _ = closure.pairs[k]
    assert mech.model.joints[mech.model.point_bodies()[a]].name == "coupler"
    n = np.asarray(frame)[:, 2]
    assert abs(abs(n @ HINGE) - 1.0) < 1e-12  # the hinge axis, in the coupler's own frame
    np.testing.assert_allclose(np.asarray(frame) @ np.asarray(frame).T, np.eye(3), atol=1e-15)
    # 2 rows for the four-bar, 3 for the rod: the rod's spin about its axis is a free joint
    assert mech.m == 5 == len(mech.passive)
    free = [mech.joint_names[i] for i in mech.elastic]
    assert len(free) == 1 and free[0].startswith("rod_")


def test_formulations_agree_and_the_dropped_row_holds(leg):
    """Away from the start pose (the yoke rolled, so the hinges no longer where they started
    in the world): SCDD, its stacked form, L-D'A and the multipliers agree to round-off, and the
    points' relative acceleration along the dropped direction is zero as well."""
    _, mech = leg
    rng = np.random.default_rng(7)
    k, _ = mech.model.closure.reduced[0]
    a, b = mech.model.closure.pairs[k]
    # point a's world frame (its body's orientation times ``frame``): the third column is the dropped direction
    n_start = mech.terms(initial_state(mech)).p_tip[a, 3:12].reshape(3, 3)[:, 2]
    roll = mech.joint_names.index("roll")
    turned = 0
    for _ in range(4):
        q, qd, tau_a = random_consistent_state(mech, rng, spread=0.5)
        tau = mech.split_tau(tau_a)
        out = {}
        for form in ("scdd", "scdd_stacked", "lda", "multipliers"):
            qdd, lam = np.zeros(mech.n), np.zeros(mech.m)
            cond, gap = accelerations(FORMULATION_CODES[form], mech.arrays, q, qd, tau, 0.0, 0.0,
                                      np.zeros(mech.n), qdd, lam)
            assert cond > 1e-6 and gap < 1e-12
            out[form] = qdd
        scale = np.abs(out["scdd"]).max()
        for form in ("scdd_stacked", "lda", "multipliers"):
            assert np.abs(out[form] - out["scdd"]).max() < 1e-12 * scale, form
        t = mech.terms(q, qd)
        rel = (t.J[a][:3] - t.J[b][:3]) @ out["scdd"] + t.a_tip[a][:3] - t.a_tip[b][:3]
        assert np.abs(rel).max() < 1e-11 * scale  # all three directions, the dropped one included
        # The hinges' direction at the start, held fixed in the world, is no longer one that holds
        # by itself once the yoke has rolled: the direction must turn with the coupler.
        n_now = t.p_tip[a, 3:12].reshape(3, 3)[:, 2]
        dJ = t.J[a][:3] - t.J[b][:3]
        assert np.abs(n_now @ dJ).max() < 1e-12 * np.abs(dJ).max()
        if abs(q[roll] - initial_state(mech)[roll]) > 0.2:
            turned += 1
            assert np.abs(n_start @ dJ).max() > 0.05 * np.abs(dJ).max()
    assert turned


def test_matches_pinocchio_on_the_urdf_export(leg, tmp_path):
    """Pinocchio on the URDF + sidecar written from the model (three rows per point closure):
    accelerations to 1e-9 relative at random states, 0.2 s under gravity to 1e-6 rad. The URDF
    + sidecar read back is the same machine, the same row dropped."""
    pytest.importorskip("pinocchio")
    _, mech = leg
    urdf = _export(mech, tmp_path)
    back = Mechanism(load_model(urdf))
    assert back.model.closure.reduced == mech.model.closure.reduced and back.joint_names == mech.joint_names
    peer = PinocchioMachine(urdf, back.model, baumgarte=(100.0, 20.0))
    rng = np.random.default_rng(11)
    for _ in range(4):
        q, qd, tau_a = random_consistent_state(mech, rng, spread=0.5)
        tau = mech.split_tau(tau_a)
        qdd, lam = np.zeros(mech.n), np.zeros(mech.m)
        accelerations(FORMULATION_CODES["scdd"], mech.arrays, q, qd, tau, 0.0, 0.0, np.zeros(mech.n), qdd, lam)
        theirs = peer.accelerations(q, qd, tau)
        assert np.abs(theirs - qdd).max() < 1e-9 * np.abs(qdd).max()
    q0 = initial_state(mech)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque([0.0, 0.0]), DURATION)
    n = mech.n
    tau0 = np.zeros(n)
    sol = solve_ivp(lambda _t, y: np.concatenate([y[n:], peer.accelerations(y[:n], y[n:], tau0)]),
                    (0.0, DURATION), np.concatenate([q0, np.zeros(n)]), method="DOP853", rtol=1e-10, atol=1e-12,
                    t_eval=run.t)
    assert sol.success
    roll = mech.joint_names.index("roll")
    assert abs(run.q[-1, roll] - q0[roll]) > 0.05  # the loop's plane turned in the world
    err = float(np.abs(sol.y[:n].T - run.q).max())
    print(f"rolling four-bar: moved {np.abs(run.q - q0).max():.3g} rad, max |q - q_pinocchio| {err:.2e} rad")
    assert err < 1e-6


def test_matches_mujoco_within_its_softness(leg):
    """MuJoCo's connect takes the three rows, softly: with solref at its floor (2 dt) and solimp
    0.9999 the hinge angles agree with ours over 0.2 s to within its constraint violation."""
    mujoco = pytest.importorskip("mujoco")
    path, mech = leg
    q0 = initial_state(mech)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque([0.0, 0.0]), DURATION)
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.eq_solref[:] = (2e-5, 1.0)
    m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    d.qpos[:] = mujoco_qpos(m, mech.joint_names, q0)
    hinges = [i for i, name in enumerate(mech.joint_names) if not name.startswith("rod_")]
    adr = [m.jnt_qposadr[m.joint(mech.joint_names[i]).id] for i in hinges]
    steps = round(SAMPLE / m.opt.timestep)
    out = [d.qpos[adr].copy()]
    for _ in range(len(run.t) - 1):
        mujoco.mj_step(m, d, nstep=steps)
        out.append(d.qpos[adr].copy())
    err = float(np.abs(np.array(out) - run.q[:, hinges]).max())
    print(f"rolling four-bar against MuJoCo (tightened): max |q - q_mujoco| {err:.2e} rad")
    assert np.abs(run.q[:, hinges] - q0[hinges]).max() > 0.05
    assert err < 1e-8  # measured 2.5e-11


def test_check_names_the_dropped_row(leg):
    path, _ = leg
    out = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "check", str(path)], capture_output=True,
                         text=True, check=True).stdout
    dropped = [line for line in out.splitlines() if line.strip().startswith("dropped")]
    assert len(dropped) == 1, out
    assert "closure 1 (body of joint coupler = body of joint rocker" in dropped[0]
    assert "holds by itself" in dropped[0]


def test_a_row_that_locks_a_motor_is_not_dropped(tmp_path):
    """The crank's hinge tilted off the others: the row along them is zero in the passive
    joints but not in the crank's, so it does not hold by itself (it would lock the motor):
    refused as before, with its line."""
    text = LEG.replace('<joint name="crank" type="hinge" axis="0 0.6 0.8"/>',
                       '<joint name="crank" type="hinge" axis="0 0.5 0.8"/>')
    path = tmp_path / "locked.xml"
    path.write_text(text)
    with pytest.raises(ModelError) as err:
        load_model(path)
    line = text.splitlines().index('    <connect body1="coupler" body2="rocker" anchor="0.2 0 0"/>') + 1
    message = str(err.value)
    assert message.startswith(f"{path}:{line}: connect coupler-rocker: not supported yet"), message
    assert "6 equations have rank 5" in message


FOLDED = (ROBOTS / "redundant_rows" / "folded.xml").read_text()


def test_a_row_still_only_at_the_start_pose_is_not_dropped(tmp_path):
    """Two hinges along z and one along y, the y one's arm upright at the start: there every
    joint moves the closure point in the x-y plane, so the row along z is zero in all joints;
    but the loop is locked (its three equations leave the crank no motion), and near the
    start pose no pose assembles to confirm the row: not dropped, the counts refuse it."""
    path = tmp_path / "folded.xml"
    path.write_text(FOLDED)
    with pytest.raises(ModelError, match="the closures give 3 equations but the legs have 2 passive joints"):
        load_model(path)


def test_modes_keep_their_damping_ratio_beside_a_free_spin(tmp_path):
    """With a free rod spin (0 Hz, no oscillation) beside a sprung tip on the lever, each mode's
    damping ratio stays its own: the tip on a torsion spring k with damping d about its pivot,
    light damping zeta ~ d / (2 sqrt(k I)) within what the moving lever changes."""
    from elastic_pm_dyn.dynamics.linear import elastic_modes
    path = tmp_path / "sprung.xml"
    tip = ('<body name="tip" pos="0.2 0 0"><joint name="tip" type="hinge" axis="0 0 1" stiffness="50" '
           'damping="0.02"/><inertial pos="0.1 0 0" mass="0.2" diaginertia="1e-5 1e-3 1e-3"/></body>')
    path.write_text(LEG.replace('<inertial pos="0.1 0 0" mass="0.2" diaginertia="1e-5 1e-3 1e-3"/>',
                                '<inertial pos="0.1 0 0" mass="0.2" diaginertia="1e-5 1e-3 1e-3"/>' + tip, 1))
    mech = Mechanism(load_model(path))
    modes = elastic_modes(mech, initial_state(mech), clamp_motors=True)
    spin = modes.natural_hz == 0.0
    assert spin.sum() == 1 and np.isnan(modes.damping_ratio[spin]).all()
    zeta = modes.damping_ratio[~spin]
    assert zeta.shape == (1,) and 0.0 < zeta[0] < 0.05
    # the tip alone: I about its pivot = 1e-3 + 0.2 * 0.1^2
    assert zeta[0] == pytest.approx(0.02 / (2 * np.sqrt(50 * 3e-3)), rel=0.05)  # 0.0258 both
    out = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "check", str(path)], capture_output=True,
                         text=True, timeout=300)
    assert "no oscillation (a free joint: no spring)" in out.stdout and "nan" not in out.stdout, out.stdout + out.stderr


def test_a_damped_ball_says_how_its_damping_is_read(tmp_path):
    """Our ball is three revolutes, each damped on its own rate; MuJoCo damps the angular
    velocity: a warning naming the file, line and joint, not a silent difference."""
    path = tmp_path / "damped.xml"
    path.write_text(LEG.replace('<joint name="rod" type="ball"/>', '<joint name="rod" type="ball" damping="0.01"/>'))
    line = path.read_text().splitlines().index('        <joint name="rod" type="ball" damping="0.01"/>') + 1
    with pytest.warns(UserWarning, match=f"damped.xml:{line}: joint 'rod': a ball's damping acts here"):
        load_model(path)
