"""Analyze bags: path error, branch forces, the ringing after the stop, one report per comparison.

Run: ``python examples/analyze_bag.py [BAG ...]`` (default: the estimates bag that
examples/observe_bag.py writes). The first bag is the baseline the others are compared with.
Writes analyze_out/summary.json, summary.md and the plots; prints what it found.
"""

import sys
from pathlib import Path

import elastic_pm_dyn as epd

MODEL = Path(__file__).resolve().parents[1] / "config" / "five_bar.yaml"
BAGS = sys.argv[1:] or ["observe_out/estimates"]
OUT = Path("analyze_out")

report = epd.analyze(MODEL, BAGS, OUT)
print(f"model natural frequencies: {', '.join(f'{f:.1f}' for f in report.model_natural_hz)} Hz")
for label, run in report.runs.items():
    print(f"{label}:")
    if run.path is not None and getattr(run.path, "max_error_m", None) is not None:  # a reference to compare with
        print(f"  end effector vs reference: max {run.path.max_error_m * 1e6:.1f} um")
    for name, peak in (run.branch_forces.peak_N if run.branch_forces else {}).items():
        print(f"  branch {name}: peak force {peak:.3f} N")
    for name, fit in run.vibration.items():
        if getattr(fit, "f_d_hz", None) is not None:  # a Note instead when nothing rang
            print(f"  branch {name}: rings at {fit.f_d_hz:.1f} Hz after the stop, damping ratio {fit.zeta:.4f}")
    for warning in run.warnings:
        print(f"  note: {warning}")
for c in report.comparison or []:  # each other run's time series minus the baseline's
    diffs = ", ".join(f"{k} {v:.3g}" for k, v in c.series_difference.items() if "max" in k)
    print(f"{c.other} - {c.baseline}: {diffs}")
print(f"plots: {', '.join((report.plots or {}).values())}; summary.json and summary.md in {OUT}")
