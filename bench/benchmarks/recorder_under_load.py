"""A 1 kHz recording of the plant's topics on a loaded machine: what the recorder lost, and
whether it said so.

Starts the plant (realtime, 1 kHz), ``--hogs`` CPU-bound processes beside it, a numbered
1 kHz stream at the plant's state QoS (``/numbered``: JointState, position[0] = k, from this
process) and a recorder (the package's, or ``--recorder-module`` for another) of all four
topics; records ``--seconds``, stops the recorder with SIGINT and reads the bag. The truth
is the numbered stream: a k missing between the first and last recorded one is a lost
message (the plant's own stamps slip when a loaded machine makes it skip periods, so they
are no such witness). Prints per topic what was recorded and what the recorder reported in
the bag's metadata (``custom_data: elastic_pm_dyn.losses``).

    .venv/bin/python bench/benchmarks/recorder_under_load.py --seconds 60 --hogs 2
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path

import yaml

from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.ros.demos.processes import NodeProcess, private_domain_id, ros_env

TOPICS = ["/numbered", "/joint_states", "/branch_forces", "/ee_pose"]
RATE = 1000.0  # [Hz] of the numbered stream


def _hog() -> None:
    x = 0
    while True:
        x = (x * 1103515245 + 12345) % 2**31


def _wait_for(proc: NodeProcess, text: str, guard: float = 600.0) -> None:
    end = time.monotonic() + guard
    while text not in proc.log.read_text(errors="replace"):
        proc.check_running()
        if time.monotonic() > end:
            sys.exit(f"{proc.name}: no '{text}' within {guard:g} s ({proc.log})")
        time.sleep(0.1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--hogs", type=int, default=2)
    ap.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"))
    ap.add_argument("--recorder-module", default="elastic_pm_dyn.ros.recorder.node")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="recorder_load_"))
    env = ros_env(private_domain_id())
    plant = NodeProcess("plant", "elastic_pm_dyn.ros.plant.node", ["-p", "sync_mode:=realtime"], env, out / "logs")
    hogs = [multiprocessing.Process(target=_hog, daemon=True) for _ in range(a.hogs)]
    rec = None
    try:
        _wait_for(plant, "robot_description")
        for h in hogs:
            h.start()
        bag = out / "bag"
        rec = NodeProcess("recorder", a.recorder_module,
                          ["-p", f"output:={bag}", "-p", f"storage:={a.storage}",
                           "-p", "topics:=[" + ",".join(TOPICS) + "]"], env, out / "logs")
        sent = _publish_numbered(env, rec, a.seconds)
        rec.stop()
    finally:
        for h in hogs:
            h.terminate()
        if rec is not None and rec.proc.poll() is None:
            rec.proc.kill()
        plant.stop()
    with open_bag(bag) as b:
        dec = b.decoder()
        counts = {c.topic: sum(1 for _ in b.messages([c])) for c in b.connections}
        numbered = [int(dec.joint_state(raw)[2][0]) for _, _, raw in b.messages(
            [c for c in b.connections if c.topic == "/numbered"])]
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    reported = json.loads((info.get("custom_data") or {}).get("elastic_pm_dyn.losses", "{}"))
    print(f"{a.seconds:g} s, {a.hogs} CPU hogs, {a.storage}, {a.recorder_module} ({out})")
    ks = sorted(set(numbered))
    missing = (ks[-1] - ks[0] + 1 - len(ks)) if ks else 0
    print(f"  /numbered: sent {sent}, recorded {len(numbered)} (k {ks[0] if ks else '-'}..{ks[-1] if ks else '-'}), "
          f"missing between first and last {missing}, duplicates {len(numbered) - len(ks)}")
    for topic in TOPICS:
        print(f"  {topic}: recorded {counts.get(topic, 0)}, reported {reported.get(topic, 'nothing')}")


def _publish_numbered(env: dict[str, str], rec: NodeProcess, seconds: float) -> int:
    """Publish /numbered at RATE for ``seconds`` once the recorder records it; returns how many were sent."""
    import os

    import rclpy
    from sensor_msgs.msg import JointState

    from elastic_pm_dyn.ros.qos import STATE_OUT_QOS
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    rclpy.init()
    try:
        node = rclpy.create_node("numbered")
        pub = node.create_publisher(JointState, "/numbered", STATE_OUT_QOS)
        k = 0

        def send() -> None:
            nonlocal k
            pub.publish(JointState(name=["k"], position=[float(k)]))
            k += 1
        end = time.monotonic() + 600.0
        while "recording /numbered" not in rec.log.read_text(errors="replace"):  # one at a time until then
            send()
            rec.check_running()
            if time.monotonic() > end:
                sys.exit("the recorder never recorded /numbered")
            time.sleep(0.01)
        t0 = time.monotonic()
        start = k
        while (now := time.monotonic()) - t0 < seconds:
            while k - start < (now - t0) * RATE:
                send()
            time.sleep(0.0005)
        node.destroy_node()
        return k
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
