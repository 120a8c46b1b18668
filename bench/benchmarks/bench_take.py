"""What a message costs a node on its way in: through rclpy's executor, or taken directly (ros/drain.py).

    .venv/bin/python bench/benchmarks/bench_take.py            # ~20 s
    .venv/bin/python bench/benchmarks/bench_take.py --messages 3000 --repeats 7

A writer node publishes a burst of ``--messages`` sensor_msgs/JointState (12 joints, the
observer's input QoS) on a private domain and waits until the reader acknowledged them all (they
wait in its queue); then the reader's node takes them, timed per message, in four ways:

- ``executor``: ``SingleThreadedExecutor.spin_once`` per message, a callback doing nothing but
  count (what a subscription callback costs before any work of its own), the reader node as our
  nodes have it (parameter services, /rosout);
- ``executor, bare node``: the same without parameter services and /rosout (what the wait set's
  size adds);
- ``drain``: one executor turn, the rest taken by :class:`~elastic_pm_dyn.ros.drain.Drain` as the
  observer and the recorder take their inputs (rclpy message objects);
- ``drain, raw``: the same taking the serialized bytes (``raw=True``, as the recorder does).

Median over ``--repeats`` bursts of the per-message time; every way in each repeat, in a
shuffled order. Writes bench/results/take.{json,md}.
"""

from __future__ import annotations

import argparse
import copy
import os
import platform
import random
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common
import common

from elastic_pm_dyn.ros.demos.processes import private_domain_id

WAYS = ("executor", "executor, bare node", "drain", "drain, raw")


def burst(way: str, n: int, context) -> float:
    """[us] per message of taking a burst of ``n`` messages ``way``."""
    from rclpy.duration import Duration
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.ros.drain import Drain
    from elastic_pm_dyn.ros.messages import doubles
    from elastic_pm_dyn.ros.qos import OBSERVER_INPUT_QOS

    bare = way == "executor, bare node"
    writer = Node("writer", context=context, start_parameter_services=False, enable_rosout=False)
    reader = Node("reader", context=context, start_parameter_services=not bare, enable_rosout=not bare)
    qos = copy.copy(OBSERVER_INPUT_QOS)
    qos.depth = max(qos.depth, n)  # the whole burst waits in the queue
    got = [0]

    def count(_msg, _info) -> None:
        got[0] += 1
    drain = Drain(max_per_turn=n)
    raw = way == "drain, raw"
    if way.startswith("drain"):
        drain.subscribe(reader, JointState, "/take_bench", count, qos, raw=raw)
    else:
        reader.create_subscription(JointState, "/take_bench", count, qos, raw=raw)
    pub = writer.create_publisher(JointState, "/take_bench", qos)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(reader)
    try:
        deadline = time.monotonic() + 60.0
        while pub.get_subscription_count() < 1:
            if time.monotonic() > deadline:
                raise RuntimeError("the reader did not match")
            time.sleep(0.01)
        m = JointState(name=[f"joint_{i}" for i in range(12)])
        m.position = m.velocity = m.effort = doubles(np.zeros(12))
        for _ in range(n):
            pub.publish(m)
        if not pub.wait_for_all_acked(Duration(seconds=60)):
            raise RuntimeError("the burst was not acknowledged")
        t0 = time.perf_counter()
        while got[0] < n:
            executor.spin_once(timeout_sec=1.0)
        return (time.perf_counter() - t0) / n * 1e6
    finally:
        executor.remove_node(reader)
        executor.shutdown()
        reader.destroy_node()
        writer.destroy_node()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    import rclpy
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id())
    times: dict[str, list[float]] = {w: [] for w in WAYS}
    try:
        for _ in range(a.repeats):
            for way in random.sample(WAYS, len(WAYS)):
                times[way].append(burst(way, a.messages, context))
    finally:
        rclpy.try_shutdown(context=context)
    med = {w: float(np.median(t)) for w, t in times.items()}
    rows = [f"| {w} | {med[w]:.1f} | {med['executor'] / med[w]:.1f} |" for w in WAYS]
    md = (f"Measured {time.strftime('%Y-%m-%d %H:%M')} on {platform.machine()}, {os.cpu_count()} cores, load "
          f"{os.getloadavg()[0]:.1f} (`bench/benchmarks/bench_take.py --messages {a.messages} --repeats {a.repeats}`)."
          "\n\n| how a JointState reaches the node | per message [us], median | executor / this |\n|---|---:|---:|\n"
          + "\n".join(rows) + "\n")
    common.write(Path(common.RESULTS), "take", {"messages": a.messages, "repeats": a.repeats, "us": times,
                                                 "median_us": med, "commit": common.commit()}, md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
