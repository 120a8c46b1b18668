"""``elastic-pm-dyn batch``: ``register_cli(subparsers)`` adds it to the main command.

    elastic-pm-dyn batch observe recordings/ --model config/five_bar.yaml --out runs/fleet \\
        -o sensors="encoders imu"
    elastic-pm-dyn batch tune manifest.csv --out runs/tuned --cluster tcp://scheduler:8786
    elastic-pm-dyn batch simulate --study study.yaml --out runs/study --jobs 8

Exit status: 0 every item done; 1 some item failed (each one line on stderr and a row in
the table); 2 a user mistake, or another batch running on --out; 130 Ctrl-C (finished
items kept: run it again to finish).
"""

from __future__ import annotations

import argparse

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet.items import KINDS

EXIT_SOME_FAILED = 1
EXIT_INTERRUPTED = 130  # as the main command's (128 + SIGINT)


def _options(pairs: list[str]) -> dict[str, object]:
    options: dict[str, object] = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        name = name.strip().removeprefix("--")
        if not sep or not name:
            raise InputError(f"-o {pair!r}: expected NAME=VALUE (an option of the {'/'.join(KINDS)} command)")
        if name in ("model", "bag", "out", "torques"):
            raise InputError(f"-o {name}: the batch sets it per item (use --model, the inputs, --out)")
        if name == "set":
            options.setdefault("set", [])
            options["set"].append(value)  # type: ignore[union-attr]
        else:
            options[name] = value
    return options


def cmd_batch(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.fleet.api import batch
    try:
        res = batch(args.kind, args.inputs, args.out, model=args.model, options=_options(args.option),
                    study=args.study, jobs=args.jobs, cluster=args.cluster, retries=args.retries,
                    item_timeout_s=args.item_timeout, wait=args.wait, progress=not args.no_progress,
                    every=args.heartbeat, plots_on=not args.no_plots)
    except KeyboardInterrupt:  # batch() said what is kept and what is left
        return EXIT_INTERRUPTED
    c = res.counts
    print(f"{c['items']} item(s): {c['ok']} done, {c['skipped']} already complete, {c['failed']} failed "
          f"in {res.wall_s:.1f} s on the {res.engine} -> {', '.join(str(f) for f in res.files[:2]) or res.out}")
    return EXIT_SOME_FAILED if c["failed"] else 0


def register_cli(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "batch", help="run observe, tune, analyze or simulate over many items (folders, globs, a manifest, a "
        "study) on every core or a Dask cluster -> one folder per item + results table",
        description="One output folder per item and results.csv/.parquet with every item's summary figures. "
                    "Complete items are skipped (a re-run resumes); a failing item is one line and a row.")
    p.add_argument("kind", choices=KINDS, help="the single-item command each item runs")
    p.add_argument("inputs", nargs="*", metavar="INPUT",
                   help="bag folders or files (simulate: torque CSV tables), folders holding them (at any depth), "
                        "globs, or a manifest (CSV/YAML: one row per item: id, model, bag|torques, robot, date, "
                        "label, any option of the command)")
    p.add_argument("--out", required=True, help="output folder (items/<id>/, results.csv, results.parquet, plots)")
    p.add_argument("--model", help="model of every item (a manifest's 'model' column overrides it)")
    p.add_argument("-o", "--option", action="append", default=[], metavar="NAME=VALUE",
                   help="an option of the command for every item, e.g. -o sensors='encoders imu' -o set=process.dt=5e-5"
                        " -o no_bag=true (repeatable; a manifest column overrides it)")
    p.add_argument("--study", help="simulate: a study file (grid or random sample over model parameters, move time, "
                   "integrator settings; see docs/batch.md) instead of inputs")
    engine = p.add_mutually_exclusive_group()
    engine.add_argument("--jobs", type=int, help="local worker processes (default: every core)")
    engine.add_argument("--cluster", metavar="ADDRESS",
                        help="run on Dask distributed: local:N (a LocalCluster of N workers) or a scheduler address")
    p.add_argument("--retries", type=int, default=2,
                   help="re-runs of an item whose worker was killed or timed out (default 2)")
    p.add_argument("--item-timeout", type=float, metavar="SECONDS",
                   help="kill an item's worker after this long (default: 120 s + 30 s per second of its recording "
                        "and pass over it: hung or stopped workers only)")
    p.add_argument("--wait", action="store_true",
                   help="another batch running on --out: wait for it to end (default: refuse)")
    p.add_argument("--heartbeat", type=float, default=10.0, metavar="SECONDS",
                   help="a progress line this often when stderr is a log or a pipe (default 10)")
    p.add_argument("--no-plots", action="store_true", help="the table only")
    p.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    p.set_defaults(func=cmd_batch)
    return p

