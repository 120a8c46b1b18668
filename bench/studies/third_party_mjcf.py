"""Public third-party MJCF models with closed loops: what ``check`` makes of each, and our
``simulate`` against MuJoCo on the same file.

For each ``*.xml`` under ROOT/<name>/ (default /tmp/thirdparty_mjcf; the files are fetched
by hand, never committed: bench/README.md says from where): loaded as ``check`` loads it; a
refusal that names an option (a free joint: ``--fix-base``; a servo: ``--servos-as-motors``)
is retried with it, and the JSON says so. What loads: DOF by role, closures, assembly
residual, elastic modes; then 0.2 s under gravity from the assembled start pose, motors
unpowered: our SCDD (DOP853, rtol 1e-10) against MuJoCo's mj_step (RK4 at dt = 1e-5 s) from
the same qpos, qvel = 0; contacts, joint limits, friction loss and actuators off in MuJoCo
(our model has none of the first three, the motors are unpowered); the equality constraints
at the file's solref/solimp and tightened (solref 2e-5 s, solimp 0.9999): MuJoCo's
constraints are soft, and the gap to ours must shrink as they are tightened. And Pinocchio
(``constraintDynamics``, DOP853 at rtol 1e-10, as bench/studies/third_party_models.py) on the URDF +
sidecar our ``urdf`` command writes from the loaded model: a peer of our dynamics on the same
reading (MuJoCo is the peer of the reading itself).

    python bench/studies/third_party_mjcf.py [ROOT] [--also FILE ...]

``--also`` adds MJCF files of this project's own (test/robots/*.xml) to the same comparison:
they are not third-party, and the table marks them so. JSON to bench/results/third_party_mjcf.json.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from elastic_pm_dyn.dynamics.linear import elastic_modes
from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.model.mjcf import compile_mjcf, mujoco_qpos
from elastic_pm_dyn.model.urdf_writer import closure_sidecar, model_to_urdf
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common, tools
from common import RESULTS
from tools.pinocchio_run import BAUMGARTE, peer_class, pinocchio

DURATION, SAMPLE = 0.2, 1e-3  # [s]
MJ_DT = 1e-5  # [s]
TIGHT = (2 * MJ_DT, 1.0), (0.9999, 0.9999, 0.001, 0.5, 2.0)  # solref at MuJoCo's floor of 2 dt


def pinocchio_run(mech: Mechanism, q0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Pinocchio on the URDF + sidecar written from our model: trajectory, its gap, wall time."""
    with tempfile.TemporaryDirectory() as tmp:
        urdf = Path(tmp) / "robot.urdf"
        urdf.write_text(model_to_urdf(mech.model))
        (Path(tmp) / "robot.yaml").write_text(closure_sidecar(mech.model))
        peer = peer_class()(urdf, mech.model, baumgarte=BAUMGARTE)
        q, wall = pinocchio(peer, mech, q0, t)
        return q, float(max(peer.gap(x) for x in q[::20])), wall


def source(path: Path) -> str | None:
    """Where the file was read from, if its first comment says (``<!-- owner/repo path @ commit``)."""
    m = re.search(r"<!--\s*(\S+/\S+ \S+ @ [0-9a-f]{40})", path.read_text())
    return m.group(1) if m else None


RETRY = {"fix_base": "fix_base=True", "servos_as_motors": "servos_as_motors=True"}  # option: what the refusal says


def load(path: Path) -> tuple[dict, Mechanism | None, dict]:
    """What check makes of the file; a refusal that names an option is retried with it (each
    recorded in the JSON)."""
    out: dict = {"source": source(path)}
    options: dict = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        while True:
            try:
                mech = Mechanism(load_model(path, **options))
                break
            except ModelError as e:
                retry = [k for k, said in RETRY.items() if said in str(e) and k not in options]
                if not retry:
                    out["error"] = str(e)
                    return out, None, options
                out[f"refused_without_{retry[0]}"] = str(e)
                options[retry[0]] = True
    out["notes"] = [str(w.message) for w in caught]
    out["options"] = options
    joints = mech.model.joints
    out.update(tree_joints=mech.n, chains=mech.n_chains, active=len(mech.active),
               springs=sum(joints[i].stiffness > 0 for i in mech.elastic),
               free=[mech.joint_names[i] for i in mech.elastic if joints[i].stiffness == 0.0],
               passive=len(mech.passive), closure_equations=mech.m, planar=mech.model.planar)
    q0 = initial_state(mech)
    out["assembly_residual_m"] = float(mech.gap(q0))
    if out["springs"]:
        out["modes_hz"] = [float(f) for f in elastic_modes(mech, q0, clamp_motors=True).natural_hz if f > 0][:4]
    return out, mech, options


