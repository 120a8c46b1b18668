"""Goals on the feedforward node: what a stamp means, and the stream while a goal computes (#38).

A goal's stamp is its start on the node's clock, 0 for now: a zero-stamped goal starts from its
first point when its reference is ready; a stamp a little in the past starts it now, whole;
a future one holds its first pose until then; a stamp from another time base (1 s after 1970
on a wall-clock node, a wall-clock stamp on simulated time, the year 2100) is refused in one
line. A goal's reference is computed in a child process: the node keeps publishing meanwhile,
a newer goal supersedes it (the child killed), and SIGINT ends the node at once.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from ros_harness import RosHarness, domain_id, require
from test_ros_cartesian_goals import FIVE_BAR_POSES, goal

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.feedforward.goal_stamps import NS, STAMP_FUTURE, STAMP_PAST, goal_start, late_start

ACTIVE = ["left_motor", "right_motor"]
WALL = 1_780_000_000 * NS  # [ns] a wall-clock now (2026)
VERTICAL = Path(__file__).resolve().parents[2] / "config" / "five_bar_vertical.yaml"


@pytest.mark.parametrize(("stamp", "now", "words"), [
    (1 * NS, WALL, "before the node's clock (wall time: 1780000000.000000000 s)"),
    (1 * NS, WALL, "looks like simulated time and the node's clock is wall time"),
    (4_102_444_800 * NS, WALL, "after the node's clock"),  # 2100-01-01
    (WALL, 5 * NS, "looks like wall time and the node's clock like simulated time"),
    (WALL - round((STAMP_PAST + 0.5) * NS), WALL, f"at most {STAMP_PAST:g} s before it"),
    (WALL + round((STAMP_FUTURE + 0.5) * NS), WALL, f"or {STAMP_FUTURE:g} s after it"),
])
def test_a_stamp_outside_the_window_is_one_line(stamp: int, now: int, words: str) -> None:
    with pytest.raises(InputError) as err:
        goal_start(stamp, now, "wall time" if now > NS * 1e9 else "simulated time (use_sim_time)")
    assert words in str(err.value) and "\n" not in str(err.value)


def test_stamps_inside_the_window_are_the_start() -> None:
    assert goal_start(0, WALL, "wall time") is None  # now
    for offset in (-STAMP_PAST, -0.001, 0.0, 0.5, STAMP_FUTURE):
        stamp = WALL + round(offset * NS)
        assert goal_start(stamp, WALL, "wall time") == stamp
    assert late_start(None, WALL, 1e-3) == 0.0
    assert late_start(WALL + NS, WALL, 1e-3) == 0.0  # to come
    assert late_start(WALL - 500_000, WALL, 1e-3) == 0.0  # within a control period: its first command is next
    assert late_start(WALL - 2 * NS, WALL, 1e-3) == pytest.approx(2.0)


@pytest.fixture
def ros():
    h = RosHarness(domain_id(10))
    yield h
    h.close()


class Node:
    """A feedforward node (source trajectory) and a listener of its commands."""

    def __init__(self, h: RosHarness, **params: Any):
        require("rclpy")
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import JointState
        from trajectory_msgs.msg import JointTrajectory, MultiDOFJointTrajectory

        from elastic_pm_dyn.ros.feedforward.node import FeedforwardNode
        from elastic_pm_dyn.ros.qos import COMMAND_QOS
        self.h = h
        overrides = [Parameter(k.replace("__", "."), value=v)
                     for k, v in {"source": "trajectory", "wait_for_subscribers": 1, **params}.items()]
        self.ff = h.add(FeedforwardNode(context=h.context, parameter_overrides=overrides))
        self.listener = h.node("listener")
        self.commands: list[Any] = []
        self.listener.create_subscription(JointState, "torque_command", self.commands.append, COMMAND_QOS)
        self.pub = self.listener.create_publisher(MultiDOFJointTrajectory, "cartesian_trajectory", COMMAND_QOS)
        self.joint_pub = self.listener.create_publisher(JointTrajectory, "trajectory", COMMAND_QOS)
        h.wait_until(lambda: self.pub.get_subscription_count() > 0 and self.joint_pub.get_subscription_count() > 0
                     and self.ff.pub_command.get_subscription_count() > 0, 10.0, "the node and the listener")

    def now_ns(self) -> int:
        return self.ff.get_clock().now().nanoseconds

    def send(self, msg: Any, stamp_ns: int = 0) -> None:
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS)
        self.pub.publish(msg)

    def accepted(self, timeout: float = 60.0) -> Any:
        self.h.wait_until(lambda: self.ff.reference is not None and self.ff.goal is None, timeout, "the goal accepted")
        return self.ff.reference

    def sent(self) -> tuple[np.ndarray, np.ndarray]:
        """(stamps [ns], torques in ACTIVE order) of the commands so far."""
        stamps = np.array([c.header.stamp.sec * NS + c.header.stamp.nanosec for c in self.commands], dtype=np.int64)
        tau = np.array([[c.effort[list(c.name).index(j)] for j in ACTIVE] for c in self.commands])
        return stamps, tau


def _five_bar_goal() -> Any:
    return goal([p[0] for p in FIVE_BAR_POSES], [[p[1], p[2], 0.0] for p in FIVE_BAR_POSES])


def _assert_commands_follow(node: Node, reference: Any, since: int) -> None:
    """Every command stamped from ``since`` on is the reference at its time since the start."""
    stamps, tau = node.sent()
    start = node.ff.start_ns
    assert start is not None
    keep = stamps >= since
    assert keep.sum() >= 5
    for ns, value in zip(stamps[keep], tau[keep], strict=True):
        np.testing.assert_allclose(value, reference.sample((ns - start) / NS).tau, rtol=0, atol=1e-12)


def test_a_zero_stamped_goal_starts_now_from_its_first_point(ros: RosHarness) -> None:
    node = Node(ros, rate=200.0, model=str(VERTICAL))  # under gravity: each pose has its own holding torques
    node.send(_five_bar_goal())
    reference = node.accepted()
    ros.wait_until(lambda: len(node.commands) >= 10, 10.0, "commands of the goal")
    stamps, tau = node.sent()
    assert node.ff.start_ns == stamps[0]  # its first command is its start
    np.testing.assert_allclose(tau[0], reference.sample(0.0).tau, rtol=0, atol=1e-12)  # the first point, at rest
    assert np.abs(tau[0] - reference.sample(reference.duration).tau).max() > 1e-3  # not the end pose's hold
    _assert_commands_follow(node, reference, stamps[0])


def test_a_stamp_just_past_starts_the_whole_goal_now_and_a_future_one_at_its_stamp(ros: RosHarness) -> None:
    node = Node(ros, rate=200.0)
    node.send(_five_bar_goal(), node.now_ns() - 2 * NS)  # 2 s ago: within the window, the start has passed
    reference = node.accepted()
    ros.wait_until(lambda: len(node.commands) >= 10, 10.0, "commands of the goal")
    stamps, tau = node.sent()
    np.testing.assert_allclose(tau[0], reference.sample(0.0).tau, rtol=0, atol=1e-12)  # whole: from its start
    _assert_commands_follow(node, reference, stamps[0])

    start = node.now_ns() + 2 * NS  # in 2 s
    node.send(goal([0.0, 0.2], [[0.05, 0.45, 0.0], [0.0, 0.4, 0.0]]), start)
    ros.wait_until(lambda: node.ff.start_ns == start, 30.0, "the second goal accepted")
    n1 = len(node.commands) + 1  # (one may be on its way)
    ros.wait_until(lambda: node.sent()[0][-1] > start + NS // 10, 10.0, "its start passed")
    stamps, _ = node.sent()
    assert (stamps[n1:] < start).any() and (stamps[n1:] >= start).any()
    _assert_commands_follow(node, node.ff.reference, int(stamps[n1]))  # its first pose held until its start


def test_far_stamps_are_refused_and_the_node_runs_on(ros: RosHarness) -> None:
    from builtin_interfaces.msg import Time
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    node = Node(ros, rate=200.0)
    year_2100 = 4_102_444_800 * NS
    for stamp in (NS, year_2100):  # sim time sent to a wall-clock node; a start in 2100
        node.send(_five_bar_goal(), stamp)
        joint = JointTrajectory(joint_names=ACTIVE, points=[JointTrajectoryPoint(positions=[2.6, 0.87])])
        joint.header.stamp.sec = stamp // NS
        node.joint_pub.publish(joint)
    ros.spin_for(0.5)
    assert node.ff.reference is None and node.ff.goal is None and not node.commands
    with pytest.raises(InputError, match=r"stamp 1\.000000000 s is .* before the node's clock \(wall time: .*looks "
                                         r"like simulated time"):
        node.ff._start_of(Time(sec=1))
    node.send(_five_bar_goal())  # and the next goal is taken
    node.accepted()


def test_a_goal_computes_beside_the_stream_and_a_newer_one_supersedes_it(ros: RosHarness) -> None:
    node = Node(ros, rate=500.0, method="elastic")
    node.send(goal([0.0, 0.2], [[-0.05, 0.35, 0.0], [-0.04, 0.36, 0.0]]))
    first = node.accepted()
    hold = first.sample(first.duration).tau
    ros.wait_until(lambda: node.ff.last_ns is not None and (node.ff.last_ns - node.ff.start_ns) / NS > first.duration,
                   30.0, "the first goal over: its end pose held")
    n = 242  # 60 s of moves: 30 000 grid points of the elastic inverse, some 20 s of computing
    node.send(goal([0.25 * k for k in range(n)], [[-0.04 + 0.005 * (k % 2), 0.36, 0.0] for k in range(n)]))
    ros.wait_until(lambda: node.ff.goal is not None, 10.0, "the long goal taken")
    long_goal = node.ff.goal
    n0 = len(node.commands)
    ros.spin_for(1.0)
    assert node.ff.goal is long_goal and not long_goal.done.is_set()  # still computing ...
    during = node.sent()[1][n0:]
    assert len(during) >= 100  # ... and the stream went on (500 Hz; a loaded machine gives fewer)
    np.testing.assert_allclose(during, np.tile(hold, (len(during), 1)), rtol=0, atol=1e-12)  # the last torque

    node.send(goal([0.0, 0.2], [[-0.04, 0.36, 0.0], [-0.05, 0.35, 0.0]]))  # a newer goal
    ros.wait_until(long_goal.done.is_set, 10.0, "the long goal cancelled")  # its child killed, long before done
    assert long_goal.cancelled and long_goal.reference is None
    second = node.accepted()
    assert second.duration < 1.0
    node.ff.close()


def interrupt(proc) -> tuple[int, float]:
    """Ctrl-C to a node process: its exit status and how long it took to end [s]."""
    start = time.monotonic()
    proc.proc.send_signal(signal.SIGINT)
    code = proc.wait(30.0)
    return code, time.monotonic() - start


def test_sigint_ends_a_node_computing_a_long_goal_at_once(tmp_path: Path) -> None:
    require("rclpy")
    from trajectory_msgs.msg import MultiDOFJointTrajectory

    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env
    from elastic_pm_dyn.ros.qos import COMMAND_QOS
    domain = domain_id(13)
    proc = NodeProcess("feedforward", "elastic_pm_dyn.ros.feedforward.node",
                       ["-p", "source:=trajectory", "-p", "method:=elastic", "-p", "wait_for_subscribers:=0"],
                       ros_env(domain), tmp_path)
    h = RosHarness(domain)
    try:
        pub = h.node("sender").create_publisher(MultiDOFJointTrajectory, "cartesian_trajectory", COMMAND_QOS)
        h.wait_until(lambda: pub.get_subscription_count() > 0, 60.0, "the node's goal subscription")
        n = 362  # 90 s of moves: some 30 s of computing
        pub.publish(goal([0.25 * k for k in range(n)], [[-0.04 + 0.005 * (k % 2), 0.36, 0.0] for k in range(n)]))
        h.wait_until(lambda: "computing its reference" in proc.log.read_text(), 30.0, "the goal taken")
        h.spin_for(1.0)
        code, took = interrupt(proc)
    finally:
        if proc.proc.poll() is None:
            os.killpg(proc.proc.pid, signal.SIGKILL)
        h.close()
    log = proc.log.read_text()
    assert code == 0, log
    assert took < 10.0, log  # the computation would take some 30 s
    assert "accepted" not in log


def test_rate_and_goal_sizes_are_bounded(ros: RosHarness) -> None:
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from elastic_pm_dyn.motion.waypoints import MAX_WAYPOINTS
    from elastic_pm_dyn.ros.params import ParameterError
    with pytest.raises(ParameterError, match=r"parameter 'rate' must be a positive number at most 10000"):
        Node(ros, rate=1e7)
    node = Node(ros, rate=200.0)
    n = MAX_WAYPOINTS + 1
    node.send(goal([k * 0.01 for k in range(n)], [[-0.05, 0.35, 0.0]] * n))
    node.joint_pub.publish(JointTrajectory(joint_names=ACTIVE, points=[JointTrajectoryPoint(positions=[2.6, 0.87])
                                                                       for _ in range(n)]))
    ros.spin_for(0.5)
    assert node.ff.goal is None and node.ff.reference is None  # refused in their callbacks, before any work


def test_sigint_ends_a_node_computing_its_elastic_line_at_once(tmp_path: Path) -> None:
    """The elastic line of ``source: line`` is computed beside the node too: the node is up (its
    services and Ctrl-C answer) while a long line computes, and it starts the line once ready."""
    require("rclpy")
    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env
    proc = NodeProcess("feedforward", "elastic_pm_dyn.ros.feedforward.node",
                       ["-p", "method:=elastic", "-p", "line.move:=60.0", "-p", "wait_for_subscribers:=0"],
                       ros_env(domain_id(13)), tmp_path)
    try:
        deadline = time.monotonic() + 300.0
        while "source line" not in proc.log.read_text():
            proc.check_running()
            assert time.monotonic() < deadline, "the node did not start"
            time.sleep(0.1)
        time.sleep(1.0)
        code, took = interrupt(proc)
    finally:
        if proc.proc.poll() is None:
            os.killpg(proc.proc.pid, signal.SIGKILL)
    log = proc.log.read_text()
    assert code == 0, log
    assert took < 10.0, log  # the line's elastic inverse takes about a minute
    assert "reference ready" not in log and "started" not in log  # up long before its line was


def run_to_end(tmp_path: Path, args: list[str]) -> tuple[int, str]:
    """A feedforward node with ``args`` run until it ends by itself: its exit status and log."""
    require("rclpy")
    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env
    proc = NodeProcess("feedforward", "elastic_pm_dyn.ros.feedforward.node", ["-p", "wait_for_subscribers:=0", *args],
                       ros_env(domain_id(13)), tmp_path)
    try:
        code = proc.wait(600.0)
    finally:
        if proc.proc.poll() is None:
            os.killpg(proc.proc.pid, signal.SIGKILL)
    return code, proc.log.read_text()


def test_an_elastic_line_starts_once_computed(tmp_path: Path) -> None:
    code, log = run_to_end(tmp_path, ["-p", "method:=elastic", "-p", "exit_when_done:=true"])
    assert code == 0, log
    ready, started, finished = (log.index(w) for w in ("reference ready", "started", "reference finished"))
    assert ready < started < finished


def test_an_elastic_line_it_refuses_ends_the_node_with_one_line(tmp_path: Path) -> None:
    code, log = run_to_end(tmp_path, ["-p", "method:=elastic", "-p", "line.end:=[1.5, 1.5]"])
    errors = [line for line in log.splitlines() if "ERROR" in line]
    assert code == 2 and len(errors) == 1 and "parameters 'line.*' with method elastic" in errors[0], errors
