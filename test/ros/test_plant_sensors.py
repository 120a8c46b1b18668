"""The plant's simulated sensors and unknown disturbance (issue #22), checked against physics.

Without ROS: the accelerometer equals the finite difference of the end effector's velocity
along a finely integrated motion; after_command differs from before_command by J dqdd of the
torque jump (a dense KKT solve); specific force, rotated axes, the encoder count grid, the
noise levels; a plant without sensors or disturbance is the plant it was; a spectrum
disturbance gives offline simulate's truth; a held disturbance acts as a commanded torque.
With ROS (lockstep): the sensor topics carry the stamps of joint_states, after_command
samples come after the command that starts at their stamp.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer.testing.scenarios import Noise, rest_state, simulate
from elastic_pm_dyn.sim.disturbances import seeded_disturbance
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.sensors import EncoderSpec, GaugeSpec, ImuSpec, SensorModel, SensorSpec, ee_acceleration
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import HeldPlusSmooth

CONFIG = Path(__file__).resolve().parents[2] / "config"
PERIOD = 1e-3
G = np.array([0.0, -9.81, 0.0])  # the five-bar stood up: gravity in its plane (the gravity override)


def torques(k: int) -> np.ndarray:
    """A command that changes every period (so the acceleration jumps at every t_k)."""
    return np.array([0.4 * np.sin(0.7 * k) + 0.1, -0.3 * np.cos(0.45 * k)])


@pytest.fixture(scope="module")
def mech() -> Mechanism:
    return Mechanism(load_model(CONFIG / "five_bar.yaml", gravity=G))


@pytest.fixture(scope="module")
def moving(mech: Mechanism) -> dict[str, Any]:
    """A plant 12 periods into a jerky motion under a spectrum and a held disturbance: the springs vibrate."""
    dist = seeded_disturbance("flat", 2, 0.05, 0.1, seed=3)
    plant = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD, dist)
    held = np.array([0.02, 0.03])
    for k in range(12):
        plant.step(torques(k), held)
    return {"plant": plant, "dist": dist, "held": held}


def spec(**imu: Any) -> SensorSpec:
    return SensorSpec(imu=ImuSpec(enabled=True, stddev=0.0, **imu))


def test_accelerometer_equals_finite_difference_of_velocity(mech: Mechanism, moving: dict) -> None:
    """a(t_k-) of the model: the central difference of the end effector's velocity J qd along a motion
    integrated at 2e-7 s through t_k with the last period's command held (and the spectrum running).
    The difference's error is a''' h^2 / 6, at most (w h)^2 / 6 = 5e-5 of |a| were all of it in the
    550 Hz mode (w = 3.5e3 1/s, h = 5e-6 s): tolerance 1e-4 |a|; RK4 at 2e-7 s and round-off
    (|v| 1e-16 / h) are far below."""
    plant, dist, held = moving["plant"], moving["dist"], moving["held"]
    t_k, chain = plant.t, int(mech.model.end_effector_chain)
    # the reference: from the plant's state one period back, a fine RK4 under the same torque
    start = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD, dist)
    for k in range(11):
        start.step(torques(k), held)
    fine = Simulator(mech, SimulationOptions(dt=2e-7))
    q, qd = start.q.copy(), start.qd.copy()
    torque = HeldPlusSmooth(torques(11) + held, dist)
    h = 5e-6
    velocity, states = [], []
    t = start.t
    for t_next in (t_k - h, t_k, t_k + h):
        fine.advance(q, qd, torque, t, t_next)
        t = t_next
        velocity.append(mech.terms(q, qd).J[chain] @ qd)
        states.append((q.copy(), qd.copy()))
    fd = (velocity[2] - velocity[0]) / (2 * h)
    q_k, qd_k = states[1]
    model = SensorModel(mech, spec(specific_force=False))
    a = model.accelerometer_true(q_k, qd_k, torques(11) + held + dist(t_k))
    assert np.abs(a).max() > 1.0  # a real motion, not a state at rest
    tol = 1e-4 * np.abs(a).max()  # measured: 1e-6
    np.testing.assert_allclose(a, fd, rtol=0, atol=tol)
    # the check sees the disturbance (0.05 N m RMS) and the torque jump: without either it fails
    assert np.abs(model.accelerometer_true(q_k, qd_k, torques(11)) - fd).max() > 10 * tol
    assert np.abs(model.accelerometer_true(q_k, qd_k, torques(12) + held + dist(t_k)) - fd).max() > 10 * tol
    # the plant's own default: the torque just before t_k is that command + the disturbance at t_k
    np.testing.assert_array_equal(plant.motor_torque(), torques(11) + held + dist(t_k))


def test_after_command_differs_by_the_torque_jump(mech: Mechanism, moving: dict) -> None:
    """a(t_k+) - a(t_k-) = J dqdd, dqdd from a dense KKT solve [M A^T; A 0] of the torque jump alone."""
    plant = moving["plant"]
    model = SensorModel(mech, spec(specific_force=False))
    before = model.accelerometer_true(plant.q, plant.qd, plant.motor_torque())
    nxt = torques(12)
    after = model.accelerometer_true(plant.q, plant.qd, plant.motor_torque(nxt, moving["held"]))
    terms = mech.terms(plant.q, plant.qd)
    n, m = mech.n, mech.m
    kkt = np.zeros((n + m, n + m))
    kkt[:n, :n], kkt[:n, n:], kkt[n:, :n] = terms.M, terms.A.T, terms.A
    rhs = np.zeros(n + m)
    rhs[mech.active] = nxt - plant.tau
    dqdd = np.linalg.solve(kkt, rhs)[:n]
    jump = terms.J[int(mech.model.end_effector_chain)] @ dqdd
    assert np.abs(jump).max() > 0.1
    np.testing.assert_allclose(after - before, jump, rtol=0, atol=1e-9 * np.abs(jump).max() + 1e-12)


def test_specific_force_rotation_and_bias(mech: Mechanism, moving: dict) -> None:
    plant = moving["plant"]
    tau = plant.motor_torque()
    a = ee_acceleration(mech, Dynamics(mech, "scdd"), plant.q, plant.qd, tau, int(mech.model.end_effector_chain))
    np.testing.assert_allclose(SensorModel(mech, spec(specific_force=True)).accelerometer_true(plant.q, plant.qd, tau),
                               a - G, rtol=0, atol=1e-12)  # at rest it would read +9.81 up
    roll, pitch, yaw = 0.3, -0.2, 0.5
    # sensor axes: world axes turned by yaw about z, then pitch about y, then roll about x (URDF rpy)
    c, s = np.cos, np.sin
    Rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    Ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    Rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    R = Rz @ Ry @ Rx
    bias = (0.1, -0.2, 0.3)
    y = SensorModel(mech, spec(rpy=(roll, pitch, yaw), bias=bias)).accelerometer_true(plant.q, plant.qd, tau)
    np.testing.assert_allclose(y, R.T @ (a - G) + bias, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(y - bias), np.linalg.norm(a - G), rtol=1e-14)


def test_encoder_quantisation_rounds_to_the_count_grid(mech: Mechanism) -> None:
    q = rest_state(mech) + 0.01
    counts = 4096
    model = SensorModel(mech, SensorSpec(encoders=EncoderSpec(enabled=True, position_stddev=0.0,
                                                              counts_per_revolution=counts)))
    pos, vel = model.encoders(q, np.zeros(mech.n))
    step = 2 * np.pi / counts
    assert vel is None
    np.testing.assert_allclose(pos / step, np.round(pos / step), rtol=0, atol=1e-9)
    assert np.all(np.abs(pos - q[mech.active]) <= step / 2 + 1e-15)
    # a prismatic motor: counts per metre
    triglide = Mechanism(load_model(CONFIG / "triglide.yaml"))
    tri = SensorModel(triglide, SensorSpec(encoders=EncoderSpec(enabled=True, position_stddev=0.0,
                                                                counts_per_metre=10_000)))
    q = rest_state(triglide) + 3.3e-5
    pos, _ = tri.encoders(q, np.zeros(triglide.n))
    np.testing.assert_allclose(pos * 1e4, np.round(pos * 1e4), rtol=0, atol=1e-6)
    assert np.all(np.abs(pos - q[triglide.active]) <= 0.5e-4 + 1e-15)


def test_noise_levels_and_seeds(mech: Mechanism) -> None:
    """Sample standard deviations of 20000 draws within 3 % (6 standard errors of sigma / sqrt(2 N))."""
    s = SensorSpec(encoders=EncoderSpec(enabled=True, position_stddev=2e-5, velocity=True, velocity_stddev=1e-2),
                   imu=ImuSpec(enabled=True, stddev=0.02, bias=(0.5, 0.0, -0.5)),
                   branch_forces=GaugeSpec(enabled=True, stddev=0.5), seed=11)
    model = SensorModel(mech, s)
    q, qd = rest_state(mech), np.zeros(mech.n)
    tau = np.zeros(2)
    truth = model.accelerometer_true(q, qd, tau)
    force = mech.branch_forces(q, qd)
    n = 20000
    enc = np.array([np.concatenate(model.encoders(q, qd)) for _ in range(n)])
    imu = np.array([model.accelerometer(q, qd, tau) for _ in range(200)])  # a dynamics evaluation each: fewer
    gauges = np.array([model.branch_forces(force) for _ in range(n)])
    np.testing.assert_allclose(enc[:, :2].std(axis=0), 2e-5, rtol=0.03)
    np.testing.assert_allclose(enc[:, 2:].std(axis=0), 1e-2, rtol=0.03)
    np.testing.assert_allclose(gauges.std(axis=0), 0.5, rtol=0.03)
    np.testing.assert_allclose(imu.std(axis=0), 0.02, rtol=0.3)  # 200 draws: 5 standard errors
    np.testing.assert_allclose(imu.mean(axis=0), truth, rtol=0, atol=5 * 0.02 / np.sqrt(200))
    np.testing.assert_allclose(truth[[0, 2]] - SensorModel(mech, spec()).accelerometer_true(q, qd, tau)[[0, 2]],
                               [0.5, -0.5], rtol=0, atol=1e-12)
    # the same seed draws the same noise; one sensor's draws do not move another's
    again = SensorModel(mech, s)
    assert np.array_equal(np.concatenate(again.encoders(q, qd)), enc[0])
    gauges_only = SensorModel(mech, SensorSpec(branch_forces=GaugeSpec(enabled=True, stddev=0.5), seed=11))
    assert np.array_equal(gauges_only.branch_forces(force), gauges[0])


def test_without_sensors_or_disturbance_the_plant_is_unchanged(mech: Mechanism) -> None:
    """No disturbance: each period is the compiled steps the plant always made (the simulator's
    fixed_steps under the held torque, as offline simulate's), bit for bit; a held disturbance of zero
    changes nothing either."""
    options = SimulationOptions(dt=1e-4, sample=PERIOD)
    a = Plant(mech, options, PERIOD)
    b = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD)
    sim = Simulator(mech, SimulationOptions(dt=1e-4, sample=PERIOD))
    q, qd = a.q.copy(), a.qd.copy()
    coef = np.zeros((3, mech.n))
    for k in range(20):
        a.step(torques(k))
        b.step(torques(k), np.zeros(2))
        coef[0, mech.active] = torques(k)
        t0 = k * PERIOD
        assert sim.fixed_steps(q, qd, coef, (t0 + PERIOD - t0) / 10, 10) == 0  # the plant's step: t = k period
        for x, y in ((a.q, q), (a.qd, qd), (b.q, q), (b.qd, qd)):
            np.testing.assert_array_equal(x, y)


def test_spectrum_disturbance_equals_offline_simulate(mech: Mechanism) -> None:
    """The plant under a SpectrumDisturbance (same seed) follows offline simulate's truth: the same
    RK4 steps, the disturbance refitted per step in both."""
    n = 30
    dist = seeded_disturbance("pink", 2, 0.05, n * PERIOD, seed=5)
    rec = simulate(mech, lambda k, t, enc: torques(k), n * PERIOD, dist, Noise(), np.random.default_rng(0),
                   truth_dt=1e-4)
    plant = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD,
                  seeded_disturbance("pink", 2, 0.05, n * PERIOD, seed=5))
    plant.q = rest_state(mech)  # simulate's start: at rest in static equilibrium
    for k in range(n):
        np.testing.assert_array_equal(plant.disturbance_at(plant.t), rec.disturbance[k])
        plant.step(torques(k))
        np.testing.assert_allclose(plant.q, rec.q[k + 1], rtol=0, atol=1e-13)
        np.testing.assert_allclose(plant.qd, rec.qd[k + 1], rtol=0, atol=1e-10)
    # the disturbance moved the machine: without it the states differ by far more than that
    bare = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD)
    bare.q = rest_state(mech)
    for k in range(n):
        bare.step(torques(k))
    assert np.abs(bare.q - plant.q).max() > 1e-7
    # the plant's stage values (sines continued by rotation) are the function's to round-off
    np.testing.assert_allclose(dist.on_grid(0.0123, 5e-5, 21), [dist(0.0123 + j * 5e-5) for j in range(21)],
                               rtol=0, atol=1e-15)
    # ETD2 takes the same refitted torque: the disturbance moves it as it moves RK4 (1.7e-4 rad here),
    # to 1e-6 of that (measured 5e-7; ETD2 at 2.5e-4 s and RK4 at 1e-4 s differ by 2e-9 rad)
    etd2 = Plant(mech, SimulationOptions(integrator="etd2", dt=2.5e-4, sample=PERIOD), PERIOD, dist)
    etd2_bare = Plant(mech, SimulationOptions(integrator="etd2", dt=2.5e-4, sample=PERIOD), PERIOD)
    etd2.q, etd2_bare.q = rest_state(mech), rest_state(mech)
    for k in range(n):
        etd2.step(torques(k))
        etd2_bare.step(torques(k))
    effect = plant.q - bare.q
    np.testing.assert_allclose(etd2.q - etd2_bare.q, effect, rtol=0, atol=1e-6 * np.abs(effect).max())


def test_static_start_stands_still_under_the_holding_torque(mech: Mechanism) -> None:
    """``start: static``: the springs carry gravity from the first instant, so a plant held by
    the rigid holding torque does not ring; ``relaxed`` (springs unloaded) sags and rings."""
    from elastic_pm_dyn.dynamics.statics import elastic_residual, holding_torques

    options = SimulationOptions(dt=1e-4, sample=PERIOD)
    static = Plant(mech, options, PERIOD, start="static")
    relaxed = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD)
    # the start is balanced: no generalised force on the springs at rest (gravity vs deflection)
    e = np.arange(len(mech.active), len(mech.ae))
    assert np.max(np.abs(elastic_residual(mech, static.q0)[e])) < 1e-9
    assert np.max(np.abs(elastic_residual(mech, relaxed.q0)[e])) > 1e-3
    assert np.array_equal(static.q0[mech.active], relaxed.q0[mech.active])  # the motors where the file puts them
    hold = holding_torques(mech, static.q0)
    for _ in range(20):
        static.step(hold)
        relaxed.step(hold)
    ringing = np.max(np.abs(relaxed.qd[mech.elastic]))
    assert ringing > 1e-4  # [rad/s] the unloaded springs take the weight: they ring
    assert np.max(np.abs(static.qd)) < 1e-4 * ringing
    with pytest.raises(InputError, match="start must be one of"):
        Plant(mech, options, PERIOD, start="sagging")


def test_held_disturbance_acts_as_a_commanded_torque(mech: Mechanism) -> None:
    d = np.array([0.05, -0.08])
    a = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD)
    b = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD)
    for k in range(10):
        a.step(torques(k), d)
        b.step(torques(k) + d)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-15)
    np.testing.assert_allclose(a.qd, b.qd, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(a.tau, torques(9))  # the command stays the command (joint_states effort)
    np.testing.assert_array_equal(a.disturbance_at(a.t), d)


# ----------------------------------------------------------------------------------- ROS
@pytest.fixture
def ros():
    h = RosHarness(domain_id(35))
    yield h
    h.close()


def test_lockstep_sensor_topics_and_timing(ros: RosHarness, mech: Mechanism) -> None:
    """Lockstep with every sensor on and after_command: encoders, gauges and the imu carry the stamps of
    joint_states; the imu sample of t_k arrives once command k was sent, and equals the noise-free
    accelerometer at the state of t_k under command k (stddev 0)."""
    require("rclpy")
    from elastic_pm_dyn_msgs.msg import BranchForces
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Imu, JointState

    from elastic_pm_dyn.bags.msgtypes import stamp_ns
    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS

    params = {"sync_mode": "lockstep", "gravity": list(G), "sensors.encoders.enabled": True,
              "sensors.imu.enabled": True, "sensors.imu.stddev": 0.0, "sensors.imu.sample_timing": "after_command",
              "sensors.branch_forces.enabled": True, "disturbance.spectrum": "flat",
              "disturbance.band": [2.0, 200.0], "disturbance.rms": 0.02, "disturbance.seed": 4}
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=[Parameter(k, value=v)
                                                                         for k, v in params.items()]))
    node = ros.node("driver")
    events: list[tuple[str, int]] = []
    states: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    imu: dict[int, np.ndarray] = {}
    n = 15
    pub = node.create_publisher(JointState, "torque_command", COMMAND_QOS)
    order = list(mech.joint_names)

    def on_state(msg: Any) -> None:
        ns = stamp_ns(msg.header.stamp)
        idx = [list(msg.name).index(j) for j in order]
        states[ns] = (np.array(msg.position)[idx], np.array(msg.velocity)[idx])
        events.append(("joint_states", ns))
        k = round(ns / 1e6)
        if k < n:
            events.append(("command", ns))
            pub.publish(JointState(name=["left_motor", "right_motor"], effort=list(torques(k))))

    def on_imu(msg: Any) -> None:
        ns = stamp_ns(msg.header.stamp)
        a = msg.linear_acceleration
        imu[ns] = np.array([a.x, a.y, a.z])
        events.append(("ee_imu", ns))

    node.create_subscription(JointState, "joint_states", on_state, STATE_QOS)
    node.create_subscription(Imu, "ee_imu", on_imu, STATE_QOS)
    last: dict[str, Any] = {}

    def on_other(msg: Any, topic: str) -> None:
        events.append((topic, stamp_ns(msg.header.stamp)))
        last[topic] = msg

    for topic, kind in (("measured_joint_states", JointState), ("measured_branch_forces", BranchForces),
                        ("disturbance", JointState), ("branch_forces", BranchForces)):
        node.create_subscription(kind, topic, lambda msg, t=topic: on_other(msg, t), STATE_QOS)
    ros.wait_until(lambda: len(imu) >= n and len(states) >= n + 1, 30.0, f"{n} imu samples")
    ros.spin_for(0.05)
    stamps = {t: [ns for kind, ns in events if kind == t] for t in
              ("joint_states", "measured_joint_states", "measured_branch_forces", "disturbance", "ee_imu", "command")}
    expected = list(np.arange(n + 1) * 1_000_000)
    for topic in ("joint_states", "measured_joint_states", "measured_branch_forces", "disturbance"):
        assert stamps[topic] == expected, topic
    assert stamps["ee_imu"] == expected[:n]  # the sample of t_n waits for command n, never sent
    for ns in stamps["ee_imu"]:  # each only once its command was sent (the order across topics is the executor's)
        assert events.index(("command", ns)) < events.index(("ee_imu", ns))
    # the encoders and gauges of t_n: their names, the truth within 6 sigma of the noise
    enc, gauge, truth = last["measured_joint_states"], last["measured_branch_forces"], last["branch_forces"]
    assert list(enc.name) == mech.active_names and len(enc.velocity) == 0
    assert np.abs(np.array(enc.position) - states[n * 1_000_000][0][mech.active]).max() < 6 * 2e-5
    assert list(gauge.name) == list(truth.name) and len(gauge.deflection) == 0
    assert np.abs(np.array(gauge.force) - np.array(truth.force)).max() < 6 * 0.5
    assert list(last["disturbance"].name) == mech.active_names
    np.testing.assert_allclose(last["disturbance"].effort, plant.plant.disturbance(n * PERIOD), rtol=0, atol=1e-15)
    # the value: the model's accelerometer at the published state under command k + the disturbance at t_k
    model = SensorModel(mech, spec())
    for k in (0, 7, n - 1):
        ns = k * 1_000_000
        q, qd = states[ns]
        tau = torques(k) + plant.plant.disturbance(k * PERIOD)
        np.testing.assert_allclose(imu[ns], model.accelerometer_true(q, qd, tau), rtol=0, atol=1e-9)


def test_lockstep_disturbance_input_acts_as_a_command(ros: RosHarness, mech: Mechanism) -> None:
    """A disturbance_torque (then a NaN one, rejected: the last valid holds) moves the plant as the same
    torque added to the commands; with sensors off no sensor topic exists, and a default plant has no
    disturbance topic either."""
    require("rclpy")
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.bags.msgtypes import stamp_ns
    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS

    def plant_node(**params: Any) -> Any:
        return ros.add(PlantNode(context=ros.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in {"sync_mode": "lockstep", **params}.items()]))

    default = plant_node()
    topics = {p.topic_name.lstrip("/") for p in default.publishers}
    assert not topics & {"measured_joint_states", "ee_imu", "measured_branch_forces", "disturbance"}
    ros.executor.remove_node(default)
    ros.nodes.remove(default)
    default.destroy_node()

    plant = plant_node(**{"disturbance.input": True, "gravity": list(G)})
    topics = {p.topic_name.lstrip("/") for p in plant.publishers}
    assert "disturbance" in topics and not topics & {"measured_joint_states", "ee_imu", "measured_branch_forces"}
    node = ros.node("driver")
    names = ["left_motor", "right_motor"]
    cmd = node.create_publisher(JointState, "torque_command", COMMAND_QOS)
    dist = node.create_publisher(JointState, "disturbance_torque", COMMAND_QOS)
    d = np.array([0.05, -0.08])
    ros.wait_until(lambda: dist.get_subscription_count() > 0, 10.0, "the disturbance subscription")
    dist.publish(JointState(name=names, effort=list(d)))
    ros.wait_until(lambda: plant.hold.disturbance is not None, 5.0, "the disturbance received")
    dist.publish(JointState(name=names, effort=[float("nan"), 0.0]))
    ros.spin_for(0.1)
    np.testing.assert_array_equal(plant.hold.disturbance, d)  # the NaN one rejected
    n = 10
    states: dict[int, np.ndarray] = {}

    def on_state(msg: Any) -> None:
        k = round(stamp_ns(msg.header.stamp) / 1e6)
        states[k] = np.array(msg.position)[[list(msg.name).index(j) for j in mech.joint_names]]
        if k < n:
            cmd.publish(JointState(name=names, effort=list(torques(k))))

    node.create_subscription(JointState, "joint_states", on_state, STATE_QOS)
    ros.wait_until(lambda: len(states) >= n + 1, 30.0, f"{n} lockstep states")
    offline = Plant(mech, SimulationOptions(dt=1e-4, sample=PERIOD), PERIOD)
    for k in range(n):
        offline.step(torques(k) + d)
        np.testing.assert_allclose(states[k + 1], offline.q, rtol=0, atol=1e-14)


def test_plant_and_observer_apply_the_same_model_overrides(ros: RosHarness) -> None:
    require("rclpy")
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.observer.node import ObserverNode
    from elastic_pm_dyn.ros.plant.node import PlantNode

    base = Mechanism(load_model(CONFIG / "triglide.yaml"))
    params = [Parameter("model", value=str(CONFIG / "triglide.yaml")), Parameter("elastic_dof_per_chain", value=2),
              Parameter("gravity", value=[0.0, 0.0, -1.62])]
    plant = ros.add(PlantNode(context=ros.context, parameter_overrides=[*params,
                                                                         Parameter("sync_mode", value="lockstep")]))
    observer = ros.add(ObserverNode(context=ros.context, parameter_overrides=params))
    for mech in (plant.plant.mech, observer.observer.session.mech):
        np.testing.assert_array_equal(mech.model.gravity, [0.0, 0.0, -1.62])
        assert len(mech.elastic) == 2 * len(base.elastic)
