"""The ``observe`` and ``tune`` subcommands: ``register_cli(subparsers)`` adds them to ``elastic-pm-dyn``.

    elastic-pm-dyn observe --model MODEL --bag BAG --out DIR [--config config/observer.yaml]
        [--sensors encoders imu branch_forces] [--torque-topic T] [--joint-topic T]
        [--imu-topic T] [--branch-topic T] [--order stamp|arrival] [--storage mcap|sqlite3]
        [--no-bag] [--smoother rts] [--set NAME=VALUE ...]
    elastic-pm-dyn tune --model MODEL --bag BAG --out tuned.yaml [--config base.yaml]
        [--sensors ...] [--set NAME=VALUE ...] [--seconds S] [--max-evaluations N] [--keep-delay]

``tune`` fits the process noise, the disturbance spectrum, the sensor noise the base file
leaves at its defaults and the command delay to the recording by maximum innovation
likelihood (no truth needed; :mod:`~elastic_pm_dyn.observer.tuning.tuning`) and writes a parameter
file that ``observe --config`` and the plant node in ``mode: observer`` read.

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
    _add_inputs(p, "output directory (estimates.csv, estimates/, summary.json)",
                "observer parameter YAML (default: config/observer.yaml of the package if present)")
    p.add_argument("--order", choices=("stamp", "arrival"), default="stamp",
                   help="process by header stamp (default) or in the bag's order (as a live node saw it)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="output bag storage")
    p.add_argument("--no-bag", action="store_true", help="write the CSV and summary only")
    p.add_argument("--smoother", choices=("rts",), default=None,
                   help="after the filter, a Rauch-Tung-Striebel pass: estimates.csv and the bag smoothed, "
                        "the filter's estimates in filtered.csv")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override an observer parameter, e.g. --set process.dt=5e-5 (a YAML 1.2 value)")
    p.set_defaults(func=cmd_observe)
    _register_tune(subparsers)
    return p


def _register_tune(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "tune", help="tune the observer's noise model to a recorded bag (maximum innovation likelihood)",
        description="Fit the process noise, disturbance spectrum, default sensor noise and the command delay "
                    "to a bag without truth (prediction-error method); write a ros__parameters YAML file.")
    _add_inputs(p, "tuned parameter YAML to write",
                "base observer parameter YAML (default: config/observer.yaml of the package if present); "
                "its sensor noise levels are kept, its other keys copied")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="override an observer parameter (kept fixed if it is a sensor noise level)")
    p.add_argument("--seconds", type=float, default=None, help="tune on the first S seconds only (default: all)")
    p.add_argument("--max-evaluations", type=int, default=160, help="filter passes at most (default 160)")
    p.add_argument("--keep-delay", action="store_true", help="keep observer.command_delay (no likelihood scan)")
    p.add_argument("--threads", type=int, default=2, help="filter passes at once (default 2)")
    p.set_defaults(func=cmd_tune)
    return p


def _add_inputs(p: argparse.ArgumentParser, out_help: str, config_help: str) -> None:
    """The model, bag, output, base config, sensor set and topics: what observe and tune read."""
    p.add_argument("--model", required=True, help="model: YAML, URDF (+ closure sidecar) or MJCF")
    p.add_argument("--closures", help="closure sidecar of a URDF model (default: robot.yaml next to it)")
    p.add_argument("--bag", required=True, help="input rosbag2 directory (mcap or sqlite3)")
    p.add_argument("--out", required=True, help=out_help)
    p.add_argument("--config", default=None, help=config_help)
    p.add_argument("--sensors", nargs="+", choices=("encoders", "imu", "branch_forces"),
                   help="sensor set (overrides the file's observer.sensors)")
    p.add_argument("--torque-topic", help="torque commands (default /torque_command)")
    p.add_argument("--applied-topic", help="the torque the drives applied, used instead of the commands from its "
                   "first message on (default /applied_torque; '' = never)")
    p.add_argument("--joint-topic", help="measured joint states (default /measured_joint_states)")
    p.add_argument("--imu-topic", help="accelerometer (default /ee_imu)")
    p.add_argument("--branch-topic", help="measured branch forces (default /measured_branch_forces)")


def _config(args: argparse.Namespace):
    from elastic_pm_dyn.observer.config import ObserverConfig, load_config
    path = args.config if args.config else (DEFAULT_CONFIG if DEFAULT_CONFIG.exists() else None)
    cfg = load_config(path)
    params = dict(cfg.parameters)
    set_names = [item.partition("=")[0].strip() for item in args.set]
    if args.sensors:
        params["sensors"] = list(args.sensors)
    for item in args.set:
        name, sep, value = item.partition("=")
        shown = repr(item if len(item) <= 60 else item[:57] + "...")  # a 10 kB value is not one line
        if not sep:
            raise InputError(f"--set {shown}: expected NAME=VALUE")
        try:
            params[name.strip().removeprefix("observer.")] = yaml12.load(value)
        except (yaml.YAMLError, RecursionError, ValueError) as exc:  # as yaml12.load_file: "!!int 1.5" is a ValueError
            reason = getattr(exc, "problem", None) or " ".join(str(exc).split())
            raise InputError(f"--set {shown}: not a valid YAML value: {reason[:200]}") from None
    for key, attr in (("torque_command", "torque_topic"), ("applied_torque", "applied_topic"),
                      ("measured_joint_states", "joint_topic"), ("ee_imu", "imu_topic"),
                      ("measured_branch_forces", "branch_topic")):
        if getattr(args, attr) is not None and (getattr(args, attr) or key == "applied_torque"):
            params[f"topics.{key}"] = getattr(args, attr)
    source = str(path) if path else "<defaults>"
    if set_names:  # a bad --set value is not the config file's fault
        source += f" with --set {', '.join(set_names)}"
    return ObserverConfig.from_parameters(params, source)


def cmd_observe(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer.drivers.bag_input import Topics
    from elastic_pm_dyn.observer.offline import observe_bag
    cfg = _config(args)
    if cfg.process.dt > 0:
        _check_steps(cfg, _bag_seconds(Path(args.bag)), str(args.bag))
    mech = Mechanism(load_model(args.model, closures=args.closures))
    res = observe_bag(mech, cfg, args.bag, args.out, Topics.from_config(cfg), args.order, args.storage,
                      not args.no_bag, log=lambda s: print(s, file=sys.stderr), smoother=args.smoother)
    s = res.summary
    sens = ", ".join(f"{k} {v.accepted} ok/{v.rejected} gated/{v.late} late"
                     + (f"/{v.future} future" if v.future else "")
                     for k, v in s.sensors.items() if k in cfg.sensors)
    print(f"{s.rows} estimates over {s.duration_s:.3f} s -> {args.out}  ({sens}; "
          f"{s.speed_factor:.1f}x real time)")
    if s.smoothing:
        sm = s.smoothing
        print(f"rts smoother: {sm['segments']} segment(s), branch-force std x{sm['branch_force_std_ratio_mean']:.3f} "
              f"of the filter's on average ({sm['wall_smooth_s']:.2f} s); the filter's estimates in filtered.csv")
    names = {reason: n for reason, n in s.joint_states_rejected.items() if n}
    if names:
        print("elastic-pm-dyn: warning: joint states not used: "
              + ", ".join(f"{n} with {reason} names" for reason, n in names.items())
              + f" (last: {s.last_joint_state_problem})", file=sys.stderr)
    level, message = s.health
    if level:
        print(f"elastic-pm-dyn: warning: observer health: {message}", file=sys.stderr)
    if s.fault:
        print(f"elastic-pm-dyn: error: {s.fault} (estimates up to the fault written)", file=sys.stderr)
        return 1
    return 0


MAX_STEPS = 1e8  # prediction steps of one pass: beyond, hours of computing (simulate's own limit is alike)


def _bag_seconds(bag: Path) -> float:
    """The bag's duration from its index (no message is read; a cut bag's warning comes later, once)."""
    import logging

    from elastic_pm_dyn.bags.reader import open_bag
    log = logging.getLogger("elastic_pm_dyn.bags")
    before, log.disabled = log.disabled, True
    try:
        with open_bag(bag) as b:
            return (b.end_ns - b.start_ns) * 1e-9
    finally:
        log.disabled = before


def _check_steps(cfg, seconds: float, bag: str) -> None:
    """Refuse, before any work, a pass of more than MAX_STEPS prediction steps."""
    dt = cfg.process.dt
    if dt > 0 and seconds / dt > MAX_STEPS:
        raise InputError(f"{bag}: {seconds:.6g} s at observer.process.dt {dt:g} s is {seconds / dt:.3g} prediction "
                         f"steps, more than {MAX_STEPS:.0e} (hours of computing): choose a larger step, or 0")


MIN_TUNE_SECONDS = 0.1  # [s] of data: ~100 control periods, the least a noise fit can use
MAX_EVALUATIONS = 100_000
MAX_THREADS = 64


def _span(events: list) -> float:
    """Seconds between the first and the last event's stamp."""
    stamps = [e.stamp_ns for e in events]
    return (max(stamps) - min(stamps)) * 1e-9 if stamps else 0.0


