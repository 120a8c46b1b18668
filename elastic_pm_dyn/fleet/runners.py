"""Run one item in a worker: the single-item command's own code, outputs into the item's folder.

``observe``, ``tune`` and ``analyze`` go through the subcommands' own parsers and functions
(:mod:`elastic_pm_dyn.observer.cli`, :mod:`elastic_pm_dyn.analysis.cli`): an item is exactly
``elastic-pm-dyn observe --model M --bag B --out <item folder> <options>``. ``simulate`` runs
what ``elastic-pm-dyn simulate`` runs (load the model and the torque table, ``Simulator.run``,
the CSV); a study point first builds its torques with the rigid feedforward of its own model.
The command's printed lines go to ``log.txt`` in the folder; the summary figures to the
record (``item.json``) and from there to the results table.

:func:`run_item` never raises for an item's fault: it returns a failure record with one line
(Ctrl-C and a killed process are the exceptions: the first stops the batch, the second is
the engine's to retry).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import re
import shutil
import socket
import time
import traceback
import warnings
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import NoReturn

import numpy as np

from elastic_pm_dyn.errors import ElasticPmDynError, InputError
from elastic_pm_dyn.fleet import store, verdict, watchdog
from elastic_pm_dyn.fleet.items import Item
from elastic_pm_dyn.output_files import atomic_dir, write_text

MAX_ERROR = 400  # characters of a failure's line
VOLATILE = ("wall", "speed_factor", "elapsed")  # figure names that measure the machine, not the result


def one_line(text: object) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= MAX_ERROR else line[:MAX_ERROR - 3] + "..."


class _Parser(argparse.ArgumentParser):
    """A subcommand's parser whose mistakes are an InputError (one line), not an exit."""

    def error(self, message: str) -> NoReturn:
        raise InputError(f"{self.prog}: {message}")

    def exit(self, status: int = 0, message: str | None = None) -> NoReturn:
        raise InputError(one_line(message or f"{self.prog}: exit {status}"))


def command_parser() -> argparse.ArgumentParser:
    """``elastic-pm-dyn`` with the observe, tune and analyze subcommands, mistakes as InputError."""
    from elastic_pm_dyn.analysis.cli import register_cli as register_analysis
    from elastic_pm_dyn.observer.cli import register_cli as register_observer
    parser = _Parser(prog="elastic-pm-dyn")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    register_observer(sub)
    register_analysis(sub)
    return parser


def _command(argv: list[str]) -> argparse.Namespace:
    return command_parser().parse_args(argv)


def _run_command(argv: list[str]) -> None:
    args = _command(argv)
    code = args.func(args)
    if code:
        raise _CommandFailed(code)


class _CommandFailed(Exception):
    """A subcommand returned a non-zero status; its reason is the last error line it printed."""


def leaves(d: Mapping, prefix: str = "") -> dict[str, float | int | str | bool | None]:
    """Scalar leaves of nested mappings, named ``a.b.c``; lists of up to 6 numbers as ``a.0`` ..."""
    out: dict[str, float | int | str | bool | None] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(leaves(v, name + "."))
        elif isinstance(v, list | tuple) and 0 < len(v) <= 6 and all(isinstance(x, int | float) for x in v):
            out.update({f"{name}.{i}": x for i, x in enumerate(v)})
        elif v is None or isinstance(v, bool | int | float | str):
            out[name] = v
    return out


def _observe(item: Item, work: Path) -> dict:
    _run_command(["observe", "--model", item.model, "--bag", item.source, "--out", str(work), *item.argv_options()])
    summary = store.read_json(work / "summary.json") or {}
    verdict.check_observe(summary)
    figures = {k: v for k, v in leaves(summary).items() if not isinstance(v, str)}
    health = summary.get("health")
    if isinstance(health, list) and health and isinstance(health[0], int):
        figures["health_level"] = health[0]  # 0 fine; the message is in summary.json
    return figures


NLL = re.compile(r"NLL \(gate off\): (\S+) -> (\S+)")


