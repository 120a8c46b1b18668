"""Benchmark of the state observer on the reference five-bar: accuracy, update time, offline speed.

    .venv/bin/python bench/benchmarks/bench_observer.py            # ~1-2 min; --quick for a short run
    .venv/bin/python bench/benchmarks/bench_observer.py --smoother # the RTS smoother only (observe --smoother rts)

Measures, on simulated 1 kHz recordings (``elastic_pm_dyn.observer.testing.scenarios``: the
reference manoeuvre and a 3 N m chirp (6 seeds), each with an unknown 2-200 Hz multisine of
0.02 N m RMS per motor):
- scores per sensor set: branch-force error RMS over the RMS of the elastic
  part (F - F_qs), the same for an open-loop elastic simulation driven by the same
  commands, motor-angle error RMS over the encoder noise, fraction of samples whose NEES
  of [q_ae, qd_ae] lies in its 95 % band (after 50 ms of settling);
- the time of one filter period as a live node spends it (prediction over 1 ms + encoder
  and accelerometer corrections + the command), median and 90th percentile over rounds,
  for relinearisation every 1 and every 4 periods;
- ``observe`` over a bag (the manoeuvre followed by holding, ``--seconds`` long): wall time
  of reading, filtering, writing CSV + bag, and the real-time factor (bag duration / wall
  time; the process start and numba's cache loading excluded, both once per run).
Writes ``bench/results/observer.json`` and ``observer.md`` and prints the tables.

``--smoother``: instead, ``observe --smoother rts`` (:mod:`elastic_pm_dyn.observer.tuning.smoother`)
with encoders + accelerometer: its cost on a 5 s bag (the filter pass, the replay of the
filter's predictions, the backward pass and outputs; best of three), and on independent
recordings (``elastic_pm_dyn.observer.testing.recordings``, seeds 9501... not used anywhere else) the
filtered and the smoothed branch-force error over the elastic part, motor-angle error over
the encoder noise, NEES in its 95 % band and the mean smoothed/filtered branch-force std.
Writes ``bench/results/observer_smoother.json`` and ``observer_smoother.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.observer import Observer, ObserverConfig  # noqa: E402
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag  # noqa: E402
from elastic_pm_dyn.observer.drivers.stream import ObserverStream  # noqa: E402
from elastic_pm_dyn.observer.offline import observe_bag  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import feed, offline_run, open_loop, quasi_static_series, score  # noqa: E402
from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import chirp_recording, manoeuvre_recording  # noqa: E402

# The `observe` subcommand on its own parser (elastic_pm_dyn/cli.py wires it in for users).
CLI = ("import argparse, sys; from elastic_pm_dyn.observer.cli import register_cli; p = argparse.ArgumentParser(); "
       "register_cli(p.add_subparsers(dest='command')); a = p.parse_args(); sys.exit(a.func(a))")
SETS = {"encoders": ("encoders",), "encoders+imu": ("encoders", "imu"),
        "encoders+gauges": ("encoders", "branch_forces")}


def accuracy(mech, seeds: list[int]) -> list[dict]:
    rows = []
    for seed in seeds:
        for rec in (manoeuvre_recording(mech, seed=seed), chirp_recording(mech, seed=seed + 100)):
            ol, F_qs = open_loop(rec), quasi_static_series(rec)
            for name, sensors in SETS.items():
                obs = Observer(mech, ObserverConfig.from_parameters({"sensors": list(sensors)}))
                s = score(rec, feed(obs, rec, sensors), ol, F_qs, settle=0.05)
                rows.append({"scenario": rec.label, "seed": seed, "sensors": name,
                             "F_ratio": s["F_ratio"], "F_ratio_open_loop": s["F_ratio_open_loop"],
                             "vs_open_loop": s["F_ratio"] / s["F_ratio_open_loop"],
                             "elastic_rms_N": s["elastic_rms_N"], "F_error_rms_N": s["F_error_rms_N"],
                             "motor_rmse_over_noise": s["motor_rmse_over_noise"],
                             "nees_in_band": s["nees_in_band"], "nees_mean": s["nees_mean"],
                             "rejected": sum(s["rejected"].values())})
    return rows


def update_times(mech, rec, rounds: int) -> dict:
    """Wall time of one live period (samples of t_k + the command of t_k), in us."""
    out = {}
    for every in (1, 8):
        for name in ("encoders", "encoders+imu"):
            sensors = SETS[name]
            times = []
            for _ in range(rounds):
                obs = Observer(mech, ObserverConfig.from_parameters(
                    {"sensors": list(sensors), "process.relinearize_every": every}))
                stream = ObserverStream(obs)
                names = rec.active_names
                for k, ns in enumerate(rec.stamp_ns):
                    ns = int(ns)
                    t0 = time.perf_counter()
                    stream.on_joint_state(ns, names, rec.encoder[k])
                    if "imu" in sensors:
                        stream.on_imu(ns, rec.accel[k])
                    stream.on_torque_command(ns, names, rec.tau_cmd[k])
                    if k > 0:
                        times.append(time.perf_counter() - t0)
            t = np.array(times) * 1e6
            out[f"{name}, relinearize every {every}"] = {"median_us": float(np.median(t)),
                                                        "p90_us": float(np.percentile(t, 90)),
                                                        "samples": len(t)}
    return out


def offline_speed(mech, seconds: float, repeats: int) -> dict:
    rec = manoeuvre_recording(mech, duration=seconds, seed=11, truth_dt=1e-4)
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "in"
        recording_to_bag(rec, bag, use=("encoders", "imu"))
        cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
        # Warm-up on a short bag: numba's cache loading and rosbags' first-use set-up, once per run.
        warm = Path(tmp) / "warm"
        recording_to_bag(manoeuvre_recording(mech, duration=0.05, seed=11), warm, use=("encoders", "imu"))
        observe_bag(mech, cfg, warm, Path(tmp) / "warm_out", log=lambda s: None)
        # Pipelined (the default) and one stage after the other, alternately: best of each.
        bests: dict = {True: None, False: None}
        for r in range(repeats):
            for pipeline in (False, True):
                out = Path(tmp) / f"out{r}{pipeline:d}"
                s = observe_bag(mech, cfg, bag, out, log=lambda s: None, pipeline=pipeline).summary
                if bests[pipeline] is None or s.wall_total_s < bests[pipeline].wall_total_s:
                    bests[pipeline] = s
        best, seq = bests[True], bests[False]
        res = {k: getattr(best, k) for k in ("duration_s", "wall_read_s", "wall_filter_s", "wall_write_s",
                                             "wall_total_s", "speed_factor", "rows")}
        res["filter_speed_factor"] = best.duration_s / best.wall_filter_s
        res["sequential"] = {k: getattr(seq, k) for k in ("wall_read_s", "wall_filter_s", "wall_write_s",
                                                          "wall_total_s", "speed_factor")}
        res["sequential"]["filter_speed_factor"] = seq.duration_s / seq.wall_filter_s
        # The command as a user runs it (new process: imports and numba cache loading included).
        t0 = time.perf_counter()
        cmd = [sys.executable, "-c", CLI,
               "observe", "--model", str(ROOT / "config" / "five_bar.yaml"), "--bag", str(bag), "--out",
               str(Path(tmp) / "cli")]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        res["cli_wall_s"] = time.perf_counter() - t0
        res["cli_status"] = proc.returncode
        res["cli_stdout"] = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else proc.stderr.strip()[-300:]
    return res


SMOOTHER_SPECS = [RecordingSpec(duration=1.0, spectrum=spectrum, disturbance_rms=0.02, seed=9501 + i)
                  for i, spectrum in enumerate(("flat", "pink", "tones", "drift"))]
SMOOTHER_SPECS += [RecordingSpec(motion="chirp", duration=1.0, spectrum="pink", disturbance_rms=0.02, seed=9505),
                   RecordingSpec(duration=1.0, spectrum="pink", disturbance_rms=0.02, seed=9506, t0=1.7e9)]


def smoother_cost(mech, seconds: float, repeats: int) -> dict:
    """Wall times of ``observe --smoother rts`` over a ``seconds`` long bag (best total of ``repeats``)."""
    rec = manoeuvre_recording(mech, duration=seconds, seed=11, truth_dt=1e-4)
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
    best = None
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "in"
        recording_to_bag(rec, bag, use=("encoders", "imu"))
        warm = Path(tmp) / "warm"
        recording_to_bag(manoeuvre_recording(mech, duration=0.05, seed=11), warm, use=("encoders", "imu"))
        observe_bag(mech, cfg, warm, Path(tmp) / "warm_out", log=lambda s: None, smoother="rts")
        for r in range(repeats):
            plain = observe_bag(mech, cfg, bag, Path(tmp) / f"plain{r}", log=lambda s: None, pipeline=False).summary
            s = observe_bag(mech, cfg, bag, Path(tmp) / f"rts{r}", log=lambda s: None, smoother="rts").summary
            if best is None or s.wall_total_s < best["smoothed"].wall_total_s:
                best = {"plain": plain, "smoothed": s}
    p, s = best["plain"], best["smoothed"]
    sm = s.smoothing
    return {"duration_s": s.duration_s, "rows": s.rows, "wall_filter_s": s.wall_filter_s,
            "wall_replay_s": sm["wall_replay_s"], "wall_smooth_s": sm["wall_smooth_s"],
            "wall_total_s": s.wall_total_s, "wall_total_without_s": p.wall_total_s,
            "speed_factor": s.speed_factor, "speed_factor_without": p.speed_factor,
            "smooth_us_per_row": 1e6 * sm["wall_smooth_s"] / max(s.rows, 1),
            "branch_force_std_ratio_mean": sm["branch_force_std_ratio_mean"]}


def smoother_accuracy(mech, specs: list[RecordingSpec]) -> list[dict]:
    rows = []
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
    with tempfile.TemporaryDirectory() as tmp:
        for spec in specs:
            rec = generate(mech, spec)
            ol, F_qs = open_loop(rec), quasi_static_series(rec)
            bag = write_bag(rec, Path(tmp) / spec.name, use=("encoders", "imu"))
            res = observe_bag(mech, cfg, bag, None, log=lambda s: None, smoother="rts")
            f = score(rec, offline_run(rec, res.filtered), ol, F_qs, settle=0.05)
            s = score(rec, offline_run(rec, res.rows), ol, F_qs, settle=0.05)
            rows.append({"recording": spec.name, "elastic_rms_N": f["elastic_rms_N"],
                         "F_ratio_open_loop": f["F_ratio_open_loop"], "F_ratio_filtered": f["F_ratio"],
                         "F_ratio_smoothed": s["F_ratio"], "smoothed_over_filtered": s["F_ratio"] / f["F_ratio"],
                         "motor_filtered": f["motor_rmse_over_noise"], "motor_smoothed": s["motor_rmse_over_noise"],
                         "nees_in_band_filtered": f["nees_in_band"], "nees_in_band_smoothed": s["nees_in_band"],
                         "std_ratio": res.summary.smoothing["branch_force_std_ratio_mean"],
                         "fault": res.summary.fault})
            print(f"{spec.name}: F err / elastic {f['F_ratio']:.3f} -> {s['F_ratio']:.3f}", flush=True)
    return rows


def smoother_markdown(result: dict) -> str:
    c = result["cost"]
    lines = [f"RTS smoother (`observe --smoother rts`, encoders + accelerometer), {result['when']} on "
             f"{result['machine']} (load {result['load']}).", "",
             f"Cost over a {c['duration_s']:.1f} s bag ({c['rows']} rows): filter {c['wall_filter_s']:.2f} s, "
             f"smoother {c['wall_smooth_s']:.2f} s (of which the replay of the filter's predictions "
             f"{c['wall_replay_s']:.2f} s; {c['smooth_us_per_row']:.0f} us per row); `observe` in total "
             f"{c['wall_total_s']:.2f} s = {c['speed_factor']:.1f}x real time (without the smoother "
             f"{c['wall_total_without_s']:.2f} s, {c['speed_factor_without']:.1f}x, one stage after the other).", "",
             "| recording | elastic RMS [N] | open loop | F err / elastic, filtered | smoothed | smoothed / filtered | "
             "motor err / noise (filt., smoothed) | NEES in band (filt., smoothed) | F std smoothed / filtered |",
             "|---|---:|---:|---:|---:|---:|---|---|---:|"]
    for r in result["accuracy"]:
        lines.append(f"| {r['recording']} | {r['elastic_rms_N']:.4f} | {r['F_ratio_open_loop']:.3f} | "
                     f"{r['F_ratio_filtered']:.3f} | {r['F_ratio_smoothed']:.3f} | "
                     f"**{r['smoothed_over_filtered']:.2f}** | {r['motor_filtered']:.2f}, {r['motor_smoothed']:.2f} | "
                     f"{r['nees_in_band_filtered']:.2f}, {r['nees_in_band_smoothed']:.2f} | {r['std_ratio']:.2f} |")
    ratios = [r["smoothed_over_filtered"] for r in result["accuracy"]]
    lines += ["", f"Median smoothed / filtered branch-force error: {np.median(ratios):.2f}."]
    return "\n".join(lines)


def smoother_main(args: argparse.Namespace, mech) -> int:
    result = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": f"{platform.processor() or platform.machine()} "
              f"({os.cpu_count()} cores)", "load": " ".join(f"{x:.2f}" for x in os.getloadavg())}
    result["cost"] = smoother_cost(mech, 2.0 if args.quick else 5.0, 1 if args.quick else 3)
    specs = [s.with_(duration=0.5) for s in SMOOTHER_SPECS[:2]] if args.quick else SMOOTHER_SPECS
    result["accuracy"] = smoother_accuracy(mech, specs)
    md = smoother_markdown(result)
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer_smoother.json").write_text(json.dumps(result, indent=2, default=float))
    (out / "observer_smoother.md").write_text(md + "\n")
    return 0


def markdown(result: dict) -> str:
    lines = [f"Five-bar observer, {result['when']} on {result['machine']} (load {result['load']}); "
             f"numpy {result['numpy']}, numba {result['numba']}.", "",
             "| scenario | sensors | seed | F err / elastic RMS | open loop | ratio to open loop | "
             "motor err / enc. noise | NEES in 95 % band | gated |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["accuracy"]:
        lines.append(f"| {r['scenario']} | {r['sensors']} | {r['seed']} | {r['F_ratio']:.3f} | "
                     f"{r['F_ratio_open_loop']:.3f} | {r['vs_open_loop']:.2f} | {r['motor_rmse_over_noise']:.2f} | "
                     f"{r['nees_in_band']:.2f} | {r['rejected']} |")
    lines += ["", "| one live period (predict 1 ms + corrections + command) | median [us] | p90 [us] |",
              "|---|---:|---:|"]
    for k, v in result["update_times"].items():
        lines.append(f"| {k} | {v['median_us']:.0f} | {v['p90_us']:.0f} |")
    o = result["offline"]
    lines += ["", f"`observe` over a {o['duration_s']:.1f} s bag (encoders + imu, {o['rows']} rows): read "
              f"{o['wall_read_s']:.2f} s, filter {o['wall_filter_s']:.2f} s, write {o['wall_write_s']:.2f} s, "
              f"total {o['wall_total_s']:.2f} s -> **{o['speed_factor']:.1f}x real time** (filter alone "
              f"{o['filter_speed_factor']:.1f}x); as a command in a new process {o['cli_wall_s']:.2f} s "
              f"(status {o['cli_status']})."]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed, few rounds, a 2 s bag")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    ap.add_argument("--smoother", action="store_true", help="the RTS smoother's cost and accuracy only")
    args = ap.parse_args()
    mech = Mechanism(load_model(ROOT / "config" / "five_bar.yaml"))
    if args.smoother:
        return smoother_main(args, mech)
    # Warm-up (compiles or loads the cached kernels).
    warm = manoeuvre_recording(mech, duration=0.05)
    feed(Observer(mech, ObserverConfig.from_parameters({})), warm, ("encoders", "imu"))
    seeds = [1] if args.quick else [1, 2, 3, 4, 5, 6]
    result = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": f"{platform.processor() or platform.machine()} "
              f"({os.cpu_count()} cores)", "load": " ".join(f"{x:.2f}" for x in os.getloadavg()),
              "numpy": np.__version__, "numba": __import__("numba").__version__}
    result["accuracy"] = accuracy(mech, seeds)
    result["update_times"] = update_times(mech, manoeuvre_recording(mech, seed=4), 2 if args.quick else 5)
    result["offline"] = offline_speed(mech, 2.0 if args.quick else 5.0, 1 if args.quick else 3)
    md = markdown(result)
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer.json").write_text(json.dumps(result, indent=2, default=float))
    (out / "observer.md").write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
