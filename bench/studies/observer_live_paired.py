"""One live observer period: the Python per message (the default) against one compiled step per
message (``Observer.steps_compiled``), paired; with ``--dispatch``, the kernels called through
their pinned entry points (the default, ``elastic_pm_dyn/pinned_kernels.py``) against the same
calls through numba's dispatcher.

    .venv/bin/python bench/studies/observer_live_paired.py [five_bar | triglide:2 | hexa:2] [--duration 0.3]
    .venv/bin/python bench/studies/observer_live_paired.py hexa:2 --dispatch

Two observers of the same configuration (encoders + accelerometer) are fed the same chirp
recording as bench/benchmarks/bench_observer_loop.py makes (its seeds), period by period, alternating which
goes first, so both see the same machine load; prints both medians and p99, the ratio of the
medians and the median of the per-period ratios, and checks that both end with the same
estimate to the bit.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common, tools
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from tools.observer_runs import machine, recording

from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.drivers.stream import ObserverStream


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("machine", nargs="?", default="five_bar")
    ap.add_argument("--duration", type=float, default=0.3)
    ap.add_argument("--dispatch", action="store_true",
                    help="pinned entry points (A) against numba's dispatcher (B), both per message in Python")
    a = ap.parse_args()
    name, mech = machine(a.machine)
    rec = recording(name, mech, a.duration)
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
    streams = {}
    for compiled in (True, False):
        obs = Observer(mech, cfg)
        if a.dispatch:
            if not compiled:
                obs._pin = lambda kernel: kernel  # every call through numba's dispatcher
        else:
            obs.steps_compiled = compiled
        streams[compiled] = ObserverStream(obs)
    times: dict[bool, list[float]] = {True: [], False: []}
    names = rec.active_names
    for k in range(len(rec.t)):
        ns = int(rec.stamp_ns[k])
        for compiled in ((True, False) if k % 2 else (False, True)):
            s = streams[compiled]
            t0 = time.perf_counter()
            s.on_joint_state(ns, names, rec.encoder[k])
            s.on_imu(ns, rec.accel[k])
            s.on_torque_command(ns, names, rec.tau_cmd[k])
            times[compiled].append(time.perf_counter() - t0)
    c, p = np.array(times[True][5:]) * 1e6, np.array(times[False][5:]) * 1e6  # the first compile
    same = np.array_equal(streams[True].obs.estimate_flat(), streams[False].obs.estimate_flat())
    what_a, what_b = ("pinned", "dispatcher") if a.dispatch else ("compiled step per message", "Python")
    print(f"{a.machine}: {what_b} median {np.median(p):.0f} us (p99 {np.percentile(p, 99):.0f}); {what_a} "
          f"{np.median(c):.0f} us (p99 {np.percentile(c, 99):.0f}); ratio of medians "
          f"{np.median(c) / np.median(p):.2f}, median of paired ratios {np.median(c / p):.2f}; same estimate: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
