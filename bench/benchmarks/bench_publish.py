"""The plant's publish path before/after: per-period ROS cost in-process, and fast-mode real-time factor.

    .venv/bin/python bench/benchmarks/bench_publish.py                 # ~4 min
    .venv/bin/python bench/benchmarks/bench_publish.py --quick         # ~1 min smoke run
    .venv/bin/python bench/benchmarks/bench_publish.py --skip-rtf      # the in-process part only

1. **Per-period ROS cost** (in this process): what the plant node does per control period
   after the physics, filling and publishing its four 1 kHz topics (``joint_states``,
   ``branch_forces``, ``ee_pose``, ``/clock``, the node's QoS, no subscriber, as in fast
   mode). ``objects`` is the path before the change (rclpy messages refilled from
   ``Plant.efforts/branches/end_effector`` and converted and serialized on publish);
   ``serialized`` is :class:`~elastic_pm_dyn.ros.messages.PlantMessages` (CDR bytes
   refilled in place, ``publish(bytes)``). The plant steps between periods (untimed), so
   every period publishes a new state; both paths alternate in blocks of 100 periods in
   random order (load from other users hits both alike). Median and p90 per period [us].
2. **Fast-mode real-time factor** of the plant node process (bench_plant.py's method:
   simulated / wall time between the first and last ``/diagnostics`` of the window, no
   state subscriber), publishing at 1 kHz, before and after back to back (alternating,
   ``--repeats`` pairs): "before" runs the package and its ``config/plant.yaml`` as of
   ``--before`` (a git commit, extracted with ``git archive`` to a temporary directory),
   "after" this checkout.
   Five-bar (dt 1e-4 s), Triglide n_ek = 2 (dt 5e-5 s: ``check`` asks for < 9.3e-5 s) and
   Hexa n_ek = 2 (dt 1e-4 s), SCDD + RK4 + projection, gravity off for the spatial
   machines (zero torque would let them fall into a singular pose and stop the plant).
Writes bench/results/publish.json and publish.md (the tables), also printed.
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common, tools
import common
from common import REPO
from tools.plant_runs import MACHINES, model_file, run_fast

from elastic_pm_dyn.ros.demos.processes import private_domain_id

BEFORE = "ebfe74fb1abc00050e9b6b5befd96ff0fc5dffc6"  # the last commit with the object publish path
BLOCK = 100  # periods per timed block


class ObjectPath:
    """Before: the plant's rclpy messages refilled per period (the node's code up to commit BEFORE)."""

    def __init__(self, plant, base_frame: str):
        from rosgraph_msgs.msg import Clock

        from elastic_pm_dyn.ros.messages import StateMessages
        self.plant = plant
        self.m = StateMessages(plant.mech, base_frame)
        self.clock = Clock()

    def publish(self, ns: int, pubs) -> None:
        from elastic_pm_dyn.bags.msgtypes import NS
        p, m = self.plant, self.m
        effort = p.efforts()
        b = p.branches(effort)
        m._set(ns, p.q, p.qd, effort, b.force, b.deflection, b.rate, p.end_effector())
        sec, nanosec = divmod(ns, NS)
        self.clock.clock.sec, self.clock.clock.nanosec = sec, nanosec
        pubs[0].publish(m.joint_state)
        pubs[1].publish(m.branch_forces)
        pubs[2].publish(m.ee_pose)
        pubs[3].publish(self.clock)


class SerializedPath:
    """After: :class:`PlantMessages` and ``publish(bytes)``, as the node's ``_publish_state``."""

    def __init__(self, plant, base_frame: str):
        from elastic_pm_dyn.ros.messages import PlantMessages
        self.m = PlantMessages(plant, base_frame)

    def publish(self, ns: int, pubs) -> None:
        m = self.m
        m.fill(ns)
        pubs[0].publish(m.joint_state_raw)
        pubs[1].publish(m.branch_forces_raw)
        pubs[2].publish(m.ee_pose_raw)
        pubs[3].publish(m.clock_raw)


