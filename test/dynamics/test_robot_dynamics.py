"""Own-robot files over time, against engines we did not write.

(a) URDF + closure sidecar: our ``simulate`` (SCDD; DOP853 at rtol 1e-10 and RK4 at
    dt = 1e-5 s) against Pinocchio's ``constraintDynamics`` on the SAME files, its closures
    built as Gepetto's loader builds them (``RigidConstraintModel`` CONTACT_3D between the
    closure frames, LOCAL), with a small Baumgarte corrector against drift, integrated by
    scipy's DOP853 at rtol 1e-10: 0.2 s from the assembled start pose under gravity (the
    five-bar has none in its file: it is driven by constant motor torques), joint angles
    agree to 1e-6 rad; also on the trees (a parallelogram Delta whose legs branch, two arms
    welded at their hands (6d), a rocker pinned to the base). Springs and dampers enter Pinocchio as joint torques
    -c (q - q0) - d qd (Pinocchio has no such elements, docs/peers.md).
(b) MJCF: the four-bar with a spring in its loop against MuJoCo's own RK4 over 0.2 s, within
    the error of MuJoCo's soft loop closure (the bound is explained at the test).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pinocchio_urdf import PinocchioMachine
from scipy.integrate import solve_ivp

from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

ROBOTS = Path(__file__).resolve().parents[1] / "robots"
FIVE_BAR_URDF = ROBOTS / "five_bar_urdf" / "robot.urdf"
FOUR_BAR_URDF = ROBOTS / "four_bar_onshape" / "robot.urdf"
DELTA_URDF = ROBOTS / "delta_urdf" / "robot.urdf"
FOUR_BAR_MJCF = ROBOTS / "four_bar_spring.xml"
TREES = ("delta_parallelogram", "weld_arms", "base_pinned", "split_rod")  # legs that branch, a 6d weld, a closure
# to the base, a rod on two balls spinning freely (a Gepetto-style sidecar)
DURATION = 0.2  # [s]
SAMPLE = 1e-3  # [s]
ANGLE_TOL = 1e-6  # [rad] (and m for the springs)
MUJOCO_TOL = 2e-4  # [rad]: MuJoCo's soft loop closure (7.4e-5 measured), see the MJCF test
# Motor torques [N m]: the five-bar has no gravity, so it is driven; the others also fall.
TORQUES = {"five_bar": [0.4, -0.3], "four_bar": [1.0], "delta": [0.8, -0.5, 0.3],
           "delta_parallelogram": [0.8, -0.5, 0.3], "weld_arms": [0.3, -0.2], "base_pinned": [0.2],
           "split_rod": [0.3]}


def pinocchio_run(peer: PinocchioMachine, mech: Mechanism, q0: np.ndarray, tau_active: np.ndarray,
                  t_eval: np.ndarray) -> np.ndarray:
    """Pinocchio's accelerations integrated by DOP853 at rtol 1e-10 in our tree coordinates."""
    n = mech.n
    tau = mech.split_tau(tau_active)

    def rhs(_t, y):
        return np.concatenate([y[n:], peer.accelerations(y[:n], y[n:], tau)])

    sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), np.concatenate([q0, np.zeros(n)]), method="DOP853",
                    rtol=1e-10, atol=1e-12, t_eval=t_eval)
    assert sol.success, sol.message
    return sol.y[:n].T


def ours(mech: Mechanism, tau_active, integrator: str) -> tuple[np.ndarray, np.ndarray]:
    options = SimulationOptions(formulation="scdd", integrator=integrator, dt=1e-5, sample=SAMPLE)
    run = Simulator(mech, options).run(ConstantTorque(list(tau_active)), DURATION)
    return run.t, run.q


CASES = [("five_bar", FIVE_BAR_URDF), ("four_bar", FOUR_BAR_URDF), ("delta", DELTA_URDF)] + \
    [(name, ROBOTS / name / "robot.urdf") for name in TREES]