def mujoco_run(path: Path, fix_base: bool, mech: Mechanism, q0: np.ndarray, t: np.ndarray,
               tight: bool) -> tuple[np.ndarray, float, float]:
    """MuJoCo's trajectory of our hinge/slide coordinates at the times t, its largest
    equality violation, and the wall time."""
    import mujoco
    m = compile_mjcf(path, fix_base)
    m.opt.timestep = MJ_DT
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.opt.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
                           | mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS | mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    if tight:
        m.eq_solref[:] = TIGHT[0]
        m.eq_solimp[:] = TIGHT[1]
    d = mujoco.MjData(m)
    d.qpos[:] = mujoco_qpos(m, mech.joint_names, q0)
    d.qvel[:] = 0.0
    adr = [m.jnt_qposadr[m.joint(n).id] for n in mech.joint_names if _is_mj_joint(m, n)]
    out = np.empty((len(t), len(adr)))
    worst = 0.0
    t0 = time.perf_counter()
    k = 0
    for step in range(round(float(t[-1]) / MJ_DT) + 1):
        if k < len(t) and step * MJ_DT >= t[k] - 0.5 * MJ_DT:
            out[k] = d.qpos[adr]
            k += 1
        mujoco.mj_step(m, d)
        rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        if rows.any():
            worst = max(worst, float(np.abs(d.efc_pos[rows]).max()))
    return out, worst, time.perf_counter() - t0


def _is_mj_joint(m, name: str) -> bool:
    import mujoco
    return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name) >= 0


def compare(path: Path, mech: Mechanism, fix_base: bool) -> dict:
    q0 = initial_state(mech)
    options = SimulationOptions(formulation="scdd", integrator="dop853", rtol=1e-10, atol=1e-12, sample=SAMPLE)
    t0 = time.perf_counter()
    run = Simulator(mech, options).run(ConstantTorque([0.0] * len(mech.active)), DURATION)
    wall = time.perf_counter() - t0
    m = compile_mjcf(path, fix_base)
    cols = [i for i, n in enumerate(mech.joint_names) if _is_mj_joint(m, n)]
    ours = run.q[:, cols]
    out = {"moved_rad": float(np.abs(ours - q0[cols]).max()), "ours_gap_m": float(run.gap.max()),
           "wall_s": {"ours_dop853": wall}, "compared_joints": len(cols)}
    closure = mech.model.closure
    if closure is None or not closure.pairs or closure.couplings:
        # the peer (test/pinocchio_urdf.py) takes the sidecar's loops, not joint couplings: MuJoCo is the peer
        out["pinocchio_our_urdf"] = {"not_run": "no loops" if closure is None or not closure.pairs
                                     else "joint couplings (tendons, <joint> equalities) are not in the Pinocchio peer"}
    else:
        q_pin, gap_pin, wall_pin = pinocchio_run(mech, q0, run.t)
        out["pinocchio_our_urdf"] = {"err_rad": float(np.abs(q_pin - run.q).max()), "gap_m": gap_pin}
        out["wall_s"]["pinocchio"] = wall_pin
    for label, tight in (("file", False), ("tight", True)):
        q_mj, violation, wall_mj = mujoco_run(path, fix_base, mech, q0, run.t, tight)
        out[f"mujoco_{label}"] = {"err_rad": float(np.abs(q_mj - ours).max()), "violation_m": violation}
        out["wall_s"][f"mujoco_{label}"] = wall_mj
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", nargs="?", default="/tmp/thirdparty_mjcf")
    ap.add_argument("--also", nargs="*", default=[], help="this project's own MJCF files, compared the same way")
    ap.add_argument("--out", default=str(RESULTS / "third_party_mjcf.json"))
    args = ap.parse_args()
    results: dict = {"load": os.getloadavg(), "models": {}}
    files = [(f"{d.name}/{f.name}", f, True) for d in sorted(Path(args.root).iterdir()) if d.is_dir()
             for f in sorted(d.glob("*.xml"))]
    files += [(f"ours/{Path(f).name}", Path(f), False) for f in args.also]
    for name, path, third_party in files:
        info, mech, options = load(path)
        info["third_party"] = third_party
        if mech is not None:
            info.update(compare(path, mech, options.get("fix_base", False)))
        results["models"][name] = info
        print(name, json.dumps(info))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"-> {args.out}  (load {results['load'][0]:.2f})")


if __name__ == "__main__":
    main()
