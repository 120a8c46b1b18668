"""Byte-for-byte: the outputs of this tree against another commit's (a restructuring changes no number).

    .venv/bin/python bench/tools/same_outputs.py                      # against the commit before the house III moves
    .venv/bin/python bench/tools/same_outputs.py --base HEAD~5 --keep /tmp/same

For the five-bar, the Triglide and the Hexa it makes, with each tree's own code (the other in a
temporary ``git worktree``, run through ``PYTHONPATH``), from the same inputs:

- ``simulate`` CSVs: 0.05 s under the holding torque plus a small sine (RK4; the five-bar also ETD2
  and DOP853);
- ``observe`` outputs (estimates CSV and bag) of one 0.3 s recording per machine (the reference
  manoeuvre on the five-bar, a gentle chirp on the others), written once by this tree, read by both;
- plant trajectories: :class:`~elastic_pm_dyn.sim.plant.Plant` stepped 50 periods, its states saved.

and compares every file byte for byte (the bag of estimates too, except its storage metadata),
and each command's exit status.
Exit status 1 if any differs. The other tree compiles its kernels afresh: minutes on a 2-core machine.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BASE = "2e20f0c^"  # the commit before the first move of issue #39 (ros/ in rooms)
MACHINES = ("five_bar", "triglide", "hexa")
RUNS = [("five_bar", "rk4"), ("five_bar", "etd2"), ("five_bar", "dop853"), ("triglide", "rk4"), ("hexa", "rk4")]

# Run in each tree (its own package on PYTHONPATH): the plant's trajectories.
PLANT_CHILD = """
import sys, numpy as np
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.simulator import SimulationOptions
model, out = sys.argv[1], sys.argv[2]
mech = Mechanism(load_model(model))
plant = Plant(mech, SimulationOptions(formulation="scdd", integrator="rk4", dt=1e-4, stabilization="projection",
                                      sample=1e-3), 1e-3, None, start="static")
hold = holding_torques(mech, rest_state(mech))
rows = []
for k in range(50):
    plant.step(hold + 0.05 * np.sin(2 * np.pi * 40 * k * 1e-3))
    rows.append(np.concatenate([[plant.t], plant.q, plant.qd]))
np.save(out, np.array(rows))
"""


def torque_table(model: Path, path: Path) -> None:
    """Holding torque plus 0.05 N m at 40 Hz on every motor, 1 kHz, as simulate reads it."""
    import numpy as np

    from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model

    mech = Mechanism(load_model(str(model)))
    hold = holding_torques(mech, rest_state(mech))
    t = np.arange(0, 0.051, 1e-3)
    tau = hold[None, :] + 0.05 * np.sin(2 * np.pi * 40 * t)[:, None]
    np.savetxt(path, np.column_stack([t, tau]), delimiter=",", header="t," + ",".join(mech.active_names),
               comments="", fmt="%.17g")


def recording(model: Path, path: Path) -> None:
    """A 0.3 s recording of ``model`` (this tree writes it; both trees read it): the reference
    manoeuvre on the five-bar (a planar path), a gentle chirp (0.3 N m) on the others."""
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag

    mech = Mechanism(load_model(str(model)))
    spec = (RecordingSpec(motion="manoeuvre", duration=0.3, seed=7) if model.stem == "five_bar" else
            RecordingSpec(motion="chirp", duration=0.3, seed=7, chirp_amplitude=0.3))
    rec = generate(mech, spec)
    write_bag(rec, path)


def outputs(tree: Path, inputs: Path, out: Path) -> None:
    """Every output of ``tree``'s code into ``out``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    out.mkdir(parents=True)

    def run(name: str, *args: str) -> None:
        done = subprocess.run([sys.executable, *args], cwd=tree, env=env, capture_output=True, text=True)
        (out / f"{name}.exit").write_text(f"{done.returncode}\n")  # a failure is behaviour too: compared
        if done.returncode != 0:
            print(f"{tree}: {name} exited {done.returncode}: {done.stderr.strip().splitlines()[-1:]}")

    for machine, integrator in RUNS:
        dt = ["--dt", "5e-4"] if integrator == "etd2" else []
        run(f"simulate_{machine}_{integrator}", "-m", "elastic_pm_dyn", "simulate", "--model",
            f"config/{machine}.yaml", "--torques", str(inputs / f"{machine}_torques.csv"), "--duration", "0.05",
            "--integrator", integrator, *dt, "--out", str(out / f"simulate_{machine}_{integrator}.csv"))
    for machine in MACHINES:
        run(f"observe_{machine}", "-m", "elastic_pm_dyn", "observe", "--model", f"config/{machine}.yaml", "--bag",
            str(inputs / f"{machine}_bag"), "--out", str(out / f"observe_{machine}"))
        run(f"plant_{machine}", "-c", PLANT_CHILD, f"config/{machine}.yaml", str(out / f"plant_{machine}.npy"))


def differences(a: Path, b: Path) -> list[str]:
    """Files that differ or exist on one side only (``metadata.yaml`` of a bag: its file names and times)."""
    found = []
    names = {p.relative_to(a) for p in a.rglob("*") if p.is_file()} | {p.relative_to(b) for p in b.rglob("*")
                                                                        if p.is_file()}
    for name in sorted(names):
        if name.name in ("metadata.yaml", "summary.json"):  # wall times, paths
            continue
        if not (a / name).exists() or not (b / name).exists():
            found.append(f"{name}: only in {'base' if (a / name).exists() else 'this tree'}")
        elif not filecmp.cmp(a / name, b / name, shallow=False):
            found.append(f"{name}: differs")
    return found


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default=BASE, help=f"commit to compare with (default {BASE})")
    ap.add_argument("--keep", type=Path, help="folder for the inputs and both outputs (default: a temporary one)")
    args = ap.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="same-outputs-"))
    inputs = work / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    for machine in MACHINES:
        torque_table(ROOT / "config" / f"{machine}.yaml", inputs / f"{machine}_torques.csv")
        if not (inputs / f"{machine}_bag").exists():
            recording(ROOT / "config" / f"{machine}.yaml", inputs / f"{machine}_bag")
    base_tree = work / "base_tree"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base_tree), args.base], check=True,
                   capture_output=True)
    try:
        outputs(base_tree, inputs, work / "base")
        outputs(ROOT, inputs, work / "this")
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base_tree)], check=False)
    found = differences(work / "base", work / "this")
    for line in found:
        print(line)
    n = sum(1 for p in (work / "this").rglob("*") if p.is_file() and p.name not in ("metadata.yaml", "summary.json"))
    print(f"{n} files compared with {args.base}: {'all identical' if not found else f'{len(found)} differ'}"
          f" ({work})")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
