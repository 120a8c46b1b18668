"""Analyze recorded runs: path accuracy, branch forces, residual vibration, closure gap; plots.

``epd.analyze`` reads one or more rosbag2 recordings of the machine (the plant node's or a
robot's: joint states, branch forces, torque commands, the reference motion, found by name
or message type), evaluates them against the model, and writes plots, summary.json and
summary.md. This script prints the main numbers of each run from the returned report
(an ``AnalysisReport``: summary.json as objects, ``report.runs[label].path.max_error_m``).
With several bags the first is the baseline the others are compared with.

Run:

    python examples/analyze_bag.py BAG [BAG ...] [--model config/five_bar.yaml] [--hold-start S] [--out DIR]

e.g. on the estimates bag that examples/observe_bag.py writes (observe_bag_out/estimates).
Writes DIR/summary.json, DIR/summary.md and DIR/*.png (default DIR: analyze_bag_out).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import elastic_pm_dyn as epd
from elastic_pm_dyn.analysis.report_types import PathMetrics, RunMetrics, VibrationFit

CONFIG = Path(__file__).resolve().parents[1] / "config"


def show(label: str, run: RunMetrics) -> None:
    print(f"{label}:")
    path = run.path  # None without a reference, a Note when there was nothing to compare
    if isinstance(path, PathMetrics) and path.max_error_m is not None:
        print(f"  end effector vs reference: max {path.max_error_m * 1e6:.1f} um, off the path "
              f"{path.max_path_deviation_m * 1e6:.1f} um, final {path.final_position_error_m * 1e6:.1f} um")
    for name, peak in (run.branch_forces.peak_N if run.branch_forces else {}).items():
        print(f"  branch {name}: peak force {peak:.3f} N")
    for name, fit in run.vibration.items():
        if isinstance(fit, VibrationFit) and fit.f_d_hz is not None:
            model = "-" if fit.model_f_n_hz is None else f"{fit.model_f_n_hz:.1f}"
            print(f"  branch {name}: rings at {fit.f_d_hz:.1f} Hz after the stop, damping ratio {fit.zeta:.4f}, "
                  f"amplitude {fit.amplitude_N:.3f} N (model: {model} Hz)")
    if run.gap is not None:
        print(f"  closure gap: max {run.gap.max_m:.3g} m")
    for name, peak in (run.torques.peak_Nm if run.torques else {}).items():
        if peak is not None:
            print(f"  motor {name}: peak torque {peak:.3f} N m")
    for warning in run.warnings:
        print(f"  note: {warning}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bags", nargs="+", type=Path, help="rosbag2 directories (mcap or sqlite3)")
    parser.add_argument("--model", type=Path, default=CONFIG / "five_bar.yaml", help="model YAML")
    parser.add_argument("--hold-start", type=float, help="start of the hold phase [s] if no reference shows it")
    parser.add_argument("--out", type=Path, default=Path("analyze_bag_out"), help="output directory")
    args = parser.parse_args(argv)

    report = epd.analyze(args.bags, args.model, args.out, hold_start=args.hold_start)
    print(f"model natural frequencies: {', '.join(f'{f:.1f}' for f in report.model_natural_hz)} Hz")
    for label, run in report.runs.items():
        show(label, run)
    for c in report.comparison or []:  # time series of each other run minus the baseline
        diffs = ", ".join(f"{k} {v:.3g}" for k, v in c.series_difference.items() if "max" in k)
        print(f"{c.other} - {c.baseline}: {diffs}")
    print(f"plots: {', '.join((report.plots or {}).values())}; summary.json and summary.md in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
