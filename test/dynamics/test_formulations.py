"""The formulations cross-check each other at random consistent states (physics by physics).

Multipliers (eqs 3-5), compact Lagrange-D'Alembert (eqs 19-26) and exact SCDD (eqs 33-41)
are three eliminations of the same constrained equations: they must agree to round-off.
"""

import numpy as np
import pytest
from conftest import random_state

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations

EXACT = ("scdd", "lda", "multipliers")


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


@pytest.mark.parametrize("machine", ["five_bar", "five_bar_vertical"])
def test_exact_formulations_agree_at_random_states(machine: str, request: pytest.FixtureRequest) -> None:
    mech = request.getfixturevalue(machine)
    dyn = {f: Dynamics(mech, f) for f in EXACT}
    rng = np.random.default_rng(1)
    worst = {f: 0.0 for f in EXACT}
    for _ in range(120):
        q, qd, tau = random_state(mech, rng)
        ref = dyn["lda"].accelerations(q, qd, tau)
        for f in ("scdd", "multipliers"):
            worst[f] = max(worst[f], _rel(dyn[f].accelerations(q, qd, tau), ref))
    assert worst["scdd"] <= 1e-9, worst
    assert worst["multipliers"] <= 1e-9, worst


def test_accelerations_satisfy_the_closure_and_the_chain_equations(five_bar) -> None:
    """A qdd = gamma (eq 8 twice differentiated) and M qdd + h = tau + A^T lambda (eq 33)."""
    mech = five_bar
    dyn = Dynamics(mech, "scdd")
    rng = np.random.default_rng(2)
    for _ in range(20):
        q, qd, tau = random_state(mech, rng)
        qdd = dyn.accelerations(q, qd, tau)
        t = mech.terms(q, qd)
        assert np.allclose(t.A @ qdd, t.gamma, rtol=0, atol=1e-10 * np.abs(t.A).max() * np.abs(qdd).max())
        lhs = t.M @ qdd + t.h
        rhs = mech.split_tau(tau) + t.A.T @ dyn.cut_force
        assert np.max(np.abs(lhs - rhs)) <= 1e-9 * np.max(np.abs(t.h) + np.abs(t.M @ qdd))


def test_scdd_and_multipliers_give_the_same_cut_forces(five_bar) -> None:
    rng = np.random.default_rng(3)
    scdd, mult = Dynamics(five_bar, "scdd"), Dynamics(five_bar, "multipliers")
    for _ in range(20):
        q, qd, tau = random_state(five_bar, rng)
        scdd.accelerations(q, qd, tau)
        mult.accelerations(q, qd, tau)
        assert _rel(scdd.cut_force, mult.cut_force) <= 1e-9


def test_one_pass_scdd_is_exact_when_the_previous_accelerations_are_current(five_bar) -> None:
    """The paper's loop (eqs 35-39) has the exact solution as its fixed point."""
    rng = np.random.default_rng(4)
    n = five_bar.n
    for _ in range(10):
        q, qd, tau = random_state(five_bar, rng)
        tau_t = five_bar.split_tau(tau)
        exact, lam = np.empty(n), np.zeros(five_bar.m)
        accelerations(FORMULATION_CODES["scdd"], five_bar.arrays, q, qd, tau_t, 0.0, 0.0, np.zeros(n), exact, lam)
        one = np.empty(n)
        accelerations(FORMULATION_CODES["scdd_one_pass"], five_bar.arrays, q, qd, tau_t, 0.0, 0.0, exact.copy(),
                      one, lam)
        assert _rel(one, exact) <= 1e-9
        # ... and not when they lag: the variant is not silently the exact one.
        lagged = np.empty(n)
        accelerations(FORMULATION_CODES["scdd_one_pass"], five_bar.arrays, q, qd, tau_t, 0.0, 0.0,
                      np.zeros(n), lagged, lam)
        assert _rel(lagged, exact) > 1e-6


def test_mass_matrix_is_symmetric_positive_definite_and_block_diagonal(five_bar) -> None:
    rng = np.random.default_rng(5)
    q, _, _ = random_state(five_bar, rng)
    M = five_bar.terms(q).M
    assert np.allclose(M, M.T, rtol=0, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(M) > 0)
    assert np.all(M[:3, 3:] == 0.0)


def test_skew_symmetry_of_mdot_minus_2c(five_bar) -> None:
    """Property 2 below eq 19: qd^T (Mdot - 2C) qd = 0, i.e. d/dt(qd^T M qd / 2) = qd^T (tau - eta - K q - D qd).

    Equivalently the Coriolis/centrifugal part of h does no work: qd . h_c = qd^T Mdot qd / 2.
    """
    mech = five_bar
    rng = np.random.default_rng(6)
    q, qd, _ = random_state(mech, rng)
    eps = 1e-7
    Mdot = (mech.terms(q + eps * qd).M - mech.terms(q - eps * qd).M) / (2 * eps)
    # h without springs/dampers/gravity: the velocity-dependent part only.
    h_total = mech.terms(q, qd).h
    h_static = mech.terms(q, np.zeros_like(qd)).h
    damping = np.array([j.damping for j in mech.model.joints])
    h_coriolis = h_total - h_static - damping * qd
    assert qd @ h_coriolis == pytest.approx(0.5 * qd @ Mdot @ qd, rel=1e-6)
