"""Two simulated robots in one ROS domain: each plant in its own namespace, each with its own clock.

Starts two ``plant_node`` processes in ``fast`` mode, in the namespaces /r1 and /r2, on a
private loopback-only domain. Their simulated time goes to /r1/clock and /r2/clock (the
plant's ``topics.clock`` is the relative ``clock``), so the two streams do not interleave on
one /clock; both report on the shared /diagnostics, each status named by its node's full name
with its own hardware_id. Prints the first stamps of each clock and the two statuses.

Run (needs ROS 2 Jazzy's rclpy and the elastic_pm_dyn_msgs package):

    python examples/two_plants.py [--out DIR] [--domain-id ID]

The plants' logs are DIR/logs/r1.log and r2.log (default DIR: two_plants_out).
"""

from __future__ import annotations

import argparse
import itertools
import os
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Clock

from elastic_pm_dyn.ros.processes import NodeProcess, private_domain_id, ros_env


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("two_plants_out"), help="directory for the logs")
    parser.add_argument("--domain-id", type=int, default=private_domain_id(), help="ROS domain (1-100)")
    parser.add_argument("--timeout", type=float, default=60.0, help="give up after this long [s]")
    args = parser.parse_args(argv)

    env = ros_env(args.domain_id)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]  # read by rcl at init
    plants = [NodeProcess(ns, "elastic_pm_dyn.ros.plant_node",
                          ["-r", f"__ns:=/{ns}", "-p", "sync_mode:=fast", "-p", "diagnostics_rate:=5.0"],
                          env, args.out / "logs") for ns in ("r1", "r2")]
    rclpy.init(domain_id=args.domain_id)
    node = rclpy.create_node("two_plants_listener")
    clocks: dict[str, list[float]] = {"r1": [], "r2": []}
    status: dict[str, str] = {}
    try:
        for ns, stamps in clocks.items():
            node.create_subscription(Clock, f"/{ns}/clock",
                                     lambda m, s=stamps: s.append(m.clock.sec + m.clock.nanosec * 1e-9), 100)
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: status.update(
            {s.name: s.hardware_id for s in m.status}), 10)
        deadline = time.monotonic() + args.timeout
        while min(len(c) for c in clocks.values()) < 5 or len(status) < 2:
            rclpy.spin_once(node, timeout_sec=0.05)
            for p in plants:
                p.check_running()
            if time.monotonic() > deadline:
                raise TimeoutError(f"no two clocks and statuses in {args.timeout:g} s")
    finally:  # also on an error, a timeout or Ctrl+C: never leave a plant running
        for p in plants:
            p.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    for ns, c in clocks.items():  # one plant each: increasing (two plants on one topic would repeat or go back)
        increasing = all(b > a for a, b in itertools.pairwise(c))
        print(f"/{ns}/clock: {len(c)} stamps, " + ", ".join(f"{t:.3f}" for t in c[:5])
              + f" ... strictly increasing: {'yes' if increasing else 'NO'}")
    for name, hardware_id in sorted(status.items()):
        print(f"/diagnostics: {name!r}, hardware_id {hardware_id!r}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
