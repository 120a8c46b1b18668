"""A bag written by our recorder node (rclpy, raw CDR, mcap) analysed like any other.

The synthetic run of bag_factory.py is published by a driver node with the wire types
of our nodes; the recorder writes it; analysis must find the same truth as from the bag
written by plain rosbags (test_analysis_bags.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from bag_factory import MODEL, T0, synthetic_run
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.analysis.report import analyze

TOPICS = ["/joint_states", "/branch_forces", "/torque_command", "/reference_joint_states", "/ee_pose"]
CHUNK = 0.1  # [s] of the run published at once, then the recorder catches up


def test_recorder_bag_is_analyzed(tmp_path):
    require("rclpy")
    require("elastic_pm_dyn_msgs.msg")
    from builtin_interfaces.msg import Time
    from elastic_pm_dyn_msgs.msg import BranchForces
    from geometry_msgs.msg import PoseStamped
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Header

    from elastic_pm_dyn.ros.recorder.node import RecorderNode

    run = synthetic_run(force_rate=2000.0)
    bag = tmp_path / "bag"

    def header(t: float) -> Header:
        ns = round((T0 + t) * 1e9)
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="world")

    def joint_state(t: float, names: list[str], pos=(), vel=(), eff=()) -> JointState:
        return JointState(header=header(t), name=names, position=[float(x) for x in pos],
                          velocity=[float(x) for x in vel], effort=[float(x) for x in eff])

    h = RosHarness(domain_id(2))
    try:
        recorder = h.add(RecorderNode(context=h.context, parameter_overrides=[
            Parameter("output", value=str(bag)), Parameter("storage", value="mcap"),
            Parameter("topics", value=TOPICS)]))
        driver = h.node("driver")
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)  # bursts: nothing dropped
        pubs = {t: driver.create_publisher(ty, t, qos) for t, ty in zip(
            TOPICS, (JointState, BranchForces, JointState, JointState, PoseStamped), strict=True)}

        def recorded(topic: str) -> int:
            return recorder.count(topic)

        h.wait_until(lambda: all(t in recorder.connections for t in TOPICS)
                     and all(p.get_subscription_count() for p in pubs.values()), 10.0, "recorder subscribed")
        motors = np.zeros((len(run.t_state), len(run.joint_names)))
        for k, n in enumerate(run.motor_names):
            motors[:, run.joint_names.index(n)] = run.tau[:, k]
        sent = {t: 0 for t in TOPICS}
        for start in np.arange(0.0, run.t_state[-1] + 1e-9, CHUNK):
            for k in np.flatnonzero((run.t_state >= start - 1e-9) & (run.t_state < start + CHUNK - 1e-9)):
                t = float(run.t_state[k])
                pubs["/joint_states"].publish(joint_state(t, run.joint_names, run.q[k], run.qd[k], motors[k]))
                pubs["/reference_joint_states"].publish(joint_state(t, run.ref_names, run.q_ref[k], run.qd_ref[k]))
                pubs["/torque_command"].publish(joint_state(t, run.motor_names, eff=run.tau[k]))
                pose = PoseStamped(header=header(t))
                pose.pose.position.x, pose.pose.position.y = (float(x) for x in run.ee[k])
                pubs["/ee_pose"].publish(pose)
                for topic in ("/joint_states", "/reference_joint_states", "/torque_command", "/ee_pose"):
                    sent[topic] += 1
            for k in np.flatnonzero((run.t_force >= start - 1e-9) & (run.t_force < start + CHUNK - 1e-9)):
                t = float(run.t_force[k])
                pubs["/branch_forces"].publish(BranchForces(
                    header=header(t), name=run.branch_names, force=[float(x) for x in run.forces[k]],
                    deflection=[0.0, 0.0], deflection_rate=[0.0, 0.0]))
                sent["/branch_forces"] += 1
            h.wait_until(lambda: all(recorded(t) == n for t, n in sent.items()), 10.0, f"chunk at {start:.1f} s")
        recorder.close()
    finally:
        h.close()

    s = analyze(MODEL, [bag], tmp_path / "out", plots_on=False).runs["bag"]
    truth = run.truth
    assert s.bag.storage == "mcap"
    assert {k: v["messages"] for k, v in s.bag.topics.items()} == {
        "/joint_states": 501, "/branch_forces": 1001, "/torque_command": 501, "/reference_joint_states": 501,
        "/ee_pose": 501}
    assert s.hold_phase.start_s == pytest.approx(0.2, abs=1e-9)
    assert s.path.max_error_m == pytest.approx(np.linalg.norm(truth["offset"]), rel=1e-6)
    assert s.gap.max_m == pytest.approx(truth["gap_max"], rel=1e-6)
    assert s.branch_forces.peak_N["left"] == pytest.approx(truth["peak_force"][0], rel=1e-12)
    v = s.vibration["left"]
    assert abs(v.f_d_hz - truth["f_d"]) < 1.0 and v.zeta == pytest.approx(truth["zeta"], rel=0.05)
    assert s.streams["joint_states"].rate_hz == pytest.approx(1000.0)  # header stamps, not arrival
    assert s.streams["joint_states"].gaps == 0
