"""Soak test of the plant node: fast mode publishing at 1 kHz for minutes, driven by a controller.

    nice -n 10 .venv/bin/python bench/benchmarks/soak_plant.py                # 10 minutes
    .venv/bin/python bench/benchmarks/soak_plant.py --minutes 1

The plant node runs as its own process (``python -m elastic_pm_dyn.ros.plant.node``) on a
private loopback domain: five-bar, SCDD + RK4 dt = 1e-4 s + projection, ``sync_mode: fast``,
``publish_rate: 1000.0``. This process is the controller: it answers every 10th state on
``joint_states`` (a 100 Hz controller: answering all of them, 2-5 kHz in fast mode, would
take the core the plant runs on) with a gentle PD torque on the motors towards a slow sine
around the start pose (``torque_command``), and reads ``/diagnostics``. What a long run must not show: memory that
grows, a closure gap that creeps, a fault, a stall. Written to bench/results/soak_plant.json:

- ``rss_growth_mib``: the plant process's resident memory at the end minus after the warm-up
  (``rss_mib`` samples every 10 s);
- ``max_closure_gap_m``: the largest closure gap over the received states (every 100th is
  checked) and over every ``/diagnostics`` report;
- ``real_time_factor``: simulated over wall time between the first and last report;
- ``messages_published``: control periods published (``periods`` of the last report; one
  ``joint_states`` each), ``states_received`` and ``commands_sent`` by the controller;
- ``faults``: ``/diagnostics`` reports at ERROR level (integration stopped).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common, tools
from common import REPO
from tools.plant_runs import Probe

from elastic_pm_dyn.ros.demos.processes import NodeProcess, private_domain_id, ros_env

START_TIMEOUT = 300.0  # [s] until the plant's first report
WARM_UP = 5.0  # [s] after it; RSS is measured from its end
RSS_EVERY = 10.0  # [s]
GAP_EVERY = 100  # check the closure gap of every 100th received state
AMPLITUDE, FREQUENCY = 0.05, 1.0  # [rad], [Hz] motor reference: q0 + A sin(2 pi f t)
KP, KD = 5.0, 0.2  # [N m/rad], [N m s/rad]: stable with the commands lagging in fast mode
CONTROL_EVERY = 10  # answer every 10th state


def _rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


class Controller(Probe):
    """PD on the motor angles, one command per received state; /diagnostics collected (the
    probe of bench_plant), faults and the largest closure gap counted."""

    def __init__(self, domain: int):
        super().__init__(domain, states=False, name="soak_controller")
        from diagnostic_msgs.msg import DiagnosticStatus
        from sensor_msgs.msg import JointState

        from elastic_pm_dyn.kinematics.assembly import initial_state
        from elastic_pm_dyn.kinematics.mechanism import Mechanism
        from elastic_pm_dyn.model.loader import load_model
        from elastic_pm_dyn.ros.messages import torque_command
        from elastic_pm_dyn.ros.qos import COMMAND_QOS, STATE_QOS

        self.error_level, self.torque_command = DiagnosticStatus.ERROR, torque_command
        self.mech = Mechanism(load_model(REPO / "config" / "five_bar.yaml"))
        self.q0 = initial_state(self.mech)[self.mech.active]
        self.pub = self.node.create_publisher(JointState, "torque_command", COMMAND_QOS)
        self.node.create_subscription(JointState, "joint_states", self._on_state, STATE_QOS)
        self.received = self.sent = self.faults = 0
        self.max_gap = 0.0
        self.index: list[int] | None = None

    def _on_state(self, msg: object) -> None:
        self.received += 1
        if self.index is None:
            self.index = [list(msg.name).index(n) for n in self.mech.joint_names]
        q = np.asarray(msg.position)[self.index]
        if self.received % GAP_EVERY == 0:
            self.max_gap = max(self.max_gap, float(self.mech.gap(q)))
        if self.received % CONTROL_EVERY:
            return
        ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        t = ns * 1e-9
        a = self.mech.active
        qd = np.asarray(msg.velocity)[self.index]
        ref = self.q0 + AMPLITUDE * np.sin(2 * np.pi * FREQUENCY * t)
        ref_rate = AMPLITUDE * 2 * np.pi * FREQUENCY * np.cos(2 * np.pi * FREQUENCY * t)
        tau = KP * (ref - q[a]) + KD * (ref_rate - qd[a])
        self.pub.publish(self.torque_command("joint_state", self.mech.active_names, tau, ns))
        self.sent += 1

    def _on_diag(self, msg: object) -> None:
        super()._on_diag(msg)
        if msg.status[0].level == self.error_level:
            self.faults += 1
        gap = self.diagnostics[-1][1].get("closure_gap_m")
        if gap:
            self.max_gap = max(self.max_gap, float(gap))


def soak(minutes: float, log_dir: Path, domain: int) -> dict:
    args = ["--params-file", str(REPO / "config" / "plant.yaml"), "-p", "sync_mode:=fast",
            "-p", "publish_rate:=1000.0", "-p", "dt:=0.0001", "-p", "formulation:=scdd",
            "-p", "stabilization:=projection", "-p", "diagnostics_rate:=1.0"]
    plant = NodeProcess("plant_soak", "elastic_pm_dyn.ros.plant.node", args, ros_env(domain), log_dir)
    ctl = Controller(domain)
    rss: list[tuple[float, float]] = []
    try:
        deadline = time.perf_counter() + START_TIMEOUT
        while not ctl.diagnostics and time.perf_counter() < deadline:  # start-up (compiles after a kernel edit)
            ctl.spin(0.5)
            plant.check_running()
        ctl.spin(WARM_UP)
        plant.check_running()
        start = time.perf_counter()
        n_diag = len(ctl.diagnostics)
        end = start + 60.0 * minutes
        while time.perf_counter() < end:
            rss.append((time.perf_counter() - start, _rss_mib(plant.proc.pid)))
            ctl.spin(min(RSS_EVERY, end - time.perf_counter()))
            plant.check_running()
        rss.append((time.perf_counter() - start, _rss_mib(plant.proc.pid)))
    finally:
        ctl.close()
        plant.stop()
    window = ctl.diagnostics[n_diag:]
    (w0, d0), (w1, d1) = window[0], window[-1]
    return {
        "minutes": minutes, "wall_s": w1 - w0,
        "real_time_factor": (float(d1["sim_time_s"]) - float(d0["sim_time_s"])) / (w1 - w0),
        "sim_time_s": float(d1["sim_time_s"]),
        "messages_published": int(d1["periods"]), "states_received": ctl.received, "commands_sent": ctl.sent,
        "commands_accepted": int(d1["commands_accepted"]), "commands_rejected": int(d1["commands_rejected"]),
        "zero_torque_periods": int(d1["zero_torque_periods"]),
        "max_closure_gap_m": ctl.max_gap, "faults": ctl.faults,
        "rss_start_mib": rss[0][1], "rss_end_mib": rss[-1][1], "rss_growth_mib": rss[-1][1] - rss[0][1],
        "rss_mib": [[round(t, 1), round(m, 2)] for t, m in rss],
        "step_time_mean_us": float(np.median([float(d["step_time_mean_us"]) for _, d in window])),
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "load_avg": os.getloadavg()},
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="soak duration (default 10)")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "soak_plant.json")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="soak_plant_") as logs:
        result = soak(args.minutes, Path(logs), private_domain_id())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    shown = {k: v for k, v in result.items() if k not in ("rss_mib", "machine")}
    print(json.dumps(shown, indent=1))
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
