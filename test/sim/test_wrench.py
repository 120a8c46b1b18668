"""The external wrench on the end effector: its joint forces, checked by physics and by MuJoCo.

- J^T w projected on q_ae equals the parallel Jacobian of seed eq 31 (a different route:
  branch directions and the static matrix S) on all three machines, couples included;
- static equilibrium: motors that push back with eq 31's torques hold still under the
  wrench (springs settle), while without them the same wrench moves the machine;
- a wall pushes only when the tool is inside it, along its normal;
- MuJoCo's ``mj_applyFT`` of the same force adds the same accelerations to the five-bar.
"""

import numpy as np
import pytest

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

    from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
    mjcf = Path(__file__).resolve().parents[1] / "robots" / "five_bar.xml"
    mech = Mechanism(load_model(mjcf))
    wmap = WrenchMap(mech)
    m = mujoco.MjModel.from_xml_path(str(mjcf))
    d = mujoco.MjData(m)
    adr = [m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in mech.joint_names]
    carrier = mech.joint_names[mech.arrays.point_body[wmap.point]]  # the joint of the point's body
    body = m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, carrier)]

    def ours(q, qd, tau):
        qdd = np.empty(mech.n)
        accelerations(FORMULATION_CODES["scdd"], mech.arrays, q, qd, tau, 0.0, 0.0, np.zeros(mech.n), qdd,
                      np.zeros(mech.m))
        return qdd

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
