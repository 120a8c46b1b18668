"""Energy balance: conserved without damping and torque, never increasing with damping."""

import numpy as np
import pytest
from conftest import random_state, without_damping

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque


def _energies(mech: Mechanism, result) -> np.ndarray:
    return np.array([sum(mech.energy(q, qd)) for q, qd in zip(result.q, result.qd, strict=True)])


def _excited_state(mech: Mechanism, seed: int):
    q, qd, _ = random_state(mech, np.random.default_rng(seed))
    return q, qd


@pytest.mark.parametrize(("formulation", "stabilization"), [("scdd", "none"), ("scdd", "projection"),
                                                            ("lda", "none")])
def test_energy_is_conserved_without_damping(five_bar_vertical, formulation: str, stabilization: str) -> None:
    """D = 0, tau = 0, gravity on: relative energy drift <= 1e-8 over 1 s (DOP853)."""
    mech = Mechanism(without_damping(five_bar_vertical.model))
    q0, qd0 = _excited_state(mech, 30)
    sim = Simulator(mech, SimulationOptions(formulation=formulation, integrator="dop853", rtol=1e-12,
                                            atol=1e-14, stabilization=stabilization, sample=0.01))
    result = sim.run(ConstantTorque(np.zeros(2)), 1.0, q0, qd0)
    e = _energies(mech, result)
    kinetic0, _ = mech.energy(q0, qd0)
    assert kinetic0 > 0.1  # the run really moves
    drift = np.max(np.abs(e - e[0])) / np.max(np.abs(e))
    assert drift <= 1e-8, drift


def test_energy_never_increases_with_damping(five_bar) -> None:
    mech = five_bar
    q0, qd0 = _excited_state(mech, 31)
    sim = Simulator(mech, SimulationOptions(formulation="scdd", integrator="dop853", rtol=1e-12, atol=1e-14,
                                            sample=0.002))
    e = _energies(mech, sim.run(ConstantTorque(np.zeros(2)), 0.3, q0, qd0))
    increase = np.diff(e)
    assert np.all(increase <= 1e-10 * e[0]), increase.max()
    assert e[-1] < e[0] - 1e-6  # and the dampers really dissipate


def test_power_balance_with_torque(five_bar) -> None:
    """dE/dt = tau . qd_a - qd^T D qd: work done by constant motor torques, no damping."""
    mech = Mechanism(without_damping(five_bar.model))
    q0, qd0 = _excited_state(mech, 32)
    tau = np.array([0.3, -0.2])
    sim = Simulator(mech, SimulationOptions(formulation="scdd", integrator="dop853", rtol=1e-12, atol=1e-14,
                                            sample=0.005))
    r = sim.run(ConstantTorque(tau), 0.2, q0, qd0)
    e = _energies(mech, r)
    work = tau @ (r.q[:, mech.active] - r.q[0, mech.active]).T  # constant torque: work = tau . delta theta
    assert np.max(np.abs(e - e[0] - work)) <= 1e-8 * np.max(np.abs(e))
