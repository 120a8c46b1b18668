"""The rigid model driven by its own feedforward follows the line; the elastic one vibrates."""

import numpy as np
import pytest

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.motion.feedforward import line_torques, rigid_feedforward
from elastic_pm_dyn.motion.trajectory import QuinticLine
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import FunctionTorque, TorqueTable

LINE = QuinticLine(np.array([-0.05, 0.35]), np.array([0.05, 0.45]), 0.2, 0.1)


def test_quintic_time_law_is_rest_to_rest() -> None:
    for t in (0.0, LINE.move):
        _, v, a = LINE(t)
        assert np.all(v == 0) and np.allclose(a, 0, atol=1e-12)
    p_mid, v_mid, _ = LINE(LINE.move / 2)
    assert np.allclose(p_mid, (LINE.start + LINE.end) / 2)
    assert np.linalg.norm(v_mid) == pytest.approx(1.875 * np.linalg.norm(LINE.end - LINE.start) / LINE.move)


@pytest.mark.parametrize("formulation", ["scdd", "lda"])
def test_rigid_model_follows_the_line_under_continuous_feedforward(five_bar_vertical, formulation: str) -> None:
    """<= 1e-8 m from the line, with gravity, under the continuous (not sampled) torques."""
    ff = rigid_feedforward(five_bar_vertical.model)
    rigid = ff.mech
    torque = FunctionTorque(lambda t: ff.torques(*LINE(t)))
    r = Simulator(rigid, SimulationOptions(formulation=formulation, sample=0.005)).run(torque, LINE.duration)
    reference = np.array([LINE(t)[0] for t in r.t])
    assert np.max(np.linalg.norm(r.ee - reference, axis=1)) <= 1e-8


def test_elastic_model_vibrates_at_the_spring_mode_under_sampled_feedforward(five_bar) -> None:
    """The paper's Fig. 3: ZOH feedforward excites the ~550 Hz branch-force vibration."""
    from elastic_pm_dyn.analysis.metrics import residual_vibration
    times, tau, _ = line_torques(five_bar.model, LINE, 1000.0)
    r = Simulator(five_bar, SimulationOptions(sample=1e-4)).run(TorqueTable(times, tau), LINE.duration)
    vib = residual_vibration(r.t, r.branch_forces[:, 0], LINE.move)
    assert 500 < vib.f_d < 600
    assert vib.amplitude > 1e-3  # N: visible, and ...
    assert np.abs(r.branch_forces).max() < 10.0  # ... small against the quasi-static force


def test_feedforward_torques_are_gravity_compensation_at_rest(five_bar_vertical) -> None:
    """At rest (hold phase) the torques hold the machine against gravity: the rigid model
    started there stays put."""
    ff = rigid_feedforward(five_bar_vertical.model)
    p = np.array([0.0, 0.4])
    tau = ff.torques(p, np.zeros(2), np.zeros(2))
    assert np.linalg.norm(tau) > 0.1
    q0 = ff.joint_motion(p, np.zeros(2), np.zeros(2))[0]
    r = Simulator(ff.mech, SimulationOptions(sample=0.01)).run(
        FunctionTorque(lambda t: tau), 0.1, q0, np.zeros(ff.mech.n))
    assert np.max(np.abs(r.q - q0)) <= 1e-12


def test_line_torques_table_shape(five_bar) -> None:
    times, tau, names = line_torques(five_bar.model, LINE, 1000.0)
    assert names == ["left_motor", "right_motor"]
    assert len(times) == 301 and tau.shape == (301, 2)
    assert np.all(tau[0] == 0) and np.all(np.isfinite(tau))
    assert Mechanism(five_bar.model).n == 6
