"""A motor spread over several sprung joints (issue #26): an MJCF fixed tendon's force f does
the work of c_i f on each joint i of the tendon, so a motor is an input u with a transmission
column b, tau_t = B u. Checked by hand on two sprung slides (static deflections c_i f / k_i,
the undamped response from rest, the natural frequencies), through every path that turns motor
inputs into tree forces (split_tau, the compiled run of torque pieces, the plant, inverse
dynamics, the observer's prediction), and against MuJoCo on Menagerie's UMI gripper (one servo
on a tendon over two sprung finger slides, no equality tying them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.dynamics.inverse import tree_inverse_dynamics
from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.dynamics.statics import elastic_residual, holding_torques
from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
UMI = ROBOTS / "third_party" / "umi_gripper.xml"
DURATION, SAMPLE = 0.2, 1e-3  # [s]

# Two equal masses on horizontal slides (gravity across them), springs k1, k2, no damping; a
# motor on a fixed tendon with coefficients c1 (on its own slide) and c2 (on the other).
M, K1, K2, C1, C2 = 0.5, 200.0, 50.0, 1.0, -0.6
TWO_SLIDES = f"""<mujoco model="two_slides">
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="a">
      <joint name="a" type="slide" axis="1 0 0" stiffness="{K1}"/>
      <inertial pos="0 0 0" mass="{M}" diaginertia="1e-3 1e-3 1e-3"/>
    </body>
    <body name="b" pos="0 0.1 0">
      <joint name="b" type="slide" axis="1 0 0" stiffness="{K2}"/>
      <inertial pos="0 0 0" mass="{M}" diaginertia="1e-3 1e-3 1e-3"/>
    </body>
  </worldbody>
  <tendon>
    <fixed name="pull">
      <joint joint="a" coef="{C1}"/>
      <joint joint="b" coef="{C2}"/>
    </fixed>
  </tendon>
  <actuator>
    <motor name="pull" tendon="pull"/>
  </actuator>
