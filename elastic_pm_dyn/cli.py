"""The ``elastic-pm-dyn`` command: one entry point, one subcommand per job.

User mistakes end with a one-line reason and a non-zero exit, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import numpy as np

from elastic_pm_dyn.errors import ElasticPmDynError, RunInterrupted, SingularConfigurationError

EXIT_USER_ERROR = 2
EXIT_RUN_FAILED = 1
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a program stopped by Ctrl-C
MAX_MESSAGE = 400  # characters of one error line
MIN_MOVE_PERIODS = 10  # a move sampled by fewer control periods is not in the torque table
MAX_TORQUE_SAMPLES = 1e6  # feedforward rows: ~17 min at 1 kHz, minutes of computing, some 50 MB of CSV
MAX_CONTROL_RATE = 1e5  # [Hz] feedforward --rate: 10x the fastest torque loops; beyond, rows without information
RTOL_MIN = 100 * float(np.finfo(float).eps)  # scipy's DOP853 raises a smaller rtol to this, with a warning


class OneLineParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line (``prog: error: ...``) and exit 2, like ours."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {_one_line(message)} (see {self.prog} --help)\n")

    def _get_values(self, action: argparse.Action, arg_strings: list[str]):
        # "--threads=--": argparse drops the "--" and hands the command [] for one number
        if action.nargs is None and action.option_strings and list(arg_strings) == ["--"]:
            self.error(f"argument {'/'.join(action.option_strings)}: expected one value, got '--'")
        return super()._get_values(action, arg_strings)


def _one_line(text: object) -> str:
    """A message as one line of at most MAX_MESSAGE characters, whatever it holds."""
    line = " ".join(str(text).split())
    return line if len(line) <= MAX_MESSAGE else line[:MAX_MESSAGE - 3] + "..."


def _error(err: object) -> None:
    print(f"elastic-pm-dyn: error: {_one_line(err)}", file=sys.stderr)


def _add_simulation_options(p: argparse.ArgumentParser) -> None:
    from elastic_pm_dyn.dynamics.direct import FORMULATIONS
    from elastic_pm_dyn.sim.simulator import INTEGRATORS, STABILIZATIONS
    p.add_argument("--method", choices=FORMULATIONS, default="scdd", help="formulation (default scdd)")
    p.add_argument("--integrator", choices=INTEGRATORS, default="rk4")
    p.add_argument("--dt", type=float, default=1e-4, help="RK4 / ETD2 step [s] (default 1e-4; etd2: see check)")
    p.add_argument("--rtol", type=float, default=1e-10, help="dop853 relative tolerance")
    p.add_argument("--atol", type=float, default=1e-12, help="dop853 absolute tolerance")
    p.add_argument("--stabilization", choices=tuple(STABILIZATIONS), default="projection")
    p.add_argument("--sample", type=float, default=1e-3, help="output interval [s] (default 1e-3)")


def _options(args: argparse.Namespace):
    from elastic_pm_dyn.sim.simulator import SimulationOptions
    return SimulationOptions(formulation=args.method, integrator=args.integrator, dt=args.dt, rtol=args.rtol,
                             atol=args.atol, stabilization=args.stabilization, sample=args.sample)


def _load(args: argparse.Namespace):
    """The model the command names: a model YAML, a URDF (+ closure sidecar) or an MJCF."""
    from elastic_pm_dyn.model.loader import load_model
    return load_model(args.model, getattr(args, "elastic_dof_per_chain", None), getattr(args, "closures", None),
                      getattr(args, "fix_base", False), getattr(args, "servos_as_motors", False),
                      closure_tol=getattr(args, "closure_tol", None), slip_speed=getattr(args, "slip_speed", None))


def _add_model(p: argparse.ArgumentParser, positional: bool = False, dof: bool = False) -> None:
    """The model arguments: the file, a URDF's closure sidecar, and (``dof``) the flexible links' discretisation."""
    what = "model: YAML, URDF (+ closure sidecar), MJCF or SDFormat (.sdf)"
    if positional:
        p.add_argument("model", help=what)
    else:
        p.add_argument("--model", required=True, help=what)
    p.add_argument("--closures", help="closure sidecar of a URDF (or SDFormat) model (default: robot.yaml next to it)")
    p.add_argument("--fix-base", action="store_true",
                   help="MJCF: weld each body on a free joint (a floating base) to the world where the file puts "
                        "it; the free joint's keyframe entries are dropped")
    p.add_argument("--servos-as-motors", action="store_true",
                   help="MJCF: a joint driven by a servo (<position>, <velocity>, <general> ...) is a motor: its "
                        "torque is the input, the servo law (kp, kv) is left out")
    p.add_argument("--closure-tol", type=float, default=None, metavar="M",
                   help="URDF, MJCF: loops the file's geometry closes only within this (m, rad; default 1e-6, 0: "
                        "exactly) load, their anchors moved to close, with a warning")
    p.add_argument("--slip-speed", type=float, default=None, metavar="V",
                   help="dry friction (MJCF frictionloss, URDF friction) regularised as F tanh(qd / V) (m/s, rad/s); "
                        "default 0: Coulomb's law, a joint sticks while the force it needs is within F")
    if dof:
        p.add_argument("--elastic-dof-per-chain", type=int, default=None,
                       help="override the model's discretisation of flexible links")


def cmd_simulate(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.sim.simulate import simulate
    try:
        result = simulate(_load(args), args.torques, args.duration, args.out, options=_options(args), hold=args.hold,
                          _prefix="--")
    except RunInterrupted as stop:
        print(f"elastic-pm-dyn: {stop} (Ctrl-C): the {len(stop.partial.t)} samples so far written to {args.out}",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    except SingularConfigurationError as err:
        if err.partial is not None:
            print(f"partial output ({len(err.partial.t)} samples) written to {args.out}", file=sys.stderr)
        raise
    print(f"{len(result.t)} samples -> {args.out}  (max gap {result.gap.max():.3g} m)")
    return 0


def cmd_feedforward(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.errors import InputError
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE as ref
    from elastic_pm_dyn.motion.poses import PoseLine
    from elastic_pm_dyn.motion.task import Task
    from elastic_pm_dyn.motion.time_laws import law_order
    from elastic_pm_dyn.motion.trajectory import make_line
    from elastic_pm_dyn.sim.held_feedforward import feedforward_table
    from elastic_pm_dyn.sim.torque import write_torque_csv
    rate = _control_rate(args)  # checked before the model is read
    model = _load(args)
    if args.waypoints is not None:
        return _waypoint_feedforward(args, model, rate)
    names = [c.upper() for c in model.ee_names]
    dims = len(names)
    axes = " ".join(f"{c}A" for c in names) + " " + " ".join(f"{c}B" for c in names)
    if args.line is None and dims != len(ref.start):
        raise InputError(f"--line is needed: the default line is the planar five-bar's, and this machine's end "
                         f"effector has {dims} coordinates: give {2 * dims} numbers {axes}")
    points = args.line or [*ref.start, *ref.end]
    if len(points) != 2 * dims:
        raise InputError(f"--line: this machine's end effector has {dims} coordinates: give {2 * dims} numbers "
                         f"{axes}, got {len(points)}")
    a, b = np.array(points[:dims]), np.array(points[dims:])
    move = ref.move if args.move is None else args.move
    if move < MIN_MOVE_PERIODS / rate:  # the samples would miss the motion (a short move or a tiny --rate)
        raise InputError(f"--move {move:g} s is shorter than {MIN_MOVE_PERIODS} control periods "
                         f"({MIN_MOVE_PERIODS / rate:g} s at {rate:g} Hz): the torque table would not hold the move")
    # the elastic inverse's torques hold the path's 4th derivative: C^4 (nonic) unless told
    elastic = args.method == "elastic" or (args.method == "shaped" and args.shaped_inverse == "elastic")
    law = args.law or ("nonic" if elastic else "quintic")
    line = make_line(a, b, ref.move if args.move is None else args.move,
                     ref.hold if args.hold is None else args.hold, law_order(law))
    samples = line.duration * rate
    if not samples <= MAX_TORQUE_SAMPLES:  # before allocating the table
        raise InputError(f"--move {line.move:g} s + --hold {line.hold:g} s at --rate {rate:g} Hz means {samples:.4g} "
                         f"samples, more than the limit of {MAX_TORQUE_SAMPLES:.0e}")
    task = Task(Mechanism(model))
    if task.kind == "platform" and task.size == 6:  # a pose: the line's points and an orientation at each end
        rpy = np.radians(args.rpy if args.rpy is not None else [0.0] * 6)
        start, end = np.concatenate([line.start, rpy[2::-1]]), np.concatenate([line.end, rpy[:2:-1]])
        line = PoseLine(start, end, line.move, line.hold, law_order(law))
    elif args.rpy is not None:
        raise InputError(f"--rpy: {model.name} has no platform orientation to command (its task coordinates: "
                         f"{', '.join(task.names)})")
    times, torques, names, _ = feedforward_table(model, line, rate, args.method, args.shaper, args.shaped_inverse,
                                                 args.elastic_inverse)
    write_torque_csv(args.out, times, torques, names)
    print(f"{len(times)} samples at {rate:g} Hz -> {args.out}  (peak |tau| "
          + ", ".join(f"{n} {v:.3f} N m" for n, v in zip(names, np.abs(torques).max(0), strict=True)) + ")")
    return 0


def _control_rate(args: argparse.Namespace) -> float:
    """feedforward's --rate (default: the reference manoeuvre's), and --move, --hold checked before any work."""
    from elastic_pm_dyn.errors import InputError
    from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE as ref
    for name in ("move", "hold"):
        value = getattr(args, name)
        if value is not None and not (np.isfinite(value) and value >= 0):
            raise InputError(f"--{name} must be a finite number of seconds >= 0, got {value!r}")
    rate = ref.control_rate if args.rate is None else args.rate
    if not rate <= MAX_CONTROL_RATE:
        raise InputError(f"--rate {rate:g} Hz is more than the {MAX_CONTROL_RATE:g} Hz a torque table may have "
                         "(10x the fastest torque loops; rows beyond hold no information)")
    return rate


def _waypoint_feedforward(args: argparse.Namespace, model, rate: float) -> int:
    """feedforward --waypoints: poses of the task coordinates or motor positions with times."""
    from elastic_pm_dyn.errors import InputError
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE as ref
    from elastic_pm_dyn.motion.task import Task
    from elastic_pm_dyn.motion.time_laws import law_order
    from elastic_pm_dyn.motion.waypoints import WaypointPath, joint_waypoint_torques, read_waypoints
    from elastic_pm_dyn.sim.held_feedforward import feedforward_table
    from elastic_pm_dyn.sim.torque import write_torque_csv
    if args.line is not None or args.rpy is not None or args.move is not None:
        raise InputError("--waypoints replaces --line, --rpy and --move: the file gives the poses and their times")
    columns, table = read_waypoints(args.waypoints)
    mech = Mechanism(model)
    task = Task(mech)
    span = float(table[-1, 0] - table[0, 0])
    if not span >= MIN_MOVE_PERIODS / rate:  # the samples would miss the motion
        raise InputError(f"--waypoints span {span:g} s, shorter than {MIN_MOVE_PERIODS} control periods "
                         f"({MIN_MOVE_PERIODS / rate:g} s at {rate:g} Hz): the torque table would not hold the move")
    hold = ref.hold if args.hold is None else args.hold
    samples = (float(table[-1, 0]) + hold) * rate
    if not samples <= MAX_TORQUE_SAMPLES:  # before any solve
        raise InputError(f"--waypoints up to t = {table[-1, 0]:g} s + --hold {hold:g} s at --rate {rate:g} Hz means "
                         f"{samples:.4g} samples, more than the limit of {MAX_TORQUE_SAMPLES:.0e}; send it in parts")
    elastic = args.method == "elastic" or (args.method == "shaped" and args.shaped_inverse == "elastic")
    law = args.law or ("nonic" if elastic else "quintic")
    if columns == task.names:
        path = WaypointPath(table[:, 0], table[:, 1:], hold, law_order(law))
        times, torques, names, _ = feedforward_table(model, path, rate, args.method, args.shaper,
                                                     args.shaped_inverse, args.elastic_inverse)
    elif all(n in columns for n in mech.active_names):
        if args.method != "rigid":
            raise InputError("--waypoints with motor positions: rigid only (the elastic inverse prescribes the "
                             f"end effector: give columns t,{','.join(task.names)})")
        times, torques, names = joint_waypoint_torques(model, columns, table, rate, hold)
    else:
        raise InputError(f"--waypoints columns {','.join(columns)}: expected t,{','.join(task.names)} (poses) or "
                         f"t,{','.join(mech.active_names)} [with _vel, _acc columns] (motor positions)")
    write_torque_csv(args.out, times, torques, names)
    print(f"{len(times)} samples at {rate:g} Hz -> {args.out}  ({len(table)} waypoints, {args.method})")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.dynamics.linear import dry_friction_step, elastic_modes
    from elastic_pm_dyn.kinematics.assembly import initial_state
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    model = _load(args)
    mech = Mechanism(model)
    print(f"model {model.name} ({model.source}): {mech.n_chains} chains, {mech.n} tree joints")
    # Free joints: passive motions the closures leave free (a rod spinning between two
    # balls), independent coordinates without a spring; they have no elastic mode.
    free = np.array([i for i in mech.elastic if model.joints[i].stiffness == 0.0], dtype=np.int64)
    sprung = np.array([i for i in mech.elastic if model.joints[i].stiffness > 0.0], dtype=np.int64)
    for role, idx in (("active", mech.active), ("elastic", sprung), ("passive", mech.passive)):
        print(f"  {role:8s} {len(idx)}: {', '.join(mech.joint_names[i] for i in idx) or '-'}")
    loop_springs = [mech.joint_names[i] for i in mech.passive if model.joints[i].stiffness > 0.0]
    if loop_springs:
        print(f"  sprung passive {len(loop_springs)}: {', '.join(loop_springs)} (springs on joints the loops fix: "
              "they act, the loops set the joints)")
    if len(free):
        print(f"  free     {len(free)}: {', '.join(mech.joint_names[i] for i in free)} "
              "(left free by the closures: unactuated, no spring)")
    print(f"  closure equations {mech.m}; non-redundant coordinates q_ae: {len(mech.ae)}")
    couplings = model.closure.couplings if model.closure is not None else ()
    for terms, constant in couplings:
        sum_text = " + ".join(f"{c:g}*{name}" for name, c in terms).replace("+ -", "- ")
        print(f"  coupling: {sum_text} = {constant:.9g} (a closure row)")
    for motor, terms in model.transmissions:
        on = ", ".join(f"{name} with {c:g} u" for name, c in terms)
        print(f"  transmission: motor {motor}'s input u (a fixed tendon's force, a servo's ctrl) drives {on}")
    for motor, low, high in model.input_ranges:
        print(f"  input range: motor {motor}'s input u clamped to [{low:g}, {high:g}] (a servo's ctrlrange, a "
              "motor's ctrl and force ranges)")
    for line in _dropped_rows(model):
        print(line)
    q = initial_state(mech)
    print("start pose:")
    for name, value in zip(mech.joint_names, q, strict=True):
        print(f"  {name:20s} {value: .9f}")
    print(f"  end effector ({', '.join(mech.ee_names)}) {np.array2string(mech.end_effector(q), precision=6)} m")
    if mech.model.planar:
        u, v, n = mech.model.plane_basis
        print(f"  planar: in the plane normal to {np.round(n, 6).tolist()}"
              + ("" if mech.ee_unit is not None else f"; u = {np.round(u, 6).tolist()}, v = {np.round(v, 6).tolist()}"))
    # The assembly mode as initial_state.assembly_mode spells it: keep it to pin the mode.
    print("  assembly mode: " + (", ".join(f"{mech.joint_names[i]} {'positive' if np.sin(q[i]) >= 0 else 'negative'}"
                                           for i in mech.passive if model.joints[i].type == "revolute") or "-"))
    print(f"  closure residual {mech.gap(q):.3g} m")
    _print_one_pass_factor(mech, q)
    if len(sprung):
        modes = elastic_modes(mech, q, clamp_motors=True)
        print("elastic modes at the start pose (motors clamped"
              + (", free joints included at 0 Hz):" if len(free) else "):"))
        for k, (f, zeta) in enumerate(zip(modes.natural_hz, modes.damping_ratio, strict=True)):
            print(f"  mode {k + 1}: {f:9.2f} Hz undamped, "
                  + (f"damping ratio {zeta:.4f}" if zeta == zeta
                     else "no oscillation" + (" (a free joint: no spring)" if f == 0 else " (overdamped)")))
        # RK4 is stable for undamped modes while |h omega| <= 2 sqrt(2).
        dt_max = 2 * np.sqrt(2) / (2 * np.pi * modes.natural_hz.max())
        print(f"  fixed-step RK4 needs dt < {dt_max:.3g} s for the fastest mode (use about a quarter "
              "of that for accuracy)")
        _print_integrator_steps(mech, q, dt_max)
    else:
        print("no elastic joints: no elastic modes")
    dry = dry_friction_step(mech, q)
    if dry is not None:
        print(f"dry friction (F tanh(qd / v_s)): fixed-step RK4 needs dt < about {dry[0]:.3g} s (joint {dry[1]}: "
              "F / v_s over its inertia); a larger --slip-speed relaxes it, a smaller one sticks better")
    return 0


def _dropped_rows(model) -> list[str]:
    """One line per closure pair with rows dropped: rows that hold by themselves (Closure.reduced,
    Closure.projected) and rows that repeat other loops' (Closure.repeated)."""
    closure = model.closure
    if closure is None:
        return []
    bodies = model.point_bodies()

    def on(i: int) -> str:
        return f"body of joint {model.joints[bodies[i]].name}" if bodies[i] >= 0 else "base"

    out = []
    for k, frame in closure.reduced:
        a, b = closure.pairs[k]
        n = np.round(np.asarray(frame)[:, 2], 6).tolist()
        out.append(f"  dropped  row {n} of closure {k + 1} ({on(a)} = {on(b)}; the direction in the frame of the "
                   f"first): it holds by itself, every joint moving both points alike along it (a loop of hinges "
                   "parallel to it, closed by a 3-D point); the two rows across it are kept")
    repeated = dict(closure.repeated)
    welded = set(closure.welds)
    # a planar machine's pairs have rows in the plane alone (frame columns 0, 1; a weld's turn about 2)
    rows = 0b100011 if tuple(closure.components) == (0, 1) else 0b111111
    for k, frame, mask in closure.projected:
        a, b = closure.pairs[k]
        F = np.asarray(frame)
        n = np.round(F[:, 2], 6).tolist()
        again = repeated.get(k, 0)
        if again:
            what = [f"position along {np.round(F[:, i], 6).tolist()}" for i in range(3) if again & (1 << i)] + \
                [f"turn about {np.round(F[:, i], 6).tolist()}" for i in range(3) if again & (8 << i)]
            frame_of = "the weld's frame" if (a, b) in welded else "the frame of the first"
            kept = bin(mask).count("1")
            out.append(f"  dropped  {_rows_text(len(what))} of closure {k + 1} ({on(a)} = {on(b)}; directions in "
                       f"{frame_of}): {', '.join(what)}: {'they repeat rows' if len(what) > 1 else 'it repeats rows'} "
                       f"of the other closures (a body closed twice, loops sharing joints); {_rows_text(kept)} kept")
        if (a, b) not in welded:
            for i in [i for i in range(3) if rows & ~mask & ~again & (1 << i)]:  # a reduced pair's row
                out.append(f"  dropped  row {np.round(F[:, i], 6).tolist()} of closure {k + 1} ({on(a)} = {on(b)}; "
                           "the direction in the frame of the first): it holds by itself, every joint moving both "
                           "points alike along it")
            continue
        still = rows & ~mask & ~again
        if not still:
            continue
        pos = [i for i in range(3) if still & (1 << i)]
        turn = [i for i in range(3) if still & (8 << i)]
        what = [f"position along {np.round(F[:, i], 6).tolist()}" for i in pos] + \
            [f"turn about {np.round(F[:, i], 6).tolist()}" for i in turn]
        out.append(f"  dropped  {len(pos) + len(turn)} rows of weld {k + 1} ({on(a)} = {on(b)}; directions in the "
                   f"weld's frame): {', '.join(what)}: they hold by themselves (a loop of hinges parallel to {n}, "
                   f"closed by a 6-D weld); {bin(mask).count('1')} rows kept")
    return out


