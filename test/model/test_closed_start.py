"""A robot file no motor setting of its own closes (issue #26): Gepetto's WL-16-like leg
(test/robots/third_party/wl16_like, visual and collision elements removed; the URDF's first
comment names the source). Six linear motors carry a foot on five 6-D welded rods and one
leg; with every motor at the URDF's zero the rods do not reach (residual 0.52 in the file's
rows, no pose of the passive joints closes them: it was refused). The loader now starts at
the nearest closed pose of all joints, motors included (the largest move: motor_6 by -0.118 m),
and says so; the machine then matches Pinocchio on the same files."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

URDF = Path(__file__).resolve().parents[1] / "robots" / "third_party" / "wl16_like" / "robot.urdf"


@pytest.fixture(scope="module")
def loaded() -> tuple[Mechanism, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mech = Mechanism(load_model(URDF))
    return mech, [str(w.message) for w in caught]


def test_starts_at_the_nearest_closed_pose_and_says_so(loaded) -> None:
    mech, said = loaded
    moved = [s for s in said if "do not close with the motors where the file puts them" in s]
    assert len(moved) == 1 and "motor_6 by -0.118" in moved[0] and "robot.urdf" in moved[0], said
    assert len(mech.active) == 6 and mech.m == len(mech.passive) == 30 and len(mech.elastic) == 6  # 6 rod spins
    q0 = initial_state(mech)
    assert mech.gap(q0) < 1e-12
    motors = q0[mech.active]
    assert 0.05 < np.abs(motors).max() < 0.2  # the motors moved, by centimetres, not metres


def test_matches_pinocchio_there(loaded) -> None:
    """Accelerations at the start pose at rest and moving (rates from random q_ae rates), unpowered
    and with random motor forces, against Pinocchio's constraintDynamics on the same files."""
    pytest.importorskip("pinocchio")
    from pinocchio_urdf import PinocchioMachine
    mech, _ = loaded
    q0 = initial_state(mech)
    peer = PinocchioMachine(URDF, mech.model)
    assert peer.gap(q0) < 1e-12
    dyn = Dynamics(mech)
    rng = np.random.default_rng(3)
    for qd_ae, tau in ((np.zeros(len(mech.ae)), np.zeros(6)),
                       (rng.uniform(-0.3, 0.3, len(mech.ae)), rng.uniform(-20, 20, 6))):
        qd = mech.tree_velocity(q0, qd_ae)
        ours = dyn.accelerations(q0, qd, tau)
        theirs = peer.accelerations(q0, qd, mech.split_tau(tau))
        scale = max(1.0, float(np.abs(theirs).max()))
        print(f"\nWL-16-like leg: |qdd - qdd_pinocchio| {float(np.abs(ours - theirs).max()):.2e} of {scale:.3g}")
        assert float(np.abs(ours - theirs).max()) < 1e-9 * scale, float(np.abs(ours - theirs).max())
