"""Spatial machines: Triglide (translational platform) and HEXA (6-DOF platform), n_ek = 1..4."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import random_state, without_damping

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.dynamics.jacobian import parallel_jacobian_transpose
from elastic_pm_dyn.dynamics.linear import compact_matrices
from elastic_pm_dyn.dynamics.statics import static_deflection
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

CONFIG = Path(__file__).resolve().parents[1].parent / "config"
SPREAD = {"triglide": 0.05, "hexa": 0.05}  # motor offsets that stay in the workspace [m or rad]


def _mech(name: str, n_ek: int = 1, gravity: bool = True) -> Mechanism:
    model = load_model(CONFIG / f"{name}.yaml", elastic_dof_per_chain=n_ek)
    if not gravity:
        model = replace(model, gravity=np.zeros(3))
    return Mechanism(model)


def _accel(mech: Mechanism, formulation: str, q, qd, tau) -> np.ndarray:
    qdd, lam = np.empty(mech.n), np.zeros(mech.m)
    cond, _ = accelerations(FORMULATION_CODES[formulation], mech.arrays, q, qd, mech.split_tau(tau), 0.0, 0.0,
                            np.zeros(mech.n), qdd, lam)
    assert cond > 1e-8
    return qdd


@pytest.mark.parametrize("name", ["triglide", "hexa"])
@pytest.mark.parametrize("n_ek", [1, 2, 4])
def test_formulations_agree_on_spatial_machines(name: str, n_ek: int) -> None:
    mech = _mech(name, n_ek)
    assert len(mech.elastic) == n_ek * (3 if name == "triglide" else 6)
    rng = np.random.default_rng(40 + n_ek)
    for _ in range(15):
        q, qd, tau = random_state(mech, rng, SPREAD[name])
        ref = _accel(mech, "lda", q, qd, tau)
        for f in ("scdd", "scdd_stacked", "multipliers"):
            err = np.max(np.abs(_accel(mech, f, q, qd, tau) - ref)) / np.max(np.abs(ref))
            assert err <= 1e-9, (f, err)


@pytest.mark.parametrize("name", ["triglide", "hexa"])
def test_energy_is_conserved_on_spatial_machines(name: str) -> None:
    mech = Mechanism(without_damping(_mech(name).model))
    q0, qd0, _ = random_state(mech, np.random.default_rng(50), SPREAD[name])
    sim = Simulator(mech, SimulationOptions(formulation="scdd", integrator="dop853", rtol=1e-12, atol=1e-14,
                                            stabilization="none", sample=0.01))
    r = sim.run(ConstantTorque(np.zeros(len(mech.active))), 0.1, q0, qd0)
    e = np.array([sum(mech.energy(q, qd)) for q, qd in zip(r.q, r.qd, strict=True)])
    assert np.max(np.abs(e - e[0])) <= 1e-8 * np.max(np.abs(e))
    assert r.gap.max() <= 1e-10


@pytest.mark.parametrize("name", ["triglide", "hexa"])
def test_closure_and_formulation_agreement_in_a_run(name: str) -> None:
    """Gravity acts, the motors are free: 20 ms of falling, SCDD (platform) against L-D'A.

    n_ek = 2 puts light rod segments between stiff springs (modes of several kHz): RK4
    needs dt below 2 sqrt(2) / omega_max, which `elastic-pm-dyn check` reports.
    """
    mech = _mech(name, 2)
    q0 = initial_state(mech)
    hold = np.zeros(len(mech.active))
    runs = {}
    for f in ("scdd", "lda"):
        sim = Simulator(mech, SimulationOptions(formulation=f, dt=2e-5, sample=0.002))
        runs[f] = sim.run(ConstantTorque(hold), 0.02, q0, np.zeros(mech.n))
    assert runs["scdd"].gap.max() <= 1e-12
    assert np.max(np.abs(runs["scdd"].q - runs["lda"].q)) <= 1e-9
    assert np.ptp(runs["scdd"].q[:, mech.active[0]]) > 1e-4  # it really moved


def test_eq31_triglide_force_against_finite_differences() -> None:
    mech = _mech("triglide")
    q, _, _ = random_state(mech, np.random.default_rng(60), SPREAD["triglide"])
    G_T = parallel_jacobian_transpose(mech, q)
    assert G_T.shape == (len(mech.ae), 3)
    fd = np.zeros((3, len(mech.ae)))
    for j in range(len(mech.ae)):
        h = 1e-7
        qs = []
        for sign in (1, -1):
            qq = q.copy()
            qq[mech.ae[j]] += sign * h
            qs.append(mech.end_effector(solve_pose(mech, qq, mech.passive)))
        fd[:, j] = (qs[0] - qs[1]) / (2 * h)
    assert np.allclose(G_T, fd.T, rtol=1e-6, atol=1e-7)


def test_eq31_hexa_wrench_against_virtual_work_of_point_forces() -> None:
    """Forces f_k on the six platform points are a wrench w = [sum f_k; sum (p_k - c) x f_k];
    eq 31 must give the same joint forces as sum_k (dp_k/dq_ae)^T f_k by finite differences."""
    mech = _mech("hexa")
    rng = np.random.default_rng(61)
    q, _, _ = random_state(mech, rng, SPREAD["hexa"])
    plat = [b for _, b in mech.model.closure.pairs]
    forces = rng.normal(size=(len(plat), 3))
    _, _, pts = mech.points(q)
    c = pts[mech.model.end_effector_chain]
    wrench = np.concatenate([forces.sum(0), sum(np.cross(pts[b] - c, f) for b, f in zip(plat, forces, strict=True))])
    tau = parallel_jacobian_transpose(mech, q) @ wrench
    fd = np.zeros(len(mech.ae))
    for j in range(len(mech.ae)):
        h = 1e-7
        work = []
        for sign in (1, -1):
            qq = q.copy()
            qq[mech.ae[j]] += sign * h
            _, _, p = mech.points(solve_pose(mech, qq, mech.passive))
            work.append(sum(p[b] @ f for b, f in zip(plat, forces, strict=True)))
        fd[j] = (work[0] - work[1]) / (2 * h)
    assert np.allclose(tau, fd, rtol=1e-6, atol=1e-7 * np.abs(fd).max())


def _linear_deflection(mech: Mechanism, q: np.ndarray, load: np.ndarray) -> np.ndarray:
    """Motors clamped: dp = G_e K_ee^-1 G_e^T w with K from the linearisation, G from eq 31."""
    _, _, K = compact_matrices(mech, q)
    e = np.arange(len(mech.active), len(mech.ae))
    G_e_T = parallel_jacobian_transpose(mech, q)[e]
    return G_e_T.T @ np.linalg.solve(K[np.ix_(e, e)], G_e_T @ load)


@pytest.mark.parametrize("n_ek", [1, 3])
def test_triglide_static_deflection_against_rod_stiffness(n_ek: int) -> None:
    """Rods are two-force members: dp = S^-T S^-1 f L / EA (hand formula), whatever n_ek."""
    mech = _mech("triglide", n_ek, gravity=False)
    q0 = initial_state(mech)
    f = np.array([5.0, -3.0, 20.0])
    q = static_deflection(mech, q0, f)
    dp = mech.end_effector(q) - mech.end_effector(q0)
    _, _, pts = mech.points(q0)
    origins, _, _ = mech.points(q0)
    S = []
    for leg, b in mech.model.closure.pairs:
        u1 = mech.joint_names.index(f"{mech.model.chains[leg].name}_u1")
        d = pts[b] - origins[u1]
        S.append(d / np.linalg.norm(d))
    S = np.array(S).T
    hand = np.linalg.solve(S.T, np.linalg.solve(S, f)) * 0.45 / 4.0e6
    assert np.allclose(dp, hand, rtol=1e-4, atol=1e-12)
    assert np.allclose(dp, _linear_deflection(mech, q0, f), rtol=1e-4, atol=1e-12)


def test_hexa_static_deflection_against_stiffness_and_jacobian() -> None:
    mech = _mech("hexa", 2, gravity=False)
    q0 = initial_state(mech)
    f = np.array([2.0, -1.0, 10.0])
    q = static_deflection(mech, q0, f)
    dp = mech.end_effector(q) - mech.end_effector(q0)
    lin = _linear_deflection(mech, q0, np.concatenate([f, np.zeros(3)]))
    assert np.linalg.norm(dp) > 1e-6
    assert np.allclose(dp, lin[:3] if lin.shape[0] == 6 else lin, rtol=1e-3, atol=1e-10)


def test_flexible_link_discretization_keeps_mass_and_stiffness() -> None:
    masses = {}
    for n_ek in (0, 1, 2, 4):
        model = load_model(CONFIG / "hexa.yaml", elastic_dof_per_chain=n_ek)
        masses[n_ek] = sum(j.body.mass for j in model.joints if j.body is not None)
        arm = [j for j in model.joints if j.name.startswith("leg1_arm_flex")]
        assert len(arm) == n_ek
        for j in arm:
            assert j.stiffness == pytest.approx(600.0 / (0.20 / (n_ek + 1)))
    assert all(m == pytest.approx(masses[1]) for m in masses.values())
    tri = load_model(CONFIG / "triglide.yaml", elastic_dof_per_chain=3)
    springs = [j for j in tri.joints if j.name.startswith("leg1_rod_flex")]
    assert sum(1 / j.stiffness for j in springs) == pytest.approx(0.45 / 4.0e6)  # in series: EA / L