@pytest.mark.parametrize(("name", "urdf"), CASES, ids=[c[0] for c in CASES])
def test_simulation_matches_pinocchio_over_time(name, urdf):
    pytest.importorskip("pinocchio")
    mech = Mechanism(load_model(urdf))
    q0 = initial_state(mech)
    tau = np.asarray(TORQUES[name], dtype=float)
    # Baumgarte gains small against the drift of the integrated closure: Kd = 2 zeta w, Kp = w^2
    # at w = 10 1/s, so that their effect stays far below the 1e-6 rad compared here.
    peer = PinocchioMachine(urdf, mech.model, baumgarte=(100.0, 20.0))
    assert peer.gap(q0) < 1e-12  # the same start pose for Pinocchio's kinematics
    t, q_dop = ours(mech, tau, "dop853")
    q_pin = pinocchio_run(peer, mech, q0, tau, t)
    _, q_rk4 = ours(mech, tau, "rk4")
    moved = float(np.abs(q_pin - q0).max())
    err_dop = float(np.abs(q_dop - q_pin).max())
    err_rk4 = float(np.abs(q_rk4 - q_pin).max())
    gap = max(peer.gap(q) for q in q_pin[::20])
    print(f"{name}: moved {moved:.3g}, max |q - q_pinocchio| DOP853 {err_dop:.2e}, RK4 {err_rk4:.2e}, "
          f"Pinocchio's closure gap {gap:.1e} m")
    assert moved > 1e-2  # a real motion, not a machine at rest
    assert err_dop < ANGLE_TOL and err_rk4 < ANGLE_TOL


def mujoco_run(xml: Path, mech: Mechanism, q0: np.ndarray, tau_active, n_samples: int) -> np.ndarray:
    """MuJoCo's own RK4 at its file's dt = 1e-4 s, motors driven through ctrl (gear 1)."""
    import mujoco
    m = mujoco.MjModel.from_xml_path(str(xml))
    d = mujoco.MjData(m)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in mech.joint_names]
    qadr = [m.jnt_qposadr[j] for j in ids]
    d.qpos[qadr] = q0
    d.ctrl[:] = tau_active
    mujoco.mj_forward(m, d)
    steps = round(SAMPLE / m.opt.timestep)
    out = [d.qpos[qadr].copy()]
    for _ in range(n_samples - 1):
        mujoco.mj_step(m, d, nstep=steps)
        out.append(d.qpos[qadr].copy())
    return np.array(out)


def test_mjcf_four_bar_matches_mujoco_over_time():
    """The MJCF four-bar is the URDF four-bar (same start pose and, up to the 1e-9 kg closure
    frames the MJCF lacks, the same run); against MuJoCo the angles agree within its soft loop.

    Why that size (measured 7.4e-5 rad, on the rocker): a ``connect`` is soft, its force
    regularised by R = (1 - d)/d * diag(A) with A the constraint-space inverse inertia and the
    impedance d capped at 0.9999 by MuJoCo (solimp 0.999999 changes nothing). The coupler's
    2e-6 kg spring half makes diag(A) ~ 1.7e5 1/kg, so R ~ 17 1/kg, far above the inverse
    inertia of the rocker and the coupler (a few 1/kg): in those directions the loop gives,
    the start accelerations differ by 18 % and the angles by ~7e-5 rad after 0.2 s. With a
    2e-3 kg spring half instead, R ~ 0.017 and the runs agree to 8e-8 rad.
    """
    pytest.importorskip("mujoco")
    mech = Mechanism(load_model(FOUR_BAR_MJCF))
    urdf = Mechanism(load_model(FOUR_BAR_URDF))
    q0 = initial_state(mech)
    np.testing.assert_allclose(q0, initial_state(urdf), rtol=0, atol=1e-14)
    tau = np.asarray(TORQUES["four_bar"], dtype=float)
    t, q = ours(mech, tau, "dop853")
    _, q_urdf = ours(urdf, tau, "dop853")
    q_mj = mujoco_run(FOUR_BAR_MJCF, mech, q0, tau, len(t))
    err = float(np.abs(q - q_mj).max())
    same = float(np.abs(q - q_urdf).max())
    print(f"four-bar MJCF: moved {np.abs(q - q0).max():.3g}, max |q - q_mujoco| {err:.2e}, "
          f"MJCF vs URDF model {same:.1e}")
    assert same < 1e-8
    assert err < MUJOCO_TOL
