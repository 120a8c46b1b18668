"""The observer at the loop's speed on every machine: one live period, offline `observe`, accuracy.

    .venv/bin/python bench/benchmarks/bench_observer_loop.py                # ~6 min on 2 cores
    .venv/bin/python bench/benchmarks/bench_observer_loop.py --quick        # 0.3 s recordings, no reference
    .venv/bin/python bench/benchmarks/bench_observer_loop.py --machines five_bar hexa:2
    .venv/bin/python bench/benchmarks/bench_observer_loop.py --rates 1000 2000  # the 1 and 2 kHz loops

For each machine (the reference five-bar, the Triglide and the Hexa at n_ek = 2) a 1 s
recording of a chirp through the spring modes on a PD loop that holds the start pose against
gravity, with a flat 2-200 Hz multisine of 0.02 N m (or N) on every motor and the default
sensor noise (``observer.testing.scenarios.chirp_recording``; seeds 7101-7103, used nowhere else),
the truth integrated by RK4 at 25 us. Encoders + accelerometer, the default configuration
(``process.integrator: etd2``, ``process.linearization: springs``) beside the reference it
replaced (``rk4`` + ``differences``: RK4 sub-steps from the fastest spring, every Jacobian
column differenced, dense expm), in the same run:

- one live period: the wall time of the per-message calls of one stamp (joint state,
  accelerometer, command) through ``ObserverStream``, as the observer node makes them;
  median, p90, p99, p99.9 and p99 / median over the recording; beside it the same with one
  compiled step per message (``Observer.steps_compiled``), in the same run; at each loop
  rate of ``--rates`` (the recording's commands and samples at that rate, the observer's
  prediction pieces as long as a period);
- the flop-count limit of the filter's period: one dense covariance step (n_x^3
  multiply-adds for Phi P Phi^T) at 5 Gflop/s, the floor issue #40 names for a filter that
  keeps a dense covariance;
- offline ``observe`` over the recording's bag: the filter's real-time factor (duration /
  ``wall_filter_s`` of summary.json, the quantity the issue measured) and the whole run's,
  best of three passes (the first loads the compiled kernels);
- accuracy: branch-force error RMS over the RMS of the elastic part, the open loop's, their
  ratio, and the fraction of samples whose NEES of [q_ae, qd_ae] lies in its 95 % band
  (after 50 ms).

Writes bench/results/observer_loop.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))  # common, tools
from tools.observer_runs import machine, recording  # noqa: E402

from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.observer import Observer, ObserverConfig  # noqa: E402
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag  # noqa: E402
from elastic_pm_dyn.observer.offline import observe_bag  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import feed as feed_live  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import open_loop, quasi_static_series, score  # noqa: E402

CONFIGS = {"etd2 + springs (default)": {},
           "rk4 + differences (before)": {"process.integrator": "rk4", "process.linearization": "differences"}}
SENSORS = ["encoders", "imu"]


def live_periods(mech: Mechanism, rec, params: dict, compiled: bool = False) -> dict:
    """One live period's wall time through the per-message API; ``compiled``: each message
    through one compiled step (``Observer.steps_compiled``), else the default (the Observer's
    Python calling the kernels piece by piece)."""
    obs = Observer(mech, ObserverConfig.from_parameters({"sensors": SENSORS, **params}))
    obs.steps_compiled = compiled
    run = feed_live(obs, rec, tuple(SENSORS), timed=True)
    t = run.update_times[5:] * 1e6  # the first periods initialise and compile
    med = float(np.median(t))
    return {"median_us": med, "p90_us": float(np.percentile(t, 90)), "p99_us": float(np.percentile(t, 99)),
            "p999_us": float(np.percentile(t, 99.9)), "p99_over_median": float(np.percentile(t, 99) / med),
            "periods": len(t), "nx": obs.nx, "run": run}


FLOP_RATE = 5e9  # [flop/s] the rate issue #40 prices a dense covariance step at


def covariance_floor_us(nx: int) -> float:
    """[us] one dense covariance step Phi P Phi^T (n_x^3 multiply-adds, the issue's count) at FLOP_RATE."""
    return nx ** 3 / FLOP_RATE * 1e6


def offline(mech: Mechanism, rec, params: dict, tmp: Path, tag: str, repeats: int = 3) -> dict:
    bag = tmp / f"{tag}_in"
    if not bag.exists():
        recording_to_bag(rec, bag, use=tuple(SENSORS))
    cfg = ObserverConfig.from_parameters({"sensors": SENSORS, **params})
    # the best of `repeats` passes: the first compiles or loads the kernels (once per process)
    s = min((observe_bag(mech, cfg, bag, tmp / f"{tag}_out_{len(list(tmp.iterdir()))}", log=lambda s: None).summary
             for _ in range(repeats)), key=lambda s: s.wall_filter_s)
    return {"filter_rtf": s.duration_s / s.wall_filter_s, "total_rtf": s.speed_factor,
            "wall_filter_s": s.wall_filter_s, "wall_total_s": s.wall_total_s}


def markdown(result: dict) -> str:
    lines = [f"Measured {result['date']} on {result['machine']}, load {result.get('load', '?')} "
             f"(`{result['command']}`).", "",
             "| machine | rate [Hz] | configuration | live period median [us] | p99 [us] | p99.9 [us] "
             "| one compiled step per message, median [us] | flop limit [us] | offline filter x real time "
             "| F error / open loop | NEES in 95 % band |",
             "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for row in result["rows"]:
        live = row["live"]
        lines.append(f"| {row['machine']} | {row.get('rate_hz', 1000):.0f} | {row['config']} | "
                     f"{live['median_us']:.0f} | {live['p99_us']:.0f} | {live.get('p999_us', float('nan')):.0f} | "
                     f"{live['steps_median_us']:.0f} | {covariance_floor_us(live.get('nx', 0)):.0f} | "
                     f"{row['offline']['filter_rtf']:.1f} | {row['vs_open_loop']:.2f} | {row['nees_in_band']:.2f} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", nargs="+", default=["five_bar", "triglide:2", "hexa:2"])
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--quick", action="store_true", help="0.3 s recordings, the default configuration only")
    ap.add_argument("--rates", nargs="+", type=float, default=[1000.0], help="[Hz] loop rates to run")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    a = ap.parse_args()
    duration = 0.3 if a.quick else a.duration
    configs = dict(list(CONFIGS.items())[:1]) if a.quick else CONFIGS
    rows = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        for spec in a.machines:
            name, mech = machine(spec)
            for rate in a.rates:
                t0 = time.perf_counter()
                rec = recording(name, mech, duration, period=1.0 / rate)
                ol, F_qs = open_loop(rec, dt=2.5e-5), quasi_static_series(rec)
                print(f"{spec} at {rate:g} Hz: recording {time.perf_counter() - t0:.1f} s", flush=True)
                for label, params in configs.items():
                    params = {**params, "process.max_interval": 1.0 / rate}  # one prediction piece a period
                    live = live_periods(mech, rec, params)
                    steps = live_periods(mech, rec, params, compiled=True)
                    live["steps_median_us"] = steps["median_us"]
                    live["steps_p99_us"] = steps["p99_us"]
                    s = score(rec, live.pop("run"), ol, F_qs, settle=0.05)
                    off = offline(mech, rec, params, tmp, f"{spec.replace(':', '_')}_{rate:g}")
                    row = {"machine": spec, "rate_hz": rate, "config": label, "live": live, "offline": off,
                           "covariance_floor_us": covariance_floor_us(live["nx"]),
                           "F_ratio": s["F_ratio"], "F_ratio_open_loop": s["F_ratio_open_loop"],
                           "vs_open_loop": s["F_ratio"] / s["F_ratio_open_loop"], "nees_in_band": s["nees_in_band"],
                           "motor_rmse_over_noise": s["motor_rmse_over_noise"]}
                    rows.append(row)
                    print(f"  {label}: live median {live['median_us']:.0f} us, p99 {live['p99_us']:.0f} us, "
                          f"p99.9 {live['p999_us']:.0f} us ({live['p99_over_median']:.2f}x); offline filter "
                          f"{off['filter_rtf']:.1f}x real time; F error / open loop {row['vs_open_loop']:.3f}; "
                          f"NEES in band {row['nees_in_band']:.2f}", flush=True)
    cores = len(os.sched_getaffinity(0))
    result = {"date": time.strftime("%Y-%m-%d"),
              "machine": f"{platform.processor() or platform.machine()}, {cores} cores",
              "command": " ".join(["bench/benchmarks/bench_observer_loop.py", *sys.argv[1:]]),
              "load": " ".join(f"{x:.1f}" for x in os.getloadavg()),
              "duration_s": duration, "rows": rows}
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer_loop.json").write_text(json.dumps(result, indent=2))
    (out / "observer_loop.md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
