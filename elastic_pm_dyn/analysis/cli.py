"""Subcommands ``analyze``, ``export`` and ``paper-figures`` of ``elastic-pm-dyn``.

``register_cli(subparsers)`` adds them to the main parser; each sets ``func`` to a
function returning the exit code. Heavy imports happen inside those functions, so
``elastic-pm-dyn --help`` stays fast. User mistakes raise :class:`InputError` (the main
CLI prints the one-line message and exits 2).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from elastic_pm_dyn.analysis.report_types import AnalysisReport, PathMetrics, VibrationFit
from elastic_pm_dyn.errors import InputError

ROLE_OPTIONS = {  # option -> role of bags.ROLES
    "--joint-states": "joint_states", "--branch-forces": "branch_forces", "--torque-command": "torque_command",
    "--reference": "reference", "--measured": "measured", "--ee-pose": "ee_pose", "--diagnostics": "diagnostics",
}


def default_model() -> str:
    """config/five_bar.yaml of the source tree, else of the installed ROS package (share/)."""
    here = Path(__file__).resolve().parents[2] / "config" / "five_bar.yaml"
    if here.is_file():
        return str(here)
    return str(Path(sys.prefix) / "share" / "elastic_pm_dyn" / "config" / "five_bar.yaml")


def _positive(kind: type):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value

    return parse


def _out_dir(text: str) -> Path:
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise InputError(f"--out {path}: exists and is not a directory")
    return path


def cmd_analyze(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.analysis.report import analyze

    if args.labels and len(args.labels) != len(args.bags):
        raise InputError(f"--labels: {len(args.labels)} labels for {len(args.bags)} bags")
    if args.labels and len(set(args.labels)) < len(args.labels):
        raise InputError("--labels must differ")
    if args.hold_start is not None and not (math.isfinite(args.hold_start) and args.hold_start >= 0):
        raise InputError(f"--hold-start must be a finite time >= 0 [s], got {args.hold_start!r}")
    topics = {role: getattr(args, role) for role in ROLE_OPTIONS.values()}
    out = _out_dir(args.out)
    report = analyze(args.model, args.bags, out, topics=topics, hold_start=args.hold_start, labels=args.labels,
                     plots_on=not args.no_plots, max_samples=args.max_samples, window_samples=args.window_samples)
    _print_summary(report)
    print(f"summary.json, summary.md{' and plots' if not args.no_plots else ''} in {out}")
    return 0


def _print_summary(report: AnalysisReport) -> None:
    for label, m in report.runs.items():
        parts = []
        if isinstance(m.path, PathMetrics) and m.path.max_error_m is not None:
            final = m.path.final_position_error_m
            parts.append(f"max EE error {m.path.max_error_m * 1e6:.4g} um, "
                         f"final {'-' if final is None else format(final * 1e6, '.4g')} um")
        for b, v in m.vibration.items():
            if isinstance(v, VibrationFit) and v.f_d_hz is not None:
                parts.append(f"{b}: {v.f_d_hz:.1f} Hz, zeta {v.zeta:.3g}, {v.amplitude_N:.3g} N")
        if m.gap is not None and m.gap.max_m is not None:
            parts.append(f"max gap {m.gap.max_m:.3g} m")
        print(f"{label}: " + ("; ".join(parts) or "no metrics"))
        for w in m.warnings:
            print(f"  warning: {w}")


def cmd_export(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.analysis.export import export_bag

    for e in export_bag(args.bag, _out_dir(args.out), args.topics):
        extra = f"; {e.dropped} values without a column" if e.dropped else ""
        extra += f"; long arrays as length only: {', '.join(e.long_arrays)}" if e.long_arrays else ""
        print(f"{e.topic} [{e.msgtype}] -> {e.file} ({e.rows} rows, {e.columns} columns{extra})")
    return 0


def cmd_paper_figures(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.analysis.paper import paper_figures

    out = _out_dir(args.out)
    figures = paper_figures(out, Path(args.model))
    for label, v in figures["fig4_gap"]["runs"].items():
        dev = figures["fig2_path"]["runs"][label].get("max_path_deviation_m") or float("nan")
        gap = v.get("max_m") or float("nan")
        print(f"{label:26s} max path deviation {dev * 1e6:8.3f} um, max gap {gap:.3g} m")
    print(f"fig2_path.png, fig3_branch_forces.png, fig4_gap.png, paper_figures.json in {out}")
    return 0


def register_cli(subparsers: argparse._SubParsersAction) -> None:
    """Add ``analyze``, ``export`` and ``paper-figures`` to the main parser's subparsers."""
    p = subparsers.add_parser(
        "analyze", help="analyse recorded runs: rosbag2 (mcap/sqlite3) -> plots, summary.json, summary.md",
        description="Metrics and plots of one bag, or of several side by side (differences to the first).")
    p.add_argument("bags", nargs="+", metavar="BAG", help="bag directory (or its .mcap/.db3 file); a second "
                   "bag is compared with the first")
    p.add_argument("--model", default=default_model(), help="model YAML (default: the reference five-bar)")
    p.add_argument("--out", default="analysis", help="output directory (default: analysis)")
    p.add_argument("--labels", nargs="+", metavar="LABEL", help="run names in plots and tables (default: bag names)")
    p.add_argument("--hold-start", type=float, metavar="S",
                   help="[s] start of the hold phase, from time zero = the first stamp of the reference (else of "
                   "the torque command, else of the joint states); default: where the reference comes to rest")
    for option, role in ROLE_OPTIONS.items():
        p.add_argument(option, dest=role, metavar="TOPIC", help=f"{role.replace('_', ' ')} topic (default: found "
                       "by name and type)")
    p.add_argument("--max-samples", type=_positive(int), metavar="N",
                   help="samples kept per topic before the overview is decimated (default 200000)")
    p.add_argument("--window-samples", type=_positive(int), metavar="N",
                   help="full-rate samples kept for the vibration fit when decimating (default 50000)")
    p.add_argument("--no-plots", action="store_true", help="summary only")
    p.set_defaults(func=cmd_analyze)

    p = subparsers.add_parser("export", help="one CSV per topic of a bag (flattened fields, named columns)")
    p.add_argument("bag", help="bag directory (or its .mcap/.db3 file)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics")
    p.set_defaults(func=cmd_export)

    p = subparsers.add_parser("paper-figures", help="the paper's Figs. 2-4: L-D'A vs SCDD (exact, one-pass) on "
                              "the reference manoeuvre -> PNG, JSON, CSV")
    p.add_argument("--model", default=default_model(), help="model YAML (default: the reference five-bar)")
    p.add_argument("--out", default="runs/paper", help="output directory (default: runs/paper)")
    p.set_defaults(func=cmd_paper_figures)
