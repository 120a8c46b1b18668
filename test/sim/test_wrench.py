"""The external wrench on the end effector: its joint forces, checked by physics and by MuJoCo.

- J^T w projected on q_ae equals the parallel Jacobian of seed eq 31 (a different route:
  branch directions and the static matrix S) on all three machines, couples included;
- static equilibrium: motors that push back with eq 31's torques hold still under the
  wrench (springs settle), while without them the same wrench moves the machine;
- a wall pushes only when the tool is inside it, along its normal;
- MuJoCo's ``mj_applyFT`` of the same force adds the same accelerations to the five-bar, and of
  a couple on the Hexa's platform (the Hexa rebuilt in MuJoCo from the package's URDF writer).
"""

from functools import partial

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.dynamics.jacobian import parallel_jacobian_transpose
from elastic_pm_dyn.dynamics.statics import holding_torques
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.simulator import SimulationOptions
from elastic_pm_dyn.sim.wrench import ExternalWrench, StepWrench, Wall, WrenchMap

MACHINES = {"five_bar": [2.0, -1.0, 0, 0, 0, 0], "triglide": [1.0, 2.0, -2.0, 0, 0, 0],
            "hexa": [1.0, -2.0, 2.0, 0.2, -0.1, 0.15]}


def _mech(name):
    return Mechanism(load_model(f"config/{name}.yaml"))


def _load(mech, G, w):
    return mech.ee_axes @ w[:3] if G.shape[1] < 6 else w


@pytest.mark.parametrize("name", list(MACHINES))
def test_joint_forces_equal_eq31(name):
    mech = _mech(name)
    q = initial_state(mech)
    W, _ = mech.passive_map(mech.terms(q))
    G = parallel_jacobian_transpose(mech, q)
    rng = np.random.default_rng(3)
    for _ in range(3):
        w = np.asarray(MACHINES[name]) * rng.uniform(-2, 2, 6)
        tau = W.T @ WrenchMap(mech).tree_forces(q, w)
        assert np.allclose(tau, G @ _load(mech, G, w), rtol=1e-9, atol=1e-12 * np.abs(tau).max())


@pytest.mark.parametrize("name", list(MACHINES))
def test_static_equilibrium(name):
    """Motors at eq 31's -G^{+T} w (plus gravity's holding torque) keep still under w; without
    the wrench's share they move > 1e3 times as far in 0.2 s."""
    mech = _mech(name)
    q0 = initial_state(mech)
    w = np.asarray(MACHINES[name], dtype=float)
    G = parallel_jacobian_transpose(mech, q0)
    push = -(G @ _load(mech, G, w))[:len(mech.active)]
    moved = {}
    for label, u in (("balanced", holding_torques(mech, q0) + push), ("free", holding_torques(mech, q0))):
        plant = Plant(mech, SimulationOptions(integrator="etd2"), 1e-3, wrench=ExternalWrench([StepWrench(0.0, w)]))
        for _ in range(200):
            plant.step(u)
        moved[label] = np.abs(plant.q[mech.active] - q0[mech.active]).max()
        assert np.allclose(plant.true_wrench, w)
    assert moved["balanced"] * 1e3 < moved["free"]


def test_wall_pushes_inside_only():
    wall = Wall([0.0, 0.3, 0.0], [0.0, -1.0, 0.0], 1e4, 10.0)
    assert np.all(wall(0.0, np.array([0.0, 0.29, 0.0]), np.zeros(3)) == 0)
    f = wall(0.0, np.array([0.1, 0.301, 0.0]), np.array([0.0, 0.05, 0.0]))
    assert np.allclose(f[:3], [0.0, -(1e4 * 1e-3 + 10.0 * 0.05), 0.0]) and np.all(f[3:] == 0)
    assert np.all(wall(0.0, np.array([0.0, 0.301, 0.0]), np.array([0.0, -2.0, 0.0])) == 0)  # no pull


