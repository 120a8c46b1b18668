"""Issue #42's figure: the held elastic feedforward of the nominal file and of the calibrated file,
each run open loop on the true (perturbed) five-bar, judged by DOP853.

    PYTHONPATH=. .venv/bin/python bench/calibration/feedforward_on_truth.py

The true machine is the case's factors on config/five_bar.yaml (bench_calibrate.py's CASES); the
calibrated file is bench/calibration/results/<case>.yaml (written by bench_calibrate.py). The true
machine starts at rest on the path's start (held there by its own springs and the table's first
sample's motors: a controller handed over to the feedforward). Path error: the largest distance
from the path's point at the same time during the move and 0.1 s after (``tracking``); end error:
the largest distance from the end point over the 0.3 s hold (``drift``). Moves not used anywhere in
the calibration. Writes bench/calibration/results/feedforward_on_truth.json and prints the table.
"""

from __future__ import annotations

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
from elastic_pm_dyn.motion.task import Task  # noqa: E402
from elastic_pm_dyn.motion.trajectory import make_line  # noqa: E402
from elastic_pm_dyn.sim.held_feedforward import feedforward_table  # noqa: E402
from elastic_pm_dyn.sim.held_inverse import rest_state  # noqa: E402
from elastic_pm_dyn.sim.simulator import SimulationOptions  # noqa: E402

RATE, HOLD, AFTER = 1000.0, 0.3, 0.1
MOVES = [("across 0.2 s", (-0.05, 0.39), (0.05, 0.39), 0.2), ("short 60 ms", (0.015, 0.36), (-0.01, 0.385), 0.06)]
OPTIONS = SimulationOptions(integrator="dop853", rtol=1e-9, atol=1e-12, sample=1e-4)


def main() -> None:
    rows = []
    for case in ("five_bar_A", "five_bar_B", "five_bar_C"):
        c = CASES[case]
        mf = ModelFile.read(REPO / c["path"])
        params = available(mf)
        truth = Mechanism(mf.model(params, [p.nominal * c["factors"].get(p.name, 1.0) for p in params]))
        models = {"nominal": load_model(str(REPO / c["path"])),
                  "calibrated": load_model(str(HERE / "results" / f"{case}.yaml"))}
        for label, start, end, move in MOVES:
            path = make_line(np.array(start), np.array(end), move, HOLD, 4)
            row = {"case": case, "move": label}
            for name, model in models.items():
                times, values, _, q0 = feedforward_table(model, path, RATE, "elastic", inverse="held")
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
    (HERE / "results" / "feedforward_on_truth.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
