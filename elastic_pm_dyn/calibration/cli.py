"""The ``calibrate`` and ``excite`` subcommands: ``register_cli(subparsers)`` adds them to ``elastic-pm-dyn``.

    elastic-pm-dyn excite --model M --out excitation.csv --max-torque T [--params ...] [--duration 5] [--rate 1000]
    elastic-pm-dyn calibrate --model M --bag B [B ...] --out calibrated.yaml [--params ...] [--config observer.yaml]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from elastic_pm_dyn.errors import InputError

MAX_THREADS = 64


def register_cli(subparsers) -> None:
    p = subparsers.add_parser("calibrate", help="fit springs, dampers, payload and friction of a model YAML to "
                              "recorded bags (maximum innovation likelihood); writes the calibrated model YAML")
    p.add_argument("--model", required=True, help="model YAML to calibrate")
    p.add_argument("--bag", nargs="+", required=True, help="recorded rosbag2 directories (mcap or sqlite3)")
    p.add_argument("--out", required=True, help="calibrated model YAML to write")
    p.add_argument("--params", nargs="+", help="what to fit: names, groups (stiffness damping payload friction "
                   "payload.inertia) or patterns (stiffness.left_*); default stiffness damping payload.mass friction")
    p.add_argument("--config", help="observer parameters (default config/observer.yaml; tune them first)")
    p.add_argument("--sensors", nargs="+", choices=("encoders", "imu", "branch_forces"),
                   help="sensor set (overrides the config's observer.sensors)")
    p.add_argument("--seconds", type=float, help="use the first S seconds of each bag")
    p.add_argument("--max-passes", type=int, default=120, help="filter passes per stage at most (default 120)")
    p.add_argument("--threads", type=int, default=2, help="filter passes at once (default 2)")
    p.add_argument("--json", help="also write the whole report as JSON here")
    p.set_defaults(func=cmd_calibrate)

    p = subparsers.add_parser("excite", help="a multisine torque table that excites the asked parameters, to add "
                              "to a holding loop's command while recording for calibrate")
    p.add_argument("--model", required=True, help="model YAML (its elastic modes set the bands)")
    p.add_argument("--out", required=True, help="torque table CSV to write (t, one column per motor)")
    p.add_argument("--max-torque", type=float, nargs="+", required=True,
                   help="each motor's torque limit [N m or N] (one value: all)")
    p.add_argument("--params", nargs="+", default=["stiffness", "damping", "payload"],
                   help="groups to excite: stiffness damping payload friction (default the first three)")
    p.add_argument("--duration", type=float, default=5.0, help="[s] (default 5)")
    p.add_argument("--rate", type=float, default=1000.0, help="the command rate [Hz] (default 1000)")
    p.add_argument("--peak-fraction", type=float, default=0.5,
                   help="the table's peak as a fraction of the limit; the rest is the holding loop's (default 0.5)")
    p.add_argument("--seed", type=int, default=0, help="the multisine's phases")
    p.set_defaults(func=cmd_excite)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.calibration.api import calibrate
    from elastic_pm_dyn.calibration.report import report
    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds must be > 0, got {args.seconds}")
    if not 1 <= args.threads <= MAX_THREADS:
        raise InputError(f"--threads must be 1 to {MAX_THREADS}, got {args.threads}")
    res = calibrate(args.model, args.bag, args.out, args.params, args.config, args.sensors, args.seconds,
                    args.max_passes, args.threads, log=lambda s: print(s, file=sys.stderr))
    print(report(res))
    print(f"-> {args.out}")
    if args.json:
        Path(args.json).write_text(json.dumps(res.as_dict(), indent=1, default=float) + "\n")
    return 0


GROUPS = ("stiffness", "damping", "payload", "friction")


def cmd_excite(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.calibration.excitation import excitation
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.sim.torque import write_torque_csv
    bad = [g for g in args.params if g not in GROUPS]
    if bad:
        raise InputError(f"--params {bad[0]!r}: excite takes groups: {', '.join(GROUPS)}")
    mech = Mechanism(load_model(args.model))
    ex = excitation(mech, args.params, args.max_torque, args.duration, args.rate, args.peak_fraction, args.seed)
    write_torque_csv(args.out, ex.t, ex.torque, ex.names)
    print(f"{len(ex.t)} samples at {args.rate:g} Hz, {len(ex.lines_hz)} lines, peak "
          + ", ".join(f"{n} {abs(ex.torque[:, k]).max():.3g}" for k, n in enumerate(ex.names)) + " -> " + args.out)
    if len(ex.modes_hz):
        print("elastic modes (motors clamped) [Hz]: " + ", ".join(f"{f:.1f}" for f in ex.modes_hz))
    for what, lo, hi in ex.bands:
        print(f"  {what}: {lo:.1f}-{hi:.1f} Hz")
    print("record: add the table to the command of a loop that holds the start pose (sample k held over one "
          "period), with every sensor the machine has; then elastic-pm-dyn calibrate --model M --bag BAG --out C")
    return 0
