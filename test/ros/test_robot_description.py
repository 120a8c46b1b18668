"""The machine in RViz: the plant node's ``robot_description`` and launch/rviz.launch.py.

1. A plant process publishes the machine's URDF once; a subscriber that starts later gets it
   (transient local). It parses, and every joint of ``joint_states`` is a joint of it.
2. A URDF machine publishes its own file; an MJCF machine and ``mode: observer`` publish
   the written URDF; ``topics.robot_description`` names the topic.
3. ``publish_robot_description: false`` switches it off.
4. The launch file is valid Python that names the installed executables and files; with
   ``launch`` installed it builds its description; its nodes get the plant's URDF and frame.
"""

from __future__ import annotations

import ast
import importlib.util
import re
import sys
import types
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.model.urdf_writer import model_to_urdf

REPO = Path(__file__).resolve().parents[2]
FIVE_BAR = REPO / "config" / "five_bar.yaml"
URDF_FIVE_BAR = REPO / "test" / "robots" / "five_bar_urdf" / "robot.urdf"
MJCF_FIVE_BAR = REPO / "test" / "robots" / "five_bar.xml"
LAUNCH_FILE = REPO / "launch" / "rviz.launch.py"
DOMAIN = domain_id(53)


def _joint_names(urdf: str) -> set[str]:
    return {j.get("name") for j in ET.fromstring(urdf).iter("joint")}


class _Listener:
    """A node that subscribes late: joint_states, and robot_description as RViz does (transient local)."""

    def __init__(self, h: RosHarness, topic: str = "robot_description"):
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        from elastic_pm_dyn.ros.qos import STATE_QOS
        from elastic_pm_dyn.ros.robot_description import DESCRIPTION_QOS
        self.node = h.node("viewer")
        self.descriptions: list[str] = []
        self.joint_names: list[str] = []
        self.node.create_subscription(String, topic, lambda m: self.descriptions.append(m.data), DESCRIPTION_QOS)
        self.node.create_subscription(JointState, "joint_states",
                                      lambda m: setattr(self, "joint_names", list(m.name)), STATE_QOS)


def _plant(h: RosHarness, **params: Any) -> Any:
    from rclpy.parameter import Parameter

    from elastic_pm_dyn.ros.plant.node import PlantNode
    overrides = [Parameter(k.replace("__", "."), value=v) for k, v in params.items()]
    return h.add(PlantNode(context=h.context, parameter_overrides=overrides))


# ------------------------------------------------------------------ a plant process
def test_a_late_subscriber_gets_the_urdf_of_a_plant_process(tmp_path: Path) -> None:
    require("rclpy")
    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", ["-p", "sync_mode:=lockstep"],
                        ros_env(DOMAIN), tmp_path)
    h = RosHarness(DOMAIN)
    try:
        probe = h.node("probe")
        h.wait_until(lambda: probe.count_publishers("/robot_description") > 0, 60.0, "the plant's robot_description")
        h.spin_for(0.3)  # published before anyone listened
        viewer = _Listener(h)
        h.wait_until(lambda: viewer.descriptions and viewer.joint_names, 10.0, "robot_description and joint_states")
        plant.check_running()
        h.spin_for(0.2)
        assert len(viewer.descriptions) == 1  # once, at start-up
        text = viewer.descriptions[0]
        assert ET.fromstring(text).tag == "robot"
        assert _joint_names(text) >= set(viewer.joint_names)
        assert text == model_to_urdf(load_model(FIVE_BAR))
    finally:
        h.close()
        plant.stop()
    log = plant.log.read_text()
    assert "robot_description on '/robot_description': 8 joints; loops closed by joint_states" in log, log
    assert "left.end = right.end" in log


# ------------------------------------------------------------------ in this process
@pytest.fixture
def ros():
    h = RosHarness(domain_id(56))
    yield h
    h.close()


