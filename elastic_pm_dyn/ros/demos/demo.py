"""The ROS demo (``elastic-pm-dyn ros-demo``, the README's demo command).

Plant, feedforward and recorder run as separate processes on a loopback-only domain
(``--domain-id``, else ``ROS_DOMAIN_ID`` when set, else a private one: :func:`run_domain_id`);
the feedforward drives the reference manoeuvre through ``torque_command``; the recorder
writes a bag; then the bag is read back with ``rosbags`` and compared with the offline
simulation of the same torques: plots of path, branch forces, gap and torques, and
``summary.json``. In ``lockstep`` the ROS run equals offline ``simulate`` to round-off;
``realtime`` shows the same manoeuvre paced by the wall clock (the feedforward's timer on the
plant's clock, ``use_sim_time``: a plant that cannot keep up slows its clock instead of
skipping periods, and the feedforward slows with it); ``fast`` lets the plant run
ahead of the wall clock with a state-triggered feedforward (one command per plant state,
applied when it arrives, a few periods late: every command is sent and recorded). A timer
feedforward cannot drive a fast plant: its timer wakes at wall-clock moments while /clock
moves many periods between two of them, so most control instants would get no command.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np

from elastic_pm_dyn.analysis import metrics, plots
from elastic_pm_dyn.bags.series import read_series
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import line_torques
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.trajectory import Line, QuinticLine
from elastic_pm_dyn.ros.demos.local_nodes import run_domain_id
from elastic_pm_dyn.ros.demos.processes import (
    NodeProcess,
    ros_env,
    wait_for_exit,
    wait_for_recording,
)
from elastic_pm_dyn.ros.params import share_path
from elastic_pm_dyn.sim.held_feedforward import held_line_torques
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable

SYNC_MODES = ("lockstep", "realtime", "fast")
FEEDFORWARDS = ("rigid", "elastic")  # the feedforward node's method
PLANT_TOPICS = ["/joint_states", "/branch_forces", "/ee_pose"]
CONTROL_RATE = REFERENCE_MANOEUVRE.control_rate  # [Hz] of plant and feedforward
DRAIN = 1.0  # [s] after the feedforward ends, for the last states to reach the recorder
# The plant's numerics, passed explicitly so the offline comparison uses the same ones.
OPTIONS = SimulationOptions(formulation="scdd", integrator="rk4", dt=1e-4, stabilization="projection",
                            sample=1.0 / CONTROL_RATE)


def fresh_bag(out: Path) -> Path:
    """``out``/bag, made ready for a new recording: a bag from an earlier run is removed, anything
    else there is refused (InputError), so no one's files are deleted."""
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    if bag.exists():
        if not (bag / "metadata.yaml").is_file():
            raise InputError(f"{bag} exists and is not a bag: remove it or choose another --out")
        shutil.rmtree(bag)
    return bag


def run_ros_demo(out: Path, model_path: Path, sync: str = "lockstep", storage: str = "mcap",
                 timeout: float = 120.0, domain_id: int | None = None,
                 line: QuinticLine = REFERENCE_MANOEUVRE.line, feedforward: str = "rigid") -> dict:
    """Run the three nodes, record, analyse; returns the summary (also in out/summary.json).

    ``feedforward``: the node's method; ``elastic`` moves the line on the 9th-order law its
    torques need (:mod:`elastic_pm_dyn.motion.elastic_inverse`)."""
    if sync not in SYNC_MODES:
        raise InputError(f"sync mode must be one of {', '.join(SYNC_MODES)}, got {sync!r}")
    if feedforward not in FEEDFORWARDS:
        raise InputError(f"feedforward must be one of {', '.join(FEEDFORWARDS)}, got {feedforward!r}")
    if feedforward == "elastic":
        line = Line(np.asarray(line.start, dtype=float), np.asarray(line.end, dtype=float), line.move, line.hold, 4)
    domain_id = run_domain_id(domain_id)  # before anything is written: a bad ROS_DOMAIN_ID is one line
    bag = fresh_bag(out)
    wall = time.monotonic()
    _run_nodes(out, bag, model_path, sync, storage, timeout, domain_id, line, feedforward)
    wall = time.monotonic() - wall
    print(f"  bag -> {bag} ({wall:.1f} s)")
    return analyse(out, bag, model_path, sync, line, wall, feedforward)