def per_period_cost(machine: str, model: Path, periods: int, seed: int) -> dict:
    """Time fill + publish of the four topics per period, both paths interleaved in blocks."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from elastic_pm_dyn_msgs.msg import BranchForces
    from geometry_msgs.msg import PoseStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.errors import SingularConfigurationError
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.ros.qos import CLOCK_QOS, STATE_QOS
    from elastic_pm_dyn.sim.plant import Plant
    from elastic_pm_dyn.sim.simulator import SimulationOptions

    _, n_ek, dt, scale = MACHINES[machine]
    options = SimulationOptions(formulation="scdd", integrator="rk4", dt=dt, stabilization="projection", sample=1e-3)
    plant = Plant(Mechanism(load_model(model)), options, 1e-3)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id())
    node = rclpy.create_node("bench_publish", context=context)
    try:
        paths = {}
        for name, cls in (("objects", ObjectPath), ("serialized", SerializedPath)):
            # own topics per path: neither path's history (depth 100, transient local) slows the other
            pubs = [node.create_publisher(JointState, f"{name}/joint_states", STATE_QOS),
                    node.create_publisher(BranchForces, f"{name}/branch_forces", STATE_QOS),
                    node.create_publisher(PoseStamped, f"{name}/ee_pose", STATE_QOS),
                    node.create_publisher(Clock, f"{name}/clock", CLOCK_QOS)]
            paths[name] = (cls(plant, "world"), pubs)
        rng = np.random.default_rng(seed)
        times: dict[str, list[float]] = {name: [] for name in paths}
        clock = time.perf_counter
        for block in range(-2, periods // BLOCK):  # two blocks of warm-up
            for name in rng.permutation(list(paths)):
                path, pubs = paths[name]
                for _ in range(BLOCK):
                    try:
                        plant.step(scale * rng.uniform(-1.0, 1.0, len(plant.tau)))
                    except SingularConfigurationError:
                        plant.reset()  # random torques ran it into a singularity: start again
                    if plant.k % 200 == 0:
                        plant.reset()  # stay near the start pose
                    ns = plant.k * 1_000_000
                    t0 = clock()
                    path.publish(ns, pubs)
                    t1 = clock()
                    if block >= 0:
                        times[name].append(t1 - t0)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    out: dict = {"machine": machine, "n_ek": n_ek, "periods": periods, "n_t": plant.mech.n,
                 "branches": len(plant.mech.model.branches)}
    for name, t in times.items():
        a = np.array(t) * 1e6
        out[name] = {"median_us": float(np.median(a)), "p90_us": float(np.percentile(a, 90)),
                     "p99_us": float(np.percentile(a, 99)), "mean_us": float(a.mean())}
    out["ratio_median"] = out["serialized"]["median_us"] / out["objects"]["median_us"]
    out["ratio_p90"] = out["serialized"]["p90_us"] / out["objects"]["p90_us"]
    return out


def extract(commit: str, into: Path) -> Path:
    """The package and its config/ at ``commit`` (git archive), for the plant process of "before"."""
    data = subprocess.run(["git", "-C", str(REPO), "archive", "--format=tar", commit, "elastic_pm_dyn", "config"],
                          check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    return into


def rtf_pairs(machines: list[str], models: dict[str, Path], before_src: Path, duration: float, repeats: int,
              log_dir: Path) -> dict:
    domain = private_domain_id()
    out: dict = {}
    for machine in machines:
        dt = MACHINES[machine][2]
        runs: dict[str, list[dict]] = {"before": [], "after": []}
        for r in range(repeats):
            order = ("before", "after") if r % 2 == 0 else ("after", "before")
            for which in order:
                print(f"fast 1 kHz, {machine}, {which}, {duration:g} s ...", flush=True)
                runs[which].append(run_fast(duration, 1000.0, log_dir, domain, model=str(models[machine]), dt=dt,
                                            source=before_src if which == "before" else None,
                                            label=f"_{machine}_{which}_{r}"))
        rtf = {k: [x["real_time_factor"] for x in v] for k, v in runs.items()}
        out[machine] = {"dt": dt, "runs": runs, "rtf_before": rtf["before"], "rtf_after": rtf["after"],
                        "rtf_before_median": float(np.median(rtf["before"])),
                        "rtf_after_median": float(np.median(rtf["after"])),
                        "ratio": float(np.median(rtf["after"]) / np.median(rtf["before"])),
                        "other_cpu_percent": [x["other_processes_cpu_percent"] for v in runs.values() for x in v]}
    return out


def tables(r: dict) -> str:
    lines = ["Per-period ROS cost: fill + publish joint_states, branch_forces, ee_pose, /clock (no subscriber) [us]",
             "", "| machine | n_t | objects median / p90 | serialized median / p90 | ratio median / p90 |",
             "|---|---:|---:|---:|---:|"]
    for c in r["cost"].values():
        o, s = c["objects"], c["serialized"]
        lines.append(f"| {c['machine']} | {c['n_t']} | {o['median_us']:.1f} / {o['p90_us']:.1f} | "
                     f"{s['median_us']:.1f} / {s['p90_us']:.1f} | {c['ratio_median']:.2f} / {c['ratio_p90']:.2f} |")
    if r.get("rtf"):
        lines += ["", "Fast mode, publish 1 kHz: real-time factor of the plant node (median of the runs)", "",
                  "| machine | dt [s] | before | after | after / before | runs each |",
                  "|---|---:|---:|---:|---:|---:|"]
        for machine, x in r["rtf"].items():
            lines.append(f"| {machine} | {x['dt']:g} | {x['rtf_before_median']:.2f} | {x['rtf_after_median']:.2f} | "
                         f"{x['ratio']:.2f} | {len(x['rtf_before'])} |")
        others = ", ".join(f"{m} {min(x['other_cpu_percent']):.0f}-{max(x['other_cpu_percent']):.0f} %"
                           for m, x in r["rtf"].items())
        lines.append(f"\nCPU of other processes during the fast-mode windows (2 cores = 200 %): {others}.")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=int, default=3000, help="timed periods per path and machine")
    parser.add_argument("--duration", type=float, default=8.0, help="fast-mode window per run [s]")
    parser.add_argument("--repeats", type=int, default=2, help="before/after pairs per machine")
    parser.add_argument("--before", default=BEFORE, help="git commit of the 'before' plant node")
    parser.add_argument("--quick", action="store_true", help="smoke run: 600 periods, 3 s windows, one pair")
    parser.add_argument("--skip-rtf", action="store_true", help="only the in-process per-period cost")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = parser.parse_args()
    if args.quick:
        args.periods, args.duration, args.repeats = 600, 3.0, 1
    results: dict = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                 "python": platform.python_version(), "load_before": os.getloadavg()},
                     "commit": common.commit(), "before": args.before}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_dir = Path(tmp)
        models = {m: model_file(m, tmp_dir) for m in MACHINES}
        results["cost"] = {}
        for machine in MACHINES:
            print(f"per-period cost, {machine}, {args.periods} periods per path ...", flush=True)
            results["cost"][machine] = per_period_cost(machine, models[machine], args.periods, seed=1)
        if not args.skip_rtf:
            before_src = extract(args.before, tmp_dir / "before")
            results["rtf"] = rtf_pairs(list(MACHINES), models, before_src, args.duration, args.repeats,
                                       tmp_dir / "logs")
    results["machine"]["load_after"] = os.getloadavg()
    common.write(args.out, "publish", results, tables(results))
    print(f"load average before/after: {results['machine']['load_before']} / {results['machine']['load_after']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