</mujoco>
"""


@pytest.fixture(scope="module")
def slides(tmp_path_factory) -> Mechanism:
    path = tmp_path_factory.mktemp("slides") / "two_slides.xml"
    path.write_text(TWO_SLIDES)
    return Mechanism(load_model(path))


def test_two_slides_load_as_a_motor_and_a_spring_with_the_tendons_transmission(slides):
    joints = {j.name: j for j in slides.model.joints}
    assert slides.active_names == ["a"] and joints["a"].stiffness == K1  # a parallel spring on the motor
    assert [slides.joint_names[i] for i in slides.elastic] == ["b"] and joints["b"].stiffness == K2
    B = np.zeros((2, 1))
    B[slides.joint_names.index("a"), 0], B[slides.joint_names.index("b"), 0] = C1, C2
    np.testing.assert_array_equal(slides.transmission, B)
    assert slides.spread


def test_split_tau_is_b_times_the_inputs(slides):
    f = 3.0
    tau = slides.split_tau(np.array([f]))
    np.testing.assert_allclose(tau[[slides.joint_names.index("a"), slides.joint_names.index("b")]], [C1 * f, C2 * f],
                               rtol=1e-15)
    rows = slides.split_tau(np.array([[1.0], [-2.0], [0.5]]))  # a torque polynomial's rows at once
    np.testing.assert_allclose(rows[:, slides.joint_names.index("b")], C2 * np.array([1.0, -2.0, 0.5]), rtol=1e-15)


def test_static_deflections_are_c_f_over_k(slides):
    """At x_i = c_i f / k_i the springs balance the tendon; a little off they do not."""
    f = 4.0
    q = np.zeros(2)
    ia, ib = slides.joint_names.index("a"), slides.joint_names.index("b")
    q[ia], q[ib] = C1 * f / K1, C2 * f / K2
    assert np.abs(elastic_residual(slides, q, tau_active=np.array([f]))).max() < 1e-12
    q[ib] *= 1.01
    assert abs(elastic_residual(slides, q, tau_active=np.array([f]))[1]) > 1e-3
    # the motor input that holds a pose against the springs, through the tendon's motor row
    q[ib] = C2 * f / K2
    np.testing.assert_allclose(holding_torques(slides, q), [f], rtol=1e-12)


def test_natural_frequencies_of_the_equal_masses(slides):
    modes = elastic_modes(slides, np.zeros(2), clamp_motors=False)
    expected = np.sqrt(np.array([K2, K1]) / M) / (2 * np.pi)
    np.testing.assert_allclose(np.sort(modes.natural_hz), expected, rtol=1e-6)


@pytest.mark.parametrize("integrator", ["rk4", "dop853"])
def test_response_from_rest_is_the_hand_solution(slides, integrator):
    """Undamped from rest under a constant tendon force: x_i = (c_i f / k_i) (1 - cos w_i t),
    w_i = sqrt(k_i / m); RK4 runs the compiled pieces (their scatter is B u), DOP853 the Python path."""
    f = 2.0
    options = SimulationOptions(integrator=integrator, dt=1e-4, rtol=1e-11, atol=1e-13, sample=SAMPLE)
    run = Simulator(slides, options).run(ConstantTorque([f]), DURATION)
    for name, c, k in (("a", C1, K1), ("b", C2, K2)):
        x = c * f / k * (1 - np.cos(np.sqrt(k / M) * run.t))
        assert np.abs(run.q[:, slides.joint_names.index(name)] - x).max() < 1e-9 * abs(c * f / k), name


def test_compiled_pieces_scatter_b_u(slides):
    """One compiled piece under inputs u equals the fixed-step kernel under the tree polynomial B u
    written by hand, bit for bit."""
    sim = Simulator(slides, SimulationOptions(integrator="rk4", dt=1e-4))
    u = np.array([[1.5], [-0.3], [0.2]])  # (3, n_a): constant, linear, quadratic parts
    q1, qd1 = np.array([0.01, -0.02]), np.zeros(2)
    q2, qd2 = q1.copy(), qd1.copy()
    out_q, out_qd = np.zeros((1, 2)), np.zeros((1, 2))
    status, done, _ = sim.run_pieces(q1, qd1, u[None], np.array([1e-4]), np.array([20]), np.array([True]),
                                     out_q, out_qd, 0)
    assert (status, done) == (0, 1)
    coef = np.zeros((3, 2))
    coef[:, slides.joint_names.index("a")] = C1 * u[:, 0]
    coef[:, slides.joint_names.index("b")] = C2 * u[:, 0]
    assert Simulator(slides, SimulationOptions(integrator="rk4", dt=1e-4)).fixed_steps(q2, qd2, coef, 1e-4, 20) == 0
    np.testing.assert_array_equal(q1, q2)
    np.testing.assert_array_equal(qd1, qd2)


def test_plant_drives_through_the_transmission(slides):
    from elastic_pm_dyn.sim.plant import Plant
    f, period = 2.0, 1e-3
    plant = Plant(slides, SimulationOptions(integrator="rk4", dt=1e-4), period)
    for _ in range(50):
        plant.step(np.array([f]))
    t = 50 * period
    ib = slides.joint_names.index("b")
    x = C2 * f / K2 * (1 - np.cos(np.sqrt(K2 / M) * t))
    assert abs(plant.q[ib] - x) < 1e-9 * abs(C2 * f / K2)


@pytest.mark.parametrize("path_servos", [None, UMI])
def test_inverse_then_direct_dynamics_round_trip(slides, path_servos):
    """Accelerations under inputs u, then the inverse dynamics of that motion: the motors' rows
    give u back through B, and nothing is left on the elastic rows."""
    mech = slides if path_servos is None else Mechanism(load_model(path_servos, servos_as_motors=True))
    rng = np.random.default_rng(7)
    q = initial_state(mech) + 0.01 * rng.standard_normal(mech.n)
    qd = 0.1 * rng.standard_normal(mech.n)
    u = rng.standard_normal(len(mech.active))
    qdd = Dynamics(mech).accelerations(q, qd, u)
    back, left = mech.motor_inputs(tree_inverse_dynamics(mech, q, qd, qdd))
    np.testing.assert_allclose(back, u, rtol=1e-9, atol=1e-9)
    assert np.abs(left).max() < 1e-9
    # with the selection (the spring's row left unforced) the motion would not be one: its row
    # carries the tendon's share of the input
    f_ae = tree_inverse_dynamics(mech, q, qd, qdd)
    assert np.abs(f_ae[len(mech.active):]).max() > 1e-3 * np.abs(u).max()


def test_rigid_model_inverse_then_direct_by_hand(slides):
    """The rigid model (spring locked) keeps B's row on its motor's joint: the input for a
    motion of slide a is (m a'' + k1 a) / c1, and the direct dynamics under it give a'' back."""
    from elastic_pm_dyn.dynamics.inverse import motor_torques
    rigid = Mechanism(slides.model.locked())
    np.testing.assert_array_equal(rigid.transmission, [[C1]])  # the locked spring's share does no work
    q, qd, qdd = np.array([0.01]), np.array([0.2]), np.array([3.0])
    u = motor_torques(rigid, q, qd, qdd)
    np.testing.assert_allclose(u, [(M * 3.0 + K1 * 0.01) / C1], rtol=1e-12)
    np.testing.assert_allclose(Dynamics(rigid).accelerations(q, qd, u), qdd, rtol=1e-12)


def test_observer_predicts_the_hand_solution_through_the_transmission(slides):
    """The observer's compiled prediction puts B u on the tree (both slides move, each by its own
    coefficient) and reports the motor joint's effort c1 f: its mean, with no sample to correct
    it, is the undamped hand solution x_i = (c_i f / k_i)(1 - cos w_i t). The motor's own spring
    is not one of ETD2's exact elastic springs: its second-order error (1.9e-6 of the deflection
    after 0.15 s) sets the tolerance."""
    from elastic_pm_dyn.observer import Observer, ObserverConfig
    f, period, steps = 2.0, 1e-3, 150
    obs = Observer(slides, ObserverConfig.from_parameters({"sensors": ["encoders"]}))
    obs.reset(0.0, np.zeros(2), np.zeros(2))
    for k in range(steps):
        obs.predict(np.array([f]), (k + 1) * period)
    est = obs.estimate()
    t = steps * period
    for name, c, k in (("a", C1, K1), ("b", C2, K2)):
        x = c * f / k * (1 - np.cos(np.sqrt(k / M) * t))
        assert abs(est.q[slides.joint_names.index(name)] - x) < 1e-5 * abs(c * f / k), name
    assert est.effort[slides.joint_names.index("a")] == pytest.approx(C1 * f, rel=1e-15)


def test_unsprung_tendon_joint_is_refused_as_under_actuated(tmp_path):
    text = TWO_SLIDES.replace(f'axis="1 0 0" stiffness="{K2}"', 'axis="1 0 0"')
    path = tmp_path / "loose.xml"
    path.write_text(text)
    with pytest.raises(ModelError) as err:
        load_model(path)
    line = text.splitlines().index('    <motor name="pull" tendon="pull"/>') + 1
    message = str(err.value)
    assert message.startswith(f"{path}:{line}: actuator 'pull': not supported yet"), message
    assert "under-actuated" in message and "\n" not in message


# ----------------------------------------------------------------------------- UMI gripper

def _no_dry_friction(model):
    """The machine with its joints' friction loss off, as the MuJoCo peer here runs it."""
    from dataclasses import replace
    return replace(model, chains=tuple(replace(c, joints=tuple(replace(j, coulomb=0.0) for j in c.joints))
                                       for c in model.chains))


