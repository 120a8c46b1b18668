"""The reference manoeuvre offline: rigid feedforward -> elastic model -> CSV, plots, summary.

Reproduces the paper's comparison (Figs. 2-4): the rigid model's torques of the
quintic line, sampled at 1 kHz and held (ZOH), drive the elastic five-bar computed by
L-D'A and by SCDD (exact, with and without projection; the paper's one-pass variant).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from elastic_pm_dyn.analysis import metrics, plots
from elastic_pm_dyn.analysis.paper import RUNS, simulate_reference
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.trajectory import QuinticLine
from elastic_pm_dyn.sim.torque import write_torque_csv


def run_offline_demo(out: Path, model_path: Path, line: QuinticLine = REFERENCE_MANOEUVRE.line) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    model = load_model(model_path)
    times, torques, names, results = simulate_reference(model, line)
    write_torque_csv(out / "torques.csv", times, torques, names)
    for label, (formulation, stab) in RUNS.items():
        slug = f"{formulation}_{stab}"
        results[label].to_csv(out / f"{slug}.csv")
        print(f"  {label:26s} -> {out / (slug + '.csv')}")

    reference = np.array([line(t)[0] for t in results["SCDD"].t])
    branch_names = [b.name for b in model.branches]
    plots.plot_path(out / "path.png", {k: r.ee for k, r in results.items()}, reference)
    plots.plot_branch_forces(
        out / "branch_forces.png", {k: r.t for k, r in results.items()},
        {k: {b: r.branch_forces[:, i] for i, b in enumerate(branch_names)} for k, r in results.items()},
        zoom=(line.move - 0.01, line.move + 0.04))
    plots.plot_gap(out / "gap.png", {k: r.t for k, r in results.items()}, {k: r.gap for k, r in results.items()})
    plots.plot_torques(out / "torques.png", times, {n: torques[:, i] for i, n in enumerate(names)})

    lda, scdd = results["L-D'A"], results["SCDD"]
    summary = {
        "model": str(model_path),
        "line": {"start": line.start.tolist(), "end": line.end.tolist(), "move_s": line.move, "hold_s": line.hold},
        "control_rate_hz": REFERENCE_MANOEUVRE.control_rate,
        "runs": {},
        "scdd_vs_lda": {
            "max_joint_difference": float(np.abs(scdd.q - lda.q).max()),
            "max_branch_force_difference_N": float(np.abs(scdd.branch_forces - lda.branch_forces).max()),
        },
    }
    for label, r in results.items():
        hold = r.t >= line.move
        vib = metrics.residual_vibration(r.t, r.branch_forces[:, 0], line.move, f_hint=550.0)
        summary["runs"][label] = {
            "max_path_deviation_m": float(metrics.straight_line_deviation(r.ee, line.start, line.end).max()),
            "final_position_error_m": float(np.linalg.norm(r.ee[-1] - line.end)),
            "peak_branch_force_N": {b: float(np.abs(r.branch_forces[:, i]).max()) for i, b in enumerate(branch_names)},
            "hold_vibration_hz": vib.f_d,
            "hold_damping_ratio": vib.zeta,
            "max_gap_m": float(r.gap.max()),
            "final_gap_m": float(r.gap[-1]),
            "hold_gap_growth_m": float(r.gap[hold][-1] - r.gap[hold][0]),
        }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"plots and summary.json in {out}")
    return summary
