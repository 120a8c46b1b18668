"""The ROS-free parts behind the nodes: command decoding, references, the plant session."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import line_torques, rigid_feedforward
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.references import JointReference, LineReference
from elastic_pm_dyn.ros.commands import CommandDecoder
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

FIVE_BAR = Path(__file__).resolve().parents[2] / "config" / "five_bar.yaml"
ACTIVE = ["left_motor", "right_motor"]
REFERENCE_LINE = REFERENCE_MANOEUVRE.line


@pytest.fixture(scope="module")
def model():
    return load_model(FIVE_BAR)


def test_command_decoder_orders_and_rejects() -> None:
    d = CommandDecoder(ACTIVE, ["right_motor", "left_motor"])
    np.testing.assert_array_equal(d.from_array([2.0, 1.0]), [1.0, 2.0])
    np.testing.assert_array_equal(d.from_joint_state(["right_motor", "left_motor"], [2.0, 1.0]), [1.0, 2.0])
    with pytest.raises(InputError, match="2 names but 1 efforts"):
        d.from_joint_state(ACTIVE, [1.0])
    with pytest.raises(InputError, match="NaN or Inf"):
        d.from_array([1.0, np.inf])
    with pytest.raises(InputError, match="must list each active joint once"):
        CommandDecoder(ACTIVE, ["left_motor", "left_motor"])


def test_line_reference_grid_equals_line_torques(model) -> None:
    times, torques, _ = line_torques(model, REFERENCE_LINE, 1000.0)
    ref = LineReference(rigid_feedforward(model), REFERENCE_LINE, 1000.0)
    np.testing.assert_array_equal([ref.sample(k / 1000.0).tau for k in range(len(times))], torques)
    off_grid = ref.sample(0.1234)  # solved on demand
    expected = rigid_feedforward(model).torques(*REFERENCE_LINE(0.1234))
    np.testing.assert_allclose(off_grid.tau, expected, rtol=1e-10, atol=1e-12)


def test_joint_reference_interpolates_smoothly(model) -> None:
    ff = rigid_feedforward(model)
    act = ff.mech.active
    times = [0.0, 0.1, 0.2]
    pos = np.array([ff.joint_motion(*REFERENCE_LINE(t))[0][act] for t in times])
    ref = JointReference(rigid_feedforward(model), ACTIVE, times, pos)  # positions only: rest-to-rest segments
    for t, p in zip(times, pos, strict=True):
        s = ref.sample(t)
        np.testing.assert_allclose(s.q[act], p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ref.sample(0.0).qd[act], 0.0, atol=1e-12)  # starts and ends at rest
    np.testing.assert_allclose(ref.sample(0.2).qd[act], 0.0, atol=1e-12)
    # accelerations continuous across a waypoint: C^4 segments, at rest there (velocity and acceleration zero)
    np.testing.assert_allclose(ref.sample(0.1).qd[act], 0.0, atol=1e-12)
    np.testing.assert_allclose(ref.sample(0.1 - 1e-7).qdd[act], ref.sample(0.1 + 1e-7).qdd[act], atol=1e-9)
    assert np.abs(ref.sample(0.025).qdd[act]).max() > 1.0  # and accelerating in between
    held = ref.sample(5.0)  # after the end: the last pose at rest, the static torque
    np.testing.assert_allclose(held.q[act], pos[-1], atol=1e-12)
    assert np.all(held.qd == 0.0)
    np.testing.assert_allclose(held.tau, 0.0, atol=1e-12)  # horizontal five-bar: no gravity


def test_plant_session_steps_resets_and_sets_state(model) -> None:
    mech = Mechanism(model)
    opts = SimulationOptions(sample=1e-3)
    plant = Plant(mech, opts, 1e-3)
    q, qd = plant.q0.copy(), np.zeros(mech.n)
    sim = Simulator(mech, SimulationOptions(sample=1e-3))
    tau = np.array([0.05, -0.03])
    for k in range(5):
        plant.step(tau)
        sim.advance(q, qd, ConstantTorque(tau), k * 1e-3, (k + 1) * 1e-3)
    np.testing.assert_array_equal(plant.q, q)  # the same arithmetic as offline
    assert plant.k == 5 and plant.t == pytest.approx(5e-3)
    spring = mech.joint_names.index("left_spring")
    assert plant.efforts()[spring] == pytest.approx(plant.branches().force[0], abs=1e-12)

    plant.reset()
    np.testing.assert_array_equal(plant.q, plant.q0)
    assert plant.k == 6  # a restart takes one period: time never runs back, the state gets its own stamp
    with pytest.raises(InputError, match="unknown joint"):
        plant.set_state(["elbow"], [0.0], [])
    msg = plant.set_state(["left_motor"], [plant.q0[0] + 0.02], [0.1])
    assert "state set" in msg and mech.gap(plant.q) < 1e-12
    assert plant.qd[0] == 0.1 and plant.qd[3] == 0.0  # right motor at rest, passive from the closure

    opts.singular_tol = 1e300  # force the breakdown
    with pytest.raises(SingularConfigurationError):
        plant.step(tau)
    assert plant.fault is not None and plant.k == 7
    with pytest.raises(SingularConfigurationError):  # stays stopped until reset
        plant.step(tau)


def test_a_state_topic_is_claimed_once_per_host_and_domain(tmp_path, monkeypatch) -> None:
    """Two plants in one namespace on one host: the second is refused at once, naming the first,
    whatever discovery has seen yet; another domain or topic is free, and the claim ends with its holder."""
    import subprocess
    import sys
    from types import SimpleNamespace

    from elastic_pm_dyn.ros.graph_checks import claim_on_host

    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))

    def node(name: str, domain: int) -> SimpleNamespace:
        return SimpleNamespace(context=SimpleNamespace(get_domain_id=lambda: domain),
                               get_fully_qualified_name=lambda: name)

    held = claim_on_host(node("/r1/plant", 7), ["/r1/joint_states"])
    again = claim_on_host(node("/r1/plant", 7), ["/r1/joint_states"])  # this process: the graph check's case
    others = [*claim_on_host(node("/r1/plant", 8), ["/r1/joint_states"]),  # another domain
              *claim_on_host(node("/r2/plant", 7), ["/r2/joint_states"])]  # another namespace
    # another process is refused too (flock holds across processes), until the holder lets go
    code = ("import sys, types; from elastic_pm_dyn.ros.graph_checks import claim_on_host\n"
            "n = types.SimpleNamespace(context=types.SimpleNamespace(get_domain_id=lambda: 7), "
            "get_fully_qualified_name=lambda: '/r1/other')\n"
            "try:\n    claim_on_host(n, ['/r1/joint_states'])\nexcept Exception as e:\n    print(e); sys.exit(2)\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "/r1/plant" in run.stdout
    for claim in [*held, *again[:0]]:  # one of the two users lets go: still held
        claim.release()
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120).returncode == 2
    for claim in [*again, *others]:
        claim.release()
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120).returncode == 0
