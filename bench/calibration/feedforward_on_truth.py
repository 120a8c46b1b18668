"""Issue #42's figure: the held elastic feedforward of the nominal file and of the calibrated file,
each run open loop on the true (perturbed) five-bar, judged by DOP853.

    PYTHONPATH=. .venv/bin/python bench/calibration/feedforward_on_truth.py [--cases five_bar_A triglide_A ...]

The true machine is the case's factors on its model file (bench_calibrate.py's CASES); the
calibrated file is bench/calibration/results/<case>.yaml (written by bench_calibrate.py). The true
machine starts at rest on the path's start (held there by its own springs and the table's first
sample's motors: a controller handed over to the feedforward). Path error: the largest distance
from the path's point at the same time during the move and 0.1 s after (``tracking``); end error:
the largest distance from the end point over the 0.3 s hold (``drift``). Moves not used anywhere in
the calibration. The five-bar at 1 kHz, the Triglide (n_ek = 1) at 2 kHz and the Hexa at 1 kHz, each
at its command rate (issue #42), the Triglide's and the Hexa's moves from bench/benchmarks/bench_feedforward.py.
Adds the cases run to bench/calibration/results/feedforward_on_truth.json and prints the table.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(HERE))

from bench_calibrate import CASES  # noqa: E402

from elastic_pm_dyn.analysis.feedforward_check import exactness  # noqa: E402
from elastic_pm_dyn.calibration.parameters import ModelFile, available  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.motion.poses import PoseLine  # noqa: E402
from elastic_pm_dyn.motion.task import Task  # noqa: E402
from elastic_pm_dyn.motion.trajectory import make_line  # noqa: E402
from elastic_pm_dyn.sim.held_feedforward import feedforward_table  # noqa: E402
from elastic_pm_dyn.sim.held_inverse import rest_state  # noqa: E402
from elastic_pm_dyn.sim.simulator import SimulationOptions  # noqa: E402

HOLD, AFTER = 0.3, 0.1
DEG = np.pi / 180
MOVES = {  # per model file: (label, start, end, move duration [s]), and the command rate [Hz]
    "config/five_bar.yaml": ([("across 0.2 s", (-0.05, 0.39), (0.05, 0.39), 0.2),
                              ("short 60 ms", (0.015, 0.36), (-0.01, 0.385), 0.06)], 1000.0),
    "config/triglide.yaml": ([("reference 0.2 s", (0, 0, -0.35), (0.03, 0.02, -0.32), 0.2),
                              ("down-back 0.15 s", (0, 0, -0.35), (-0.02, 0.03, -0.37), 0.15)], 2000.0),
    "config/hexa.yaml": ([("reference 0.2 s", (0, 0, -0.4, 0, 0, 0), (0.02, 0.02, -0.385, 5 * DEG, 0, 0), 0.2),
                          ("tilt 0.25 s", (0, 0, -0.4, 0, 0, 0), (-0.02, 0.01, -0.39, 0, 3 * DEG, -3 * DEG), 0.25)],
                         1000.0),
}
OPTIONS = SimulationOptions(integrator="dop853", rtol=1e-9, atol=1e-12, sample=1e-4)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", nargs="+", default=["five_bar_A", "five_bar_B", "five_bar_C"], choices=list(CASES))
    args = ap.parse_args()
    out = HERE / "results" / "feedforward_on_truth.json"
    rows = [r for r in (json.loads(out.read_text()) if out.exists() else []) if r["case"] not in args.cases]
    for case in args.cases:
        c = CASES[case]
        moves, rate = MOVES[c["path"]]
        mf = ModelFile.read(REPO / c["path"])
        params = available(mf)
        truth = Mechanism(mf.model(params, [p.nominal * c["factors"].get(p.name, 1.0) for p in params]))
        models = {"nominal": load_model(str(REPO / c["path"])),
                  "calibrated": load_model(str(HERE / "results" / f"{case}.yaml"))}
        for label, start, end, move in moves:
            a, b = np.array(start, dtype=float), np.array(end, dtype=float)
            path = PoseLine(a, b, move, HOLD, 4) if len(a) == 6 else make_line(a, b, move, HOLD, 4)
            row = {"case": case, "move": label, "rate_hz": rate}
            for name, model in models.items():
                times, values, _, q0 = feedforward_table(model, path, rate, "elastic", inverse="held")
                # the true machine at rest on the path's start, and its static branch forces at the end
                q_start, _ = rest_state(truth, Task(truth), np.asarray(path(0.0)[0]), q0)
                q_end, _ = rest_state(truth, Task(truth), np.asarray(path(path.duration)[0]), q0)
                static = truth.branch_forces(q_end, np.zeros(truth.n))
                s = exactness(truth, times, values, q_start, path, move, path.duration, static, OPTIONS, AFTER)
                row[name] = {"path_m": s.tracking, "end_m": s.drift, "contour_m": s.contour}
            row["path_ratio"] = row["calibrated"]["path_m"] / row["nominal"]["path_m"]
            row["end_ratio"] = row["calibrated"]["end_m"] / row["nominal"]["end_m"]
            rows.append(row)
            nom, cal = row["nominal"], row["calibrated"]
            print(f"{case} {label}: path {nom['path_m'] * 1e6:.3g} -> {cal['path_m'] * 1e6:.3g}"
                  f" um ({row['path_ratio']:.3g}), end {row['nominal']['end_m'] * 1e6:.3g} -> "
                  f"{row['calibrated']['end_m'] * 1e6:.3g} um ({row['end_ratio']:.3g})", flush=True)
    out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
