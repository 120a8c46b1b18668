"""The observer, default configuration, on test recordings it was not tuned on.

    .venv/bin/python bench/studies/observer_recordings.py            # the full matrix, ~10-15 min on 2 cores
    .venv/bin/python bench/studies/observer_recordings.py --quick    # 4 short recordings, < 2 min
    .venv/bin/python bench/studies/observer_recordings.py --quick --tune  # each tuned first (elastic-pm-dyn tune)
    .venv/bin/python bench/studies/observer_recordings.py --hard --tune   # where the defaults fail, ~15 min

Recordings (``elastic_pm_dyn.observer.testing.recordings``; seeds 7001... held out from every seed
the observer's defaults were fitted on): the reference manoeuvre and a 3 N m chirp through
the spring mode, 1 s each, with a flat, 1/f, few-tone or drifting torque disturbance of
0.02 or 0.1 N m RMS per motor, and five ways of recording them (:data:`WAYS`: accelerometer
sample before or after the command of t_k acts, command delay 0 or 1 period, stamps from 0
or from an epoch, 1.7e9 s): 80 recordings; ``--quick``: four of 0.5 s. Every bag written
with receive times after the stamps, mcap and sqlite3 alternately. ``observe``
(``observe_bag``, the default configuration, only ``sensors`` set) runs on each with
encoders / encoders + imu / encoders + gauges.

Per recording and sensor set: branch-force error RMS / RMS of the elastic part (F - F_qs),
the same ratio for the open loop (the elastic model driven by the commands as they acted,
without the disturbance: ``observer.testing.evaluation.open_loop``; with a command delay also as
stamped, as the observer applies them: in the JSON) and filter / open loop,
motor-angle error RMS / encoder noise, fraction of samples whose NEES of [q_ae, qd_ae] lies
in its 95 % band, mean NIS per sensor over its dof, gated samples per sensor, whether the
CSV's t column tells the stamps apart; all after 50 ms of settling. The truth's convergence
is checked once (RK4 at 25 us against 12.5 us on the first recording).
``--tune``: before each observe run, the configuration is tuned to the bag with that sensor
set (``observer.tuning.tuning.tune``, what ``elastic-pm-dyn tune`` does: no truth), and the table
has the default's figures beside the tuned ones.
Writes ``bench/results/observer_recordings.json`` and ``observer_recordings.md``
(``observer_recordings_tuned.*`` with ``--tune``).
"""

from __future__ import annotations

import argparse
import itertools
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

from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.observer import ObserverConfig  # noqa: E402
from elastic_pm_dyn.observer.drivers.bag_input import Topics, read_events  # noqa: E402
from elastic_pm_dyn.observer.drivers.results import SENSORS  # noqa: E402
from elastic_pm_dyn.observer.offline import observe_bag  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import offline_run, open_loop, quasi_static_series, score  # noqa: E402
from elastic_pm_dyn.observer.testing.recordings import EPOCH, RecordingSpec, generate, write_bag  # noqa: E402
from elastic_pm_dyn.observer.tuning import tuning  # noqa: E402

SETS = {"encoders": ("encoders",), "encoders+imu": ("encoders", "imu"),
        "encoders+gauges": ("encoders", "branch_forces")}
SETTLE = 0.05  # [s]
# (accelerometer timing, command delay [periods], stamp origin [s])
WAYS = [("before_command", 0, 0.0), ("after_command", 0, 0.0), ("before_command", 1, 0.0),
        ("before_command", 0, EPOCH), ("after_command", 1, EPOCH)]


def hard() -> list[RecordingSpec]:
    """Where the defaults fail (bench/README.md): 0.1 N m flat, 1/f or tones under the manoeuvre
    (the accelerometer drags the filter off), and a one-period command delay; seeds 7201...
    held out from the full matrix's."""
    base = RecordingSpec(duration=1.0, disturbance_rms=0.1, seed=7201)
    return [base, base.with_(spectrum="pink", seed=7202), base.with_(spectrum="tones", seed=7203),
            base.with_(disturbance_rms=0.02, command_delay=1, seed=7204),
            base.with_(motion="chirp", spectrum="pink", disturbance_rms=0.02, command_delay=1, seed=7205)]


