"""Run the state observer over a recorded bag and summarise its branch-force estimates.

The observer (an extended Kalman filter over the SCDD model) reads the torque commands and
the sensor topics of a rosbag2 (motor encoders, an end-effector accelerometer, strain gauges
on the rods: whichever the configuration's ``sensors`` name) and estimates every joint,
the spring deflections included, and the branch forces with their standard deviations.

Without BAG the script first makes its own input: the library's scenario generator
simulates a short, noisy recording of the reference manoeuvre (unknown disturbance torques
on the motors, sensor noise) and writes it as the bag a robot would give; the estimates are
then also compared with the simulated truth.

Run:

    python examples/observe_bag.py [BAG] [--model config/five_bar.yaml] [--config config/observer.yaml]
                                   [--sensors encoders imu] [--duration 0.3] [--out DIR]

Writes DIR/estimates.csv, DIR/estimates/ (a bag of the estimates, which ``analyze`` reads)
and DIR/summary.json (default DIR: observe_bag_out; without BAG also DIR/recording/).
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

import elastic_pm_dyn as epd
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag  # test-data tools, not the public face
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

CONFIG = Path(__file__).resolve().parents[1] / "config"
SETTLE = 0.05  # [s] the filter's start-up transient, left out of the comparison with the truth


def remove_bag(path: Path) -> None:
    """Clear the bag of an earlier run (rosbag2 will not overwrite one); never touch anything else."""
    if (path / "metadata.yaml").is_file():
        shutil.rmtree(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag", nargs="?", type=Path, help="rosbag2 directory; omitted: simulate one")
    parser.add_argument("--model", type=Path, default=CONFIG / "five_bar.yaml", help="model YAML")
    parser.add_argument("--config", type=Path, default=CONFIG / "observer.yaml", help="observer parameter YAML")
    parser.add_argument("--sensors", nargs="+", choices=("encoders", "imu", "branch_forces"), help="sensor set")
    parser.add_argument("--duration", type=float, default=0.3, help="simulated recording [s] (without BAG)")
    parser.add_argument("--out", type=Path, default=Path("observe_bag_out"), help="output directory")
    args = parser.parse_args(argv)

    mech = epd.Mechanism(epd.load_model(args.model))
    config = epd.load_observer_config(args.config)
    if args.sensors:
        config = config.with_overrides(sensors=args.sensors)
    args.out.mkdir(parents=True, exist_ok=True)
    bag, truth = args.bag, None
    if bag is None:
        truth = manoeuvre_recording(mech, seed=1, duration=args.duration)
        bag = args.out / "recording"
        remove_bag(bag)
        recording_to_bag(truth, bag)
        print(f"simulated {args.duration:g} s of the reference manoeuvre with sensor noise -> {bag}")

    remove_bag(args.out / "estimates")
    result = epd.observe(mech, config, bag, args.out, log=lambda line: None)
    s = result.summary  # summary.json as an ObserveSummary
    print(f"{s.rows} estimates over {s.duration_s:.3f} s of {bag} ({s.speed_factor:.3g}x real time), "
          f"sensors {', '.join(config.sensors)}")
    for sensor in config.sensors:
        st = s.sensors[sensor]
        print(f"  {sensor}: {st.accepted} accepted, {st.rejected} gated out, mean NIS {st.mean_nis:.2f}")
    if s.fault:
        print(f"the filter stopped: {s.fault}")
        return 1

    estimates = result.rows.est
    t = np.array([e.t for e in estimates])
    force = np.array([e.branch_force for e in estimates])
    std = np.array([e.branch_force_std for e in estimates])
    print(f"{'branch':8s} {'min [N]':>9s} {'max [N]':>9s} {'mean std [N]':>13s}"
          + (f" {'RMS error vs truth [N]':>23s}" if truth else ""))
    for i, name in enumerate(estimates[0].branch_names):
        line = f"{name:8s} {force[:, i].min():9.3f} {force[:, i].max():9.3f} {std[:, i].mean():13.4f}"
        if truth is not None:
            settled = t >= truth.t[0] + SETTLE
            k = np.searchsorted(truth.t, t[settled] - 1e-9)  # one estimate per recorded stamp
            line += f" {np.sqrt(np.mean((force[settled, i] - truth.F[k, i]) ** 2)):23.4f}"
        print(line)
    print(f"estimates.csv, estimates/ and summary.json in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
