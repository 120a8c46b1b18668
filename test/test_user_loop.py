"""A controller a user writes (examples/own_controller.py: default QoS, a PD on the plant's encoders
plus the holding torque) closes the loop with the shipped defaults (issue #37).

Each node is its own process, started in the natural order: the plant from
config/plant_sensors.yaml, the observer from the machine's shipped observer file as ``ros-demo
--observer`` picks it (config/observer_<machine>.yaml, else config/observer_node.yaml; both with
only the model changed), a recorder, then the controller, which reads only the encoder topic and
was started after the plant published its first state: the plant publishes it again until the
first command, so nothing needs a kick or a reset. The bag is scored as ``ros-demo --observer``
scores its own loop (ros/loop_demo.py: analyse_loop): every plant state of the loop has its
estimate, the branch-force error against the true forces' elastic part, and the live estimates
equal offline ``observe`` over the same recording. A controller started before the plant starts
the loop too.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from ros_harness import domain_id, require

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config"
EXAMPLE = ROOT / "examples" / "own_controller.py"
START = 900.0  # [s] a cold start compiles the kernels (minutes on a loaded 2-core machine)
PERIODS = 1000  # 1 s of loop at 1 kHz
MACHINES = {"five_bar": "five_bar.yaml", "triglide": "triglide.yaml", "hexa": "hexa.yaml"}
DOMAINS = {"five_bar": domain_id(96), "triglide": domain_id(97), "hexa": domain_id(98), "first": domain_id(99)}
TOPICS = ["/joint_states", "/branch_forces", "/ee_pose", "/torque_command", "/measured_joint_states", "/ee_imu",
          "/disturbance", "/observer/joint_states", "/observer/branch_forces", "/observer/ee_pose"]


def run_user_loop(out: Path, model: Path, domain: int, controller_first: bool = False) -> dict:
    """Plant, observer, recorder and the example controller on ``domain``; the loop's summary."""
    import time

    from elastic_pm_dyn.ros.loop_demo import LoopOptions, analyse_loop
    from elastic_pm_dyn.ros.params import observer_config_for
    from elastic_pm_dyn.ros.processes import NodeProcess, ros_env, wait_for_recording

    env = ros_env(domain)
    logs, bag = out / "logs", out / "bag"
    procs: list[NodeProcess] = []
    controller = None
    try:
        def user_controller() -> subprocess.Popen:
            return subprocess.Popen([sys.executable, str(EXAMPLE), str(model), str(PERIODS)], env=env,
                                    stdout=(logs / "controller.log").open("w"), stderr=subprocess.STDOUT)

        def observer() -> None:  # started, and up: its subscriptions made (it says so in one line)
            procs.append(NodeProcess("observer", "elastic_pm_dyn.ros.observer_node",
                                     ["--params-file", str(observer_config_for(model)), "-p", f"model:={model}"],
                                     env, logs))
            deadline = time.monotonic() + START
            while "one estimate per" not in (logs / "observer.log").read_text(errors="replace"):
                procs[-1].check_running()
                assert time.monotonic() < deadline, "the observer did not start"
                time.sleep(0.1)

        logs.mkdir(parents=True, exist_ok=True)
        procs.append(NodeProcess("recorder", "elastic_pm_dyn.ros.recorder",
                                 ["--params-file", str(CONFIG / "recorder.yaml"), "-p", f"output:={bag}",
                                  "-p", f"topics:=[{', '.join(TOPICS)}]"], env, logs))
        if controller_first:
            controller = user_controller()
            observer()
        procs.append(NodeProcess("plant", "elastic_pm_dyn.ros.plant_node",
                                 ["--params-file", str(CONFIG / "plant_sensors.yaml"), "-p", f"model:={model}"],
                                 env, logs))
        wait_for_recording(["/joint_states"], domain, START, procs)
        if controller is None:
            observer()
            # a user starts the controller once the observer is up: its estimate of the first state is out
            wait_for_recording(["/observer/joint_states"], domain, START, procs)
            controller = user_controller()
        controller.wait(timeout=START)
        assert controller.returncode == 0, (logs / "controller.log").read_text()
        wait_for_recording(["/observer/joint_states"], domain, START, procs)
        time.sleep(2.0)  # the last messages reach the recorder
    finally:
        if controller is not None and controller.poll() is None:
            controller.kill()
        for p in reversed(procs):
            p.stop()
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model

    opts = LoopOptions(model=model, duration=PERIODS * 1e-3, observer_config=observer_config_for(model))
    return analyse_loop(out, bag, Mechanism(load_model(model)), opts, 0.0)


@pytest.mark.parametrize("machine", list(MACHINES))
def test_user_controller_started_last_closes_the_loop(machine: str, tmp_path: Path) -> None:
    require("rclpy")
    s = run_user_loop(tmp_path, CONFIG / MACHINES[machine], DOMAINS[machine])
    states = s["plant_states_in_loop"]
    assert states >= PERIODS, s  # the loop reached its end
    assert s["plant_states_without_estimate"] <= 0.01 * states, s
    assert s["F_ratio"] <= 0.5, s  # error / RMS of the true forces' elastic part
    assert s["branch_force_error_ratio_to_open_loop"] < 1.0, s


def test_user_controller_started_first(tmp_path: Path) -> None:
    require("rclpy")
    s = run_user_loop(tmp_path, CONFIG / "five_bar.yaml", DOMAINS["first"], controller_first=True)
    assert s["plant_states_in_loop"] >= PERIODS, s
    assert s["plant_states_without_estimate"] <= 0.01 * s["plant_states_in_loop"], s