def matrix(quick: bool, hard_only: bool = False) -> list[RecordingSpec]:
    if hard_only:
        return hard()
    if quick:
        base = RecordingSpec(duration=0.5, disturbance_rms=0.02, seed=7001)
        return [base, base.with_(accel_timing="after_command", seed=7002),
                base.with_(t0=EPOCH, disturbance_rms=0.1, seed=7003),
                base.with_(motion="chirp", spectrum="pink", command_delay=1, seed=7004)]
    specs = []
    seed = 7001
    for motion, spectrum, rms, (timing, delay, t0) in itertools.product(
            ("manoeuvre", "chirp"), ("flat", "pink", "tones", "drift"), (0.02, 0.1), WAYS):
        specs.append(RecordingSpec(motion=motion, duration=1.0, spectrum=spectrum, disturbance_rms=rms, seed=seed,
                                   accel_timing=timing, command_delay=delay, t0=t0))
        seed += 1
    return specs


def convergence(mech, spec: RecordingSpec) -> dict:
    """Largest truth difference between RK4 at the spec's step and at half of it, over the noise."""
    a, b = generate(mech, spec), generate(mech, spec.with_(truth_dt=spec.truth_dt / 2))
    n, act = spec.noise, mech.active
    return {"recording": spec.name, "dt": [spec.truth_dt, spec.truth_dt / 2],
            "motor_angle_over_encoder_noise": float(np.abs(a.q[:, act] - b.q[:, act]).max() / n.encoder),
            "accel_over_noise": float(np.abs(a.accel_true - b.accel_true).max() / n.accelerometer),
            "branch_force_over_noise": float(np.abs(a.F - b.F).max() / n.branch_force)}


def csv_distinct_t(out: Path) -> bool:
    """Does the t column of estimates.csv hold one value per row (the stamps told apart)?"""
    t = np.loadtxt(out / "estimates.csv", delimiter=",", skiprows=1, usecols=0, ndmin=1)
    return len(np.unique(t)) == len(t)


def tuned_config(mech, cfg: ObserverConfig, bag: Path) -> tuple[ObserverConfig, dict]:
    """``cfg`` tuned to ``bag`` as ``elastic-pm-dyn tune`` does (defaults), and what it found."""
    events = tuning.select(read_events(bag, Topics.from_config(cfg), cfg)[0], None)
    res = tuning.tune(mech, cfg, events, log=lambda s: None)
    info = {"changed": {k: [a, b] for k, (a, b) in res.changed.items()}, "nll": [res.before.nll, res.after.nll],
            "evaluations": res.evaluations, "wall_s": res.wall_s}
    return ObserverConfig.from_parameters(res.params, "<tuned>"), info


