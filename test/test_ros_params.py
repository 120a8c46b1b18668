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

CONFIG = Path(__file__).resolve().parents[1] / "config"
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
    from elastic_pm_dyn.ros.feedforward_node import FeedforwardNode
    from elastic_pm_dyn.ros.plant_node import PlantNode
    from elastic_pm_dyn.ros.recorder import RecorderNode
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
    ("plant", "sensors.imu.stddev", -1.0, "parameter 'sensors.imu.stddev' must be a number >= 0"),
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
    ("feedforward", "line.start", [0.0, 0.4, 0.1], "need 2 coordinates"),
    ("feedforward", "line.move", -0.2, "parameter 'line.move' must be a positive number"),
    ("feedforward", "trigger", "clock", "parameter 'trigger' is 'clock'"),
    ("recorder", "storage", "rosbag1", "parameter 'storage' is 'rosbag1'"),
    ("recorder", "topics", ["/a", "/b"], None),  # valid: control case
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
        [sys.executable, "-m", "elastic_pm_dyn.ros.plant_node", "--ros-args", "--params-file",
         str(CONFIG / "plant.yaml"), "-p", "publish_rate:=1000"],
        env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert lines == ["plant_node: error: parameter 'publish_rate' must be a float (e.g. 1000.0, not 1000), "
                     "got integer 1000"]
    bad_file = tmp_path / "bad.yaml"
    bad_file.write_text("/**:\n  ros__parameters:\n    command_joints: [1, a]\n")
    proc = subprocess.run([sys.executable, "-m", "elastic_pm_dyn.ros.plant_node", "--ros-args",
                           "--params-file", str(bad_file)], env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("plant_node: error: ROS arguments rejected:")
