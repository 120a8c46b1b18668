"""Observe a bag: the EKF's branch forces and their uncertainty from a recording.

Run: ``python examples/observe_bag.py [BAG]``. Without BAG it first simulates a recording of
the reference manoeuvre with sensor noise (observe_out/recording) and also prints each branch
force's RMS error against the simulated truth. Writes (afresh) observe_out/estimates.csv,
observe_out/estimates/ (a bag of the estimates, which ``analyze`` reads) and summary.json.
"""

import shutil
import sys
from pathlib import Path

import numpy as np

import elastic_pm_dyn as epd
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag  # test-data tools, not the public face
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

CONFIG = Path(__file__).resolve().parents[1] / "config"
OUT, DURATION, SETTLE = Path("observe_out"), 0.2, 0.05  # [s] recording simulated; start-up left out of the RMS
SENSORS = ("encoders", "imu", "branch_forces")  # strain gauges too: config/observer.yaml has encoders + imu

mech = epd.Mechanism(epd.load_model(CONFIG / "five_bar.yaml"))
config = epd.load_observer_config(CONFIG / "observer.yaml").with_overrides(sensors=list(SENSORS))
bag, truth = Path(sys.argv[1]) if sys.argv[1:] else OUT / "recording", None
shutil.rmtree(OUT / "estimates" if sys.argv[1:] else OUT, ignore_errors=True)  # rosbag2 does not overwrite a bag
if not sys.argv[1:]:  # no bag given: simulate one, the truth kept
    recording_to_bag(truth := manoeuvre_recording(mech, seed=1, duration=DURATION), bag)
s = (result := epd.observe(mech, config, bag, OUT, log=lambda line: None)).summary
print(f"{s.rows} estimates over {s.duration_s:.3f} s of {bag}" + (f"; filter stopped: {s.fault}" if s.fault else ""))
for sensor in config.sensors:
    print(f"  {sensor}: {s.sensors[sensor].accepted} accepted, {s.sensors[sensor].rejected} gated out")
t, force = np.array([e.t for e in result.rows.est]), np.array([e.branch_force for e in result.rows.est])
for i, name in enumerate(result.rows.est[0].branch_names):
    print(f"{name} {force[:, i].min():.3f} .. {force[:, i].max():.3f} N", end="")
    if truth:  # one estimate per recorded stamp, after the filter's start-up
        settled = t >= truth.t[0] + SETTLE
        error = force[settled, i] - truth.F[np.searchsorted(truth.t, t[settled] - 1e-9), i]
        print(f", RMS error vs truth {np.sqrt(np.mean(error ** 2)):.4f} N", end="")
    print()
