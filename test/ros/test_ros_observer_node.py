"""The observer node (``observer_node``): the plant node's ``mode: observer`` as its own node.

Real rclpy nodes in this process on a private domain (test/ros_harness.py), fed one message
at a time as in test_ros_observer.py:
1. config/observer_node.yaml is config/plant_observer.yaml without ``mode``, both with
   config/observer.yaml's observer block;
2. the node starts from its file and publishes, on the same messages, exactly the estimates
   of the plant node in ``mode: observer``; the accelerometer sample timing it chose is
   logged (info) by the diagnostics timer, a sensor far off with its likely cause (warning);
3. a wrong parameter stops the start with one line (node process and ``elastic-pm-dyn observer``);
4. the launch file starts the installed executable with the installed parameter file.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from ros_harness import RosHarness, domain_id, require

from elastic_pm_dyn.bags.msgtypes import stamp_ns
from elastic_pm_dyn.observer.config import flatten
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "config"
NODE_FILE = CONFIG / "observer_node.yaml"
PLANT_FILE = CONFIG / "plant_observer.yaml"
SENSORS = ["encoders", "imu", "branch_forces"]
DOMAIN = domain_id(77)
SAMPLES = 130  # past the accelerometer timing's first choice (0.1 s)
OUTPUTS = ("js", "bf", "pose", "std")


def _params(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())["/**"]["ros__parameters"]


@pytest.fixture(scope="module")
def rec(five_bar):
    return manoeuvre_recording(five_bar, duration=SAMPLES * 1e-3, seed=5)


class _Logger:
    """Records what a node logs (rclpy's own logger keys its throttling on the call site)."""

    def __init__(self, lines: list[tuple[str, str]]):
        self.lines = lines

    def info(self, text: str, **kwargs: Any) -> None:
        self.lines.append(("info", text))

    def warning(self, text: str, **kwargs: Any) -> None:
        self.lines.append(("warning", text))

    def error(self, text: str, **kwargs: Any) -> None:
        self.lines.append(("error", text))


def _run(params_file: Path, node_class: str, rec: Any,
         **params: Any) -> tuple[dict[str, list], list[tuple[str, str]], Any]:
    """Start the node from ``params_file`` (all three sensors, fast diagnostics; ``params``
    override more), send the recording sample by sample; what it published and logged, and
    its flat parameters."""
    h = RosHarness(DOMAIN, args=["test", "--ros-args", "--params-file", str(params_file)])
    try:
        from diagnostic_msgs.msg import DiagnosticArray
        from elastic_pm_dyn_msgs.msg import BranchForces
        from geometry_msgs.msg import PoseStamped, Vector3
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import Imu, JointState
        from std_msgs.msg import Header

        from elastic_pm_dyn.ros.messages import stamp
        from elastic_pm_dyn.ros.observer.node import ObserverNode
        from elastic_pm_dyn.ros.plant.node import PlantNode
        from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS, OBSERVER_INPUT_QOS, STATE_QOS
        overrides = [Parameter(k, value=v) for k, v in
                     {"observer.sensors": SENSORS, "diagnostics_rate": 50.0, **params}.items()]
        cls = {"observer": ObserverNode, "plant": PlantNode}[node_class]
        node = h.add(cls(context=h.context, parameter_overrides=overrides))
        logged: list[tuple[str, str]] = []
        node.get_logger = lambda: _Logger(logged)
        values = {k: node.get_parameter(k).value for k in flatten(_params(params_file))}
        mode = node.observer
        session = mode.session
        feeder = h.node("feeder")
        types = {"torque_command": JointState, "joint_state": JointState, "imu": Imu, "branch_forces": BranchForces}
        topics = {"torque_command": "/torque_command", "joint_state": "/measured_joint_states", "imu": "/ee_imu",
                  "branch_forces": "/measured_branch_forces"}
        pubs = {k: feeder.create_publisher(types[k], topics[k], OBSERVER_INPUT_QOS) for k in types}
        out: dict[str, list] = {k: [] for k in (*OUTPUTS, "diag")}
        for key, msg_type, topic, qos in (("js", JointState, mode.pub_joint_states.topic_name, STATE_QOS),
                                          ("bf", BranchForces, mode.pub_branch_forces.topic_name, STATE_QOS),
                                          ("pose", PoseStamped, mode.pub_ee_pose.topic_name, STATE_QOS),
                                          ("std", JointState, mode.pub_stddev.topic_name, STATE_QOS),
                                          ("diag", DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)):
            feeder.create_subscription(msg_type, topic, out[key].append, qos)
        h.wait_until(lambda: all(p.get_subscription_count() for p in pubs.values())
                     and mode.pub_joint_states.get_subscription_count()
                     and mode.pub_stddev.get_subscription_count(), 10.0, "discovery")

        def send(kind: str, msg: Any) -> None:
            n = session.received[kind]
            pubs[kind].publish(msg)
            h.wait_until(lambda: session.received[kind] > n, 5.0, f"the node to take a {kind} message")

        for k in range(len(rec.t)):
            t = stamp(int(rec.stamp_ns[k]))
            a = rec.accel[k]
            send("imu", Imu(header=Header(stamp=t), linear_acceleration=Vector3(x=a[0], y=a[1], z=a[2])))
            send("branch_forces", BranchForces(header=Header(stamp=t), name=rec.branch_names,
                                               force=rec.branch[k].tolist()))
            send("joint_state", JointState(header=Header(stamp=t), name=rec.active_names,
                                           position=rec.encoder[k].tolist()))
            send("torque_command", JointState(header=Header(stamp=t), name=rec.active_names,
                                              effort=rec.tau_cmd[k].tolist()))
        n = len(rec.t)
        h.wait_until(lambda: all(len(out[key]) >= n for key in OUTPUTS), 10.0, "every estimate")
        seen = len(out["diag"])
        h.wait_until(lambda: len(out["diag"]) > seen, 5.0, "a diagnostics report after the run")
        h.spin_for(0.02)
        return out, logged, values
    finally:
        h.close()


def test_parameter_files_agree() -> None:
    """The node's file is the plant node's observer file without ``mode``; both carry
    config/observer.yaml's observer block unchanged."""
    node, plant = _params(NODE_FILE), _params(PLANT_FILE)
    assert "mode" not in node and plant.pop("mode") == "observer"
    # the node publishes under its own name (beside a plant), the plant in observer mode as the plant
    assert node.pop("topics") == {k: v if k == "joint_states_stddev" else f"~/{v}"
                                  for k, v in plant.pop("topics").items()}
    assert node == plant
    assert node["observer"] == _params(CONFIG / "observer.yaml")["observer"]


def test_machine_observer_files_differ_from_the_generic_only_in_observer_values() -> None:
    """config/observer_<machine>.yaml (tuned for a shipped machine) is config/observer_node.yaml with
    other values of some observer.* parameters: the same node parameters, the same observer keys
    and types (floats as floats), and it loads for its machine; its header says how it was tuned."""
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer import Observer
    from elastic_pm_dyn.observer.config import load_config
    generic = _params(NODE_FILE)
    files = sorted(p for p in CONFIG.glob("observer_*.yaml") if p != NODE_FILE)
    assert {p.name for p in files} >= {"observer_five_bar.yaml", "observer_triglide.yaml", "observer_hexa.yaml"}
    for path in files:
        model = CONFIG / f"{path.stem.removeprefix('observer_')}.yaml"
        assert model.is_file(), path
        own = _params(path)
        assert {**own, "observer": None} == {**generic, "observer": None}, path
        mine, base = flatten(own["observer"]), flatten(generic["observer"])
        assert mine.keys() == base.keys(), path
        assert all(type(mine[k]) is type(base[k]) for k in base), path
        assert any(mine[k] != base[k] for k in base), path
        assert "elastic-pm-dyn tune --model" in path.read_text(), path
        Observer(Mechanism(load_model(model)), load_config(path))  # valid for its machine


def test_a_machines_own_observer_file_is_found_beside_its_model(tmp_path: Path) -> None:
    """observer_config_for (ros-demo --observer, the user-loop test): observer_<model stem>.yaml
    beside the model file, else the generic node file; a model of the same name elsewhere is
    another machine and does not get it."""
    require("rclpy")
    from elastic_pm_dyn.ros.params import observer_config_for
    model = tmp_path / "my_machine.yaml"
    assert observer_config_for(model) == NODE_FILE  # none beside it
    (tmp_path / "observer_my_machine.yaml").write_text("")
    assert observer_config_for(model) == tmp_path / "observer_my_machine.yaml"
    assert observer_config_for(str(model)) == tmp_path / "observer_my_machine.yaml"
    for name in ("hexa.yaml", "five_bar.urdf"):
        assert observer_config_for(tmp_path / name) == NODE_FILE
    assert observer_config_for("") == observer_config_for(CONFIG / "five_bar.yaml")  # the packaged five-bar


def test_node_publishes_the_plant_nodes_observer_estimates(rec: Any, five_bar: Any) -> None:
    require("rclpy")
    ours, logged, values = _run(NODE_FILE, "observer", rec)
    # Every value of its file reached the node, with its YAML type (two overridden in _run).
    for key, value in flatten(_params(NODE_FILE)).items():
        if key in ("observer.sensors", "diagnostics_rate"):
            continue
        got = list(values[key]) if isinstance(value, list) else values[key]
        assert got == value and type(got) is type(value), key
    plant, _, _ = _run(PLANT_FILE, "plant", rec)
    n = len(rec.t)
    for key in OUTPUTS:
        assert len(ours[key]) == len(plant[key]) == n, key
        assert [stamp_ns(m.header.stamp) for m in ours[key]] == [int(ns) for ns in rec.stamp_ns], key
    worst = 0.0
    for a, b in zip(ours["js"] + ours["std"], plant["js"] + plant["std"], strict=True):
        assert list(a.name) == list(b.name) == five_bar.joint_names
        for x, y in ((a.position, b.position), (a.velocity, b.velocity), (a.effort, b.effort)):
            worst = max(worst, float(np.max(np.abs(np.asarray(x) - y))) if len(x) else 0.0)
    for a, b in zip(ours["bf"], plant["bf"], strict=True):
        for x, y in ((a.force, b.force), (a.force_stddev, b.force_stddev), (a.deflection, b.deflection)):
            worst = max(worst, float(np.max(np.abs(np.asarray(x) - y))))
    for a, b in zip(ours["pose"], plant["pose"], strict=True):
        p, q = a.pose.position, b.pose.position
        worst = max(worst, abs(p.x - q.x), abs(p.y - q.y), abs(p.z - q.z))
    assert worst == 0.0, f"observer node and plant node (mode: observer) differ by {worst:.3g}"
    # Its diagnostics carry its own name and the timing it chose; the choice is logged once, at info.
    status = ours["diag"][-1].status[0]
    assert status.name == "/observer: observer"  # the fully qualified name: two observers in two namespaces differ
    assert {kv.key: kv.value for kv in status.values}["imu.sample_timing"] == "before_command"
    choices = [text for level, text in logged if "accelerometer sample timing" in text]
    assert len(choices) == 1 and choices[0].startswith("accelerometer sample timing: chose before_command at t = ")
    assert ("info", choices[0]) in logged


def test_node_names_a_far_off_sensor_with_its_cause(rec: Any) -> None:
    """The accelerometer's noise level set 2.5x too low: a warning names it and the cause, and
    so does /diagnostics."""
    require("rclpy")
    out, logged, _ = _run(NODE_FILE, "observer", rec, **{"observer.imu.stddev": [0.008]})
    warnings = [text for level, text in logged if level == "warning" and "imu: NIS" in text]
    assert warnings and "noise level too low (imu.stddev)" in warnings[-1]
    values = {kv.key: kv.value for kv in out["diag"][-1].status[0].values}
    assert values["imu.nis_diagnosis"] in warnings[-1]


def _one_line_error(argv: list[str]) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.run([sys.executable, "-m", *argv], env=env, capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize(("argv", "line"), [
    (["elastic_pm_dyn.ros.observer.node", "--ros-args", "--params-file", str(NODE_FILE),
      "-p", "observer.imu.stddev:=[-0.02]"],
     "observer_node: error: parameter 'observer.imu.stddev': needs one or more values > 0, got [-0.02]"),
    (["elastic_pm_dyn.ros.observer.node", "--ros-args", "--params-file", str(NODE_FILE), "-p", "sync_mode:=fast"],
     "observer_node: error: unknown parameter(s) sync_mode (known: "),
    (["elastic_pm_dyn", "observer", "--params-file", str(NODE_FILE), "--ros-args",
      "-p", "observer.gating.probabilty:=0.99"],
     "observer_node: error: unknown parameter(s) observer.gating.probabilty "
     "(did you mean observer.gating.probability?)"),
    (["elastic_pm_dyn", "observer", "--params-file", str(NODE_FILE), "--model", str(REPO / "missing.yaml")],
     "observer_node: error: parameter 'model': no such file "),
])
def test_node_refuses_to_start_with_one_line(argv: list[str], line: str) -> None:
    require("rclpy")
    proc = _one_line_error(argv)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(line), proc.stderr


def test_launch_file_uses_the_installed_executable_and_file() -> None:
    """The launch file cannot run without a full ROS install; check what it refers to."""
    tree = ast.parse((REPO / "launch" / "observer.launch.py").read_text())
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    scripts = set(re.findall(r'"(\w+) = elastic_pm_dyn\.', (REPO / "setup.py").read_text()))
    assert "observer_node" in scripts & strings
    assert {"observer_node.yaml", "observer"} <= strings and NODE_FILE.is_file()
