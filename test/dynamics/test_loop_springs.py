"""Springs on joints a loop fixes (issue #26): the Robotiq 2F-85 v4 and xArm grippers of MuJoCo
Menagerie (test/robots/third_party/, mesh geoms removed; their first comment names the source).

Each finger is a four-bar of one degree of freedom (driver, spring link, follower) whose spring
link carries a preloaded spring (stiffness 0.05, springref 2.62): the loop fixes that joint, so
it is passive with its spring, not an independent elastic coordinate (which left the loop short
of joints: "the closures give 5 equations but the legs have 3 passive joints"). Checked against
MuJoCo with its constraints tightened over 0.2 s from the file's pose: the preload moves the
fingers, so the springs must act where MuJoCo puts them.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import PASSIVE
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.model.mjcf import compile_mjcf, mujoco_qpos
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

THIRD = Path(__file__).resolve().parents[1] / "robots" / "third_party"
GRIPPERS = {"robotiq_2f85_v4.xml": ("left_spring_link_joint", "right_spring_link_joint"),
            "xarm7_hand.xml": ("left_inner_knuckle_joint", "right_inner_knuckle_joint")}
DURATION, SAMPLE, MJ_DT = 0.2, 1e-3, 1e-5


def _mujoco(path: Path, mech: Mechanism, q0: np.ndarray, samples: int) -> np.ndarray:
    """MuJoCo from our start pose at rest, constraints tightened (solref at its floor 2 dt,
    solimp 0.9999), contacts, limits, friction loss and actuators off (the motor unpowered), RK4."""
    mujoco = pytest.importorskip("mujoco")
    m = compile_mjcf(path)
    m.opt.timestep = MJ_DT
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.opt.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
                           | mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS | mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    m.eq_solref[:] = (2 * MJ_DT, 1.0)
    m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    d.qpos[:] = mujoco_qpos(m, mech.joint_names, q0)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in mech.joint_names]
    out = [d.qpos[adr].copy()]
    for _ in range(samples - 1):
        mujoco.mj_step(m, d, nstep=round(SAMPLE / MJ_DT))
        out.append(d.qpos[adr].copy())
    return np.array(out)


def _no_dry_friction(model):
    """The machine with its joints' friction loss off, as the MuJoCo peer here runs it."""
    from dataclasses import replace
    return replace(model, chains=tuple(replace(c, joints=tuple(replace(j, coulomb=0.0) for j in c.joints))
                                       for c in model.chains))


@pytest.mark.parametrize("name", list(GRIPPERS))
def test_a_spring_on_a_joint_its_loop_fixes_is_passive_and_matches_mujoco(name: str) -> None:
    path = THIRD / name
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mech = Mechanism(_no_dry_friction(load_model(path, servos_as_motors=True)))  # off in MuJoCo here too
    said = [str(w.message) for w in caught if "sits on a loop" in str(w.message) or "sit on a loop" in str(w.message)]
    assert len(said) == 1 and all(n in said[0] for n in GRIPPERS[name]), said
    joints = {j.name: j for j in mech.model.joints}
    for spring in GRIPPERS[name]:
        assert joints[spring].role == PASSIVE and joints[spring].stiffness == 0.05 and joints[spring].rest == 2.62
    assert mech.m == len(mech.passive) == 5 and len(mech.active) == 1 and len(mech.ae) == 1
    q0 = initial_state(mech)
    run = Simulator(mech, SimulationOptions(integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)) \
        .run(ConstantTorque(np.zeros(1)), DURATION)
    peer = _mujoco(path, mech, q0, len(run.t))
    err = float(np.abs(peer - run.q).max())
    moved = float(np.abs(run.q - q0).max())
    print(f"\n{name}: moved {moved:.3g} rad, gap {run.gap.max():.2e} m, max |q - q_mujoco| {err:.2e} rad")
    assert moved > 5e-3  # the preloaded springs close the fingers
    assert run.gap.max() < 1e-12
    assert err < 1e-6


def test_without_its_spring_the_same_loop_still_counts(tmp_path) -> None:
    """The same gripper with the spring links' springs removed: the joints are plain passive
    joints, the same counts, the same machine (the springs only change what drives it)."""
    text = (THIRD / "xarm7_hand.xml").read_text().replace('stiffness="0.05" springref="2.62" ', "")
    path = tmp_path / "hand.xml"
    path.write_text(text)
    mech = Mechanism(load_model(path, servos_as_motors=True))
    assert mech.m == len(mech.passive) == 5
    assert float(np.abs(mech.model.joints[2].stiffness)) == 0.0


def test_a_loop_short_of_joints_without_springs_is_still_refused(tmp_path) -> None:
    """The spring link welded (no joint): one loop joint fewer than its rows, nothing to make
    passive: refused in one line with the counts, as before."""
    text = (THIRD / "xarm7_hand.xml").read_text() \
        .replace('<joint name="left_inner_knuckle_joint" class="spring_link"/>', "")
    path = tmp_path / "hand.xml"
    path.write_text(text)
    with pytest.raises(ModelError) as err:
        load_model(path, servos_as_motors=True)
    assert "\n" not in str(err.value) and "equations" in str(err.value), str(err.value)