def cmd_tune(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer.drivers.bag_input import Topics, read_events
    from elastic_pm_dyn.observer.tuning import tuning
    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds must be > 0, got {args.seconds}")
    if args.seconds is not None and args.seconds < MIN_TUNE_SECONDS:
        raise InputError(f"--seconds {args.seconds:g}: tuning needs at least {MIN_TUNE_SECONDS:g} s of data")
    if not 8 <= args.max_evaluations <= MAX_EVALUATIONS:
        raise InputError(f"--max-evaluations must be 8 to {MAX_EVALUATIONS}, got {args.max_evaluations}")
    if not 1 <= args.threads <= MAX_THREADS:
        raise InputError(f"--threads must be 1 to {MAX_THREADS} (filter passes at once), got {args.threads}")
    cfg = _config(args)
    base_path = args.config if args.config else (DEFAULT_CONFIG if DEFAULT_CONFIG.exists() else None)
    # the sensor noise a user gave (a file of theirs, --set) stays as given
    explicit = tuning.explicit_names(args.config) | {item.partition("=")[0].strip().removeprefix("observer.")
                                                     for item in args.set}
    mech = Mechanism(load_model(args.model, closures=args.closures))
    events, _ = read_events(Path(args.bag), Topics.from_config(cfg), cfg)
    events = tuning.select(events, args.seconds)
    if not events:
        raise InputError(f"{args.bag}: no messages on the observer's topics")
    span = _span(events)
    _check_steps(cfg, span, str(args.bag))
    if span < MIN_TUNE_SECONDS:  # a "tuned" file fitted to (almost) no data would be a silent failure
        raise InputError(f"{args.bag}: {span:g} s of observer input{' in --seconds' if args.seconds else ''}; "
                         f"tuning needs at least {MIN_TUNE_SECONDS:g} s")
    res = tuning.tune(mech, cfg, events, explicit, delay=not args.keep_delay, max_evaluations=args.max_evaluations,
                      threads=max(1, args.threads), log=lambda s: print(s, file=sys.stderr))
    tuning.write_parameters(res.params, args.out, base_path)
    print(tuning.report(res))
    print(f"-> {args.out}")
    return 0
