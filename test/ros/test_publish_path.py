"""The plant's serialized publish path: the same messages as the rclpy-object path, field by field.

:class:`~elastic_pm_dyn.ros.messages.PlantMessages` serializes joint_states, branch_forces,
ee_pose and /clock once and overwrites stamp and numbers in place. The expectation here is
the object path it replaced: :class:`~elastic_pm_dyn.ros.messages.StateMessages` filled from
``Plant.efforts``, ``Plant.branches`` and ``Plant.end_effector``. Numbers are compared bit for
bit (their bytes), over random torques on the five-bar, the Triglide and the Hexa (n_ek = 2),
and once through a real lockstep plant node and subscriber.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.simulator import SimulationOptions

CONFIG = Path(__file__).resolve().parents[2] / "config"
PERIOD = 1e-3
# file, elastic DOF per chain, RK4 step (`check`: the Triglide at n_ek = 2 needs dt < 9.3e-5 s), torque scale
MACHINES = {"five_bar": ("five_bar.yaml", None, 1e-4, 0.05), "triglide": ("triglide.yaml", 2, 5e-5, 20.0),
            "hexa": ("hexa.yaml", 2, 1e-4, 0.5)}


def _bits(values: Any) -> bytes:
    return np.asarray(values, dtype=np.float64).tobytes()


def expected_messages(plant: Plant, ns: int, base_frame: str) -> Any:
    """The object path: StateMessages filled from the Plant's own outputs (as the node did before)."""
    from elastic_pm_dyn.ros.messages import StateMessages
    m = StateMessages(plant.mech, base_frame)
    effort = plant.efforts()
    b = plant.branches(effort)
    m._set(ns, plant.q, plant.qd, effort, b.force, b.deflection, b.rate, plant.end_effector())
    return m


def assert_same_state(got: dict[str, Any], want: Any) -> None:
    """``got``: decoded joint_states, branch_forces, ee_pose, clock; ``want``: StateMessages."""
    js, w = got["joint_states"], want.joint_state
    assert (js.header.stamp.sec, js.header.stamp.nanosec, js.header.frame_id) == (
        w.header.stamp.sec, w.header.stamp.nanosec, w.header.frame_id)
    assert list(js.name) == list(w.name)
    for field in ("position", "velocity", "effort"):
        assert _bits(getattr(js, field)) == _bits(getattr(w, field)), field
    bf, w = got["branch_forces"], want.branch_forces
    assert (bf.header.stamp.sec, bf.header.stamp.nanosec, bf.header.frame_id) == (
        w.header.stamp.sec, w.header.stamp.nanosec, w.header.frame_id)
    assert list(bf.name) == list(w.name)
    for field in ("force", "deflection", "deflection_rate", "force_stddev"):
        assert _bits(getattr(bf, field)) == _bits(getattr(w, field)), field
    pose, w = got["ee_pose"], want.ee_pose
    assert (pose.header.stamp.sec, pose.header.stamp.nanosec, pose.header.frame_id) == (
        w.header.stamp.sec, w.header.stamp.nanosec, w.header.frame_id)
    p, o, wp, wo = pose.pose.position, pose.pose.orientation, w.pose.position, w.pose.orientation
    assert _bits([p.x, p.y, p.z, o.x, o.y, o.z, o.w]) == _bits([wp.x, wp.y, wp.z, wo.x, wo.y, wo.z, wo.w])
    if "clock" in got:
        clock = got["clock"].clock
        assert (clock.sec, clock.nanosec) == (w.header.stamp.sec, w.header.stamp.nanosec)


@pytest.fixture(scope="module", params=list(MACHINES))
def plant(request: Any) -> Plant:
    require("rclpy")
    name, n_ek, dt, scale = MACHINES[request.param]
    model = load_model(CONFIG / name, elastic_dof_per_chain=n_ek) if n_ek else load_model(CONFIG / name)
    options = SimulationOptions(formulation="scdd", integrator="rk4", dt=dt, stabilization="projection",
                                sample=PERIOD)
    p = Plant(Mechanism(model), options, PERIOD)
    p.scale = scale
    return p


def test_serialized_messages_equal_the_object_path(plant: Plant) -> None:
    """Over 30 periods of random torques (and an epoch-sized stamp): every field bit for bit."""
    from elastic_pm_dyn.ros.messages import PlantMessages
    rng = np.random.default_rng(7)
    plant.reset()
    messages = PlantMessages(plant, "world")
    base = 1_700_000_000 * 10**9 + 123
    for k in range(30):
        plant.step(plant.scale * rng.uniform(-1.0, 1.0, len(plant.tau)))
        ns = base + k * 1_000_000
        messages.fill(ns)
        got = {"joint_states": messages.joint_state, "branch_forces": messages.branch_forces,
               "ee_pose": messages.ee_pose, "clock": messages.clock}
        assert_same_state(got, expected_messages(plant, ns, "world"))


def test_rosbags_reads_the_serialized_bytes(plant: Plant) -> None:
    """A second reader (rosbags, as the recorder's bags are read) decodes the same bytes alike."""
    from elastic_pm_dyn.bags.typestore import make_typestore
    from elastic_pm_dyn.ros.messages import PlantMessages
    store = make_typestore()
    messages = PlantMessages(plant, "base")
    messages.fill(5 * 10**9 + 7)
    js = store.deserialize_cdr(messages.joint_state_raw, "sensor_msgs/msg/JointState")
    assert _bits(js.position) == _bits(plant.q) and list(js.name) == list(plant.mech.joint_names)
    pose = store.deserialize_cdr(messages.ee_pose_raw, "geometry_msgs/msg/PoseStamped")
    assert pose.header.frame_id == "base" and pose.pose.orientation.w == 1.0
    bf = store.deserialize_cdr(messages.branch_forces_raw, "elastic_pm_dyn_msgs/msg/BranchForces")
    assert _bits(bf.deflection_rate) == _bits(plant.qd[plant.mech.branch_joints]) and len(bf.force_stddev) == 0