def _tune(item: Item, work: Path, log: io.StringIO) -> dict:
    from elastic_pm_dyn.model import yaml12
    out = work / "tuned.yaml"
    options = item.argv_options()
    if "--threads" not in options:  # the pool already fills the cores; a pass per thread would oversubscribe
        options += ["--threads", "1"]
    _run_command(["tune", "--model", item.model, "--bag", item.source, "--out", str(out), *options])
    verdict.check_tune(log.getvalue())
    figures: dict = {}
    match = NLL.search(log.getvalue())
    if match:
        figures["nll_before"], figures["nll_after"] = float(match[1]), float(match[2])
    data = yaml12.load_file(out)
    for body in (data or {}).values():
        if isinstance(body, dict) and isinstance(body.get("ros__parameters"), dict):
            observer = body["ros__parameters"].get("observer")
            if isinstance(observer, dict):
                figures.update({f"tuned.{k}": v for k, v in leaves(observer).items() if not isinstance(v, str)})
    return figures


def _analyze(item: Item, work: Path) -> dict:
    _run_command(["analyze", item.source, "--model", item.model, "--out", str(work), *item.argv_options()])
    summary = store.read_json(work / "summary.json") or {}
    from elastic_pm_dyn.model.loader import load_model
    verdict.check_analyze(summary, load_model(item.model).active_names)
    runs = summary.get("runs") or {}
    figures = leaves(next(iter(runs.values()))) if len(runs) == 1 else leaves(runs)
    return {k: v for k, v in figures.items() if not isinstance(v, str)}


def simulation_parser() -> argparse.ArgumentParser:
    """``elastic-pm-dyn simulate``'s options (the item gives model, torques and output)."""
    from elastic_pm_dyn.dynamics.direct import FORMULATIONS
    from elastic_pm_dyn.sim.simulator import INTEGRATORS, STABILIZATIONS
    p = _Parser(prog="elastic-pm-dyn simulate")
    p.add_argument("--duration", type=float, help="[s] (default: the torque table's last time)")
    p.add_argument("--hold", choices=("zoh", "linear"), default="zoh")
    p.add_argument("--method", choices=FORMULATIONS, default="scdd")
    p.add_argument("--integrator", choices=INTEGRATORS, default="rk4")
    p.add_argument("--dt", type=float, default=1e-4)
    p.add_argument("--rtol", type=float, default=1e-10)
    p.add_argument("--atol", type=float, default=1e-12)
    p.add_argument("--stabilization", choices=tuple(STABILIZATIONS), default="projection")
    p.add_argument("--sample", type=float, default=1e-3)
    p.add_argument("--elastic-dof-per-chain", type=int)
    p.add_argument("--closures")
    p.add_argument("--fix-base", action="store_true")
    p.add_argument("--servos-as-motors", action="store_true")
    return p


def _options(method: str, integrator: str, dt: float, rtol: float, atol: float, stabilization: str, sample: float):
    from elastic_pm_dyn.sim.simulator import SimulationOptions
    for name, value in (("dt", dt), ("rtol", rtol), ("atol", atol), ("sample", sample)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"--{name} must be a positive number, got {value!r}")
    return SimulationOptions(formulation=method, integrator=integrator, dt=dt, rtol=rtol, atol=atol,
                             stabilization=stabilization, sample=sample)


def _simulate(item: Item, work: Path) -> dict:
    if item.study:
        return _study_point(item, work)
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.sim.simulator import Simulator
    from elastic_pm_dyn.sim.torque import load_torque_csv
    a = simulation_parser().parse_args(item.argv_options())
    mech = Mechanism(load_model(item.model, a.elastic_dof_per_chain, a.closures, a.fix_base, a.servos_as_motors))
    sim = Simulator(mech, _options(a.method, a.integrator, a.dt, a.rtol, a.atol, a.stabilization, a.sample))
    torque = load_torque_csv(item.source, mech.active_names, a.hold)
    duration = float(torque.times[-1] - torque.times[0]) if a.duration is None else a.duration
    sim.check_run_size(duration, prefix="--")
    result = sim.run(torque, duration)
    result.to_csv(work / "simulation.csv")
    return simulation_figures(result)


