"""The ``observe`` subcommand: ``register_cli(subparsers)`` adds it to ``elastic-pm-dyn``.

    elastic-pm-dyn observe --model MODEL --bag BAG --out DIR [--config config/observer.yaml]
        [--sensors encoders imu branch_forces] [--torque-topic T] [--joint-topic T]
        [--imu-topic T] [--branch-topic T] [--order stamp|arrival] [--storage mcap|sqlite3]
        [--no-bag] [--set NAME=VALUE ...]

Exit status: 0 done; 1 the filter faulted (partial output written); 2 a user mistake
(one line on stderr, as every subcommand).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model import yaml12

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent.parent / "config" / "observer.yaml"


def register_cli(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "observe", help="run the state observer (EKF) over a recorded bag -> CSV + bag of estimates",
        description="Estimate every joint (incl. elastic deflections), branch forces and their standard "
                    "deviations from a bag's torque commands and sensor topics.")
    p.add_argument("--model", required=True, help="model YAML")
    p.add_argument("--bag", required=True, help="input rosbag2 directory (mcap or sqlite3)")
    p.add_argument("--out", required=True, help="output directory (estimates.csv, estimates/, summary.json)")
    p.add_argument("--config", default=None,
                   help="observer parameter YAML (default: config/observer.yaml of the package if present)")
    p.add_argument("--sensors", nargs="+", choices=("encoders", "imu", "branch_forces"),
                   help="sensor set (overrides the file's observer.sensors)")
    p.add_argument("--torque-topic", help="torque commands (default /torque_command)")
    p.add_argument("--joint-topic", help="measured joint states (default /measured_joint_states)")
    p.add_argument("--imu-topic", help="accelerometer (default /ee_imu)")
    p.add_argument("--branch-topic", help="measured branch forces (default /measured_branch_forces)")
    p.add_argument("--order", choices=("stamp", "arrival"), default="stamp",
                   help="process by header stamp (default) or in the bag's order (as a live node saw it)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="output bag storage")
    p.add_argument("--no-bag", action="store_true", help="write the CSV and summary only")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override an observer parameter, e.g. --set process.dt=5e-5 (a YAML 1.2 value)")
    p.set_defaults(func=cmd_observe)
    return p


def _config(args: argparse.Namespace):
    from elastic_pm_dyn.observer.config import ObserverConfig, load_config
    path = args.config if args.config else (DEFAULT_CONFIG if DEFAULT_CONFIG.exists() else None)
    cfg = load_config(path)
    params = dict(cfg.parameters)
    if args.sensors:
        params["sensors"] = list(args.sensors)
    for item in args.set:
        name, sep, value = item.partition("=")
        if not sep:
            raise InputError(f"--set {item!r}: expected NAME=VALUE")
        try:
            params[name.strip().removeprefix("observer.")] = yaml12.load(value)
        except yaml.YAMLError as exc:
            raise InputError(f"--set {item!r}: {exc}") from None
    for key, attr in (("torque_command", "torque_topic"), ("measured_joint_states", "joint_topic"),
                      ("ee_imu", "imu_topic"), ("measured_branch_forces", "branch_topic")):
        if getattr(args, attr):
            params[f"topics.{key}"] = getattr(args, attr)
    return ObserverConfig.from_parameters(params, str(path) if path else "<defaults>")


def cmd_observe(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer.bag_input import Topics
    from elastic_pm_dyn.observer.offline import observe_bag
    cfg = _config(args)
    mech = Mechanism(load_model(args.model))
    res = observe_bag(mech, cfg, args.bag, args.out, Topics.from_config(cfg), args.order, args.storage,
                      not args.no_bag, log=lambda s: print(s, file=sys.stderr))
    s = res.summary
    sens = ", ".join(f"{k} {v['accepted']} ok/{v['rejected']} gated/{v['late']} late"
                     + (f"/{v['future']} future" if v["future"] else "")
                     for k, v in s["sensors"].items() if k in cfg.sensors)
    print(f"{s['rows']} estimates over {s['duration_s']:.3f} s -> {args.out}  ({sens}; "
          f"{s['speed_factor']:.1f}x real time)")
    names = {reason: n for reason, n in s["joint_states_rejected"].items() if n}
    if names:
        print("elastic-pm-dyn: warning: joint states not used: "
              + ", ".join(f"{n} with {reason} names" for reason, n in names.items())
              + f" (last: {s['last_joint_state_problem']})", file=sys.stderr)
    level, message = s["health"]
    if level:
        print(f"elastic-pm-dyn: warning: observer health: {message}", file=sys.stderr)
    if s["fault"]:
        print(f"elastic-pm-dyn: error: {s['fault']} (estimates up to the fault written)", file=sys.stderr)
        return 1
    return 0
