"""A planar machine moves in whatever plane its joint axes say, not only x-y.

The five-bar URDF of test/robots/five_bar_urdf is written again with its base frame turned
(every joint on the base link gets its origin rotated by R, the sidecar's gravity too, and
its start point is given in the new plane's components): in x-y (R = I), in y-z, in x-z and
in a tilted plane. Each copy must (a) load as planar with the plane found from its axes and
end-effector components named after the user's base axes (x, y / y, z / x, z) or u, v on
the tilted plane; (b) move exactly as the x-y machine does: the same joint angles over
0.05 s of RK4 to round-off, the tips rotated by R; (c) agree with Pinocchio's
``constraintDynamics`` on the same files (closures as Gepetto's loader builds them,
test/pinocchio_urdf.py): accelerations to 1e-9 relative at random consistent states, and
0.2 s under gravity to 1e-6 rad.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from pinocchio_urdf import PinocchioMachine
from scipy.spatial.transform import Rotation
from test_robot_dynamics import pinocchio_run

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.kinematics.assembly import initial_state, random_consistent_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import matrix_to_rpy, rpy_to_matrix
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

SOURCE = Path(__file__).resolve().parents[1] / "robots" / "five_bar_urdf"
GRAVITY_XY = np.array([0.0, -9.81, 0.0])  # in the x-y machine's plane: it falls and swings
TORQUE = [0.4, -0.3]
PLANES = {  # R: the x-y machine's frame -> the new base frame; the component names expected
    "xy": (np.eye(3), ["x", "y"]),
    "yz": (np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), ["y", "z"]),  # axes along x
    "xz": (Rotation.from_euler("x", -90, degrees=True).as_matrix(), ["x", "z"]),  # axes along y
    "tilted": (Rotation.from_rotvec([0.3, -0.5, 0.7]).as_matrix(), ["u", "v"]),
}


def _f(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def write_rotated(R: np.ndarray, out: Path, start_xyz: np.ndarray) -> Path:
    """The five-bar files with the base frame turned by R (a joint on the base: origin R p, R R0)."""
    tree = ET.parse(SOURCE / "robot.urdf")
    for joint in tree.getroot().iter("joint"):
        if joint.find("parent").get("link") != "base_link":
            continue
        origin = joint.find("origin")
        p = np.array([float(x) for x in origin.get("xyz", "0 0 0").split()])
        R0 = rpy_to_matrix(np.array([float(x) for x in origin.get("rpy", "0 0 0").split()]))
        origin.set("xyz", _f(R @ p))
        origin.set("rpy", _f(matrix_to_rpy(R @ R0)))
    out.mkdir(parents=True, exist_ok=True)
    tree.write(out / "robot.urdf")
    side = yaml.safe_load((SOURCE / "robot.yaml").read_text())
    side["gravity"] = [float(g) for g in R @ GRAVITY_XY]
    # the start point in the new machine's in-plane components (of its end effector's axes)
    side["initial_state"].pop("end_effector")
    (out / "robot.yaml").write_text(yaml.safe_dump(side))
    basis = Mechanism(load_model(out / "robot.urdf")).ee_axes
    side["initial_state"]["end_effector"] = [float(c) for c in basis @ (R @ start_xyz)]
    (out / "robot.yaml").write_text(yaml.safe_dump(side))
    return out / "robot.urdf"


@pytest.fixture(scope="module")
def machines(tmp_path_factory):
    root = tmp_path_factory.mktemp("planes")
    # the x-y machine's start point (the shipped file's end_effector [-0.05, 0.35]), in 3d
    mech0 = Mechanism(load_model(SOURCE / "robot.urdf"))
    start = mech0.points(initial_state(mech0))[2][mech0.model.end_effector_chain]
    out = {}
    for name, (R, names) in PLANES.items():
        urdf = write_rotated(R, root / name, start)
        out[name] = (urdf, Mechanism(load_model(urdf)), R, names)
    return out


@pytest.mark.parametrize("plane", list(PLANES))
def test_loads_in_its_plane_with_the_users_components(machines, plane):
    _, mech, R, names = machines[plane]
    model = mech.model
    assert model.planar and mech.m == 2
    assert mech.ee_names == names
    # the plane's normal is the machine's axis direction, R z
    assert np.allclose(np.abs(model.plane_basis[2] @ (R @ [0.0, 0.0, 1.0])), 1.0, atol=1e-12)
    q0 = initial_state(mech)
    assert mech.gap(q0) < 1e-13


@pytest.mark.parametrize("plane", [p for p in PLANES if p != "xy"])
def test_same_motion_rotated(machines, plane):
    """Joint angles are frame-free: the turned machine under turned gravity moves as the x-y one."""
    _, ref, _, _ = machines["xy"]
    _, mech, R, names = machines[plane]
    q0_ref, q0 = initial_state(ref), initial_state(mech)
    assert np.abs(q0 - q0_ref).max() < 1e-12
    options = SimulationOptions(formulation="scdd", integrator="rk4", dt=1e-5, sample=1e-3)
    run_ref = Simulator(ref, options).run(ConstantTorque(TORQUE), 0.05)
    run = Simulator(mech, options).run(ConstantTorque(TORQUE), 0.05)
    assert np.abs(run_ref.q - q0_ref).max() > 1e-2  # it moved
    assert np.abs(run.q - run_ref.q).max() < 1e-10
    tips_ref, tips = ref.points(run_ref.q[-1])[2], mech.points(run.q[-1])[2]
    assert np.abs(tips - tips_ref @ R.T).max() < 1e-12
    # the end effector's components are the tip's along the user's in-plane directions
    ee_point = tips[mech.model.end_effector_chain]
    assert np.abs(run.ee[-1] - mech.ee_axes @ ee_point).max() < 1e-15
    assert run.header()[1 + 2 * mech.n:3 + 2 * mech.n] == [f"ee_{c}" for c in names]


@pytest.mark.parametrize("plane", list(PLANES))
def test_matches_pinocchio(machines, plane):
    pytest.importorskip("pinocchio")
    urdf, mech, _, _ = machines[plane]
    peer = PinocchioMachine(urdf, mech.model, baumgarte=(100.0, 20.0))
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(3):
        q, qd, tau_a = random_consistent_state(mech, rng)
        ours = Dynamics(mech).accelerations(q, qd, tau_a)
        theirs = peer.accelerations(q, qd, mech.split_tau(tau_a))
        worst = max(worst, float(np.abs(ours - theirs).max() / np.abs(theirs).max()))
    assert worst <= 1e-9
    q0 = initial_state(mech)
    assert peer.gap(q0) < 1e-12
    options = SimulationOptions(formulation="scdd", integrator="rk4", dt=1e-5, sample=1e-3)
    run = Simulator(mech, options).run(ConstantTorque(TORQUE), 0.2)
    q_pin = pinocchio_run(peer, mech, q0, np.asarray(TORQUE), run.t)
    err = float(np.abs(run.q - q_pin).max())
    print(f"{plane}: accelerations {worst:.1e} relative; moved {np.abs(q_pin - q0).max():.3g} rad, "
          f"max |q - q_pinocchio| {err:.2e} rad")
    assert np.abs(q_pin - q0).max() > 1e-2
    assert err < 1e-6


def test_equilibrated_pivot_ratio_is_free_of_scale():
    """SCDD's conditioning: the pivot ratio of D S D (D = diag(S)^-1/2) from S's own factors.
    Rows scaled by 1e-6..1e6 (units, a 6 mg ball beside 10 g links) leave it as it was;
    S's raw pivot ratio drops with the scales; a singular S stays (near) zero."""
    from elastic_pm_dyn.small_linalg import equilibrated_pivot_ratio, lu_factor
    rng = np.random.default_rng(5)
    B = rng.normal(size=(6, 9))
    S = B @ B.T

    def ratios(A):
        lu, piv, work = A.copy(), np.empty(len(A), dtype=np.int64), np.empty(len(A))
        raw = lu_factor(lu, piv)
        return raw, equilibrated_pivot_ratio(lu, piv, np.diag(A).copy(), work)

    raw, eq = ratios(S)
    D = 1 / np.sqrt(np.diag(S))
    assert abs(eq - ratios(S * D[:, None] * D[None, :])[1]) < 1e-3 * eq  # the equilibrated matrix's own
    worst_raw, worst_eq = 1.0, 1.0
    for _ in range(20):
        d = 10.0 ** rng.uniform(-6, 6, 6)
        raw_s, eq_s = ratios(S * d[:, None] * d[None, :])
        worst_raw, worst_eq = min(worst_raw, raw_s / raw), min(worst_eq, eq_s / eq)
    # the pivot order follows the scaled rows: not exactly invariant (5.6e-4 of its own at worst here),
    # where the raw ratio falls with the scales (to 1e-19 here)
    print(f"raw ratio down to {worst_raw:.1e} of its own, equilibrated to {worst_eq:.1e}")
    assert worst_raw < 1e-12 and worst_eq > 1e-4
    B[5] = B[0] + B[1]  # a dependent row: singular
    assert ratios(B @ B.T)[1] < 1e-12
