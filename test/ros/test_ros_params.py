"""Parameter files load; a wrong parameter stops a node at start-up with a one-line reason."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from ros_harness import RosHarness, domain_id, require

CONFIG = Path(__file__).resolve().parents[2] / "config"
DOMAIN = domain_id(80)


def _flatten(tree: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[prefix + key] = value
    return out


def _node_class(name: str) -> type:
    require("rclpy")
    from elastic_pm_dyn.ros.feedforward.node import FeedforwardNode
    from elastic_pm_dyn.ros.plant.node import PlantNode
    from elastic_pm_dyn.ros.recorder.node import RecorderNode
    return {"plant": PlantNode, "plant_sensors": PlantNode, "feedforward": FeedforwardNode,
            "recorder": RecorderNode}[name]


@pytest.mark.parametrize("name", ["plant", "plant_sensors", "feedforward", "recorder"])
def test_parameter_file_loads(name: str, tmp_path: Path) -> None:
    """Every value of config/<name>.yaml reaches the node, with its YAML type."""
    path = CONFIG / f"{name}.yaml"
    expected = _flatten(yaml.safe_load(path.read_text())["/**"]["ros__parameters"])
    extra = ["-p", f"output:={tmp_path / 'bag'}"] if name == "recorder" else []
    h = RosHarness(DOMAIN, args=["test", "--ros-args", "--params-file", str(path), *extra])
    try:
        node = h.add(_node_class(name)(context=h.context))
        for key, value in expected.items():
            if key == "output":
                continue
            got = node.get_parameter(key).value
            got = list(got) if isinstance(value, list) else got
            assert got == (value or []) if isinstance(value, list) else got == value, key
            assert type(got) is type(value), key
        node.close()
    finally:
        h.close()


@pytest.mark.parametrize(("node", "param", "value", "reason"), [
    ("plant", "formulation", "scdd2", "parameter 'formulation' is 'scdd2', expected one of"),
    ("plant", "sync_mode", "turbo", "parameter 'sync_mode' is 'turbo'"),
    ("plant", "publish_rate", 1000, "parameter 'publish_rate' must be a float"),
    ("plant", "publish_rate", -5.0, "parameter 'publish_rate' must be a positive number"),
    ("plant", "dt", 0.0, "parameter 'dt' must be a positive number"),
    ("plant", "command_timeout", 1, "parameter 'command_timeout' must be a float"),  # runtime: same line
    ("plant", "command_timeout", -0.5, "parameter 'command_timeout' must be a positive number"),
    ("plant", "realtime.priority", 120, "parameter 'realtime.priority' must lie in 0-99"),
    ("plant", "realtime.overrun", "drop", "parameter 'realtime.overrun' is 'drop'"),
    ("plant", "command_joints", ["left_motor"], "parameter 'command_joints'"),
    ("plant", "model", "/no/such/model.yaml", "parameter 'model': no such file"),
    ("plant", "formulaton", "lda", "unknown parameter(s) formulaton"),
    ("plant", "sensors.imu.stddev", -1.0, "parameter 'sensors.imu.stddev' must be a number in [0, 1000]"),
    ("plant", "sensors.imu.sample_timing", "later", "parameter 'sensors.imu.sample_timing' is 'later'"),
    ("plant", "sensors.imu.rpy", [0.0, 1.0], "parameter 'sensors.imu.rpy' must be 3 finite numbers"),
    ("plant", "sensors.encoders.counts_per_revolution", 4096.0, "must be an integer"),
    ("plant", "sensors.imu.enabeld", True, "did you mean sensors.imu.enabled"),
    ("plant", "disturbance.spectrum", "blue", "parameter 'disturbance.spectrum' is 'blue'"),
    ("plant", "disturbance.band", [200.0, 2.0], "parameter 'disturbance.band' must be [low, high]"),
    ("plant", "gravity", [0.0, -9.81], "parameter 'gravity' must be 3 finite numbers"),
    ("plant", "gravity", [0, -9, 0], "parameter 'gravity' must be a list of a float"),
    ("plant", "elastic_dof_per_chain", 9, "parameter 'elastic_dof_per_chain' must lie in 0-8"),
    ("plant", "gravity", [0.0, -9.81, 0.0], None),  # valid: control case
    ("plant", "diagnostics_rate", 1e9, "parameter 'diagnostics_rate' must be a positive number at most 100"),
    ("plant", "marker_rate", 0.0, "parameter 'marker_rate' must be a positive number at most 100"),
    ("feedforward", "line.start", [0.0, 0.4, 0.1], "need 2 coordinates"),
    ("feedforward", "line.move", -0.2, "parameter 'line.move' must be a positive number"),
    ("feedforward", "trigger", "clock", "parameter 'trigger' is 'clock'"),
    ("recorder", "storage", "rosbag1", "parameter 'storage' is 'rosbag1'"),
    ("recorder", "topics", ["/a", "/b"], None),  # valid: control case
    ("recorder", "topics", ["joint states"], "parameter 'topics': 'joint states' is no topic name (topic name"),
])
def test_wrong_parameter_fails_with_reason(node: str, param: str, value: Any, reason: str | None,
                                           tmp_path: Path) -> None:
    require("rclpy")
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.params import ParameterError
    overrides = [Parameter(param, value=value)]
    if node == "recorder":
        overrides.append(Parameter("output", value=str(tmp_path / "bag")))
    h = RosHarness(DOMAIN)
    try:
        if reason is None:
            h.add(_node_class(node)(context=h.context, parameter_overrides=overrides)).close()
            return
        with pytest.raises(ParameterError) as err:
            h.add(_node_class(node)(context=h.context, parameter_overrides=overrides))
        assert reason in str(err.value)
        assert "\n" not in str(err.value)
    finally:
        h.close()


def test_node_process_refuses_to_start_with_one_line(tmp_path: Path) -> None:
    """The console entry: exit status 2 and exactly one line on stderr naming the parameter."""
    require("rclpy")
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.run(
        [sys.executable, "-m", "elastic_pm_dyn.ros.plant.node", "--ros-args", "--params-file",
         str(CONFIG / "plant.yaml"), "-p", "publish_rate:=1000"],
        env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert lines == ["plant_node: error: parameter 'publish_rate' must be a float (e.g. 1000.0, not 1000), "
                     "got integer 1000"]
    bad_file = tmp_path / "bad.yaml"
    bad_file.write_text("/**:\n  ros__parameters:\n    command_joints: [1, a]\n")
    proc = subprocess.run([sys.executable, "-m", "elastic_pm_dyn.ros.plant.node", "--ros-args",
                           "--params-file", str(bad_file)], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("plant_node: error: ROS arguments rejected:")


class _RemoteParameters:
    """Sets a node's parameters as ``ros2 param set`` does: rclpy's parameter client, i.e. the
    SetParameters service (arrays arrive at the node as array.array, not as lists)."""

    def __init__(self, h: RosHarness, node_name: str):
        from rclpy.parameter_client import AsyncParameterClient
        self.h = h
        self.client = AsyncParameterClient(h.node("param_client"), node_name)
        h.wait_until(self.client.services_are_ready, 60.0, f"{node_name}'s parameter services")

    def set(self, **values: Any) -> list[Any]:
        from rclpy.parameter import Parameter
        future = self.client.set_parameters([Parameter(k.replace("__", "."), value=v) for k, v in values.items()])
        self.h.wait_until(future.done, 60.0, "the set_parameters response")
        return list(future.result().results)


def _refused(result: Any, *words: str) -> bool:
    return not result.successful and "\n" not in result.reason and all(w in result.reason for w in words)


def test_observer_parameters_change_through_the_parameter_client() -> None:
    """docs/ros.md's ``ros2 param set /observer observer.imu.stddev "[0.05]"`` over the service:
    accepted, in the running filter; a wrong array type and an unbounded rate refused in one line."""
    require("rclpy")
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.observer.node import ObserverNode
    h = RosHarness(DOMAIN)
    try:
        node = h.add(ObserverNode(context=h.context, parameter_overrides=[
            Parameter("observer.sensors", value=["encoders", "imu"])]))
        obs = node.observer.session.obs
        remote = _RemoteParameters(h, "/observer")
        ok = remote.set(observer__imu__stddev=[0.05], observer__encoders__position_stddev=[1e-4],
                        diagnostics_rate=5.0)
        assert all(r.successful for r in ok), [r.reason for r in ok]
        assert list(node.get_parameter("observer.imu.stddev").value) == [0.05]
        assert obs.imu.var == pytest.approx(0.05 ** 2)
        assert obs.encoders.pos_var == pytest.approx(1e-8)
        assert node.observer.timers["diagnostics_rate"].timer_period_ns == 200_000_000

        (wrong_type,) = remote.set(observer__imu__stddev=[1, 2])
        assert _refused(wrong_type, "parameter 'observer.imu.stddev' must be a list of a float", "[1, 2]")
        assert "array(" not in wrong_type.reason
        (negative,) = remote.set(observer__imu__stddev=[-1.0])
        assert _refused(negative, "imu.stddev")
        (too_fast,) = remote.set(marker_rate=1e9)
        assert _refused(too_fast, "parameter 'marker_rate' must be a positive number at most 100")
        assert obs.imu.var == pytest.approx(0.05 ** 2)  # the refusals left the filter as it was
        assert node.get_parameter("marker_rate").value == 30.0
    finally:
        h.close()


def test_plant_parameters_change_through_the_parameter_client() -> None:
    """Every runtime parameter of the plant, disturbance.timeout too, over the service; rates bounded."""
    require("rclpy")
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    h = RosHarness(DOMAIN)
    try:
        plant = h.add(PlantNode(context=h.context, parameter_overrides=[
            Parameter("sync_mode", value="lockstep"), Parameter("disturbance.input", value=True)]))
        remote = _RemoteParameters(h, "/plant")
        ok = remote.set(command_timeout=0.05, disturbance__timeout=0.02, marker_rate=10.0,
                        diagnostics_rate=100.0, lockstep__waiting_republish_period=0.25)
        assert all(r.successful for r in ok), [r.reason for r in ok]
        assert (plant.hold.timeout, plant.hold.disturbance_timeout, plant.sync.republish_period) == (0.05, 0.02, 0.25)
        assert plant.marker_timer.timer_period_ns == 100_000_000
        assert plant.diagnostics_timer.timer_period_ns == 10_000_000
        assert plant.get_parameter("disturbance.timeout").value == 0.02

        (too_fast,) = remote.set(diagnostics_rate=1e9)
        assert _refused(too_fast, "parameter 'diagnostics_rate' must be a positive number at most 100, got 1")
        (negative,) = remote.set(disturbance__timeout=-1.0)
        assert _refused(negative, "parameter 'disturbance.timeout' must be a positive number")
        (fixed,) = remote.set(disturbance__rms=1.0)
        assert not fixed.successful  # read-only: the spectrum is set up at start-up
        assert plant.hold.disturbance_timeout == 0.02 and plant.diagnostics_timer.timer_period_ns == 10_000_000
    finally:
        h.close()