def _print_one_pass_factor(mech, q: np.ndarray) -> None:
    """The paper's one-pass SCDD at the start pose: its convergence factor and what follows (dynamics/one_pass.py)."""
    from elastic_pm_dyn.dynamics.one_pass import one_pass_convergence_factor
    if mech.m == 0:
        print("  --method scdd_one_pass: no closure rows, nothing to iterate (it is exact SCDD)")
        return
    rho = one_pass_convergence_factor(mech, q)
    verdict = ("converges (its lag shrinks by this factor per evaluation)" if rho < 1.0
               else "diverges: refused here, use scdd (the default)")
    print(f"  --method scdd_one_pass: convergence factor {rho:.3g} at the start pose; it {verdict}")


def _rows_text(n: int) -> str:
    return f"{n} row" if n == 1 else f"{n} rows"


def _print_integrator_steps(mech, q: np.ndarray, rk4_limit: float) -> None:
    """One line per integrator: the step it needs and why (bench/benchmarks/README_integrators.md)."""
    from elastic_pm_dyn.sim import exponential
    rate, n_sub = exponential.substeps_at(mech, q, exponential.RECOMMENDED_STEP)
    print("integrators (step for branch forces within 1 % of their elastic part, "
          "bench/benchmarks/README_integrators.md):")
    print(f"  rk4:  stability limit {rk4_limit:.3g} s (fastest mode); the accuracy needed {rk4_limit / 30:.2g}-"
          f"{rk4_limit / 4:.2g} s (1/30 to 1/4 of the limit) on the machines measured")
    print(f"  etd2: no stability limit from the springs (integrated exactly: {n_sub} sub-steps per "
          f"{exponential.RECOMMENDED_STEP:g} s step, fastest frozen rate below {rate / (2 * np.pi):.4g} Hz); "
          f"dt = {exponential.RECOMMENDED_STEP:g} s for torques held per 1 ms control period (6 of 7 machines "
          f"measured; the Triglide at n_ek = 4 needed {exponential.RECOMMENDED_STEP / 2:g} s), "
          f"{exponential.RECOMMENDED_STEP / 2:g} s for smooth torques up to ~1 kHz; not with --method lda")
    print("  dop853: adaptive (rtol); the reference, slow (Python right-hand side)")


