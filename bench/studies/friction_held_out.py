"""Dry friction on cases drawn from a seed, not those the tests were developed on: our ``simulate`` at
its default settings (Coulomb's law) against MuJoCo's friction loss tightened (solref 2e-5,
solimp 0.9999; equalities at solref 2e-4, solimp 0.9999), from rest, 0.2 s.

Per draw: the four-bar of test/robots/menagerie_style/hinge_two_connects.xml (its sites agreeing)
with friction loss on its three joints drawn from [0.005, 0.3] N m and a motor torque from
[-0.1, 0.1] N m; and the Menagerie-style arm (test/robots/menagerie_style/arm.xml; limits,
contacts and force ranges off, its own friction loss) from a pose drawn within +-1 rad, its
three servos' ctrl held at values drawn within their ranges. Ours: SCDD, DOP853 at rtol 1e-11,
atol 1e-13; MuJoCo: RK4 at 1e-5 s, ctrl held.

    python bench/studies/friction_held_out.py [--seed 41] [--draws 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulate import simulate

ROBOTS = Path(__file__).resolve().parents[2] / "test" / "robots" / "menagerie_style"
SAMPLE = 0.01


def peer(path: Path, names: list[str], q0: np.ndarray, ctrl: np.ndarray, samples: int) -> np.ndarray:
    import mujoco
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = 1e-5
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.dof_solref[:] = (2e-5, 1.0)
    m.dof_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    m.eq_solref[:] = (2e-4, 1.0)
    m.eq_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
    d = mujoco.MjData(m)
    adr = [m.jnt_qposadr[m.joint(name).id] for name in names]
    d.qpos[adr] = q0
    d.ctrl[:] = ctrl
    out = [d.qpos[adr].copy()]
    for _ in range(samples - 1):
        mujoco.mj_step(m, d, nstep=round(SAMPLE / m.opt.timestep))
        out.append(d.qpos[adr].copy())
    return np.array(out)


def compare(path: Path, ctrl: np.ndarray, q0: np.ndarray | None = None) -> tuple[float, float, int]:
    """(max |q - q_mujoco|, largest motion, joints that never moved) over 0.2 s from rest."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mech = Mechanism(load_model(path))
    start = initial_state(mech) if q0 is None else q0
    run = simulate(mech, ctrl, 0.2, integrator="dop853", rtol=1e-11, atol=1e-13, sample=SAMPLE, q0=start)
    other = peer(path, mech.joint_names, start, ctrl, len(run.t))
    moved = np.abs(run.q - start).max(axis=0)
    return float(np.abs(other - run.q).max()), float(moved.max()), int(np.sum(moved == 0.0))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=41)
    parser.add_argument("--draws", type=int, default=3)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    four_bar = (ROBOTS / "hinge_two_connects.xml").read_text().replace("0.16215643", "0.16215639")
    arm = (ROBOTS / "arm.xml").read_text().replace(
        '<option gravity="0 0 -9.81" timestep="0.002"/>',
        '<option gravity="0 0 -9.81"><flag limit="disable" contact="disable"/></option>')
    arm = arm.replace(' forcerange="-8 8"', "").replace(' forcerange="-3 3"', "")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for draw in range(args.draws):
            text = four_bar
            frictions = rng.uniform(0.005, 0.3, 3)
            for name, f in zip(("crank", "coupler", "rocker"), frictions, strict=True):
                joint = f'<joint name="{name}" axis="0 0 1"'
                text = text.replace(joint, f'{joint} frictionloss="{f:.4f}"')
            path = Path(tmp) / f"four_bar_{draw}.xml"
            path.write_text(text)
            torque = rng.uniform(-0.1, 0.1, 1)
            err, moved, still = compare(path, torque)
            worst = max(worst, err)
            print(f"four-bar, friction {np.round(frictions, 4)} N m, torque {torque[0]:.4f} N m: max |q - q_mujoco| "
                  f"{err:.2e} rad, moved {moved:.3g} rad, {still} joints never moved")
            path = Path(tmp) / f"arm_{draw}.xml"
            path.write_text(arm)
            q0 = rng.uniform(-1.0, 1.0, 3)
            ctrl = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-3, 3), rng.uniform(-2, 2)])
            err, moved, still = compare(path, ctrl, q0)
            worst = max(worst, err)
            print(f"arm from {np.round(q0, 3)} rad, ctrl {np.round(ctrl, 3)}: max |q - q_mujoco| {err:.2e} rad, "
                  f"moved {moved:.3g} rad, {still} joints never moved")
    print(f"worst {worst:.2e} rad")
    return 0


if __name__ == "__main__":
    sys.exit(main())
