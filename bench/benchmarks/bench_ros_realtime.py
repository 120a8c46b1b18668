"""Realtime plant with a controller in the loop: delivered rate, jitter, command-to-state latency, late periods.

    .venv/bin/python bench/benchmarks/bench_ros_realtime.py                  # 10 s window at 1 kHz
    .venv/bin/python bench/benchmarks/bench_ros_realtime.py --duration 20 --cpus 1 --priority 50

The plant node runs as its own process (``sync_mode: realtime``, five-bar, SCDD + RK4
dt = 1e-4 s, 1 kHz, ``realtime.keep_gc_out``; ``--cpus`` / ``--priority`` pass
``realtime.cpu_affinity`` / ``realtime.priority``). This process is the controller: it answers
every ``joint_states`` with a ``torque_command`` at once (default QoS) and records the states'
arrival times. Reported:
- at the controller: state inter-arrival p50 / p99 / max (jitter) and the received rate;
- from the plant's /diagnostics, over the windows inside the measurement: delivered rate,
  command-to-state latency p50 / p99 / max (command arrival in the plant to the first state
  computed with it; the window's percentiles, their median and worst over the windows), late
  and slipped periods, cycle load (cycle time / period: above 1 the plant cannot keep up),
  share of periods that started with a fresh command;
- the CPU other processes used meanwhile (the machine may be shared: read the figures with it).
Writes bench/results/ros_realtime.json and prints the table of bench/benchmarks/README_ros_realtime.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))  # common, tools

from tools.plant_runs import WARM_UP, CpuWindow, Probe  # noqa: E402

from elastic_pm_dyn.ros.demos.processes import NodeProcess, private_domain_id, ros_env  # noqa: E402


class Controller(Probe):
    """The probe, answering each state with a command (plain default QoS)."""

    def __init__(self, domain: int):
        super().__init__(domain, states=True, name="bench_controller")
        from sensor_msgs.msg import JointState
        self.msg = JointState(name=["left_motor", "right_motor"], effort=[0.0, 0.0])
        self.pub = self.node.create_publisher(JointState, "torque_command", 10)

    def _on_state(self, msg: object) -> None:
        super()._on_state(msg)
        self.pub.publish(self.msg)


def run(duration: float, cpus: list[int], priority: int, log_dir: Path, domain: int) -> dict:
    args = ["--params-file", str(REPO / "config" / "plant.yaml"), "-p", "sync_mode:=realtime",
            "-p", "publish_rate:=1000.0", "-p", "diagnostics_rate:=1.0", "-p", f"realtime.priority:={priority}"]
    if cpus:
        args += ["-p", f"realtime.cpu_affinity:={cpus}"]
    plant = NodeProcess("plant_realtime", "elastic_pm_dyn.ros.plant.node", args, ros_env(domain), log_dir)
    probe = Controller(domain)
    try:
        probe.spin(WARM_UP)
        plant.check_running()
        cpu = CpuWindow(plant.proc.pid)
        n_diag = len(probe.diagnostics)
        probe.record = True
        probe.spin(duration)
        probe.record = False
        usage = cpu.stop()
        plant.check_running()
    finally:
        probe.close()
        plant.stop()
    gaps = np.diff(probe.arrivals) * 1e3
    diags = [d for _, d in probe.diagnostics[n_diag + 1:]]  # windows wholly inside the measurement

    def col(key: str) -> np.ndarray:
        return np.array([float(d[key]) for d in diags if d.get(key)])

    p50, p99, lmax = col("latency_p50_ms"), col("latency_p99_ms"), col("latency_max_ms")
    return {
        "window_s": duration, "windows": len(diags), "cpus": cpus, "priority": priority,
        "received_rate_hz": len(probe.arrivals) / duration,
        "interarrival_ms": {"p50": float(np.percentile(gaps, 50)), "p99": float(np.percentile(gaps, 99)),
                            "max": float(gaps.max())},
        "delivered_rate_hz": float(np.median(col("delivered_rate_hz"))),
        "latency_ms": {"p50_median": float(np.median(p50)), "p99_median": float(np.median(p99)),
                       "p99_worst": float(p99.max()), "max": float(lmax.max())},
        "late_periods": int(diags[-1]["late_periods"]) - int(diags[0]["late_periods"]),
        "slipped_periods": int(diags[-1]["slipped_periods"]) - int(diags[0]["slipped_periods"]),
        "max_lateness_ms": float(col("max_lateness_window_ms").max()),
        "cycle_load_mean": float(np.median(col("cycle_load_mean"))),
        "cycle_load_max": float(col("cycle_load_max").max()),
        "fresh_command_share": float(np.median(col("fresh_command_share"))),
        "gc_time_ms_max": float(col("gc_time_ms").max()),
        **usage,
    }


def table(r: dict) -> str:
    i, lat = r["interarrival_ms"], r["latency_ms"]
    rows = [
        ("received rate at the controller / delivered by the plant", f"{r['received_rate_hz']:.1f} / "
         f"{r['delivered_rate_hz']:.1f} Hz"),
        ("state inter-arrival p50 / p99 / max", f"{i['p50']:.3f} / {i['p99']:.3f} / {i['max']:.2f} ms"),
        ("command-to-state latency p50 / p99 (median of windows) / p99 worst / max",
         f"{lat['p50_median']:.3f} / {lat['p99_median']:.3f} / {lat['p99_worst']:.3f} / {lat['max']:.2f} ms"),
        ("late periods / slipped periods in the window", f"{r['late_periods']} / {r['slipped_periods']} "
         f"(worst lateness {r['max_lateness_ms']:.2f} ms)"),
        ("cycle load mean / max (above 1: cannot keep up)", f"{r['cycle_load_mean']:.3f} / {r['cycle_load_max']:.3f}"),
        ("periods with a fresh command", f"{r['fresh_command_share'] * 100:.1f} %"),
        ("plant CPU / other processes (2 cores = 200 %)",
         f"{r['plant_cpu_percent']:.0f} % / {r['other_processes_cpu_percent']:.0f} %"),
    ]
    return "\n".join(["| quantity | measured |", "|---|---|", *(f"| {a} | {b} |" for a, b in rows)])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0, help="[s] measurement window")
    parser.add_argument("--cpus", type=int, nargs="*", default=[], help="realtime.cpu_affinity of the plant")
    parser.add_argument("--priority", type=int, default=0, help="realtime.priority (SCHED_FIFO) of the plant")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "ros_realtime.json")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        result = run(args.duration, args.cpus, args.priority, Path(tmp), private_domain_id())
    result["machine"] = {"cpus": len(os.sched_getaffinity(0)), "python": platform.python_version(),
                         "platform": platform.platform(), "load_average_1_5_15": list(os.getloadavg())}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    print(table(result))
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