def cmd_urdf(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.model.urdf_writer import model_to_urdf
    text = model_to_urdf(_load(args))
    if args.out is None:
        sys.stdout.write(text if text.endswith("\n") else text + "\n")
    else:
        from elastic_pm_dyn.output_files import write_text
        write_text(args.out, text)
        print(f"URDF -> {args.out}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.demo import run_offline_demo
    run_offline_demo(Path(args.out), Path(args.model))
    return 0


def _ros_argv(params_file: str | None, overrides: dict[str, str], extra: list[str]) -> list[str]:
    """argv for a node's main(): one --ros-args section, the user's own arguments last (they win)."""
    argv = ["elastic-pm-dyn", "--ros-args"]
    if params_file:
        argv += ["--params-file", params_file]
    for name, value in overrides.items():
        argv += ["-p", f"{name}:={value}"]
    return argv + extra


def _add_ros_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=[], metavar="ARG",
                   help="the rest of the line goes to ROS, e.g. --ros-args -p dt:=5.0e-5 -r __node:=plant2")


def cmd_plant(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.ros.plant.node import main as plant_main
    overrides = {k: v for k, v in (("sync_mode", args.sync), ("model", args.model)) if v}
    return plant_main(_ros_argv(args.params_file, overrides, args.ros_args))


def cmd_observer(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.ros.observer.node import main as observer_main
    overrides = {"model": args.model} if args.model else {}
    return observer_main(_ros_argv(args.params_file, overrides, args.ros_args))


def cmd_record(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.ros.recorder.node import main as recorder_main
    overrides = {"output": args.out, "storage": args.storage}
    if args.topics:
        overrides["topics"] = "[" + ", ".join(args.topics) + "]"
    return recorder_main(_ros_argv(args.params_file, overrides, args.ros_args))


def cmd_bag_repair(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.bags.repair import repair_bag
    report = repair_bag(args.bag, args.out)
    print("\n".join(report.lines()))
    return 0


def cmd_ros_demo(args: argparse.Namespace) -> int:
    from elastic_pm_dyn.errors import InputError
    from elastic_pm_dyn.ros.demos.demo import run_ros_demo
    from elastic_pm_dyn.ros.demos.processes import NodeProcessError
    loop_only = [f"--{n.replace('_', '-')}" for n in ("elastic_dof_per_chain", "seed", "duration", "observer_config",
                                                      "kp", "kd") if getattr(args, n) is not None]
    if args.observer and args.feedforward != "rigid":
        raise InputError("--feedforward elastic: the open-loop demo only (not with --observer)")
    if loop_only and not args.observer:
        raise InputError(f"{', '.join(loop_only)}: only with --observer (the closed loop)")
    try:
        if args.observer:
            from elastic_pm_dyn.ros.demos.loop_demo import LoopOptions, run_loop_demo
            if args.sync != "lockstep":
                raise InputError("--observer runs in lockstep only")
            opts = LoopOptions(Path(args.model), args.elastic_dof_per_chain, 1 if args.seed is None else args.seed,
                               2.0 if args.duration is None else args.duration,
                               Path(args.observer_config) if args.observer_config else None, args.kp, args.kd,
                               storage=args.storage, timeout=args.timeout or 1800.0, domain_id=args.domain_id)
            run_loop_demo(Path(args.out), opts)
            return 0
        run_ros_demo(Path(args.out), Path(args.model), args.sync, args.storage, args.timeout or 120.0, args.domain_id,
                     feedforward=args.feedforward)
    except NodeProcessError as err:
        print(f"elastic-pm-dyn: error: {err}", file=sys.stderr)
        return EXIT_RUN_FAILED
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="elastic-pm-dyn", description="Dynamics of elastic parallel manipulators")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("simulate", help="simulate a model under a torque table")
    _add_model(p, dof=True)
    p.add_argument("--torques", required=True, help="CSV with header t,<active joint names>")
    p.add_argument("--duration", type=float, required=True, help="[s]")
    p.add_argument("--out", required=True, help="output CSV")
    p.add_argument("--hold", choices=("zoh", "linear"), default="zoh")
    _add_simulation_options(p)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("feedforward", help="inverse-dynamics torques of a straight line: the rigid model's or the "
                       "elastic model's (--method elastic)")
    _add_model(p, dof=True)
    # Unset options take the reference manoeuvre's values (motion.manoeuvre), read when the command runs.
    p.add_argument("--line", type=float, nargs="+", metavar="X",
                   help="start and end point: XA YA XB YB (planar) or six numbers (spatial); "
                        "default: the reference manoeuvre's")
    p.add_argument("--move", type=float, help="move time [s] (default: the reference manoeuvre's)")
    p.add_argument("--hold", type=float, help="hold time at the end [s] (default: the reference manoeuvre's)")
    p.add_argument("--rate", type=float, help="sample rate [Hz] (default: the reference manoeuvre's)")
    p.add_argument("--method", choices=("rigid", "elastic", "shaped"), default="rigid",
                   help="rigid: the rigid model's inverse dynamics sampled at t_k; elastic: the elastic model's "
                        "(the deflections compensated; --elastic-inverse picks how the hold is treated); shaped: "
                        "the rigid inverse of the path through an input shaper of the elastic modes (--shaper)")
    p.add_argument("--elastic-inverse", choices=("held", "continuous"), default="held",
                   help="the elastic inverse (--method elastic, or shaped with --shaped-inverse elastic): held "
                        "(default): the samples solved for the machine that holds them at --rate, which follows "
                        "the path and ends at rest; continuous: the continuous inverse, each sample its mean over "
                        "the period (faster to compute; the hold leaves micrometres of path error and a drift)")
    p.add_argument("--shaper", choices=("zv", "zvd", "ei"), default="zvd",
                   help="--method shaped: the shaper (default zvd), built from the free-motor elastic modes at the "
                        "path's start and end; the move lengthens by its length")
    p.add_argument("--shaped-inverse", choices=("rigid", "elastic"), default="rigid",
                   help="--method shaped: the inverse dynamics after the shaper (default rigid)")
    p.add_argument("--law", choices=("quintic", "septic", "nonic"),
                   help="rest-to-rest time law (C^2, C^3, C^4); default quintic for rigid, nonic for elastic")
    p.add_argument("--rpy", type=float, nargs=6, metavar=("RA", "PA", "YA", "RB", "PB", "YB"),
                   help="a 6-DOF platform's orientation at the start and the end: roll pitch yaw [deg] "
                        "(R = Rz(yaw) Ry(pitch) Rx(roll)), interpolated on SO(3) with the line's time law; "
                        "default 0 (level)")
    p.add_argument("--waypoints", help="CSV t,<task coordinates> (poses: rest-to-rest segments through them) or "
                   "t,<active joints>[,<joint>_vel ...][,<joint>_acc ...] (motor positions, rigid only) "
                   "instead of --line")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_feedforward)

    p = sub.add_parser("check", help="DOF, start pose, closure residual, natural frequencies")
    _add_model(p, positional=True, dof=True)
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("urdf", help="the machine as URDF (for robot_state_publisher and RViz); "
                       "a URDF machine's own file unchanged")
    _add_model(p, positional=True, dof=True)
    p.add_argument("--out", help="URDF file to write (default: standard output)")
    p.set_defaults(func=cmd_urdf)

    p = sub.add_parser("demo", help="the reference manoeuvre: feedforward -> SCDD and L-D'A -> CSV + plots")
    p.add_argument("--model", default=str(Path(__file__).resolve().parent.parent / "config" / "five_bar.yaml"))
    p.add_argument("--out", default="runs/demo")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("plant", help="ROS 2 plant node: the elastic model in the loop (see config/plant.yaml)")
    p.add_argument("--params-file", help="ROS parameter YAML (e.g. config/plant.yaml)")
    p.add_argument("--sync", choices=("realtime", "fast", "lockstep"), help="sync mode (overrides the file)")
    p.add_argument("--model", help="model YAML (overrides the file)")
    _add_ros_args(p)
    p.set_defaults(func=cmd_plant)

    p = sub.add_parser("observer", help="ROS 2 observer node: the state observer (EKF) live, estimates on the "
                       "plant's topics (see config/observer_node.yaml)")
    p.add_argument("--params-file", help="ROS parameter YAML (e.g. config/observer_node.yaml)")
    p.add_argument("--model", help="model YAML (overrides the file)")
    _add_ros_args(p)
    p.set_defaults(func=cmd_observer)

    p = sub.add_parser("record", help="record ROS 2 topics into a rosbag2 (mcap or sqlite3) with rosbags")
    p.add_argument("--out", default="bag", help="bag directory to create (default: bag)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="topics (default: the demo's)")
    p.add_argument("--params-file", help="ROS parameter YAML (e.g. config/recorder.yaml)")
    _add_ros_args(p)
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("bag-repair", help="a finished copy of a bag cut off or damaged (a killed recorder): "
                       "every message that can be read, same storage, topics and types")
    p.add_argument("bag", help="bag directory (or its .mcap/.db3 file)")
    p.add_argument("--out", help="bag directory to create (default: <bag>_repaired next to it)")
    p.set_defaults(func=cmd_bag_repair)

    p = sub.add_parser("ros-demo", help="the reference manoeuvre through ROS 2: plant + feedforward + recorder "
                       "processes -> bag, plots, summary")
    p.add_argument("--model", default=str(Path(__file__).resolve().parent.parent / "config" / "five_bar.yaml"))
    p.add_argument("--out", default="runs/demo")
    p.add_argument("--sync", choices=("lockstep", "realtime", "fast"), default="lockstep",
                   help="lockstep: deterministic, equals offline simulate (default); realtime: wall-clock paced; "
                        "fast: the plant runs ahead of the wall clock, the feedforward answers each state")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    p.add_argument("--feedforward", choices=("rigid", "elastic"), default="rigid",
                   help="the feedforward node's method: rigid (default) or elastic (the elastic inverse on the "
                        "9th-order law: the manoeuvre without its ringing)")
    p.add_argument("--timeout", type=float, help="[s] limit for the run (default 120; with --observer 1800)")
    p.add_argument("--domain-id", type=int, help="ROS domain id 0-232 (default: ROS_DOMAIN_ID when it is set, so "
                   "the shell's ros2 tools see the run; else a private one from the process id)")
    p.add_argument("--observer", action="store_true",
                   help="the closed loop: plant with sensors and a disturbance, observer node, PD + feedforward "
                        "controller, recorder; summary with estimate vs truth vs open loop "
                        "(docs/nodes.md, 'Closing the loop')")
    p.add_argument("--elastic-dof-per-chain", type=int, help="--observer: override the model's discretisation")
    p.add_argument("--seed", type=int, help="--observer: seed of the sensor noise and the disturbance (default 1)")
    p.add_argument("--duration", type=float, help="--observer: [s] of loop (default 2)")
    p.add_argument("--observer-config", help="--observer: observer parameter file, e.g. one written by "
                   "'elastic-pm-dyn tune' (default: the machine's own, observer_<model stem>.yaml beside the model "
                   "as config/observer_hexa.yaml, else config/observer_node.yaml)")
    p.add_argument("--kp", type=float, nargs="+", help="--observer: PD gains [N m/rad], one or one per motor "
                   "(default: a 2 Hz loop, damping 0.1, on the machine's inertia)")
    p.add_argument("--kd", type=float, nargs="+", help="--observer: [N m s/rad], one or one per motor")
    p.set_defaults(func=cmd_ros_demo)
    from elastic_pm_dyn.analysis.cli import register_cli as register_analysis
    from elastic_pm_dyn.calibration.cli import register_cli as register_calibration
    from elastic_pm_dyn.fleet.cli import register_cli as register_batch
    from elastic_pm_dyn.observer.cli import register_cli as register_observer
    register_analysis(sub)
    register_observer(sub)
    register_batch(sub)
    register_calibration(sub)
    return parser


def _validate(args: argparse.Namespace) -> None:
    from elastic_pm_dyn.errors import InputError
    if args.command == "feedforward" and args.line is not None and len(args.line) not in (4, 6):
        raise InputError("--line takes 4 numbers (planar) or 6 (spatial)")
    names = ("duration", "rate") + (("dt", "sample", "rtol", "atol") if args.command == "simulate" else ())
    for name in names:
        value = getattr(args, name, None)
        # not a number at all: argparse turns "--duration=--" into []
        if value is not None and not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
            raise InputError(f"--{name} must be a positive number, got {value!r}")
    if args.command == "simulate" and args.rtol < RTOL_MIN:
        raise InputError(f"--rtol {args.rtol:g} is below the {RTOL_MIN:.3g} DOP853 can honour in double precision")


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    """A warning from the package as one line, like the errors (not Python's two with the source line)."""
    return f"elastic-pm-dyn: warning: {message}\n"


def _names_never_fail_a_terminal() -> None:
    """A joint name a terminal's encoding cannot show (CJK on a Latin-1 console) is printed
    escaped (\\u5de6), not a UnicodeEncodeError traceback: files are written in UTF-8 whatever it is."""
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure") and (stream.encoding or "").lower().replace("-", "") != "utf8":
            stream.reconfigure(errors="backslashreplace")


def main(argv: list[str] | None = None) -> int:
    _names_never_fail_a_terminal()
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    warnings.formatwarning = _one_line_warning
    try:
        _validate(args)
        return func(args)
    except SingularConfigurationError as err:
        _error(err)
        return EXIT_RUN_FAILED
    except ElasticPmDynError as err:
        _error(err)
        return EXIT_USER_ERROR
    except OSError as err:
        _error(err)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:  # outside a run (which writes what it has): nothing to save
        print("elastic-pm-dyn: interrupted (Ctrl-C)", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
