"""Byte-for-byte: every output of ``analyze`` (and ``paper-figures``) of this tree against another commit's.

    .venv/bin/python bench/tools/same_analysis.py                    # against the commit before the analysis was typed
    .venv/bin/python bench/tools/same_analysis.py --base-tree /tmp/wt-base --keep /tmp/same-analysis

The bags are written once, by this tree, with the test fixtures (``test/bag_factory.py``):
the reference run (mcap), a second run (sqlite3 without definitions, Float64MultiArray
commands), an epoch-stamped run (header stamps near 1.77e9 s), a run with the observer's wrench
topics (estimate, standard deviations, the plant's truth, contact events), a run with infinite and
NaN efforts, one whose plant reports infinite and NaN closure gaps and command ages (and has no
joint states), one with NaN joint states around the hold start and a branch force all NaN (metrics
that are NaN or infinite: null in JSON, named in the warnings, null differences), and a run of
joint states and commands only. Each tree's own code (the other in a
``git worktree``, run through ``PYTHONPATH``) then analyses them: one bag, two and three side by
side, plots on and off, decimated, with ``--hold-start``, and ``paper_figures`` on a short manoeuvre.

Compared: every file (summary.json, summary.md, CSVs, paper_figures.json, the PNGs), each
command's standard output (the output folder's name replaced) and exit status. A PNG that differs
in bytes is compared by its pixels too (matplotlib writes its version into the metadata).
Exit status 1 if anything differs.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BASE = "ccc0239"  # the commit before the analysis was typed from the start (issue #39 item 4)
EPOCH = 1_765_000_000.0  # [s] header stamp of the manoeuvre start in the epoch-stamped bag

# label: (bags, extra arguments of analyze)
ANALYSES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "one": (("ref_mcap",), ()),
    "two": (("ref_mcap", "other_sqlite"), ("--labels", "SCDD", "L-D'A")),
    "three": (("ref_mcap", "epoch_mcap", "wrench_mcap"), ()),
    "epoch": (("epoch_mcap",), ()),
    "wrench": (("wrench_mcap",), ()),
    "non_finite": (("non_finite_mcap",), ("--no-plots",)),
    "non_finite_plots": (("non_finite_mcap",), ()),
    "nan": (("nan_mcap",), ()),
    "two_nan": (("ref_mcap", "nan_mcap"), ("--no-plots",)),
    "inf": (("inf_mcap",), ()),
    "two_inf": (("ref_mcap", "inf_mcap"), ()),
    "partial": (("partial_sqlite",), ()),
    "partial_hold": (("partial_sqlite",), ("--hold-start", "0.2", "--no-plots")),
    "decimated": (("ref_mcap",), ("--max-samples", "200", "--window-samples", "800")),
    "sqlite_alone": (("other_sqlite",), ("--no-plots",)),
}

PAPER_CHILD = """
import sys
from pathlib import Path
from elastic_pm_dyn.analysis.paper import RUNS, paper_figures
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.trajectory import QuinticLine
line = QuinticLine(REFERENCE_MANOEUVRE.line.start, REFERENCE_MANOEUVRE.line.end, move=0.05, hold=0.03)
runs = {k: v for k, v in RUNS.items() if k != "SCDD (no stabilisation)"}
figs = paper_figures(Path(sys.argv[2]), Path(sys.argv[1]), line, runs)
print(sorted(figs))
"""

# Prints the report analyze returns (the object, not the file): its repr is compared too.
REPORT_CHILD = """
import sys
from elastic_pm_dyn.analysis.report import analyze
r = analyze(sys.argv[1], sys.argv[3:], sys.argv[2], plots_on=False)
print(repr(r))
"""


def _wrench_messages(run: object, ts: object) -> list:
    """The observer's wrench estimate and standard deviations, the plant's true wrench and contact events."""
    import bag_factory
    import numpy as np

    from elastic_pm_dyn.bags.msgtypes import VECTOR3, WRENCH_STAMPED

    m = bag_factory.Messages(ts)
    T = ts.types

    def wrench(t: float, f: np.ndarray) -> object:
        w = T["geometry_msgs/msg/Wrench"](force=T[VECTOR3](x=f[0], y=f[1], z=f[2]),
                                          torque=T[VECTOR3](x=f[3], y=f[4], z=f[5]))
        return T[WRENCH_STAMPED](header=m.header(t), wrench=w)

    def at(t: float) -> int:
        return round((bag_factory.T0 + t + bag_factory.LATENCY) * 1e9)

    out = []
    push = np.array([1.5, -0.5, 0.0, 0.0, 0.0, 0.02])
    for k, t in enumerate(run.t_state):
        on = float(t >= 0.25)
        truth = on * push
        est = truth + 0.05 * np.sin(7.0 * k) * np.array([1, 1, 0, 0, 0, 0.01])
        out.append(("/observer/wrench", WRENCH_STAMPED, at(t), wrench(t, est)))
        out.append(("/observer/wrench_stddev", WRENCH_STAMPED, at(t), wrench(t, np.full(6, 0.1))))
        out.append(("/wrench", WRENCH_STAMPED, at(t), wrench(t, truth)))
    for t in (0.2531, 0.4007):
        out.append(("/observer/contact", WRENCH_STAMPED, at(t), wrench(t, push)))
    return out


def _infinite_diagnostics(messages: list, m: object) -> list:
    """Without joint states (the gap from the plant's diagnostics); the plant reports an infinite closure
    gap at the hold start (0.2 s), a NaN one at the end and an infinite command age once."""
    from elastic_pm_dyn.bags.msgtypes import DIAGNOSTIC_ARRAY

    out = []
    for topic, msgtype, t_ns, msg in messages:
        if topic == "/joint_states":
            continue
        if msgtype == DIAGNOSTIC_ARRAY:
            t = round(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - 1000.0, 6)
            gap = {0.2: "inf", 0.5: "nan"}.get(t, "1e-9")
            msg = m.diagnostics(t, {"command_age_s": "inf" if t == 0.3 else "0.001", "closure_gap_m": gap})
        out.append((topic, msgtype, t_ns, msg))
    return out


def make_bags(inputs: Path) -> None:
    """The input bags (see module doc), written by this tree's test fixtures."""
    from dataclasses import replace

    import numpy as np

    sys.path.insert(0, str(ROOT / "test"))
    import bag_factory
    from bag_factory import run_messages, synthetic_run, write_bag

    from elastic_pm_dyn.bags.typestore import make_typestore

    ts = make_typestore()
    run = synthetic_run()
    other = synthetic_run(offset=(0.0, 3e-4), amplitude=1.0)

    def bag(name: str, messages: list, storage: str = "mcap", definitions: bool = True) -> None:
        if not (inputs / name).exists():
            write_bag(inputs / name, messages, storage, definitions)

    bag("ref_mcap", run_messages(run, ts))
    bag("other_sqlite", run_messages(other, ts, command="float_array"), "sqlite3", False)
    t0 = bag_factory.T0
    try:
        bag_factory.T0 = EPOCH
        bag("epoch_mcap", run_messages(run, ts))
    finally:
        bag_factory.T0 = t0
    bag("wrench_mcap", sorted(run_messages(run, ts) + _wrench_messages(run, ts), key=lambda x: x[2]))
    tau = run.tau.copy()
    tau[10:15, 0] = np.inf
    tau[:, 1] = np.nan
    bag("non_finite_mcap", run_messages(replace(run, tau=tau), ts))
    q, forces = run.q.copy(), run.forces.copy()
    q[200:203] = np.nan  # around the hold start: NaN gap there
    forces[:, 1] = np.nan  # one branch all NaN: NaN and infinite metrics
    bag("nan_mcap", run_messages(replace(run, q=q, forces=forces), ts))
    bag("inf_mcap", _infinite_diagnostics(run_messages(run, ts), bag_factory.Messages(ts)))
    bag("partial_sqlite", run_messages(run, ts, topics={"/joint_states", "/torque_command"}), "sqlite3")


def outputs(tree: Path, inputs: Path, out: Path) -> None:
    """Every output of ``tree``'s code into ``out`` (run with ``out`` as the working folder)."""
    env = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg")
    out.mkdir(parents=True)
    model = str(inputs / "five_bar.yaml")

    def run(name: str, *args: str) -> None:
        done = subprocess.run([sys.executable, *args], cwd=out, env=env, capture_output=True, text=True)
        (out / f"{name}.exit").write_text(f"{done.returncode}\n")  # a failure is behaviour too: compared
        (out / f"{name}.stdout").write_text(done.stdout.replace(str(out), "<out>"))
        if done.returncode != 0:
            print(f"{tree}: {name} exited {done.returncode}: {done.stderr.strip().splitlines()[-1:]}")

    for name, (bags, extra) in ANALYSES.items():
        run(f"analyze_{name}", "-m", "elastic_pm_dyn", "analyze", *[str(inputs / b) for b in bags],
            "--model", model, "--out", name, *extra)
    run("report_object", "-c", REPORT_CHILD, model, "report_object",
        *[str(inputs / b) for b in ("ref_mcap", "nan_mcap", "non_finite_mcap")])
    run("paper_figures", "-c", PAPER_CHILD, model, "paper")


def _same_pixels(a: Path, b: Path) -> bool:
    import numpy as np
    from matplotlib.image import imread

    x, y = imread(a), imread(b)
    return x.shape == y.shape and bool(np.array_equal(x, y))


def differences(a: Path, b: Path) -> tuple[list[str], int]:
    """Files that differ or exist on one side only, and how many were compared."""
    found = []
    names = {p.relative_to(a) for p in a.rglob("*") if p.is_file()} | {p.relative_to(b) for p in b.rglob("*")
                                                                        if p.is_file()}
    for name in sorted(names):
        if not (a / name).exists() or not (b / name).exists():
            found.append(f"{name}: only in {'base' if (a / name).exists() else 'this tree'}")
        elif not filecmp.cmp(a / name, b / name, shallow=False):
            if name.suffix == ".png" and _same_pixels(a / name, b / name):
                found.append(f"{name}: bytes differ, pixels identical")
            else:
                found.append(f"{name}: differs")
    return found, len(names)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default=BASE, help=f"commit to compare with (default {BASE})")
    ap.add_argument("--base-tree", type=Path, help="an existing checkout of the base (instead of --base)")
    ap.add_argument("--keep", type=Path, help="folder for the inputs and both outputs (default: a temporary one)")
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="same-analysis-"))
    inputs = work / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "config" / "five_bar.yaml", inputs / "five_bar.yaml")
    make_bags(inputs)
    for side in ("base", "this"):
        shutil.rmtree(work / side, ignore_errors=True)
    base_tree = args.base_tree
    if base_tree is None:
        base_tree = work / "base_tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base_tree), args.base],
                       check=True, capture_output=True)
    try:
        outputs(base_tree.resolve(), inputs, work / "base")
        outputs(ROOT, inputs, work / "this")
    finally:
        if args.base_tree is None:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base_tree)], check=False)
    found, n = differences(work / "base", work / "this")
    for line in found:
        print(line)
    real = [f for f in found if not f.endswith("pixels identical")]
    print(f"{n} files compared with {args.base_tree or args.base}: "
          f"{'all identical' if not found else f'{len(found)} differ ({len(real)} beyond PNG metadata)'} ({work})")
    return 1 if real else 0


if __name__ == "__main__":
    sys.exit(main())
