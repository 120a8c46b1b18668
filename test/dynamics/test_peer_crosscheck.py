"""Physics cross-check against Pinocchio's constraintDynamics (skipped without ``pin``).

The Pinocchio five-bar (bench/tools/peers_five_bar.py) is built from the numbers of
docs/five_bar.md, not from our YAML loader, so this also checks what the
loader made of config/five_bar.yaml (end-effector mass split, rotor inertia, spring).
Its joint order and signs are our tree order and signs. The closure is a 3D contact
between the chain ends, solved by Pinocchio's proximal algorithm with mu = 1e-9: exact
at convergence (the regularisation only makes the all-zero z row solvable).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from consistent_states import consistent_states  # noqa: E402

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402

REPO = Path(__file__).resolve().parents[1].parent
sys.path.insert(0, str(REPO / "bench" / "tools"))
from peers_five_bar import PinFiveBar, five_bar_spec  # noqa: E402

N_STATES = 20
REL_TOL = 1e-9  # reached: ~1e-15 (round-off); 1e-6 would still show a modelling error


def _scdd(mech: Mechanism, q, qd, tau):
    qdd, lam = np.empty(mech.n), np.zeros(mech.m)
    cond, gap = accelerations(FORMULATION_CODES["scdd"], mech.arrays, q, qd, tau, 0.0, 0.0, np.zeros(mech.n),
                              qdd, lam)
    assert cond > 1e-6 and gap < 1e-12
    return qdd, lam


@pytest.mark.parametrize("config, gravity", [("five_bar.yaml", (0.0, 0.0, 0.0)),
                                             ("five_bar_vertical.yaml", (0.0, -9.81, 0.0))])
def test_scdd_matches_pinocchio_constraint_dynamics(config, gravity):
    path = REPO / "config" / config
    if not path.exists():
        pytest.skip(f"{config} not in this checkout")
    mech = Mechanism(load_model(path))
    assert np.allclose(mech.arrays.gravity, gravity), "peer model's gravity must match the config"
    assert mech.joint_names == ["left_motor", "left_spring", "left_elbow",
                                "right_motor", "right_spring", "right_elbow"]
    peer = PinFiveBar(five_bar_spec(gravity))
    worst_qdd = worst_lam = 0.0
    for q, qd, tau in consistent_states(mech, np.random.default_rng(20240), N_STATES):
        qdd, lam = _scdd(mech, q, qd, tau)
        a = peer.accelerations(q, qd, tau)
        assert peer.prox.iter < peer.prox.max_iter, "Pinocchio's proximal solver did not converge"
        worst_qdd = max(worst_qdd, float(np.abs(a - qdd).max() / np.abs(qdd).max()))
        # Cut force: our multiplier is the force on the left chain end, world frame;
        # Pinocchio's contact force is the same force in the left elbow's joint frame.
        psi = q[0] + q[2]
        c, s = np.cos(psi), np.sin(psi)
        f = peer.contact_force()
        f_world = np.array([c * f[0] - s * f[1], s * f[0] + c * f[1]])
        worst_lam = max(worst_lam, float(np.abs(f_world - lam).max() / np.abs(lam).max()))
    print(f"{config}: max rel. error qdd {worst_qdd:.2e}, cut force {worst_lam:.2e} over {N_STATES} states")
    assert worst_qdd <= REL_TOL
    assert worst_lam <= REL_TOL
