"""Two simulated robots in one ROS domain: each plant in its own namespace, each with its own clock.

Starts two ``plant_node`` in ``fast`` mode in /r1 and /r2. Their simulated time goes to /r1/clock and /r2/clock
(the plant's ``topics.clock`` is the relative ``clock``), so the two streams do not interleave on one /clock; both
report on the shared /diagnostics, each status named by its node's full name with its own hardware_id. Prints the
first stamps of each clock and the two statuses. Run: ``python examples/two_plants.py`` (domain: ROS_DOMAIN_ID;
the plants' logs: two_plants_out/r1.log and r2.log).
"""
import itertools
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Clock

from elastic_pm_dyn.ros.demos.local_nodes import LocalNodes

NAMESPACES, STAMPS, TIMEOUT = ("r1", "r2"), 5, 900.0  # clock stamps to wait for; give up after [s] (cold: compiles)
clocks, status = {ns: [] for ns in NAMESPACES}, {}  # stamps per namespace; hardware_id per status name

with LocalNodes(Path("two_plants_out")) as ros:
    for ns in NAMESPACES:
        ros.start(ns, ["-r", f"__ns:=/{ns}", "-p", "sync_mode:=fast", "-p", "diagnostics_rate:=5.0"])
    node = rclpy.create_node("two_plants_listener")
    for ns, stamps in clocks.items():
        node.create_subscription(Clock, f"/{ns}/clock",
                                 lambda m, s=stamps: s.append(m.clock.sec + m.clock.nanosec * 1e-9), 100)
    node.create_subscription(DiagnosticArray, "/diagnostics",
                             lambda m: status.update({s.name: s.hardware_id for s in m.status}), 10)
    ros.spin_until(node, lambda: min(map(len, clocks.values())) >= STAMPS and len(status) >= 2, TIMEOUT)
for ns, c in clocks.items():  # one plant each: increasing (two plants on one topic would repeat or go back)
    increasing = all(b > a for a, b in itertools.pairwise(c))
    print(f"/{ns}/clock: {len(c)} stamps, " + ", ".join(f"{t:.3f}" for t in c[:STAMPS])
          + f" ... strictly increasing: {'yes' if increasing else 'NO'}")
for name, hardware_id in sorted(status.items()):
    print(f"/diagnostics: {name!r}, hardware_id {hardware_id!r}")
