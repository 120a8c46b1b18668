"""Feedforward acceptance bench (issue #24): rigid vs elastic feedforward on the elastic plant.

    .venv/bin/python bench/benchmarks/bench_feedforward.py --out runs/bench_feedforward [--integrator dop853] [--quick]

For every machine (five-bar; Triglide n_ek = 1, 2; Hexa n_ek = 1, 2) and move (the reference
move, which the tests were written on, and three moves no number was tuned on; the Hexa's are
6-D poses, one with a 5 degree turn) the elastic plant is started at rest where the path
starts (its springs loaded by gravity, the end effector on the start point) and driven open
loop at 1 kHz, zero-order hold, by

- ``rigid``: the rigid model's torques sampled at t_k, quintic law (the package's feedforward before);
- ``rigid C4``: the same on the 9th-order law (what the time law alone does);
- ``elastic``: the elastic inverse on the 9th-order law, each sample the mean over its period;
- ``elastic cont.``: the elastic inverse's torques applied continuously (no hold): the ZOH-free
  limit; what separates it from ``elastic`` is the zero-order hold's own excitation;
- ``elastic at 2 kHz``: the elastic inverse held at 2 kHz (model's plant): what the 1 kHz
  hold costs;
- ``shaped``: the rigid torques of the quintic path through a ZVD shaper of the free-motor
  elastic modes (the move longer by the shaper's length; its path deviation against the
  shaped path),

on plants with the model's stiffness and 10 % softer and stiffer. Scores
(:mod:`elastic_pm_dyn.analysis.feedforward_check`): path deviation during the move (distance of
the task coordinates from the path at the same time; the Hexa's mixes m and rad), residual
vibration (largest branch-force deviation from the static value over the hold) and the time
the elastic inverse takes (best of three, wall clock: on a loaded machine it waits for the
CPU). Writes ``feedforward.json`` and ``feedforward.md``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from elastic_pm_dyn.analysis.feedforward_check import score
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import elastic_line_motion, path_shaper, path_torques
from elastic_pm_dyn.motion.poses import PoseLine
from elastic_pm_dyn.motion.shaping import ShapedPath
from elastic_pm_dyn.motion.trajectory import make_line
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import FunctionTorque

ROOT = Path(__file__).resolve().parents[2]
RATE = 1000.0
HOLD = 0.2
DEG = np.pi / 180
FIVE_BAR_MOVES = [("reference", (-0.05, 0.35), (0.05, 0.45), 0.2), ("down-right", (0.0, 0.38), (0.06, 0.33), 0.15),
                  ("left-slow", (0.04, 0.42), (-0.07, 0.40), 0.3), ("short-fast", (-0.03, 0.30), (0.03, 0.40), 0.1)]
TRIGLIDE_MOVES = [("reference", (0, 0, -0.35), (0.03, 0.02, -0.32), 0.2),
                  ("down-back", (0, 0, -0.35), (-0.02, 0.03, -0.37), 0.15),
                  ("sideways", (0.01, -0.01, -0.34), (0.04, -0.03, -0.34), 0.25),
                  ("vertical", (0, 0, -0.35), (0, 0, -0.30), 0.2)]
HEXA_MOVES = [("reference", (0, 0, -0.4, 0, 0, 0), (0.02, 0.02, -0.385, 5 * DEG, 0, 0), 0.2),
              ("tilt", (0, 0, -0.4, 0, 0, 0), (-0.02, 0.01, -0.39, 0, 3 * DEG, -3 * DEG), 0.25),
              ("shift", (0, 0, -0.4, 0, 0, 0), (0.03, -0.02, -0.41, 0, 0, 0), 0.2),
              ("lift", (0, 0, -0.4, 0, 0, 0), (0, 0, -0.37, 0, 0, 0), 0.15)]
MACHINES = [("five_bar", "config/five_bar.yaml", None, FIVE_BAR_MOVES),
            ("triglide n_ek=1", "config/triglide.yaml", 1, TRIGLIDE_MOVES),
            ("triglide n_ek=2", "config/triglide.yaml", 2, TRIGLIDE_MOVES),
            ("hexa n_ek=1", "config/hexa.yaml", 1, HEXA_MOVES),
            ("hexa n_ek=2", "config/hexa.yaml", 2, HEXA_MOVES)]
STIFFNESS = (1.0, 0.9, 1.1)


def _path(start, end, move: float, order: int):
    a, b = np.array(start, dtype=float), np.array(end, dtype=float)
    return PoseLine(a, b, move, HOLD, order) if len(a) == 6 else make_line(a, b, move, HOLD, order)


def run_move(model, start, end, move: float, options: SimulationOptions, stiffness=STIFFNESS) -> dict:
    mech = Mechanism(model)
    c4, quintic = _path(start, end, move, 4), _path(start, end, move, 2)
    seconds = []
    for _ in range(3):
        t0 = time.perf_counter()
        motion = elastic_line_motion(model, c4, 1.0 / RATE)
        seconds.append(time.perf_counter() - t0)
    q0 = motion.q[int(np.argmin(np.abs(motion.t)))]
    static = mech.branch_forces(motion.q[-1], np.zeros(mech.n))
    tables = {"rigid": path_torques(model, quintic, RATE, "rigid"),
              "rigid C4": path_torques(model, c4, RATE, "rigid"),
              "elastic": path_torques(model, c4, RATE, "elastic"),
              "shaped": path_torques(model, quintic, RATE, "shaped", "zvd")}
    paths = {"rigid": quintic, "rigid C4": c4, "elastic": c4,
             "shaped": ShapedPath(quintic, path_shaper(model, quintic, "zvd"))}
    out: dict = {"compute_s": min(seconds), "passes": motion.passes, "scores": {}}
    for k in stiffness:
        plant = mech if k == 1.0 else Mechanism(model.with_stiffness_scaled(k))
        row = {}
        for name, (times, values, _, _) in tables.items():
            row[name] = score(plant, times, values, q0, paths[name], paths[name].move, c4.duration, static,
                              options).as_dict()
        out["scores"][f"{k:g}"] = row
    # the ZOH-free limit on the model's plant: the continuous elastic torques
    r = Simulator(mech, options).run(FunctionTorque(motion.torque()), c4.duration, q0=q0)
    from elastic_pm_dyn.motion.task import Task
    task = Task(mech)
    y = np.array([task.coordinates(q) for q in r.q])
    y_ref = np.array([c4(float(t))[0] for t in r.t])
    moving = r.t <= move
    out["continuous"] = {"path_deviation": float(np.linalg.norm(y - y_ref, axis=1)[moving].max()),
                         "residual_vibration": float(np.abs(r.branch_forces[~moving] - static).max())}
    # the same elastic inverse held at twice the rate: what the 1 kHz hold itself costs
    times, values, _, _ = path_torques(model, c4, 2 * RATE, "elastic")
    out["elastic_2kHz"] = score(mech, times, values, q0, c4, move, c4.duration, static, options).as_dict()
    return out


def markdown(results: dict) -> str:
    lines = ["| machine | move | plant k | path dev. rigid | rigid C4 | elastic | ratio | residual vib. rigid [N] | "
             "rigid C4 | elastic | ratio | shaped (ZVD) | ratio | elastic cont. (no ZOH): path / vib. | "
             "elastic at 2 kHz: path / vib. | inverse [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for machine, moves in results["machines"].items():
        for move, res in moves.items():
            for k, row in res["scores"].items():
                p = [row[m]["path_deviation"] for m in ("rigid", "rigid C4", "elastic")]
                v = [row[m]["residual_vibration"] for m in ("rigid", "rigid C4", "elastic")]
                vs = row["shaped"]["residual_vibration"] if "shaped" in row else float("nan")
                shaped = f"{vs:.3g} | {v[0] / max(vs, 1e-300):.0f}x"
                cont = (f"{res['continuous']['path_deviation']:.2g} / {res['continuous']['residual_vibration']:.2g}"
                        if k == "1" else "")
                if "elastic_2kHz" in res and k == "1":
                    two = res["elastic_2kHz"]
                    cont += f" | {two['path_deviation']:.2g} / {two['residual_vibration']:.2g}"
                elif k == "1":
                    cont += " | "
                lines.append(f"| {machine} | {move} | {k} | {p[0]:.3g} | {p[1]:.3g} | {p[2]:.3g} | "
                             f"{p[0] / max(p[2], 1e-300):.0f}x | {v[0]:.3g} | {v[1]:.3g} | {v[2]:.3g} | "
                             f"{v[0] / max(v[2], 1e-300):.0f}x | {shaped} | {cont} | "
                             f"{res['compute_s']:.3f} |" if k == "1" else
                             f"| | | {k} | {p[0]:.3g} | {p[1]:.3g} | {p[2]:.3g} | {p[0] / max(p[2], 1e-300):.0f}x | "
                             f"{v[0]:.3g} | {v[1]:.3g} | {v[2]:.3g} | {v[0] / max(v[2], 1e-300):.0f}x | {shaped} "
                             "| | | |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/bench_feedforward")
    ap.add_argument("--integrator", choices=("rk4", "dop853"), default="rk4",
                    help="rk4 at 10 us (default; 0.35 rad a step of the five-bar's mode) or dop853 at rtol 1e-9")
    ap.add_argument("--quick", action="store_true", help="the reference move of each machine only")
    ap.add_argument("--machines", nargs="+", help="names to run (default all)")
    args = ap.parse_args()
    options = (SimulationOptions(integrator="dop853", rtol=1e-9, atol=1e-12, sample=1e-4) if args.integrator == "dop853"
               else SimulationOptions(integrator="rk4", dt=1e-5, sample=1e-4))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {"integrator": args.integrator, "rate": RATE, "hold": HOLD, "machines": {}}
    for name, config, nek, moves in MACHINES:
        if args.machines and name not in args.machines:
            continue
        model = load_model(ROOT / config, nek)
        results["machines"][name] = {}
        for move_name, start, end, move in moves[:1] if args.quick else moves:
            t0 = time.perf_counter()
            results["machines"][name][move_name] = run_move(model, start, end, move, options)
            print(f"{name} {move_name}: {time.perf_counter() - t0:.0f} s", flush=True)
            (out / "feedforward.json").write_text(json.dumps(results, indent=1))
            (out / "feedforward.md").write_text(markdown(results))
    print(markdown(results))


if __name__ == "__main__":
    main()
