"""How long ``elastic-pm-dyn tune`` takes on a 5 s recording, and what it gains.

    .venv/bin/python bench/benchmarks/bench_tune.py            # 5 s recording, ~1-2 min on 2 cores
    .venv/bin/python bench/benchmarks/bench_tune.py --duration 2

A held-out test recording (``observer.testing.recordings``: the reference manoeuvre under a flat
0.1 N m disturbance, where the defaults fail) is written as a bag; ``elastic-pm-dyn tune``
runs on it with encoders + accelerometer (its defaults: the whole recording, two filter
passes at once), then ``observe`` with the default and with the tuned file. Reports the
tuning's wall time, filter passes and time per pass, the NLL before and after, and the
branch-force error against the open loop (the truth is used for scoring only). Writes ``bench/results/bench_tune.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from elastic_pm_dyn.cli import main as cli_main  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.observer import ObserverConfig  # noqa: E402
from elastic_pm_dyn.observer.config import load_config  # noqa: E402
from elastic_pm_dyn.observer.offline import observe_bag  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import offline_run, open_loop, quasi_static_series, score  # noqa: E402
from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag  # noqa: E402

MODEL = ROOT / "config" / "five_bar.yaml"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=5.0, help="[s] of the recording")
    ap.add_argument("--seed", type=int, default=8501)
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    args = ap.parse_args()
    mech = Mechanism(load_model(MODEL))
    spec = RecordingSpec(duration=args.duration, spectrum="flat", disturbance_rms=0.1, seed=args.seed)
    rec = generate(mech, spec)
    ol, F_qs = open_loop(rec), quasi_static_series(rec)
    with tempfile.TemporaryDirectory() as tmp:
        bag = write_bag(rec, Path(tmp) / "rec")
        tuned = Path(tmp) / "tuned.yaml"
        wall = time.perf_counter()
        text = io.StringIO()
        with contextlib.redirect_stdout(text):
            status = cli_main(["tune", "--model", str(MODEL), "--bag", str(bag), "--out", str(tuned),
                               "--sensors", "encoders", "imu"])
        wall = time.perf_counter() - wall
        print(text.getvalue())
        if status:
            return status
        passes = int(re.search(r"\((\d+) filter passes\)", text.getvalue()).group(1))
        scores = {}
        for name, cfg in (("default", ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})),
                          ("tuned", load_config(tuned))):
            res = observe_bag(mech, cfg, bag, None, log=lambda s: None)
            s = score(rec, offline_run(rec, res.rows), ol, F_qs, settle=0.05)
            scores[name] = {"vs_open_loop": s["F_ratio"] / s["F_ratio_open_loop"], "nees_in_band": s["nees_in_band"],
                            "gated": {k: v.rejected for k, v in res.observer.stats.items()},
                            "observe_wall_s": res.summary.wall_total_s}
    result = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
              "machine": f"{platform.processor() or platform.machine()} ({os.cpu_count()} cores)",
              "load": " ".join(f"{x:.2f}" for x in os.getloadavg()), "recording": spec.name,
              "duration_s": args.duration, "tune_wall_s": wall, "filter_passes": passes,
              "wall_per_pass_s": wall / passes, "scores": scores}
    print(json.dumps(result, indent=2, default=float))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_tune.json").write_text(json.dumps(result, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
