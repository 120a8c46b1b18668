"""Nothing lost III (issue #38) on live nodes: a second plant in a namespace where one runs refuses
to start (one line) and the first keeps its stream; a long ``~/step`` ends on Ctrl-C; bad topic
names and absurd sensor or disturbance settings are one line at start-up."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from ros_harness import domain_id, require

from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env

CONFIG = Path(__file__).resolve().parents[2] / "config"
START = 900.0  # [s] a cold start compiles the kernels
DOMAIN = domain_id(1)


def wait_for_line(proc: NodeProcess, text: str, timeout: float = START) -> None:
    deadline = time.monotonic() + timeout
    while text not in proc.log.read_text(errors="replace"):
        proc.check_running()
        assert time.monotonic() < deadline, f"no {text!r} in {proc.log}"
        time.sleep(0.1)


def test_a_second_plant_in_the_same_namespace_refuses_and_the_first_runs_on(tmp_path: Path) -> None:
    require("rclpy")
    env = ros_env(DOMAIN)
    args = ["-r", "__ns:=/r1", "-p", "sync_mode:=lockstep"]
    first = NodeProcess("first", "elastic_pm_dyn.ros.plant.node", args, env, tmp_path)
    second = None
    try:
        wait_for_line(first, "lockstep; commands")
        time.sleep(1.0)  # its status on /diagnostics (1 Hz): it is alive
        second = NodeProcess("second", "elastic_pm_dyn.ros.plant.node", args, env, tmp_path)
        wait_for_line(first, "lockstep; commands")  # (the first is still up)
        deadline = time.monotonic() + START
        while second.proc.poll() is None and "lockstep; commands" not in second.log.read_text(errors="replace"):
            assert time.monotonic() < deadline, "the second plant neither started nor refused"
            time.sleep(0.1)
        assert second.proc.wait(timeout=30) == 2, second.log.read_text()
        lines = [line for line in second.log.read_text().splitlines() if "error" in line]
        assert len(lines) == 1 and "already runs" in lines[0], second.log.read_text()
        first.check_running()
        # elsewhere it starts
        third = NodeProcess("third", "elastic_pm_dyn.ros.plant.node", ["-r", "__ns:=/r2", *args[2:]], env, tmp_path)
        try:
            wait_for_line(third, "lockstep; commands")
        finally:
            third.stop()
    finally:
        if second is not None and second.proc.poll() is None:
            second.stop()
        first.stop()


def test_a_long_step_ends_on_ctrl_c(tmp_path: Path) -> None:
    """~/step of a million periods (minutes) while the node is asked to stop: it answers with what it
    did and the process ends, long before the periods would be done."""
    require("rclpy")
    from elastic_pm_dyn_msgs.srv import StepPeriods
    from ros_harness import RosHarness
    from std_srvs.srv import Trigger

    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", ["-p", "sync_mode:=lockstep"],
                        ros_env(domain_id(3)), tmp_path)
    h = RosHarness(domain_id(3))
    try:
        wait_for_line(plant, "lockstep; commands")
        node = h.node("caller")
        assert h.call(node.create_client(Trigger, "/plant/pause"), Trigger.Request(), START).success
        step = node.create_client(StepPeriods, "/plant/step")
        h.wait_until(step.service_is_ready, START, "~/step")
        future = step.call_async(StepPeriods.Request(periods=1_000_000))
        wait_for_line(plant, "paused at")
        time.sleep(1.0)  # inside the step now
        began = time.monotonic()
        plant.proc.send_signal(signal.SIGINT)
        code = plant.proc.wait(timeout=120)
        stopped_after = time.monotonic() - began
        assert code == 0, plant.log.read_text()
        assert stopped_after < 60.0  # a million periods take minutes
        h.spin_for(0.5)
        if future.done():  # the answer may or may not get out before the process ends
            assert not future.result().success and "stopping" in future.result().message
    finally:
        h.close()
        if plant.proc.poll() is None:
            plant.stop()


@pytest.mark.parametrize("override, words", [
    ("sensors.topics.ee_imu:=''", "is no topic name"),
    ("topics.joint_states:=bad name", "is no topic name"),
    ("sensors.encoders.position_stddev:=1.0e308", "must be a number in [0, 1000]"),
    ("disturbance.rms:=1.0e300", "must be a number in [0, 10000]"),
    ("disturbance.duration:=1.0e12", "must be in (0, 60] s"),
    ("disturbance.duration:=-1.0", "must be a positive number"),
])
def test_absurd_settings_are_one_line_at_start_up(tmp_path: Path, override: str, words: str) -> None:
    require("rclpy")
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant.node",
                        ["--params-file", str(CONFIG / "plant_sensors.yaml"), "-p", override],
                        ros_env(DOMAIN), tmp_path)
    assert plant.wait(START) == 2
    text = plant.log.read_text()
    errors = [line for line in text.splitlines() if "error" in line.lower()]
    assert len(errors) == 1 and words in errors[0] and "Traceback" not in text, text