def test_step_ramp_and_bad_input():
    s = StepWrench(0.1, [2.0, 0, 0, 0, 0, 0], ramp=0.01)
    assert s(0.09, None, None)[0] == 0 and s(0.105, None, None)[0] == pytest.approx(1.0) and s(1, None, None)[0] == 2
    with pytest.raises(InputError):
        StepWrench(0.0, [1.0, np.nan, 0, 0, 0, 0])
    with pytest.raises(InputError):
        ExternalWrench().hold([1.0, 2.0])
    with pytest.raises(InputError, match="within"):
        ExternalWrench().hold([1e300, 0, 0, 0, 0, 0])
    with pytest.raises(InputError, match="couple"):
        WrenchMap(_mech("five_bar")).tree_forces(initial_state(_mech("five_bar")), np.array([0, 0, 0, 0, 0, 1.0]))


@pytest.mark.parametrize("name", ["five_bar", "triglide"])
def test_work_of_a_constant_force_is_the_energy_gained(name):
    """Undamped machine, motors free: a constant world force f on the tool does the work
    f . (p(T) - p(0)), and the machine's energy (kinetic + springs + gravity) grows by exactly that
    (independent of how the force was mapped to the joints)."""
    from conftest import without_damping
    mech = Mechanism(without_damping(load_model(f"config/{name}.yaml")))
    f = np.array([1.5, -2.0, 1.0 if name == "triglide" else 0.0, 0, 0, 0])
    plant = Plant(mech, SimulationOptions(dt=2.5e-5), 1e-3, wrench=ExternalWrench([StepWrench(0.0, f)]))
    wm = WrenchMap(mech)
    p0, e0 = wm.point_state(plant.q, plant.qd)[0], sum(mech.energy(plant.q, plant.qd))
    hold = holding_torques(mech, plant.q)
    for _ in range(60):
        plant.step(hold)
    work = f[:3] @ (wm.point_state(plant.q, plant.qd)[0] - p0)
    gained = sum(mech.energy(plant.q, plant.qd)) - e0 - hold @ (plant.q[mech.active] - initial_state(mech)[mech.active])
    assert abs(work) > 1e-3  # it moved
    assert gained == pytest.approx(work, rel=1e-4)


def _mujoco_addresses(m, mech, wmap):
    """MuJoCo's dof address of each of our tree joints, and the body that carries the wrench's point
    (the body of the point's joint)."""
    import mujoco
    adr = [m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in mech.joint_names]
    carrier = mech.joint_names[mech.arrays.point_body[wmap.point]]
    return adr, m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, carrier)]


def _scdd_accelerations(mech, q, qd, tau):
    qdd = np.empty(mech.n)
    accelerations(FORMULATION_CODES["scdd"], mech.arrays, q, qd, tau, 0.0, 0.0, np.zeros(mech.n), qdd,
                  np.zeros(mech.m))
    return qdd


def test_a_force_at_the_end_effector_accelerates_as_in_mujoco():
    """MuJoCo, an engine we did not write, maps the same force at the end-effector point
    (``mj_applyFT`` on the body that carries it) to generalised forces; the accelerations it adds
    to the reference five-bar (test/robots/five_bar.xml, the loop a nearly hard ``connect``)
    equal ours from WrenchMap's J^T f within MuJoCo's soft loop (~2e-5, docs/peers.md)."""
    import sys
    from pathlib import Path

    mujoco = pytest.importorskip("mujoco")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # test/: consistent_states
    from consistent_states import consistent_states

    mjcf = Path(__file__).resolve().parents[1] / "robots" / "five_bar.xml"
    mech = Mechanism(load_model(mjcf))
    wmap = WrenchMap(mech)
    m = mujoco.MjModel.from_xml_path(str(mjcf))
    d = mujoco.MjData(m)
    adr, body = _mujoco_addresses(m, mech, wmap)
    ours = partial(_scdd_accelerations, mech)

    def theirs(q, qd, tau, f, p):
        mujoco.mj_resetData(m, d)
        d.qpos[adr], d.qvel[adr] = q, qd
        mujoco.mj_forward(m, d)  # positions first: mj_applyFT reads the body's frame
        qfrc = np.zeros(m.nv)
        mujoco.mj_applyFT(m, d, f, np.zeros(3), p, body, qfrc)
        d.qfrc_applied[adr] = tau
        d.qfrc_applied[:] += qfrc
        mujoco.mj_forward(m, d)
        return d.qacc[adr].copy()

    rng = np.random.default_rng(43)
    worst = 0.0
    for q, qd, tau in consistent_states(mech, rng, 6):
        f = np.array([*rng.uniform(-3.0, 3.0, 2), 0.0])  # [N], in the machine's plane
        p, _ = wmap.point_state(q, qd)
        ours_added = ours(q, qd, tau + wmap.tree_forces(q, np.concatenate([f, np.zeros(3)]))) - ours(q, qd, tau)
        theirs_added = theirs(q, qd, tau, f, p) - theirs(q, qd, tau, np.zeros(3), p)
        worst = max(worst, float(np.abs(ours_added - theirs_added).max() / np.abs(ours_added).max()))
    print(f"MuJoCo five-bar, a force at the end effector: max rel. difference of the added qdd {worst:.2e}")
    assert worst < 1e-3