def study_model(model, p: Mapping):
    """The model with a study point's parameters (see study.MODEL_PARAMETERS): the scales
    first (mass_scale includes the end-effector mass the loader lumped into the chain ends),
    then the payload added at the end effector."""
    k, d, m = (float(p.get(name, 1.0)) for name in ("stiffness_scale", "damping_scale", "mass_scale"))

    def joint(j):
        if j.role == "elastic":
            j = replace(j, stiffness=j.stiffness * k, damping=j.damping * d)
        if j.body is not None and m != 1.0:
            j = replace(j, body=replace(j.body, mass=j.body.mass * m, inertia=j.body.inertia * m))
        return j

    chains = [replace(c, joints=tuple(joint(j) for j in c.joints)) for c in model.chains]
    payload = float(p.get("payload", 0.0))
    if payload > 0:  # a point mass at the end effector, split over the chain ends as the loader lumps the model's own
        from elastic_pm_dyn.model.description import Body
        closure = model.closure
        owners = (0,) if closure is None else (closure.hub,) if closure.hub >= 0 else closure.chains
        for ci in owners:
            c = chains[ci]
            last = c.joints[-1]
            point = Body(payload / len(owners), c.end_xyz.copy(), np.zeros((3, 3)))
            body = point if last.body is None else last.body.combined(point)
            chains[ci] = replace(c, joints=c.joints[:-1] + (replace(last, body=body),))
    return replace(model, chains=tuple(chains), end_effector_mass=model.end_effector_mass + payload)


def _study_point(item: Item, work: Path) -> dict:
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.motion.feedforward import line_torques
    from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE as ref
    from elastic_pm_dyn.motion.trajectory import make_line
    from elastic_pm_dyn.sim.simulator import Simulator
    from elastic_pm_dyn.sim.torque import TorqueTable, write_torque_csv
    p = dict(item.study)
    model = study_model(load_model(item.model, p.get("elastic_dof_per_chain"), p.get("closures")), p)
    dims = len(model.ee_names)
    points = p.get("line", (*ref.start, *ref.end))
    if len(points) != 2 * dims:
        raise InputError(f"the study's line has {len(points)} numbers; this machine's end effector has {dims} "
                         f"coordinates: give 'line' with {2 * dims}")
    rate = float(p.get("rate", ref.control_rate))
    line = make_line(np.array(points[:dims]), np.array(points[dims:]), float(p.get("move", ref.move)),
                     float(p.get("hold", ref.hold)))
    times, torques, names = line_torques(model, line, rate)
    write_torque_csv(work / "torques.csv", times, torques, names)
    mech = Mechanism(model)
    sim = Simulator(mech, _options(str(p.get("method", "scdd")), str(p.get("integrator", "rk4")),
                                   float(p.get("dt", 1e-4)), float(p.get("rtol", 1e-10)), float(p.get("atol", 1e-12)),
                                   str(p.get("stabilization", "projection")), float(p.get("sample", 1e-3))))
    sim.check_run_size(line.duration)
    result = sim.run(TorqueTable(times, torques), line.duration)
    result.to_csv(work / "simulation.csv")
    figures = simulation_figures(result)
    target = np.array([line(t)[0] for t in result.t])
    error = np.linalg.norm(result.ee - target, axis=1)
    figures["path_error_max_m"] = float(error.max())
    hold = result.t >= line.move
    figures["residual_vibration_m"] = float(error[hold].max()) if hold.any() else float("nan")
    return figures


def simulation_figures(result) -> dict:
    """Peak branch forces and torques, the closure gap, the elastic joints' peak deflection."""
    mech = result.mech
    figures: dict = {"samples": len(result.t), "max_gap_m": float(np.max(result.gap))}
    force = np.abs(result.branch_forces)
    if force.size:
        figures["peak_branch_force_N"] = float(force.max())
        for b, col in zip(mech.model.branches, force.T, strict=True):
            figures[f"peak_F.{b.name}"] = float(col.max())
    for name, col in zip(mech.active_names, np.abs(result.tau).T, strict=True):
        figures[f"peak_tau.{name}"] = float(col.max())
    for i in mech.elastic:
        figures[f"peak_deflection.{mech.joint_names[i]}"] = float(np.max(np.abs(result.q[:, i])))
    return figures