def one_recording(mech, spec: RecordingSpec, storage: str, tmp: Path, tune: bool = False) -> list[dict]:
    rec = generate(mech, spec)
    ol, F_qs = open_loop(rec), quasi_static_series(rec)
    # the open loop as the observer applies the commands (from their stamps): differs only with a delay
    ol_stamped = open_loop(rec, as_acted=False) if spec.command_delay else ol
    bag = write_bag(rec, tmp / f"{spec.name}_{storage}", storage)
    keep = rec.t >= rec.t[0] + SETTLE - 1e-12
    rows = []
    for name, sensors in SETS.items():
        cfg = ObserverConfig.from_parameters({"sensors": list(sensors)})
        default = None
        if tune:
            res = observe_bag(mech, cfg, bag, None, log=lambda s: None, write_estimates_bag=False)
            d = score(rec, offline_run(rec, res.rows), ol, F_qs, settle=SETTLE)
            default = {"vs_open_loop": d["F_ratio"] / d["F_ratio_open_loop"], "nees_in_band": d["nees_in_band"],
                       "gated": {k: v.rejected for k, v in res.observer.stats.items() if k in sensors}}
            cfg, default["tuning"] = tuned_config(mech, cfg, bag)
        out = tmp / f"{spec.name}_{name}"
        res = observe_bag(mech, cfg, bag, out, log=lambda s: None, write_estimates_bag=False)
        run = offline_run(rec, res.rows)
        s = score(rec, run, ol, F_qs, settle=SETTLE)
        s_stamped = score(rec, run, ol_stamped, F_qs, settle=SETTLE) if spec.command_delay else s
        smoothed = None
        if tune:  # the offline user's best estimate: the RTS smoother over the tuned filter
            sm = observe_bag(mech, cfg, bag, None, log=lambda s: None, write_estimates_bag=False, smoother="rts")
            ss = score(rec, offline_run(rec, sm.rows), ol, F_qs, settle=SETTLE)
            smoothed = {"vs_open_loop": ss["F_ratio"] / ss["F_ratio_open_loop"], "nees_in_band": ss["nees_in_band"]}
        timing = res.summary.sample_timing["in_use"] if "imu" in sensors else None
        nis = np.array(res.rows.nis, dtype=float)
        stamps = np.asarray(res.rows.t, dtype=np.int64)
        late = stamps >= rec.stamp_ns[keep][0]
        per_sensor = {}
        for j, sensor in enumerate(SENSORS):
            st = res.observer.stats.get(sensor)
            if sensor not in sensors or st is None:
                continue
            vals = nis[late, j]
            vals = vals[np.isfinite(vals)]
            dof = sum(d for _, d in st.window) / len(st.window) if st.window else float("nan")
            per_sensor[sensor] = {"mean_nis": float(np.mean(vals)) if len(vals) else float("nan"), "dof": dof,
                                  "accepted": st.accepted, "gated": st.rejected}
        rows.append({
            "recording": spec.name, "motion": spec.motion, "spectrum": spec.spectrum,
            "disturbance_rms": spec.disturbance_rms, "seed": spec.seed, "accel_timing": spec.accel_timing,
            "command_delay": spec.command_delay, "t0": spec.t0, "storage": storage, "sensors": name,
            "F_ratio": s["F_ratio"], "F_ratio_open_loop": s["F_ratio_open_loop"],
            "F_ratio_open_loop_stamped": s_stamped["F_ratio_open_loop"],
            "vs_open_loop": s["F_ratio"] / s["F_ratio_open_loop"], "elastic_rms_N": s["elastic_rms_N"],
            "motor_rmse_over_noise": s["motor_rmse_over_noise"], "nees_in_band": s["nees_in_band"],
            "nees_mean": s["nees_mean"], "sensors_nis": per_sensor, "fault": res.summary.fault,
            "health": list(res.summary.health), "csv_t_distinct": csv_distinct_t(out), "default": default,
            "smoothed": smoothed, "sample_timing": timing})
    return rows


def _f(x: float, fmt: str = ".3f") -> str:
    return "nan" if x != x else format(x, fmt)


def _timing_found(row: dict) -> str:
    """Did ``auto`` end on the accelerometer's true sample timing ("-" without accelerometer)?"""
    if row.get("sample_timing") is None:
        return "-"
    return "yes" if row["sample_timing"] == row["accel_timing"] else f"no ({row['sample_timing']})"


