"""The plant node as a process under measurement, shared by bench/benchmarks/bench_plant.py,
bench_publish.py and soak_plant.py (moved here from bench_plant.py and bench_publish.py unchanged,
so that no bench script imports another).

``Probe`` subscribes like a controller (``joint_states`` arrival times, ``/diagnostics``),
``CpuWindow`` splits the CPU of a window between the plant, the probe and everyone else,
``run_fast`` measures a fast-mode plant's real-time factor, and ``MACHINES`` / ``model_file``
are the machines of the publish-path and integrator runs.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common
from common import REPO

from elastic_pm_dyn.ros.demos.processes import NodeProcess, ros_env

WARM_UP = 3.0  # [s] after start-up: discovery, first diagnostics
START_TIMEOUT = 180.0  # [s] fast mode: the window starts after the first /diagnostics

# name: (model file, elastic DOF per chain, RK4 step [s], torque scale of the in-process run)
MACHINES = {"five_bar": ("five_bar.yaml", 1, 1e-4, 0.05), "triglide_nek2": ("triglide.yaml", 2, 5e-5, 20.0),
            "hexa_nek2": ("hexa.yaml", 2, 1e-4, 0.5)}


class Probe:
    """The subscriber side: joint_states arrival times (``states``), /diagnostics values."""

    def __init__(self, domain: int, states: bool, name: str = "bench_probe"):
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState

        from elastic_pm_dyn.ros.qos import DIAGNOSTICS_QOS, STATE_QOS
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.arrivals: list[float] = []
        self.diagnostics: list[tuple[float, dict[str, str]]] = []
        self.record = False
        if states:
            self.node.create_subscription(JointState, "joint_states", self._on_state, STATE_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, DIAGNOSTICS_QOS)

    def _on_state(self, _msg: object) -> None:
        if self.record:
            self.arrivals.append(time.perf_counter())

    def _on_diag(self, msg: object) -> None:
        self.diagnostics.append((time.perf_counter(), {kv.key: kv.value for kv in msg.status[0].values}))

    def spin(self, seconds: float) -> None:
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.node.destroy_node()
        self.executor.shutdown(timeout_sec=2.0)
        self.rclpy.try_shutdown(context=self.context)


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


def _busy_seconds() -> float:
    """CPU time of the whole machine (all cores) spent outside idle and iowait [s]."""
    user, nice, system, _idle, _iowait, irq, softirq, steal = (
        int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:9])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


class CpuWindow:
    """CPU used over a window by the plant, by this process, and by everything else (other users)."""

    def __init__(self, plant_pid: int):
        self.pid = plant_pid
        self.start = (time.perf_counter(), _cpu_seconds(plant_pid), _cpu_seconds(os.getpid()), _busy_seconds())

    def stop(self) -> dict:
        wall, plant, own, busy = (b - a for a, b in zip(self.start, (
            time.perf_counter(), _cpu_seconds(self.pid), _cpu_seconds(os.getpid()), _busy_seconds()), strict=True))
        return {"plant_cpu_percent": 100.0 * plant / wall, "probe_cpu_percent": 100.0 * own / wall,
                "other_processes_cpu_percent": 100.0 * (busy - plant - own) / wall}


def _start_plant(sync: str, publish_rate: float, log_dir: Path, domain: int, model: str = "", dt: float = 1e-4,
                 source: Path | None = None, label: str = "", integrator: str = "rk4") -> NodeProcess:
    """The plant node process; ``source``: a directory holding another version of the package
    and its ``config/`` (bench_publish.py's "before"), which the child uses instead of this checkout's."""
    params = (source or REPO) / "config" / "plant.yaml"  # each version with its own parameter file
    args = ["--params-file", str(params), "-p", f"sync_mode:={sync}",
            "-p", f"publish_rate:={publish_rate!r}", "-p", f"dt:={dt!r}", "-p", "formulation:=scdd",
            "-p", "stabilization:=projection", "-p", "diagnostics_rate:=1.0"] + (["-p", f"model:={model}"] if model
                                                                                  else [])
    if integrator != "rk4":  # an older checkout (source) may not know the parameter's other values
        args += ["-p", f"integrator:={integrator}"]
    env = ros_env(domain)
    name = f"plant_{sync}_{publish_rate:g}{label}"
    if source is None:
        return NodeProcess(name, "elastic_pm_dyn.ros.plant.node", args, env, log_dir)
    env["PYTHONPATH"] = os.pathsep.join([str(source), env.get("PYTHONPATH", "")])
    here = os.getcwd()
    os.chdir(source)  # python -m puts the working directory first on sys.path
    try:
        return NodeProcess(name, "elastic_pm_dyn.ros.plant.node", args, env, log_dir)
    finally:
        os.chdir(here)


def run_fast(duration: float, publish_rate: float, log_dir: Path, domain: int, **start: Any) -> dict:
    """``start``: further arguments of :func:`_start_plant` (model, dt, source, label)."""
    plant = _start_plant("fast", publish_rate, log_dir, domain, **start)
    probe = Probe(domain, states=False)  # a 2-5 kHz subscriber would take the CPU the plant is measured on
    try:
        start_by = time.perf_counter() + START_TIMEOUT  # a first start may compile the kernels
        while not probe.diagnostics and time.perf_counter() < start_by:
            plant.check_running()
            probe.spin(0.5)
        probe.spin(WARM_UP)
        plant.check_running()
        cpu = CpuWindow(plant.proc.pid)
        n_diag = len(probe.diagnostics)
        probe.spin(duration)
        usage = cpu.stop()
        plant.check_running()
    finally:
        probe.close()
        plant.stop()
    window = probe.diagnostics[n_diag:]
    (w0, d0), (w1, d1) = window[0], window[-1]
    rtf = (float(d1["sim_time_s"]) - float(d0["sim_time_s"])) / (w1 - w0)
    return {"window_s": w1 - w0, "publish_rate_hz": publish_rate, "real_time_factor": rtf,
            "step_time_mean_us": float(np.median([float(d["step_time_mean_us"]) for _, d in window])),
            "cycle_time_mean_us": float(np.median([float(d["cycle_time_mean_us"]) for _, d in window])),
            **usage}


def model_file(machine: str, out_dir: Path) -> Path:
    """The machine's YAML with its ``elastic_dof_per_chain`` set (the node has no parameter for it)
    and without gravity: under zero torque the spatial machines would fall into a singular pose and
    stop; resting, they cost the same per step."""
    name, n_ek, _, _ = MACHINES[machine]
    text = (REPO / "config" / name).read_text()
    if machine != "five_bar":
        for key, value in (("elastic_dof_per_chain: 1", f"elastic_dof_per_chain: {n_ek}"),
                           ("gravity: [0.0, 0.0, -9.81]", "gravity: [0.0, 0.0, 0.0]")):
            assert key in text, f"{name}: no '{key}' line"
            text = text.replace(key, value)
    path = out_dir / f"{machine}.yaml"
    path.write_text(text)
    return path
