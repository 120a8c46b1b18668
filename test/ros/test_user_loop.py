"""A controller a user writes (examples/own_controller.py: default QoS, a PD on the plant's encoders
plus the holding torque) closes the loop with the shipped defaults (issue #37).

Each node is its own process, started in the natural order: the plant from
config/plant_sensors.yaml, the observer from the machine's shipped observer file as ``ros-demo
--observer`` picks it (config/observer_<machine>.yaml, else config/observer_node.yaml; both with
only the model changed), a recorder, then the controller, which reads only the encoder topic and
was started after the plant published its first state: the plant publishes it again until the
first command, so nothing needs a kick or a reset. The bag is scored as ``ros-demo --observer``
scores its own loop (ros/demos/loop_demo.py: analyse_loop): every plant state of the loop has its
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

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "config"
EXAMPLE = ROOT / "examples" / "own_controller.py"
START = 900.0  # [s] a cold start compiles the kernels (minutes on a loaded 2-core machine)
PERIODS = 1000  # 1 s of loop at 1 kHz
MACHINES = {"five_bar": "five_bar.yaml", "triglide": "triglide.yaml", "hexa": "hexa.yaml"}
# Branch-force error / RMS of the elastic part (issue #37: <= 0.5), and / the open loop's. On the Hexa
# holding still, any estimator that knows only the disturbance's spectrum stays above 0.72 of the
# open loop (bench/studies/observer_spectrum_bound.py --machines hexa --rms 0.02 --duration 1.0: 6.45
# of 8.90 mN), and this open loop is 0.80 of the elastic part: F_ratio >= ~0.58 is physics, not
# the filter (which reaches 0.61, within 5 % of the bound). The Triglide's open loop shares the
# plant's RK4 error (19 mN of its branch forces), so the observer only just beats it.
F_RATIO = {"five_bar": 0.5, "triglide": 0.5, "hexa": 0.65}
OPEN_LOOP = {"five_bar": 0.6, "triglide": 1.0, "hexa": 0.8}
DOMAINS = {"five_bar": domain_id(96), "triglide": domain_id(97), "hexa": domain_id(93), "first": domain_id(99),
           "realtime": domain_id(94)}
TOPICS = ["/joint_states", "/branch_forces", "/ee_pose", "/torque_command", "/applied_torque", "/measured_joint_states",
          "/ee_imu", "/disturbance", "/observer/joint_states", "/observer/branch_forces", "/observer/ee_pose",
          "/diagnostics"]


def run_user_loop(out: Path, model: Path, domain: int, controller_first: bool = False,
                  plant_args: tuple[str, ...] = (), analyse: bool = True, observer_args: tuple[str, ...] = (),
                  recorder_args: tuple[str, ...] = (), controller_prefix: tuple[str, ...] = ()) -> dict | Path:
    """Plant, observer, recorder and the example controller on ``domain`` (``*_args``: more node
    arguments; ``controller_prefix``: what the controller's command line starts with, e.g. chrt);
    the loop's summary (``analyse`` False: the bag)."""
    import time

    from elastic_pm_dyn.ros.demos.loop_demo import LoopOptions, analyse_loop
    from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env, wait_for_recording
    from elastic_pm_dyn.ros.params import observer_config_for

    env = ros_env(domain)
    logs, bag = out / "logs", out / "bag"
    procs: list[NodeProcess] = []
    controller = None
    try:
        def user_controller() -> subprocess.Popen:
            # it starts once the plant, the observer and the recorder listen to its commands
            return subprocess.Popen([*controller_prefix, sys.executable, str(EXAMPLE), str(model), str(PERIODS), "3"],
                                    env=env,
                                    stdout=(logs / "controller.log").open("w"), stderr=subprocess.STDOUT)

        def observer() -> None:  # started, and up: its subscriptions made (it says so in one line)
            procs.append(NodeProcess("observer", "elastic_pm_dyn.ros.observer.node",
                                     ["--params-file", str(observer_config_for(model)), "-p", f"model:={model}",
                                      *observer_args], env, logs))
            deadline = time.monotonic() + START
            while "one estimate per" not in (logs / "observer.log").read_text(errors="replace"):
                procs[-1].check_running()
                assert time.monotonic() < deadline, "the observer did not start"
                time.sleep(0.1)

        logs.mkdir(parents=True, exist_ok=True)
        procs.append(NodeProcess("recorder", "elastic_pm_dyn.ros.recorder.node",
                                 ["--params-file", str(CONFIG / "recorder.yaml"), "-p", f"output:={bag}",
                                  "-p", f"topics:=[{', '.join(TOPICS)}]", *recorder_args], env, logs))
        if controller_first:
            controller = user_controller()
            observer()
        procs.append(NodeProcess("plant", "elastic_pm_dyn.ros.plant.node",
                                 ["--params-file", str(CONFIG / "plant_sensors.yaml"), "-p", f"model:={model}",
                                  *plant_args], env, logs))
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
    if not analyse:
        return bag
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
    assert s["F_ratio"] <= F_RATIO[machine], s  # error / RMS of the true forces' elastic part
    assert s["branch_force_error_ratio_to_open_loop"] < OPEN_LOOP[machine], s


def test_user_controller_started_first(tmp_path: Path) -> None:
    require("rclpy")
    s = run_user_loop(tmp_path, CONFIG / "five_bar.yaml", DOMAINS["first"], controller_first=True)
    assert s["plant_states_in_loop"] >= PERIODS, s
    assert s["plant_states_without_estimate"] <= 0.01 * s["plant_states_in_loop"], s
    # lockstep: the torque the plant says it applied over each period is the command of its stamp
    efforts = read_efforts(tmp_path / "bag", ("/torque_command", "/applied_torque"))
    commands, applied = efforts["/torque_command"], efforts["/applied_torque"]
    # A loaded recorder may miss a few of either: the user's controller publishes on default QoS
    # (KEEP_LAST 10), so a burst that the transport drops while the recorder's process is starved
    # cannot be sent again (seen: 20 in a row, counted as lost in the recorder's log; the plant's
    # own topics, with deep histories, were repaired). The check is the pairing below.
    both = set(commands) & set(applied)
    assert len(applied) >= PERIODS and len(both) >= 0.95 * PERIODS
    assert all(commands[ns] == applied[ns] for ns in both)


def read_efforts(bag: Path, topics: tuple[str, ...]) -> dict[str, dict[int, list[float]]]:
    """stamp [ns] -> effort of each JointState topic of ``bag``."""
    from rosbags.typesys import Stores, get_typestore

    from elastic_pm_dyn.bags.msgtypes import stamp_ns
    from elastic_pm_dyn.bags.reader import open_bag

    typestore = get_typestore(Stores.ROS2_JAZZY)
    out: dict[str, dict[int, list[float]]] = {t: {} for t in topics}
    with open_bag(bag) as b:
        for conn, _, raw in b.messages([c for c in b.connections if c.topic in topics]):
            msg = typestore.deserialize_cdr(raw, conn.msgtype)
            out[conn.topic][stamp_ns(msg.header.stamp)] = list(msg.effort)
    return out


NICE = ("-p", "realtime.nice:=-10")


def cpu_hogs(n: int) -> list[subprocess.Popen]:
    """Busy processes (a loaded machine): each spins until killed."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def test_user_controller_in_realtime_beside_two_cpu_hogs(loop_soak: None, tmp_path: Path) -> None:
    """Realtime: the plant advances on its own clock, slowed when it cannot keep up (never skipping
    a period); every state of the loop gets its estimate, the stamps stay on the 1 ms grid and the
    plant reports its real-time factor. The loop asks more than the 2 cores (the plant runs at
    0.45-0.57 of real time); the observer keeps up because it takes what waits on its inputs in one
    executor turn (ros/drain.py) and publishes serialized estimates: 5 of 5 runs on a quiet machine
    with the two hogs (2026-12-07; 50-64 % of the states estimated before)."""
    require("rclpy")
    import numpy as np
    from rosbags.typesys import Stores, get_typestore

    from elastic_pm_dyn.bags.msgtypes import stamp_ns
    from elastic_pm_dyn.bags.reader import open_bag

    # A realtime loop beside other load is scheduled ahead of it, as docs/ros.md tells a user to run
    # theirs: the plant, the controller, the observer and the recorder at nice -10 (at nice 0 each of
    # the six processes gets a third of a core: the controller fell seconds behind and its PD loop
    # flung the five-bar through its singular poses).
    if subprocess.run(["nice", "-n", "-10", "true"], capture_output=True).returncode != 0:
        pytest.skip("a negative nice value is not permitted here (nice -n -10 true failed)")
    hogs = cpu_hogs(2)
    try:
        # the controller first: a realtime plant runs from its start, with or without commands
        bag = run_user_loop(tmp_path, CONFIG / "five_bar.yaml", DOMAINS["realtime"], controller_first=True,
                            plant_args=("-p", "sync_mode:=realtime", "-p", "diagnostics_rate:=5.0", *NICE),
                            controller_prefix=("nice", "-n", "-10"), observer_args=NICE, recorder_args=NICE,
                            analyse=False)
    finally:
        for h in hogs:
            h.kill()
    stamps: dict[str, list[int]] = {"/measured_joint_states": [], "/observer/joint_states": [], "/torque_command": []}
    factors = []
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with open_bag(bag) as b:
        for conn, _, raw in b.messages([c for c in b.connections if c.topic in (*stamps, "/diagnostics")]):
            msg = typestore.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == "/diagnostics":
                factors += [float(kv.value) for st in msg.status if st.name.endswith(": plant")
                            for kv in st.values if kv.key == "real_time_factor_total"]
            else:
                stamps[conn.topic].append(stamp_ns(msg.header.stamp))
    commands = np.array(sorted(set(stamps["/torque_command"])))
    states = np.array(sorted(set(stamps["/measured_joint_states"])))
    loop = states[(states >= commands[0]) & (states <= commands[-1])]  # the states the controller answered
    assert len(loop) >= PERIODS - 1
    assert set(np.diff(states).tolist()) == {1_000_000}  # on the grid: no period skipped
    applied = np.array(sorted(read_efforts(bag, ("/applied_torque",))["/applied_torque"]))
    assert np.all(np.isin(loop[:-1], applied))  # what acted over each period of the loop, said by the plant
    estimated = np.isin(loop, stamps["/observer/joint_states"])
    assert estimated.mean() >= 0.99, f"{np.sum(~estimated)} of {len(loop)} states without an estimate"
    assert factors and factors[-1] > 0 and all(0 <= f <= 1.05 for f in factors)  # 0 before the first period