def markdown(result: dict) -> str:
    c = result["convergence"]
    what = "tuned to each recording (elastic-pm-dyn tune)" if result.get("tune") else "default configuration"
    lines = [f"Observer ({what}) on independent recordings, {result['when']} on {result['machine']}; "
             f"{len(result['rows']) // len(SETS)} recordings, {result['wall_s']:.0f} s. Truth converged: RK4 "
             f"{c['dt'][0]:g} s vs {c['dt'][1]:g} s differ by at most {c['motor_angle_over_encoder_noise']:.1e} "
             f"encoder noise, {c['accel_over_noise']:.1e} accelerometer noise, {c['branch_force_over_noise']:.1e} "
             f"gauge noise.", "",
             "| recording | sensors | elastic RMS [N] | F err / elastic | open loop | filter / open loop | "
             "motor err / noise | NEES in band | NIS / dof (enc, imu, gauges) | gated (enc, imu, gauges) | CSV t ok |",
             "|---|---|---:|---:|---:|---:|---:|---:|---|---|:-:|"]
    if result.get("tune"):
        lines[-2] = lines[-2].replace("filter / open loop |", "filter / open loop (default) | smoother / open loop |"
                                      ).replace("NEES in band |", "NEES in band (default) |").replace(
            "CSV t ok |", "CSV t ok | timing found |")
        lines[-1] += "---:|:-:|"
    for r in result["rows"]:
        ns = r["sensors_nis"]
        nis = ", ".join(_f(ns[s]["mean_nis"] / ns[s]["dof"], ".2f") if s in ns else "-" for s in SENSORS)
        gated = ", ".join(str(ns[s]["gated"]) if s in ns else "-" for s in SENSORS)
        d = r.get("default")
        vs = _f(r["vs_open_loop"], ".2f") + (f" ({_f(d['vs_open_loop'], '.2f')})" if d else "")
        if r.get("smoothed"):
            vs += f" | {_f(r['smoothed']['vs_open_loop'], '.2f')}"
        nees = _f(r["nees_in_band"], ".2f") + (f" ({_f(d['nees_in_band'], '.2f')})" if d else "")
        lines.append(f"| {r['recording']} | {r['sensors']} | {_f(r['elastic_rms_N'])} | {_f(r['F_ratio'])} | "
                     f"{_f(r['F_ratio_open_loop'])} | {vs} | "
                     f"{_f(r['motor_rmse_over_noise'], '.1f')} | {nees} | {nis} | {gated} | "
                     f"{'yes' if r['csv_t_distinct'] else 'no'} |"
                     + (f" {_timing_found(r)} |" if result.get("tune") else ""))
    lines += ["", "Medians per sensor set (filter / open loop; NEES in band):", ""]
    for name in SETS:
        sub = [r for r in result["rows"] if r["sensors"] == name]
        line = (f"- {name}: {np.nanmedian([r['vs_open_loop'] for r in sub]):.2f}; "
                f"{np.nanmedian([r['nees_in_band'] for r in sub]):.2f}")
        if result.get("tune"):
            line += (f"; smoother / open loop {np.nanmedian([r['smoothed']['vs_open_loop'] for r in sub]):.2f}"
                     f" (default: {np.nanmedian([r['default']['vs_open_loop'] for r in sub]):.2f}; "
                     f"{np.nanmedian([r['default']['nees_in_band'] for r in sub]):.2f}; tuning "
                     f"{np.median([r['default']['tuning']['wall_s'] for r in sub]):.0f} s median)")
        lines.append(line)
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4 recordings of 0.5 s")
    ap.add_argument("--tune", action="store_true", help="tune the configuration to each recording first")
    ap.add_argument("--hard", action="store_true", help="only the 5 recordings where the defaults fail")
    ap.add_argument("--every", type=int, default=1, metavar="K",
                    help="every K-th recording of the matrix only (with --tune: --every 6 is 14 recordings that "
                         "still cover both motions, all spectra, both amplitudes and every timing/delay/epoch way)")
    ap.add_argument("--offset", type=int, default=0, metavar="I",
                    help="with --every: start at the I-th recording (--every 6 --offset 3: 13 other recordings)")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    args = ap.parse_args()
    wall0 = time.perf_counter()
    mech = Mechanism(load_model(ROOT / "config" / "five_bar.yaml"))
    specs = matrix(args.quick, args.hard)[args.offset::max(1, args.every)]
    result = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": f"{platform.processor() or platform.machine()} "
              f"({os.cpu_count()} cores)", "load": " ".join(f"{x:.2f}" for x in os.getloadavg()),
              "quick": args.quick, "hard": args.hard, "tune": args.tune, "specs": [s.name for s in specs]}
    result["convergence"] = convergence(mech, specs[0].with_(duration=min(specs[0].duration, 0.5)))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, spec in enumerate(specs):
            rows += one_recording(mech, spec, ("mcap", "sqlite3")[i % 2], Path(tmp), args.tune)
            print(f"[{i + 1}/{len(specs)}] {spec.name}", flush=True)
    result["rows"] = rows
    result["wall_s"] = time.perf_counter() - wall0
    md = markdown(result)
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = ("observer_recordings" + ("_hard" if args.hard else "") + ("_tuned" if args.tune else "")
            + (f"_every{args.every}" if args.every > 1 else "") + (f"_offset{args.offset}" if args.offset else ""))
    (out / f"{stem}.json").write_text(json.dumps(result, indent=2, default=float))
    (out / f"{stem}.md").write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
