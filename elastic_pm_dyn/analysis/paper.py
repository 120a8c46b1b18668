"""``elastic-pm-dyn paper-figures``: the seed paper's comparison (Figs. 2-4) on the reference five-bar.

The rigid model's feedforward torques of the reference manoeuvre (1 kHz, zero-order
hold) drive the elastic model computed by L-D'A and by SCDD (exact, with and without
projection; the paper's one-pass variant): :func:`simulate_reference`, the entries of :data:`RUNS`.
The runs go through the same metrics and plots as a bag (:mod:`report`), the figures
named after the paper; ``paper_figures.json`` holds the numbers behind each figure and
``fig*.csv`` the plotted series.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from elastic_pm_dyn.analysis.report import PLOT_NAMES, write_report
from elastic_pm_dyn.analysis.report_types import AnalysisReport, clean
from elastic_pm_dyn.analysis.run_data import ModelInfo, RunData, run_from_simulation
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.feedforward import line_torques
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.trajectory import QuinticLine
from elastic_pm_dyn.output_files import staged_files
from elastic_pm_dyn.sim.result import SimulationResult
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import TorqueTable

RUNS = {  # label: (formulation, stabilisation)
    "L-D'A": ("lda", "none"),
    "SCDD": ("scdd", "projection"),
    "SCDD (no stabilisation)": ("scdd", "none"),
    "SCDD one-pass (paper)": ("scdd_one_pass", "none"),
}
PAPER_NAMES = {**PLOT_NAMES, "path": "fig2_path.png", "branch_forces": "fig3_branch_forces.png",
               "gap": "fig4_gap.png"}


def simulate_reference(model: Model, line: QuinticLine = REFERENCE_MANOEUVRE.line, runs: dict = RUNS,
                       sample: float = REFERENCE_MANOEUVRE.sample
                       ) -> tuple[np.ndarray, np.ndarray, list[str], dict[str, SimulationResult]]:
    """The rigid feedforward torques of ``line`` (held, ZOH) driving the elastic model once per entry of
    ``runs`` (label: (formulation, stabilisation)). Returns (times, torques, motor names, results)."""
    mech = Mechanism(model)
    times, torques, names = line_torques(model, line, REFERENCE_MANOEUVRE.control_rate)
    table = TorqueTable(times, torques, "zoh")
    results = {}
    for label, (formulation, stab) in runs.items():
        sim = Simulator(mech, SimulationOptions(formulation=formulation, stabilization=stab, sample=sample))
        results[label] = sim.run(table, line.duration)
    return times, torques, names, results


def paper_figures(out: Path, model_path: Path, line: QuinticLine = REFERENCE_MANOEUVRE.line, runs: dict = RUNS,
                  sample: float = REFERENCE_MANOEUVRE.sample) -> dict:
    """Simulate, then write the figures, ``summary.json``/``.md``, ``paper_figures.json`` and CSVs
    (all of them, or none: :func:`~elastic_pm_dyn.output_files.staged_files`)."""
    info = ModelInfo.load(model_path)
    times, torques, _, results = simulate_reference(info.model, line, runs, sample)
    data: list[RunData] = []
    for label, res in results.items():
        ref = np.array([line(t)[0] for t in res.t])
        data.append(run_from_simulation(res, label, reference=ref, hold_start=line.move, torque_times=times,
                                        torques=torques))
    extra = {"manoeuvre": {"start_m": line.start.tolist(), "end_m": line.end.tolist(), "move_s": line.move,
                           "hold_s": line.hold, "control_rate_hz": 1.0 / (times[1] - times[0]),
                           "output_sample_s": sample},
             "formulations": {k: {"formulation": f, "stabilization": s} for k, (f, s) in runs.items()}}
    with staged_files(out) as stage:
        report = write_report(stage, data, info, names=PAPER_NAMES, extra=extra)
        figures = _figure_numbers(report, data, results)
        (stage / "paper_figures.json").write_text(json.dumps(clean(figures), indent=2))
        _write_series(stage, data)
    return figures


def _figure_numbers(report: AnalysisReport, data: list[RunData], results: dict) -> dict:
    runs = report.runs

    def pick(section: str, keys: tuple[str, ...]) -> dict:  # None where a run lacks the section or key
        return {label: {k: getattr(getattr(m, section), k, None) for k in keys} for label, m in runs.items()}

    figures = {
        "model": report.model, "model_natural_hz": report.model_natural_hz,
        "manoeuvre": report.extra["manoeuvre"], "formulations": report.extra["formulations"],
        "fig2_path": {"file": PAPER_NAMES["path"], "data": "fig2_path.csv",
                      "runs": pick("path", ("max_path_deviation_m", "max_error_m", "rms_error_m",
                                            "final_position_error_m"))},
        "fig3_branch_forces": {"file": PAPER_NAMES["branch_forces"], "data": "fig3_branch_forces.csv",
                               "runs": {label: {"peak_N": getattr(m.branch_forces, "peak_N", None),
                                                "residual_vibration": {b: {k: getattr(v, k, None) for k in (
                                                    "f_d_hz", "zeta", "amplitude_N", "model_f_n_hz")}
                                                    for b, v in m.vibration.items()}}
                                        for label, m in runs.items()}},
        "fig4_gap": {"file": PAPER_NAMES["gap"], "data": "fig4_gap.csv",
                     "runs": pick("gap", ("max_m", "t_max_s", "at_hold_start_m", "final_m"))},
    }
    # Agreement of every run with the first (L-D'A): the paper's claim that SCDD equals it.
    base_label = data[0].label
    base = results[base_label]
    figures["difference_to_" + base_label] = {
        label: {"max_joint_difference": float(np.abs(r.q - base.q).max()),
                "max_branch_force_difference_N": float(np.abs(r.branch_forces - base.branch_forces).max()),
                "max_end_effector_difference_m": float(np.linalg.norm(r.ee - base.ee, axis=1).max())}
        for label, r in results.items() if label != base_label and r.q.shape == base.q.shape}
    return figures


def _write_series(out: Path, data: list[RunData]) -> None:
    """The plotted series, one CSV per figure, runs side by side on the common time grid."""
    t = data[0].t
    same = all(r.t is not None and r.t.shape == t.shape and np.allclose(r.t, t) for r in data)
    if not same:
        return
    ref = data[0].reference_at(t)
    cols, head = [t, ref[:, 0], ref[:, 1]], ["t", "reference_x", "reference_y"]
    for r in data:
        cols += [r.ee[:, 0], r.ee[:, 1]]
        head += [f"{r.label} x", f"{r.label} y"]
    _csv(out / "fig2_path.csv", head, cols)
    cols, head = [t], ["t"]
    for r in data:
        for b, f in r.forces.items():
            cols.append(f)
            head.append(f"{r.label} F_{b}")
    _csv(out / "fig3_branch_forces.csv", head, cols)
    _csv(out / "fig4_gap.csv", ["t"] + [f"{r.label} gap" for r in data], [t] + [r.gap for r in data])


def _csv(path: Path, head: list[str], cols: list[np.ndarray]) -> None:
    # Quote the names: run labels contain commas-free text but spaces and apostrophes (L-D'A).
    header = ",".join('"' + h.replace('"', '""') + '"' for h in head)
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.17g", encoding="utf-8")