def test_a_couple_on_the_hexa_platform_accelerates_as_in_mujoco():
    """The Hexa (config/hexa.yaml) rebuilt in MuJoCo from the package's own URDF writer
    (model_to_urdf: the tree; closure_sidecar: the six leg-end/platform pairs, added as site
    ``connect`` equalities through MjSpec; motor rotor inertia as armature). MuJoCo's
    ``mj_applyFT`` of a couple (and of a force) on the platform body gives the tree forces
    WrenchMap gives, and the accelerations they add under the closures equal ours:
    - with MuJoCo's own mass matrix and constraint Jacobian, the loop held hard (the added
      accelerations are linear in the added force: dqdd = (M^-1 - M^-1 J^T (J M^-1 J^T)^-1 J M^-1) df,
      the bias and J' qd terms cancel) to ~5e-9: what is left is the 1e-9 kg masses and 1e-10
      kg m^2 axial inertias MuJoCo needs where our model has none (massless cross links,
      slender rods);
    - MuJoCo's soft solver itself to ~1.2e-3: its constraint impedance is capped at 0.9999,
      so the loop's reaction falls short by ~1e-4 of the constrained response (solref 2e-4,
      the tightest it takes at a 1e-4 s step)."""
    mujoco = pytest.importorskip("mujoco")
    import yaml

    from elastic_pm_dyn.kinematics.assembly import solve_pose
    from elastic_pm_dyn.model.urdf_writer import closure_sidecar, model_to_urdf

    model = load_model("config/hexa.yaml")
    mech = Mechanism(model)
    wmap = WrenchMap(mech)
    urdf = model_to_urdf(model).replace('ixx="0.0"', 'ixx="1e-10"')  # MuJoCo: positive inertia eigenvalues
    urdf = urdf.replace("<link name=\"world\"/>", '<mujoco><compiler fusestatic="false" discardvisual="true"/>'
                        '</mujoco><link name="world"/>', 1)  # the closure frames kept as bodies
    spec = mujoco.MjSpec.from_string(urdf)
    spec.option.gravity = [0.0, 0.0, 0.0]
    spec.option.timestep = 1e-4
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    for b in spec.bodies:  # the massless links between joints (a universal joint's cross, the platform's slides)
        if b.name != "world" and b.mass == 0.0 and b.first_joint() is not None:
            b.mass, b.inertia, b.explicitinertial = 1e-9, [1e-12] * 3, True
    for j in model.joints:
        if j.rotor_inertia:
            spec.joint(j.name).armature = j.rotor_inertia
    pairs = yaml.safe_load(closure_sidecar(model))["closed_loop"]
    assert len(pairs) == 6
    for k, (a, b) in enumerate(pairs):
        spec.body(a).add_site(name=f"loop{k}_a")
        spec.body(b).add_site(name=f"loop{k}_b")
        spec.add_equality(type=mujoco.mjtEq.mjEQ_CONNECT, objtype=mujoco.mjtObj.mjOBJ_SITE, name1=f"loop{k}_a",
                          name2=f"loop{k}_b", solref=[2e-4, 1.0], solimp=[0.9999, 0.9999, 0.001, 0.5, 2.0])
    m = spec.compile()
    d = mujoco.MjData(m)
    assert m.nv == mech.n
    adr, body = _mujoco_addresses(m, mech, wmap)
    assert m.body(body).name == "platform_roll_link"
    ours = partial(_scdd_accelerations, mech)

    def theirs(q, qd, tau, w, p):
        """MuJoCo's tree forces of w, the accelerations its soft solver adds, those of the hard loop."""
        mujoco.mj_resetData(m, d)
        d.qpos[adr], d.qvel[adr] = q, qd
        mujoco.mj_forward(m, d)
        qfrc = np.zeros(m.nv)
        mujoco.mj_applyFT(m, d, w[:3], w[3:], p, body, qfrc)
        M = np.empty((m.nv, m.nv))
        for i in range(m.nv):
            col = np.zeros(m.nv)
            mujoco.mj_mulM(m, d, col, np.eye(m.nv)[i].copy())
            M[:, i] = col
        Jc = d.efc_J.reshape(d.nefc, m.nv)[d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY]
        assert Jc.shape[0] == 18  # six 3-d connects
        Mi = np.linalg.inv(M)
        hard = Mi @ qfrc - Mi @ Jc.T @ np.linalg.solve(Jc @ Mi @ Jc.T, Jc @ Mi @ qfrc)
        d.qfrc_applied[adr] = tau
        mujoco.mj_forward(m, d)
        before = d.qacc.copy()
        d.qfrc_applied[:] += qfrc
        mujoco.mj_forward(m, d)
        return qfrc[adr], (d.qacc - before)[adr], hard[adr]

    rng = np.random.default_rng(4343)
    q0 = initial_state(mech)
    worst = {"tree forces": 0.0, "hard loop": 0.0, "MuJoCo's soft loop": 0.0}
    for k in range(4):
        q = q0.copy()
        q[mech.active] += rng.uniform(-0.05, 0.05, len(mech.active))
        q[mech.elastic] += rng.uniform(-1e-3, 1e-3, len(mech.elastic))
        q = solve_pose(mech, q, mech.passive)
        qd = mech.tree_velocity(q, np.concatenate([rng.uniform(-1.0, 1.0, len(mech.active)),
                                                   rng.uniform(-0.05, 0.05, len(mech.elastic))]))
        tau = mech.split_tau(rng.uniform(-0.5, 0.5, len(mech.active)))
        w = np.zeros(6)
        if k < 3:  # couples [N m] on the platform; the last a force [N] at its end-effector point
            w[3:] = rng.uniform(-0.3, 0.3, 3)
        else:
            w[:3] = rng.uniform(-3.0, 3.0, 3)
        p, _ = wmap.point_state(q, qd)
        tree = wmap.tree_forces(q, w)
        added = ours(q, qd, tau + tree) - ours(q, qd, tau)
        f_mj, soft, hard = theirs(q, qd, tau, w, p)
        scale = np.abs(added).max()
        assert scale > 1.0  # [rad/s^2, m/s^2]: the couple moves the machine
        worst["tree forces"] = max(worst["tree forces"], float(np.abs(f_mj - tree).max() / np.abs(tree).max()))
        worst["hard loop"] = max(worst["hard loop"], float(np.abs(hard - added).max() / scale))
        worst["MuJoCo's soft loop"] = max(worst["MuJoCo's soft loop"], float(np.abs(soft - added).max() / scale))
    print("MuJoCo Hexa, a couple on the platform: max rel. difference", {k: f"{v:.1e}" for k, v in worst.items()})
    assert worst["tree forces"] < 1e-12
    assert worst["hard loop"] < 1e-7
    assert worst["MuJoCo's soft loop"] < 3e-3
