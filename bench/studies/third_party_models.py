"""Public third-party robots (URDF + robot.yaml in Gepetto's example-parallel-robots
convention): what ``check`` makes of each, and our ``simulate`` against Pinocchio.

For each directory under ROOT (default /tmp/thirdparty) holding robot.urdf + robot.yaml:
DOF by role (motors, springs, free joints, passive), closures by type, the assembly
residual and the elastic modes if any; then 0.2 s under gravity from the assembled start
pose with the motors unpowered (zero torque): our SCDD (DOP853 at rtol 1e-10, RK4 at
dt = 1e-5 s) against Pinocchio's ``constraintDynamics`` on the same files (the closures
as Gepetto's loader builds them, see test/pinocchio_urdf.py, imported by path), integrated
by DOP853 at rtol 1e-10 with the same small Baumgarte corrector as
test/dynamics/test_robot_dynamics.py. A legged robot's root link is fixed (a hanging leg): the
files are fixed-root trees; Gepetto loads them with a free flyer for walking.

    python bench/studies/third_party_models.py [ROOT] [--only NAME ...]

JSON to bench/results/third_party.json; the table is in bench/README.md.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import yaml

from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common, tools
from common import RESULTS
from tools.pinocchio_run import BAUMGARTE, peer_class, pinocchio

DURATION, SAMPLE = 0.2, 1e-3  # [s]


def source(urdf: Path) -> str | None:
    """Where the file was read from, if its first comment says (``<!-- owner/repo path @ commit ...``)."""
    m = re.search(r"<!--\s*(\S+/\S+ \S+ @ [0-9a-f]{40})", urdf.read_text())
    return m.group(1) if m else None


def summary(urdf: Path) -> tuple[dict, Mechanism | None]:
    side = yaml.safe_load((urdf.parent / "robot.yaml").read_text()) or {}
    kinds = [("3d" if str(k).lower() == "3d" else "6d") for k in side.get("type", ["6d"] * len(side["closed_loop"]))]
    out = {"source": source(urdf), "closures": {k: kinds.count(k) for k in ("3d", "6d") if k in kinds}}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            mech = Mechanism(load_model(urdf))
        except ModelError as e:
            out["error"] = str(e)
            return out, None
    out["notes"] = [str(w.message) for w in caught]
    joints = mech.model.joints
    free = [mech.joint_names[i] for i in mech.elastic if joints[i].stiffness == 0.0]
    sprung = [mech.joint_names[i] for i in mech.elastic if joints[i].stiffness > 0.0]
    out.update(tree_joints=mech.n, chains=mech.n_chains, active=len(mech.active), springs=len(sprung),
               free=free, passive=len(mech.passive), closure_equations=mech.m, planar=mech.model.planar)
    q0 = initial_state(mech)
    out["assembly_residual_m"] = float(mech.gap(q0))
    if sprung:
        out["modes_hz"] = [float(f) for f in elastic_modes(mech, q0).natural_hz if f > 0][:4]
    return out, mech


def ours(mech: Mechanism, integrator: str) -> tuple[np.ndarray, np.ndarray, float]:
    options = SimulationOptions(formulation="scdd", integrator=integrator, dt=1e-5, sample=SAMPLE)
    t0 = time.perf_counter()
    run = Simulator(mech, options).run(ConstantTorque([0.0] * len(mech.active)), DURATION)
    return run.t, run.q, time.perf_counter() - t0


def compare(urdf: Path, mech: Mechanism) -> dict:
    q0 = initial_state(mech)
    peer = peer_class()(urdf, mech.model, baumgarte=BAUMGARTE)
    out = {"pinocchio_start_gap_m": float(peer.gap(q0))}
    t, q_dop, wall_dop = ours(mech, "dop853")
    _, q_rk4, wall_rk4 = ours(mech, "rk4")
    q_pin, wall_pin = pinocchio(peer, mech, q0, t)
    out.update(moved_rad=float(np.abs(q_pin - q0).max()),
               err_dop853_rad=float(np.abs(q_dop - q_pin).max()),
               err_rk4_rad=float(np.abs(q_rk4 - q_pin).max()),
               pinocchio_gap_m=float(max(peer.gap(q) for q in q_pin[::20])),
               ours_gap_m=float(max(mech.gap(q) for q in q_dop[::20])),
               wall_s={"dop853": wall_dop, "rk4": wall_rk4, "pinocchio": wall_pin})  # the first run compiles
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", nargs="?", default="/tmp/thirdparty")
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--out", default=str(RESULTS / "third_party.json"))
    args = ap.parse_args()
    results = {"load": os.getloadavg(), "robots": {}}
    for d in sorted(Path(args.root).iterdir()):
        urdf = d / "robot.urdf"
        if not urdf.is_file() or (args.only and d.name not in args.only):
            continue
        info, mech = summary(urdf)
        if mech is not None:
            info.update(compare(urdf, mech))
        results["robots"][d.name] = info
        print(d.name, json.dumps(info))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"-> {args.out}  (load {results['load'][0]:.2f})")


if __name__ == "__main__":
    main()