def test_a_urdf_machine_publishes_its_own_file_on_the_named_topic(ros: RosHarness) -> None:
    _plant(ros, sync_mode="lockstep", model=str(URDF_FIVE_BAR), topics__robot_description="five_bar/description")
    ros.spin_for(0.1)
    viewer = _Listener(ros, "five_bar/description")
    ros.wait_until(lambda: viewer.descriptions and viewer.joint_names, 10.0, "robot_description and joint_states")
    assert viewer.descriptions == [URDF_FIVE_BAR.read_text()]
    assert _joint_names(viewer.descriptions[0]) >= set(viewer.joint_names)


@pytest.mark.parametrize(("model", "params"), [
    (MJCF_FIVE_BAR, {"sync_mode": "lockstep"}),
    (FIVE_BAR, {"mode": "observer"}),
], ids=["mjcf", "observer_mode"])
def test_other_machines_publish_the_written_urdf(ros: RosHarness, model: Path, params: dict) -> None:
    _plant(ros, model=str(model), **params)
    ros.spin_for(0.1)
    viewer = _Listener(ros)
    ros.wait_until(lambda: viewer.descriptions, 10.0, "robot_description")
    machine = load_model(model)
    assert viewer.descriptions == [model_to_urdf(machine)]
    # The observer publishes joint_states only from measurements: its names are the mechanism's.
    assert _joint_names(viewer.descriptions[0]) >= set(Mechanism(machine).joint_names)


def test_the_description_can_be_switched_off(ros: RosHarness) -> None:
    plant = _plant(ros, sync_mode="lockstep", publish_robot_description=False)
    viewer = _Listener(ros)
    ros.wait_until(lambda: bool(viewer.joint_names), 10.0, "joint_states")
    ros.spin_for(0.3)
    assert viewer.descriptions == [] and plant.pub_robot_description is None
    assert viewer.node.count_publishers("/robot_description") == 0


def test_the_check_names_what_robot_state_publisher_would_ignore() -> None:
    from elastic_pm_dyn.ros.robot_description import loop_closures, missing_joints, urdf_root_link
    machine = load_model(URDF_FIVE_BAR)
    text = URDF_FIVE_BAR.read_text()
    names = Mechanism(machine).joint_names
    assert missing_joints(text, names) == []
    assert missing_joints(text, [*names, "wrist_x", "wrist_y"]) == ["wrist_x", "wrist_y"]  # a ball the sidecar made
    assert loop_closures(machine) == ["left_upper_arm.end = right_upper_arm.end"]
    assert urdf_root_link(text) == "base_link" and urdf_root_link(model_to_urdf(load_model(FIVE_BAR))) == "world"
    # An exporter's ball joint, re-typed SPHERICAL in robot.yaml: its three revolutes are not in the file.
    hexa = load_model(REPO / "test" / "robots" / "hexa_exported" / "robot.urdf")
    assert missing_joints(model_to_urdf(hexa), hexa.joint_names) == ["leg1_ball_x", "leg1_ball_y", "leg1_ball_z"]


# ------------------------------------------------------------------ the launch file
def test_launch_file_is_valid_and_names_installed_things() -> None:
    """It cannot run without a full ROS install; check what it refers to."""
    source = LAUNCH_FILE.read_text()
    tree = ast.parse(source, str(LAUNCH_FILE))
    compile(tree, str(LAUNCH_FILE), "exec")
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    scripts = set(re.findall(r'"(\w+) = elastic_pm_dyn\.', (REPO / "setup.py").read_text()))
    assert {"plant_node", "feedforward_node"} <= scripts & strings
    assert {"robot_state_publisher", "rviz2"} <= strings
    for name in ("plant.yaml", "feedforward.yaml", "five_bar.rviz"):
        assert name in strings and (REPO / "config" / name).is_file()
    rviz = (REPO / "config" / "five_bar.rviz").read_text()
    for display in ("RobotModel", "TF", "MarkerArray"):
        assert f"Class: rviz_default_plugins/{display}\n" in rviz
    assert "Durability Policy: Transient Local" in rviz and "Value: /robot_description" in rviz
    assert 'glob("config/*.rviz")' in (REPO / "setup.py").read_text()  # installed beside the parameter files