def test_lockstep_node_publishes_the_expected_messages() -> None:
    """A lockstep plant node and a subscriber: what arrives on the four topics is, field by field,
    the object path's message of an offline Plant driven by the same commands."""
    require("rclpy")
    from elastic_pm_dyn_msgs.msg import BranchForces
    from geometry_msgs.msg import PoseStamped
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.qos import CLOCK_QOS, COMMAND_QOS, STATE_QOS
    n = 40
    rng = np.random.default_rng(3)
    torques = 0.05 * rng.uniform(-1.0, 1.0, (n, 2))  # active order: left_motor, right_motor
    h = RosHarness(domain_id(38))
    try:
        node = h.add(PlantNode(context=h.context, parameter_overrides=[
            Parameter("sync_mode", value="lockstep"), Parameter("publish_rate", value=1000.0)]))
        listener = h.node("listener")
        received: dict[str, dict[int, Any]] = {t: {} for t in ("joint_states", "branch_forces", "ee_pose", "clock")}
        pub = listener.create_publisher(JointState, "torque_command", COMMAND_QOS)

        def on_state(msg: Any) -> None:
            k = round((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) / 1e6)
            received["joint_states"][k] = msg
            if k < n:
                pub.publish(JointState(name=["left_motor", "right_motor"], effort=[float(x) for x in torques[k]]))

        def keep(topic: str) -> Any:
            def store(msg: Any) -> None:
                st = msg.clock if topic == "clock" else msg.header.stamp
                received[topic][round((st.sec * 10**9 + st.nanosec) / 1e6)] = msg
            return store

        listener.create_subscription(BranchForces, "branch_forces", keep("branch_forces"), STATE_QOS)
        listener.create_subscription(PoseStamped, "ee_pose", keep("ee_pose"), STATE_QOS)
        listener.create_subscription(Clock, "/clock", keep("clock"), CLOCK_QOS)
        listener.create_subscription(JointState, "joint_states", on_state, STATE_QOS)
        # /clock is volatile: its t = 0 sample, published at start-up, may precede the subscription
        h.wait_until(lambda: all(len(r) >= n + (t != "clock") for t, r in received.items())
                     and n in received["clock"], 30.0, f"{n + 1} states on each topic")
        offline = Plant(node.plant.mech, node.plant.options, node.plant.period)
        for k in range(n + 1):
            if k:
                offline.step(torques[k - 1])
            got = {topic: r[k] for topic, r in received.items() if k in r}
            assert_same_state(got, expected_messages(offline, k * 1_000_000, "world"))
        assert all(k in received["clock"] for k in range(1, n + 1))
    finally:
        h.close()


@pytest.mark.parametrize("name", ["five_bar", "hexa"])
def test_estimate_messages_carry_the_estimate_bit_for_bit(name: str) -> None:
    """The observer's serialized estimate messages decode to the Estimate's own numbers, field by
    field (an estimate with wrench-free random numbers in every field, an epoch-sized stamp)."""
    require("rclpy")
    from elastic_pm_dyn.observer.core.estimate import Estimate
    from elastic_pm_dyn.ros.messages import EstimateMessages, ee_in_base
    file, n_ek, _, _ = MACHINES[name]
    mech = Mechanism(load_model(CONFIG / file, elastic_dof_per_chain=n_ek) if n_ek else load_model(CONFIG / file))
    rng = np.random.default_rng(11)
    n, nb, ne = mech.n, len(mech.model.branches), len(mech.ee_names)
    messages = EstimateMessages(mech, "base")
    for k in range(3):
        e = Estimate(0.0, *rng.normal(size=(5, n)), [b.name for b in mech.model.branches], *rng.normal(size=(4, nb)),
                     rng.normal(size=ne), rng.normal(size=ne), [], np.zeros(0), np.zeros(0), np.zeros(0),
                     np.zeros((0, 0)))
        ns = 1_700_000_000 * 10**9 + 987_654_321 + k * 1_000_000
        messages.fill(ns, e)
        sec, nanosec = divmod(ns, 10**9)
        js, bf, pose, std = messages.joint_state, messages.branch_forces, messages.ee_pose, messages.stddev
        for m in (js, bf, pose, std):
            assert (m.header.stamp.sec, m.header.stamp.nanosec) == (sec, nanosec)
        assert list(js.name) == list(std.name) == list(mech.joint_names) and js.header.frame_id == ""
        assert [_bits(js.position), _bits(js.velocity), _bits(js.effort)] == [_bits(e.q), _bits(e.qd), _bits(e.effort)]
        assert [_bits(std.position), _bits(std.velocity), len(std.effort)] == [_bits(e.q_std), _bits(e.qd_std), 0]
        assert list(bf.name) == [b.name for b in mech.model.branches]
        assert [_bits(bf.force), _bits(bf.force_stddev), _bits(bf.deflection), _bits(bf.deflection_rate)] == [
            _bits(e.branch_force), _bits(e.branch_force_std), _bits(e.deflection), _bits(e.deflection_rate)]
        p, o = pose.pose.position, pose.pose.orientation
        assert pose.header.frame_id == "base" and (o.x, o.y, o.z, o.w) == (0.0, 0.0, 0.0, 1.0)
        assert _bits([p.x, p.y, p.z]) == _bits(ee_in_base(e.ee, mech.ee_unit, mech.ee_axes))