def _run_nodes(out: Path, bag: Path, model_path: Path, sync: str, storage: str, timeout: float,
               domain_id: int, line: QuinticLine | Line, feedforward: str = "rigid") -> None:
    env = ros_env(domain_id)
    logs = out / "logs"
    o = OPTIONS
    plant_args = ["--params-file", str(share_path("config", "plant.yaml")), "-p", f"model:={model_path}",
                  "-p", f"sync_mode:={sync}", "-p", f"publish_rate:={CONTROL_RATE!r}",
                  "-p", f"formulation:={o.formulation}", "-p", f"integrator:={o.integrator}",
                  "-p", f"dt:={o.dt!r}", "-p", f"stabilization:={o.stabilization}"]
    ff_args = ["--params-file", str(share_path("config", "feedforward.yaml")), "-p", f"model:={model_path}",
               "-p", f"rate:={CONTROL_RATE!r}", "-p", "trigger:=" + ("timer" if sync == "realtime" else "state"),
               # realtime: the timer on the plant's clock (/clock), which slows when the plant cannot keep up
               "-p", f"use_sim_time:={str(sync == 'realtime').lower()}",
               "-p", f"line.start:={[float(x) for x in line.start]}", "-p", f"line.end:={[float(x) for x in line.end]}",
               "-p", f"line.move:={float(line.move)!r}", "-p", f"line.hold:={float(line.hold)!r}",
               "-p", f"method:={feedforward}", "-p", "autostart:=true", "-p", "exit_when_done:=true",
               "-p", "wait_for_subscribers:=2"]  # the plant and the recorder
    rec_args = ["--params-file", str(share_path("config", "recorder.yaml")), "-p", f"output:={bag}",
                "-p", f"storage:={storage}"]
    procs: list[NodeProcess] = []
    try:
        procs.append(NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", plant_args, env, logs))
        procs.append(NodeProcess("recorder", "elastic_pm_dyn.ros.recorder.node", rec_args, env, logs))
        print(f"  plant ({sync}) and recorder started on ROS domain {domain_id}; logs in {logs}")
        # The manoeuvre starts once the recorder has received the plant's messages (it then also
        # waits for the feedforward's topics: wait_for_subscribers = 2 on torque_command). The
        # plant publishes its start state until the first command; a subscription in the graph
        # alone once recorded nothing (issue #29), so the graph is not what is waited for.
        wait_for_recording(PLANT_TOPICS, domain_id, timeout, procs)
        ff = NodeProcess("feedforward", "elastic_pm_dyn.ros.feedforward.node", ff_args, env, logs)
        procs.append(ff)
        print("  recorder ready; feedforward started")
        code = wait_for_exit(ff, procs[:2], timeout)
        if code:
            raise ff.failure(code)
    except BaseException:  # also Ctrl+C: never leave nodes running

        for p in reversed(procs):
            p.stop()
        raise
    time.sleep(DRAIN)
    for p in procs[1::-1]:  # recorder first: it closes the bag
        p.stop()


def analyse(out: Path, bag: Path, model_path: Path, sync: str, line: QuinticLine | Line, wall: float,
            feedforward: str = "rigid") -> dict:
    """Bag -> plots and summary, with the offline simulation of the same torques beside it."""
    model = load_model(model_path)
    mech = Mechanism(model)
    topics = read_series(bag)
    missing = [t for t in [*PLANT_TOPICS, "/torque_command"] if t not in topics]
    if missing:
        raise InputError(f"{bag}: no messages on {', '.join(missing)} (see {out / 'logs'})")
    js, bf, pose, cmd = (topics[t] for t in ("/joint_states", "/branch_forces", "/ee_pose", "/torque_command"))
    t0 = cmd.t[0]  # the manoeuvre starts with the first command
    # Samples of the manoeuvre present on all three state topics (each was subscribed when
    # the recorder discovered it), matched by stamp.
    stamps = [np.round((s.t - t0) * 1e9).astype(np.int64) for s in (js, bf, pose)]
    common = np.intersect1d(np.intersect1d(stamps[0], stamps[1]), stamps[2])
    common = common[(common >= 0) & (common <= round(line.duration * 1e9))]
    if len(common) < 2:
        raise InputError(f"{bag}: no plant states during the manoeuvre (see {out / 'logs'})")
    i_js, i_bf, i_pose = (np.searchsorted(s, common) for s in stamps)
    t = common * 1e-9
    q = np.column_stack([js.column("position", n) for n in mech.joint_names])[i_js]
    qd = np.column_stack([js.column("velocity", n) for n in mech.joint_names])[i_js]
    ee = mech.ee_of(pose.values["position"][i_pose])
    forces = {b.name: bf.column("force", b.name)[i_bf] for b in model.branches}
    gap = np.array([mech.gap(x) for x in q])

    if feedforward == "elastic":  # in mech.active_names order; the node's default inverse, held
        times, torques, _, _ = held_line_torques(model, line, CONTROL_RATE)
    else:
        times, torques, _ = line_torques(model, line, CONTROL_RATE)
    offline = Simulator(mech, OPTIONS).run(TorqueTable(times, torques, "zoh"), line.duration)
    label = f"ROS plant ({sync})"
    reference = np.array([line(s)[0] for s in t])
    plots.plot_path(out / "path.png", {label: ee, "offline simulate": offline.ee}, reference)
    offline_forces = {b.name: offline.branch_forces[:, i] for i, b in enumerate(model.branches)}
    plots.plot_branch_forces(out / "branch_forces.png", {label: t, "offline simulate": offline.t},
                             {label: forces, "offline simulate": offline_forces},
                             zoom=(line.move - 0.01, line.move + 0.04))
    plots.plot_gap(out / "gap.png", {label: t}, {label: gap})
    plots.plot_torques(out / "torques.png", cmd.t - t0, {n: cmd.values["effort"][:, cmd.names.index(n)]
                                                         for n in mech.active_names})

    summary = {
        "sync_mode": sync, "model": str(model_path), "bag": str(bag), "run_wall_time_s": round(wall, 3),
        "line": {"start": line.start.tolist(), "end": line.end.tolist(), "move_s": line.move, "hold_s": line.hold},
        "messages": {topic: len(s.t) for topic, s in topics.items()},
        # realtime on a loaded machine: missed controller ticks and plant periods show here
        "commands_in_manoeuvre": int(np.sum(cmd.t - t0 < line.duration - 1e-9)),
        "commands_expected": round(line.duration * CONTROL_RATE),
        "states_in_manoeuvre": len(t),
        "longest_state_gap_s": float(np.diff(t).max()),
        "max_path_deviation_m": float(metrics.straight_line_deviation(ee, line.start, line.end).max()),
        "final_position_error_m": float(np.linalg.norm(ee[-1] - line.end)),
        "feedforward": feedforward,
        "peak_branch_force_N": {n: float(np.abs(f).max()) for n, f in forces.items()},
        # the ringing after the move: deviation from the last 50 ms of the hold's mean (the static force)
        "residual_vibration_N": {n: _residual(t, f, line.move) for n, f in forces.items()},
        "max_gap_m": float(gap.max()),
    }
    if sync == "lockstep":  # same torques, same steps: the ROS run must equal offline simulate
        idx = np.searchsorted(np.round(offline.t, 9), np.round(t, 9))
        ok = (idx < len(offline.t)) & np.isclose(offline.t[np.minimum(idx, len(offline.t) - 1)], t, atol=1e-9)
        summary["offline_compared_samples"] = int(ok.sum())
        summary["max_joint_position_difference_vs_offline"] = float(np.abs(q[ok] - offline.q[idx[ok]]).max())
        summary["max_joint_velocity_difference_vs_offline"] = float(np.abs(qd[ok] - offline.qd[idx[ok]]).max())
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"  plots (path, branch_forces, gap, torques) and summary.json in {out}")
    print("  residual_vibration_N: " + ", ".join(f"{n} {v:.3g}" for n, v in summary["residual_vibration_N"].items()))
    for key in ("commands_in_manoeuvre", "states_in_manoeuvre", "max_path_deviation_m", "max_gap_m",
                "max_joint_position_difference_vs_offline"):
        if key in summary:
            print(f"  {key}: {summary[key]:.6g}")
    return summary


def _residual(t: np.ndarray, force: np.ndarray, move: float) -> float:
    """Largest deviation over the hold from the mean of its last 50 ms (0 without a hold)."""
    hold = t >= move
    if not hold.any():
        return 0.0
    static = float(np.mean(force[t >= max(t[-1] - 0.05, move)]))
    return float(np.abs(force[hold] - static).max())
