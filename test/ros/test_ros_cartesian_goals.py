"""Cartesian goals (trajectory_msgs/MultiDOFJointTrajectory) on the feedforward node.

The conversion of a goal to the task path, each bad goal refused with one line, and a real
node on a private domain: a good goal after bad ones streams the torques the CLI's
``feedforward --waypoints`` writes for the same poses (rigid and elastic methods).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require
from scipy.spatial.transform import Rotation

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model.loader import load_model

CONFIG = Path(__file__).resolve().parents[2] / "config"
FIVE_BAR, TRIGLIDE, HEXA = CONFIG / "five_bar.yaml", CONFIG / "triglide.yaml", CONFIG / "hexa.yaml"
ACTIVE = ["left_motor", "right_motor"]
# five-bar: the reference manoeuvre's start, then two poses (m, s): a move the bench did not tune on
FIVE_BAR_POSES = [(0.0, -0.05, 0.35), (0.15, 0.0, 0.42), (0.3, 0.05, 0.45)]


def goal(times: list[float], xyz: list[list[float]], quats: list[list[float]] | None = None,
         name: str = "end_effector", frame: str = "world", twist: list[float] | None = None) -> Any:
    """A MultiDOFJointTrajectory of one joint (quaternions x, y, z, w; identity if None)."""
    require("trajectory_msgs")
    from builtin_interfaces.msg import Duration
    from geometry_msgs.msg import Quaternion, Transform, Twist, Vector3
    from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint
    msg = MultiDOFJointTrajectory(joint_names=[name])
    msg.header.frame_id = frame
    for k, t in enumerate(times):
        q = [0.0, 0.0, 0.0, 1.0] if quats is None else quats[k]
        tr = Transform(translation=Vector3(x=float(xyz[k][0]), y=float(xyz[k][1]), z=float(xyz[k][2])),
                       rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
        sec = int(t)
        p = MultiDOFJointTrajectoryPoint(transforms=[tr], time_from_start=Duration(sec=sec,
                                                                                  nanosec=round((t - sec) * 1e9)))
        if twist is not None:
            p.velocities = [Twist(linear=Vector3(x=twist[0], y=twist[1], z=twist[2]),
                                  angular=Vector3(x=twist[3], y=twist[4], z=twist[5]))]
        msg.points.append(p)
    return msg


def five_bar_goal(**kw: Any) -> Any:
    return goal([p[0] for p in FIVE_BAR_POSES], [[p[1], p[2], 0.0] for p in FIVE_BAR_POSES], **kw)


def test_hexa_goal_is_the_platform_pose_in_urdf_rpy() -> None:
    from elastic_pm_dyn.ros.feedforward.cartesian_goals import goal_waypoints
    model = load_model(HEXA)
    # yaw 5 deg about z, then pitch 2 deg: R = Rz(yaw) Ry(pitch), written as a quaternion by hand
    yaw, pitch = np.radians(5.0), np.radians(2.0)
    qz = np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])
    qy = np.array([0.0, np.sin(pitch / 2), 0.0, np.cos(pitch / 2)])
    x1, y1, z1, w1 = qz
    x2, y2, z2, w2 = qy
    q = [w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
         w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2]  # qz * qy
    times, points, rates, _ = goal_waypoints(goal([0.0, 0.2], [[0, 0, -0.4], [0.02, 0.02, -0.385]],
                                        [[0, 0, 0, 1], q], name="platform"), model, "world")
    np.testing.assert_allclose(times, [0.0, 0.2])
    np.testing.assert_allclose(points[0], [0, 0, -0.4, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(points[1], [0.02, 0.02, -0.385, yaw, pitch, 0.0], atol=1e-12)
    assert not np.any(rates)


@pytest.mark.parametrize("model_file, msg, words", [
    (FIVE_BAR, lambda: five_bar_goal(name="tool0"), "joint_names"),
    (FIVE_BAR, lambda: five_bar_goal(frame="map"), "frame 'map'"),
    (FIVE_BAR, lambda: goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [np.nan, 0.4, 0.0]]), "NaN"),
    (FIVE_BAR, lambda: goal([0.0, 0.2, 0.2], [[-0.05, 0.35, 0.0]] * 3), "strictly increasing"),
    (FIVE_BAR, lambda: goal([0.0], [[-0.05, 0.35, 0.0]]), "at least two"),
    (FIVE_BAR, lambda: goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [0.0, 0.4, 0.01]]), "out of the plane"),
    (FIVE_BAR, lambda: goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [0.0, 0.4, 0.0]],
                            [[0, 0, 0, 1], list(Rotation.from_euler("z", 5, degrees=True).as_quat())]),
     "cannot turn"),
    (TRIGLIDE, lambda: goal([0.0, 0.2], [[0, 0, -0.35], [0.01, 0, -0.34]],
                            [[0, 0, 0, 1], list(Rotation.from_euler("x", 1, degrees=True).as_quat())],
                            name="platform"), "cannot turn"),
    (FIVE_BAR, lambda: goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [0.0, 0.4, 0.0]], [[0, 0, 0, 1], [0, 0, 0, 0]]),
     "unit quaternion"),
    (FIVE_BAR, lambda: goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [0.0, 0.4, 0.0]], twist=[0.1, 0, 0, 0, 0, 0]),
     "the first and the last waypoint"),
    (FIVE_BAR, lambda: goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [0.0, 0.4, 0.0]], twist=[0, 0, 0, 0, 0, 0.1]),
     "cannot turn"),
    (FIVE_BAR, lambda: goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [0.0, 0.4, 0.0]], twist=[0, 0, 0.1, 0, 0, 0]),
     "out of the plane"),
])
def test_bad_goal_is_one_line(model_file: Path, msg: Any, words: str) -> None:
    from elastic_pm_dyn.ros.feedforward.cartesian_goals import goal_path
    with pytest.raises(InputError) as err:
        goal_path(msg(), load_model(model_file), "world", 2, 1000.0)
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.fixture
def ros():
    h = RosHarness(domain_id(59))
    yield h
    h.close()


def _node(h: RosHarness, **params: Any) -> Any:
    require("rclpy")
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.feedforward.node import FeedforwardNode
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(FeedforwardNode(context=h.context, parameter_overrides=overrides))


def _cli_table(tmp_path: Path, method: str) -> np.ndarray:
    poses = tmp_path / "poses.csv"
    poses.write_text("t,x,y\n" + "".join(f"{t},{x},{y}\n" for t, x, y in FIVE_BAR_POSES))
    out = tmp_path / f"tau_{method}.csv"
    assert main(["feedforward", "--model", str(FIVE_BAR), "--waypoints", str(poses), "--method", method,
                 "--hold", "0", "--out", str(out)]) == 0
    return np.loadtxt(out, delimiter=",", skiprows=1)


@pytest.mark.parametrize("method", ["rigid", "elastic", "shaped"])
def test_node_streams_the_cli_waypoint_torques_after_refusing_bad_goals(ros: RosHarness, tmp_path: Path,
                                                                       method: str) -> None:
    from sensor_msgs.msg import JointState
    from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

    from elastic_pm_dyn.ros.qos import COMMAND_QOS
    table = _cli_table(tmp_path, method)
    listener = ros.node("listener")
    commands: list[Any] = []
    listener.create_subscription(JointState, "torque_command", commands.append, COMMAND_QOS)
    ff = _node(ros, source="trajectory", method=method, wait_for_subscribers=1)
    pub = listener.create_publisher(MultiDOFJointTrajectory, "cartesian_trajectory", COMMAND_QOS)
    joint_pub = listener.create_publisher(JointTrajectory, "trajectory", COMMAND_QOS)
    ros.wait_until(lambda: pub.get_subscription_count() > 0 and joint_pub.get_subscription_count() > 0, 10.0,
                   "goal subscriptions")
    for bad in (five_bar_goal(name="tool0"), five_bar_goal(frame="map"),
                goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [0.5, 0.5, 0.0]]),  # unreachable: 0.71 m from the base
                goal([0.0, 0.2, 0.1], [[-0.05, 0.35, 0.0]] * 3),
                goal([0.0, 0.005], [[-0.05, 0.35, 0.0], [-0.05, 0.351, 0.0]]),  # 5 control periods
                goal([0.0, 500.0], [[-0.05, 0.35, 0.0], [-0.05, 0.351, 0.0]])):  # 5e5 of them
        pub.publish(bad)
    if method != "rigid":  # motor positions do not fix the end effector's path: refused, node alive
        from trajectory_msgs.msg import JointTrajectoryPoint
        joint_pub.publish(JointTrajectory(joint_names=ACTIVE, points=[JointTrajectoryPoint(positions=[2.6, 0.87])]))
    ros.spin_for(0.5)
    assert ff.reference is None and not commands

    pub.publish(five_bar_goal())
    ros.wait_until(lambda: ff.reference is not None, 30.0, "the goal accepted")
    ros.wait_until(lambda: len(commands) >= 20, 10.0, "commands of the goal")
    stamps = np.array([c.header.stamp.sec * 10**9 + c.header.stamp.nanosec for c in commands])
    k = np.round((stamps - stamps[0]) * 1e-6).astype(int)  # control instants (timer: some may be skipped)
    k = k[k < len(table)]
    sent = np.array([[c.effort[list(c.name).index(j)] for j in ACTIVE] for c in commands[:len(k)]])
    np.testing.assert_allclose(sent, table[k, 1:], rtol=0, atol=1e-12)
    # and the whole table, off the timer: the reference's grid samples are the CLI's rows
    ref = np.array([ff.reference.sample(t).tau for t in table[:, 0]])
    np.testing.assert_allclose(ref, table[:, 1:], rtol=0, atol=1e-12)


def test_moving_waypoints_with_zero_rates_are_the_rest_to_rest_path_and_pass_given_twists() -> None:
    """Hermite segments of degree 2 r + 1 with zero rates are the rest-to-rest law per segment;
    a twist at a waypoint is the path's rate there; a yaw rate is the angular twist about z."""
    from elastic_pm_dyn.motion.waypoints import MovingWaypointPath, WaypointPath
    from elastic_pm_dyn.ros.feedforward.cartesian_goals import goal_path, goal_waypoints
    times = np.array([0.0, 0.1, 0.25])
    points = np.array([[-0.05, 0.35], [0.0, 0.42], [0.05, 0.45]])
    zero = np.zeros_like(points)
    for order in (2, 4):
        moving, resting = MovingWaypointPath(times, points, zero, zero, 0.0, order), WaypointPath(times, points, 0.0,
                                                                                                  order)
        for t in np.linspace(-0.01, 0.26, 55):
            for a, b in zip(moving(float(t)), resting(float(t)), strict=True):
                np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)  # round-off of degree-9 polynomials
    five_bar = load_model(FIVE_BAR)
    msg = goal(list(times), [[x, y, 0.0] for x, y in points])
    msg.points[1].velocities = goal([0.0], [[0, 0, 0]], twist=[0.4, 0.1, 0.0, 0, 0, 0]).points[0].velocities
    path = goal_path(msg, five_bar, "world", 4, 1000.0)
    y, yd, ydd = path(0.1)
    np.testing.assert_allclose(y, points[1], atol=1e-15)
    np.testing.assert_allclose(yd, [0.4, 0.1], atol=1e-12)
    np.testing.assert_allclose(ydd, [0.0, 0.0], atol=1e-9)
    hexa = load_model(HEXA)
    spin = goal([0.0, 0.1, 0.2], [[0, 0, -0.4], [0.01, 0, -0.39], [0.02, 0.02, -0.385]], name="platform")
    spin.points[1].velocities = goal([0.0], [[0, 0, 0]], twist=[0.1, 0.0, 0.15, 0, 0, 0.5]).points[0].velocities
    _, _, rates, _ = goal_waypoints(spin, hexa, "world")
    np.testing.assert_allclose(rates[1], [0.1, 0.0, 0.15, 0.5, 0.0, 0.0], atol=1e-12)


def test_elastic_torques_of_a_goal_with_moving_waypoints_keep_the_plant_on_it() -> None:
    """A goal passed with a twist (C^4 Hermite segments): the elastic inverse's continuous torques
    drive the elastic five-bar along it to 1e-7 m."""
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.motion.feedforward import elastic_line_motion
    from elastic_pm_dyn.ros.feedforward.cartesian_goals import goal_path
    from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
    from elastic_pm_dyn.sim.torque import FunctionTorque
    model = load_model(FIVE_BAR)
    msg = five_bar_goal()
    msg.points[1].velocities = goal([0.0], [[0, 0, 0]], twist=[0.4, 0.1, 0.0, 0, 0, 0]).points[0].velocities
    path = goal_path(msg, model, "world", 4, 1000.0)
    motion = elastic_line_motion(model, path, 1e-3)
    q0 = motion.q[int(np.argmin(np.abs(motion.t)))]
    r = Simulator(Mechanism(model), SimulationOptions(integrator="rk4", dt=1e-5, sample=1e-4)).run(
        FunctionTorque(motion.torque()), path.duration + 0.02, q0=q0)
    y = np.array([path(float(t))[0] for t in r.t])
    assert np.linalg.norm(r.ee - y, axis=1).max() <= 1e-7
