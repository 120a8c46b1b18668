"""Nodes that always recover, and the true cause of a blow-up.

A fault keeps the last good state; a blow-up says 'state diverged', not 'singular
configuration'; every service answers (success false with a reason) whatever the request;
~/reset and ~/set_state (also a partial one after a blow-up) recover; lockstep answers a
rejected command with the last valid one held for the period; warnings are throttled per
kind. L-D'A started at a type-2 singularity stops, and `check` there says it is singular.
Node logic in this process (callbacks called directly), plus one real node process.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.errors import DivergedStateError, InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model, parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

FIVE_BAR = Path(__file__).resolve().parents[2] / "config" / "five_bar.yaml"
HUGE = np.array([1e6, -1e6])  # [N m] blows the integration up within a period
TAU = np.array([0.01, -0.02])
MOTORS = ["left_motor", "right_motor"]


def singular_start_text() -> str:
    """The five-bar started with both arms stretched along x and the forearms in line, meeting at
    the origin: a type-2 (parallel) singularity of the rigid machine."""
    text = FIVE_BAR.read_text()
    return text[:text.index("initial_state:")] + (
        "initial_state:\n  active: {left_motor: 3.141592653589793, right_motor: 0.0}\n"
        "  guess: {left_elbow: -3.0, right_elbow: 3.0}\n")


@pytest.fixture(scope="module")
def mech() -> Mechanism:
    return Mechanism(load_model(FIVE_BAR))


# ---------------------------------------------------------------- the stepper, without ROS
def blow_up(plant: Plant) -> DivergedStateError:
    with pytest.raises(DivergedStateError) as exc:
        for _ in range(100):
            plant.step(HUGE)
    return exc.value


def test_blow_up_is_a_diverged_state_and_keeps_the_last_good_state(mech: Mechanism) -> None:
    plant = Plant(mech, SimulationOptions(sample=1e-3), 1e-3)
    err = blow_up(plant)
    text = str(err)
    assert text.startswith("state diverged at t = ") and "|qdd| = " in text, text
    assert "step too large or torque too high" in text and "singular" not in text
    assert isinstance(err, SingularConfigurationError)  # stops a run as a singular configuration does
    assert np.all(np.isfinite(plant.q)) and np.all(np.isfinite(plant.qd))
    assert plant.gap() < 1e-12 and plant.fault is not None
    with pytest.raises(SingularConfigurationError):
        plant.step(TAU)  # stays stopped
    # a partial set_state (motors only) recovers
    message = plant.set_state(MOTORS, [plant.q0[0], plant.q0[3]], [])
    assert "state set" in message and plant.fault is None and plant.gap() < 1e-12
    for _ in range(20):
        plant.step(TAU)
    assert np.all(np.isfinite(plant.q)) and plant.gap() < 1e-12
    blow_up(plant)
    plant.reset()
    assert plant.fault is None and plant.gap() < 1e-12
    plant.step(TAU)


def test_set_state_refuses_absurd_values_and_keeps_the_state(mech: Mechanism) -> None:
    plant = Plant(mech, SimulationOptions(sample=1e-3), 1e-3)
    plant.step(TAU)
    q, qd = plant.q.copy(), plant.qd.copy()
    for names, position, velocity in ((["left_motor"], [1e300], []), (["left_motor"], [-1e300], []),
                                      (["left_motor"], [plant.q0[0]], [1e300]), (["left_motor"], [np.inf], []),
                                      (["left_motor", "left_motor"], [1.0, 1.0], []), (["elbow"], [0.0], []),
                                      ([], [], []),  # an empty request (it was "state set")
                                      (["left_elbow"], [0.0], []),  # a passive angle the closure does not allow
                                      (list(mech.joint_names), list(plant.q), [0.1, 0, 0, 0, 0, 0.3])):  # nor rates
        with pytest.raises(InputError) as err:
            plant.set_state(names, position, velocity)
        assert "\n" not in str(err.value)
        if not names:
            assert "an empty request" in str(err.value)
        elif "left_elbow" in names:
            assert "state not reachable: the closure puts left_elbow" in str(err.value)
        np.testing.assert_array_equal(plant.q, q)
        np.testing.assert_array_equal(plant.qd, qd)
    assert "state set" in plant.set_state(list(mech.joint_names), list(q), [])  # the state it has: consistent


def test_lda_started_at_a_type_2_singularity_stops_there() -> None:
    mech = Mechanism(parse_model(YamlSource(singular_start_text(), "singular.yaml")))
    q0 = initial_state(mech)
    torque = ConstantTorque(np.array([0.1, -0.1]))
    with pytest.raises(SingularConfigurationError) as exc:
        Simulator(mech, SimulationOptions(formulation="lda", sample=0.005)).run(torque, 0.05, q0=q0)
    assert exc.value.time is not None and exc.value.time < 0.005
    assert "singular configuration" in str(exc.value) and "dh/dq_p" in str(exc.value)
    # the elastic machine itself moves on from there
    r = Simulator(mech, SimulationOptions(formulation="scdd", sample=0.005)).run(torque, 0.05, q0=q0)
    assert r.gap.max() < 1e-12 and abs(r.q[-1, 0] - q0[0]) > 1e-4


def test_check_at_a_singular_start_says_singular(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "singular.yaml"
    path.write_text(singular_start_text())
    code = main(["check", str(path)])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1 and "Traceback" not in err
    assert "singular configuration" in err and "cannot assemble" not in err, err


# ---------------------------------------------------------------- the plant node's logic
@pytest.fixture(scope="module")
def ros():
    h = RosHarness(domain_id(23))
    yield h
    h.close()


def make_plant(h: RosHarness, **params: Any) -> Any:
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    return h.add(PlantNode(context=h.context, parameter_overrides=overrides))


def command(names: list[str], effort: list[float]) -> Any:
    from sensor_msgs.msg import JointState
    return JointState(name=names, effort=[float(e) for e in effort])


def set_state(plant: Any, names: list[str], position: list[float], velocity: list[float] = ()) -> Any:
    from elastic_pm_dyn_msgs.srv import SetJointState
    from sensor_msgs.msg import JointState
    request = SetJointState.Request(state=JointState(name=names, position=[float(p) for p in position],
                                                     velocity=[float(v) for v in velocity]))
    return plant.sim_services.on_set_state(request, SetJointState.Response())


def reset(plant: Any) -> Any:
    from std_srvs.srv import Trigger
    return plant.sim_services.on_reset(Trigger.Request(), Trigger.Response())


def send(plant: Any, msg: Any) -> None:
    plant._on_command(msg)
    plant.sync.on_commands()


def test_plant_services_answer_every_request_and_recover_from_a_blow_up(ros: RosHarness) -> None:
    plant = make_plant(ros, sync_mode="lockstep")
    p = plant.plant
    q0 = p.q0
    send(plant, command(MOTORS, TAU))
    good = p.q.copy()
    for names, position, velocity in ((["left_motor"], [np.nan], []), (["left_motor"], [np.inf], []),
                                      (["left_motor"], [1e300], []), (["left_motor"], [q0[0]], [np.nan]),
                                      (["nope"], [0.0], []), (["left_motor", "left_motor"], [1.0, 1.0], []),
                                      (["left_motor"], [], []), (["left_motor"], [1.0], [1.0, 2.0])):
        response = set_state(plant, names, position, velocity)
        assert not response.success and response.message, (names, position, velocity)
    np.testing.assert_array_equal(p.q, good)

    send(plant, command(MOTORS, HUGE))  # blows up: integration stops at the last good state
    assert p.fault is not None and "state diverged" in p.fault
    assert np.all(np.isfinite(p.q)) and p.gap() < 1e-12
    response = set_state(plant, MOTORS, [q0[0], q0[3]])  # motors only
    assert response.success, response.message
    assert p.fault is None and p.gap() < 1e-12
    k = p.k
    send(plant, command(MOTORS, TAU))
    assert p.k == k + 1
    send(plant, command(MOTORS, HUGE))
    response = reset(plant)
    assert response.success, response.message
    assert p.fault is None and p.gap() < 1e-12
    np.testing.assert_array_equal(p.q, q0)


def test_lockstep_answers_a_rejected_command_with_the_last_valid_one(ros: RosHarness) -> None:
    plant = make_plant(ros, sync_mode="lockstep")
    published: list[int] = []
    publish = plant.publish_state
    plant.publish_state = lambda: (published.append(plant.plant.k), publish())[1]
    p = plant.plant
    send(plant, command(MOTORS, TAU))
    assert p.k == 1 and published == [1]
    for bad in (command(MOTORS, [np.nan, 0.0]), command(["left_motor", "elbow"], TAU),
                command(["left_motor"], [0.1]), command(["left_motor", "left_motor"], TAU), command([], [])):
        k = p.k
        send(plant, bad)
        assert p.k == k + 1 and published[-1] == k + 1  # one period advanced and published
        np.testing.assert_array_equal(p.tau, TAU)  # the last valid command held
    assert plant.stats.rejected == 5


def test_warnings_are_throttled_per_kind(ros: RosHarness, capfd: pytest.CaptureFixture) -> None:
    plant = make_plant(ros, sync_mode="lockstep")
    capfd.readouterr()
    for _ in range(3):
        send(plant, command(["left_motor", "elbow"], TAU))  # a steady stream of one kind...
    send(plant, command(MOTORS, [np.nan, 0.0]))  # ...must not hide another
    plant._on_command(command(MOTORS, TAU))
    err = capfd.readouterr().err
    assert err.count("unknown joint") == 1, err
    assert "NaN or Inf" in err, err


# ---------------------------------------------------------------- a real node process
def test_plant_process_answers_nan_within_a_period_and_recovers(tmp_path: Path) -> None:
    require("rclpy")
    from elastic_pm_dyn_msgs.srv import SetJointState
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger

    from elastic_pm_dyn.bags.msgtypes import stamp_ns
    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env
    from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS
    domain = domain_id(29)
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", ["-p", "sync_mode:=lockstep"],
                        ros_env(domain), tmp_path)
    h = RosHarness(domain)
    try:
        node = h.node("controller")
        states: list[tuple[int, np.ndarray]] = []
        node.create_subscription(JointState, "joint_states",
                                 lambda m: states.append((stamp_ns(m.header.stamp), np.array(m.position))),
                                 STATE_QOS)
        pub = node.create_publisher(JointState, "torque_command", COMMAND_QOS)
        h.wait_until(lambda: bool(states) and pub.get_subscription_count() > 0, 600.0, "the plant's first state")
        plant.check_running()

        def answer(msg: Any) -> float:
            n, t0 = len(states), time.monotonic()
            pub.publish(msg)
            h.wait_until(lambda: len(states) > n, 5.0, "the answer to a command")
            return time.monotonic() - t0

        answer(command(MOTORS, TAU))
        stamp = states[-1][0]
        wall = answer(command(MOTORS, [np.nan, 0.0]))
        assert states[-1][0] == stamp + 1_000_000 and wall < 2.0  # the next period, at once
        pub.publish(command(MOTORS, HUGE))
        h.spin_for(1.0)
        plant.check_running()
        gap_mech = Mechanism(load_model(FIVE_BAR))
        assert all(np.all(np.isfinite(q)) and gap_mech.gap(q) < 1e-12 for _, q in states)

        set_client = node.create_client(SetJointState, "/plant/set_state")
        reset_client = node.create_client(Trigger, "/plant/reset")
        q0 = initial_state(gap_mech)
        n = len(states)
        response = h.call(set_client, SetJointState.Request(state=JointState(name=MOTORS,
                                                                                position=[q0[0], q0[3]])))
        assert response.success, response.message
        h.wait_until(lambda: len(states) > n, 5.0, "the state set")
        assert gap_mech.gap(states[-1][1]) < 1e-12
        response = h.call(reset_client, Trigger.Request())
        assert response.success, response.message
        answer(command(MOTORS, TAU))
        assert gap_mech.gap(states[-1][1]) < 1e-12
        plant.check_running()
    finally:
        h.close()
        plant.stop()


# ---------------------------------------------------------------- the observer node's logic
def test_observer_services_answer_every_request_and_warnings_are_per_kind(capfd: pytest.CaptureFixture) -> None:
    from elastic_pm_dyn_msgs.srv import SetJointState
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState
    from std_srvs.srv import Trigger

    from elastic_pm_dyn.ros.messages import stamp
    from elastic_pm_dyn.ros.observer.node import ObserverNode
    h = RosHarness(domain_id(26))
    try:
        node = h.add(ObserverNode(context=h.context,
                                  parameter_overrides=[Parameter("observer.sensors", value=["encoders"])]))
        mode = node.observer
        q0 = initial_state(Mechanism(load_model(FIVE_BAR)))
        names = ["left_motor", "right_motor"]

        def joint_state(ns: int, position: list[float]) -> JointState:
            msg = JointState(name=names, position=position)
            msg.header.stamp = stamp(ns)
            return msg

        def torque(ns: int) -> JointState:
            msg = command(MOTORS, TAU)
            msg.header.stamp = stamp(ns)
            return msg

        for k in range(3):
            mode._on_command(torque(k * 1_000_000))
            mode._on_joint_state(joint_state(k * 1_000_000, [q0[0], q0[3]]))
        capfd.readouterr()
        for _ in range(3):
            mode._on_command(torque(0))  # a steady stream of late commands...
        mode._on_command(command(MOTORS, [np.nan, 0.0]))  # ...must not hide a NaN one
        err = capfd.readouterr().err
        assert err.count("before the previous one") == 1 and "NaN or Inf" in err, err

        for names_, position, velocity in ((["left_motor"], [np.nan], []), (["left_motor"], [1e300], []),
                                           (["left_motor", "left_motor"], [1.0, 1.0], []), (["x"], [0.0], []),
                                           ([], [], []), (["left_motor"], [1.0], [np.inf]),
                                           (["left_motor"], [], [])):
            request = SetJointState.Request(state=JointState(name=names_, position=[float(p) for p in position],
                                                             velocity=[float(v) for v in velocity]))
            response = mode._on_set_state(request, SetJointState.Response())
            assert not response.success and response.message, (names_, position, velocity)
        response = mode._on_reset(Trigger.Request(), Trigger.Response())
        assert response.success, response.message
    finally:
        h.close()