RUNNERS: dict[str, Callable[..., dict]] = {"observe": _observe, "analyze": _analyze, "simulate": _simulate}


def _figures(item: Item, work: Path, log: io.StringIO) -> dict:
    if item.kind == "tune":
        return _tune(item, work, log)
    return RUNNERS[item.kind](item, work)


def _error_line(err: BaseException, log: str) -> str:
    if isinstance(err, _CommandFailed):  # the command printed its reason
        lines = [ln for ln in log.splitlines() if "error:" in ln] or log.splitlines()[-1:] or [f"exit {err}"]
        return one_line(lines[-1].split("error:", 1)[-1])
    if isinstance(err, ElasticPmDynError | OSError):
        return one_line(err)
    return one_line(f"{type(err).__name__}: {err}")  # a fault of ours: the traceback is in the record


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    return f"elastic-pm-dyn: warning: {message}\n"


def run_item(item: Item, out: str | Path, attempt: int | None = 1, timeout: float | None = None) -> dict:
    """Run ``item`` into ``out/items/<id>`` (complete or not at all); its record (see the module docstring).

    An item already complete in ``out`` is not run again: its record comes from disk (an
    engine that re-runs a task whose result it lost, as Dask does when a worker dies).
    ``attempt`` None: counted in ``out`` (an engine that retries by itself); ``timeout``: the
    process kills itself when the item runs longer (an engine that cannot see a hung task)."""
    out = Path(out)
    done = store.complete(out, item)
    if done is not None:
        return {**done, "reused": True}
    attempt = store.begin_attempt(out, item) if attempt is None else attempt
    with watchdog.armed(timeout, lambda: store.note_timeout(out, item, timeout)):
        return _run(item, out, attempt)


def _run(item: Item, out: Path, attempt: int) -> dict:
    target = store.item_dir(out, item)
    base = {"id": item.id, "kind": item.kind, "key": item.key, "attempt": attempt, "host": socket.gethostname(),
            "pid": os.getpid()}
    log = io.StringIO()
    start = time.perf_counter()
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with atomic_dir(target) as work:
            work.mkdir()
            with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log), warnings.catch_warnings():
                warnings.simplefilter("default")
                warnings.formatwarning = _one_line_warning
                figures = _figures(item, work, log)
            record = {**base, "status": "ok", "error": None, "wall_s": time.perf_counter() - start,
                      "warnings": verdict.warnings_of(log.getvalue()), "figures": _clean(figures), "item": item.row()}
            (work / "log.txt").write_text(log.getvalue())
            write_text(work / store.RECORD, json.dumps(record, indent=1, default=str) + "\n")
            if target.exists():  # an older result of other inputs: this one replaces it
                shutil.rmtree(target)
        store.clear_failure(out, item)
        return record
    except KeyboardInterrupt:
        raise
    except (Exception, SystemExit) as err:
        record = {**base, "status": "failed", "error": _error_line(err, log.getvalue()),
                  "warnings": verdict.warnings_of(log.getvalue()),
                  "wall_s": time.perf_counter() - start, "figures": {}, "item": item.row(),
                  "log": log.getvalue()[-4000:],
                  "traceback": None if isinstance(err, ElasticPmDynError | _CommandFailed)
                  else traceback.format_exc()[-4000:]}
        with contextlib.suppress(Exception):  # a full disk: the record still goes back to the batch
            store.write_failure(out, record)
        return record


def _clean(figures: Mapping) -> dict:
    """JSON-safe figures: numpy scalars as Python numbers, non-finite floats as None."""
    out = {}
    for k, v in figures.items():
        if isinstance(v, np.generic):
            v = v.item()
        if isinstance(v, float) and not math.isfinite(v):
            v = None
        out[k] = v
    return out


def deterministic(figures: Mapping) -> dict:
    """The figures that depend on the inputs only (not the machine's speed)."""
    return {k: v for k, v in figures.items() if not any(w in k for w in VOLATILE)}