def _umi_mujoco(q0: np.ndarray, names: list[str], ctrl: dict[str, float], samples: int) -> np.ndarray:
    """MuJoCo on the same file, each actuator a force input (the servos' gain and bias and the
    control range cleared: ``servos_as_motors``), contacts, limits and friction loss off (our model
    has none), RK4 at 1e-5 s, equalities tightened (it has none): joint positions at each sample."""
    mujoco = pytest.importorskip("mujoco")
    m = mujoco.MjModel.from_xml_path(str(UMI))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.opt.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
                           | mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    m.eq_solref[:] = (2e-5, 1.0)
    m.actuator_gaintype[:] = mujoco.mjtGain.mjGAIN_FIXED
    m.actuator_biastype[:] = mujoco.mjtBias.mjBIAS_NONE
    m.actuator_gainprm[:] = 0.0
    m.actuator_gainprm[:, 0] = 1.0
    m.actuator_biasprm[:] = 0.0
    m.actuator_ctrllimited[:] = 0
    m.actuator_forcelimited[:] = 0
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(n).id] for n in names]
    d.qpos[adr] = q0
    for name, value in ctrl.items():
        d.ctrl[m.actuator(name).id] = value
    steps = round(SAMPLE / m.opt.timestep)
    out = [d.qpos[adr].copy()]
    for _ in range(samples - 1):
        mujoco.mj_step(m, d, nstep=steps)
        out.append(d.qpos[adr].copy())
    return np.array(out)


def test_umi_gripper_loads_with_its_tendon_spread_over_both_fingers():
    mech = Mechanism(load_model(UMI, servos_as_motors=True))
    names = mech.joint_names
    assert mech.active_names[-1] == "right_finger_joint" and len(mech.active) == 7
    assert [names[i] for i in mech.elastic] == ["left_finger_joint"] and not len(mech.passive)
    column = mech.transmission[:, mech.active_names.index("right_finger_joint")]
    expected = np.zeros(mech.n)
    expected[names.index("right_finger_joint")] = expected[names.index("left_finger_joint")] = 0.5  # the coefs
    np.testing.assert_array_equal(column, expected)


def test_umi_gripper_matches_mujoco_under_a_tendon_force():
    """0.2 s under gravity with the fingers' tendon pulled by 4 N and a small push on the x
    slide and a torque on the rz hinge (it turns the fingers with it); every joint against MuJoCo's
    (friction loss off in both: test_friction_loss.py has it)."""
    mech = Mechanism(_no_dry_friction(load_model(UMI, servos_as_motors=True)))
    q0 = initial_state(mech)
    inputs = {"right_finger_joint": 4.0, "gripper_joint_x": 0.3, "gripper_joint_rz": 2.0}
    u = [inputs.get(n, 0.0) for n in mech.active_names]
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE)) \
        .run(ConstantTorque(u), DURATION)
    actuators = {"right_finger_joint": "fingers_actuator", "gripper_joint_x": "gripper_joint_x_act",
                 "gripper_joint_rz": "gripper_joint_rz_act"}
    peer = _umi_mujoco(q0, mech.joint_names, {actuators[n]: v for n, v in inputs.items()}, len(run.t))
    fingers = [mech.joint_names.index(n) for n in ("left_finger_joint", "right_finger_joint")]
    opened = float(np.abs(run.q[:, fingers] - q0[fingers]).max())
    err = float(np.abs(peer - run.q).max())
    print(f"UMI gripper against MuJoCo: fingers moved {opened:.3g} m, max |q - q_mujoco| {err:.2e}")
    assert opened > 5e-3  # the tendon opens both fingers
    assert err < 1e-6