def _load_launch_file() -> types.ModuleType:
    spec = importlib.util.spec_from_file_location("rviz_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_launch_file_builds_its_description() -> None:
    try:
        import launch_ros  # noqa: F401
        from launch import LaunchDescription
    except ImportError as exc:  # the repository's launch/ folder is then a namespace package without it
        pytest.skip(f"ROS 2 launch not installed ({exc}): pip-only ROS has no launch wheels")
    assert isinstance(_load_launch_file().generate_launch_description(), LaunchDescription)


class _Recorded:
    """Stands for a launch class: records its arguments."""

    def __init__(self, *args: Any, **kwargs: Any):
        self.args, self.kwargs = args, kwargs


class _Configuration(_Recorded):
    def perform(self, context: dict[str, str]) -> str:
        return context[self.args[0]]


@pytest.mark.parametrize(("model", "root"), [("", "world"), (str(URDF_FIVE_BAR), "base_link")],
                         ids=["shipped_five_bar", "urdf_machine"])
def test_launch_file_gives_its_nodes_the_plants_urdf_and_frame(monkeypatch: pytest.MonkeyPatch, model: str,
                                                               root: str) -> None:
    """The launch file's own logic with stand-ins for launch and launch_ros (not installed here)."""
    require("rclpy")  # the package's ROS side computes the URDF as the plant does
    stubs = {"launch": {"LaunchDescription": _Recorded}, "launch.actions": {"DeclareLaunchArgument": _Recorded,
             "OpaqueFunction": _Recorded}, "launch.conditions": {"IfCondition": _Recorded},
             "launch.launch_context": {"LaunchContext": dict}, "launch.substitutions": {
             "LaunchConfiguration": _Configuration}, "launch_ros": {}, "launch_ros.actions": {"Node": _Recorded},
             "launch_ros.parameter_descriptions": {"ParameterValue": _Recorded}}
    for name, attrs in stubs.items():
        monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(**attrs))
    description = _load_launch_file().generate_launch_description()
    opaque = description.args[0][-1]
    nodes = {n.kwargs["executable"]: n.kwargs for n in opaque.kwargs["function"]({"model": model,
                                                                                    "sync_mode": "realtime"})}
    assert set(nodes) == {"plant_node", "robot_state_publisher", "rviz2", "feedforward_node"}
    plant = nodes["plant_node"]["parameters"][1]
    machine = load_model(plant["model"])
    urdf = nodes["robot_state_publisher"]["parameters"][0]["robot_description"]
    assert urdf.args == (model_to_urdf(machine),) and urdf.kwargs == {"value_type": str}
    assert plant["frames.base"] == root and nodes["rviz2"]["arguments"][-2:] == ["-f", root]
    assert Path(nodes["rviz2"]["arguments"][1]).name == "five_bar.rviz"
    # realtime too: the plant's clock (/clock), which slows when the plant cannot keep up
    assert nodes["robot_state_publisher"]["parameters"][0]["use_sim_time"] is True
    assert nodes["feedforward_node"]["parameters"][1]["use_sim_time"] is True


def test_the_observer_node_publishes_the_written_urdf(ros: RosHarness) -> None:
    """The observer's own executable publishes the description as the plant does, under its own
    name (beside a plant's /robot_description)."""
    from elastic_pm_dyn.ros.observer.node import ObserverNode
    ros.add(ObserverNode(context=ros.context))
    ros.spin_for(0.1)
    viewer = _Listener(ros, "/observer/robot_description")
    ros.wait_until(lambda: viewer.descriptions, 10.0, "robot_description")
    machine = load_model(FIVE_BAR)
    assert viewer.descriptions == [model_to_urdf(machine)]
