"""A motor's torque scale (model YAML key ``torque_scale`` on an active joint, issue #42): the motor
applies torque_scale * u for a command u. So the scaled machine under u moves exactly as the file's
machine under torque_scale * u (simulator and plant), needs 1 / torque_scale of the file's command
to hold a pose against gravity or to follow a motion (statics, inverse dynamics), and a file
without the key is the file it was (transmission exactly the identity)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from elastic_pm_dyn.dynamics.inverse import motor_torques
from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state
from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

CONFIG = Path(__file__).resolve().parents[2] / "config"
SCALE = {"left_motor": 0.8, "right_motor": 1.25}


def _scaled(tmp_path: Path, source: str, scales: dict[str, float]) -> Path:
    data = yaml.safe_load((CONFIG / source).read_text())
    for chain in data["chains"]:
        for joint in chain["joints"]:
            if joint.get("name") in scales:
                joint["torque_scale"] = scales[joint["name"]]
    out = tmp_path / f"scaled_{source}"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def test_a_file_without_the_key_is_unchanged() -> None:
    mech = Mechanism(load_model(CONFIG / "five_bar.yaml"))
    assert np.array_equal(mech.transmission[mech.active], np.eye(len(mech.active))) and not mech.spread


def test_the_scaled_machine_under_u_moves_as_the_file_under_scale_u(tmp_path: Path) -> None:
    """Same trajectory, bit-near: the force on each motor's joint is s u in both."""
    scaled = Mechanism(load_model(_scaled(tmp_path, "five_bar_vertical.yaml", SCALE)))
    plain = Mechanism(load_model(CONFIG / "five_bar_vertical.yaml"))
    u = np.array([0.3, -0.2])
    s = np.array([SCALE[n] for n in plain.active_names])
    opts = SimulationOptions(integrator="rk4", dt=2e-5, sample=1e-3)
    a = Simulator(scaled, opts).run(ConstantTorque(u), 0.05)
    b = Simulator(plain, opts).run(ConstantTorque(s * u), 0.05)
    assert np.abs(a.q - b.q).max() < 1e-12 * (1 + np.abs(b.q).max())
    # and not as the file under u itself: the scale acts
    c = Simulator(plain, opts).run(ConstantTorque(u), 0.05)
    assert np.abs(c.q - b.q)[:, plain.active].max() > 1e-4


def test_holding_and_inverse_dynamics_need_one_over_the_scale(tmp_path: Path) -> None:
    """Gravity on the vertical five-bar: the motors must apply the file's holding torque, so the
    command is that torque / s; likewise for an accelerating motion."""
    scaled = Mechanism(load_model(_scaled(tmp_path, "five_bar_vertical.yaml", SCALE)))
    plain = Mechanism(load_model(CONFIG / "five_bar_vertical.yaml"))
    s = np.array([SCALE[n] for n in plain.active_names])
    q = rest_state(plain)
    hold = holding_torques(plain, q)
    assert np.abs(hold).min() > 1e-3  # gravity loads both motors
    np.testing.assert_allclose(holding_torques(scaled, q), hold / s, rtol=1e-10)
    rng = np.random.default_rng(3)
    qd, qdd = 0.1 * rng.standard_normal(plain.n), rng.standard_normal(plain.n)
    np.testing.assert_allclose(motor_torques(scaled, q, qd, qdd), motor_torques(plain, q, qd, qdd) / s, rtol=1e-10)


def test_only_motors_take_a_positive_scale(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match="torque_scale"):
        load_model(_scaled(tmp_path, "five_bar.yaml", {"left_spring": 1.1}))
    with pytest.raises(ModelError, match=r"positive|> 0"):
        load_model(_scaled(tmp_path, "five_bar.yaml", {"left_motor": 0.0}))
