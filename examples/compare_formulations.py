"""The three exact formulations of the direct dynamics agree to round-off, and what each costs.

Multipliers (Lagrange equations of the first kind, eqs 3-5), compact Lagrange-D'Alembert
(eqs 19-26) and SCDD (eqs 33-41) are three eliminations of the same constrained equations.
At random consistent states (closure satisfied in position and velocity, random motor
torques) their accelerations must agree to round-off, and SCDD and the multipliers also
give the same cut forces. Then each is timed per call.

Run:

    python examples/compare_formulations.py [--model config/five_bar.yaml] [--states 200] [--seed 1]

Prints, per formulation, the largest relative difference of the accelerations from L-D'A
and the time per call; exits with status 1 if any difference exceeds --tolerance.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import elastic_pm_dyn as epd

CONFIG = Path(__file__).resolve().parents[1] / "config"
EXACT = ("lda", "scdd", "multipliers")


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=CONFIG / "five_bar.yaml", help="model YAML")
    parser.add_argument("--states", type=int, default=200, help="random consistent states")
    parser.add_argument("--seed", type=int, default=1, help="random generator seed")
    parser.add_argument("--spread", type=float, default=0.2, help="motor range about the start pose [rad or m]")
    parser.add_argument("--tolerance", type=float, default=1e-9, help="largest relative difference accepted")
    args = parser.parse_args(argv)

    mech = epd.Mechanism(epd.load_model(args.model))
    rng = np.random.default_rng(args.seed)
    states, misses = [], 0
    while len(states) < args.states:
        try:  # a random motor pose may be out of reach of a small machine: draw another
            states.append(epd.random_consistent_state(mech, rng, spread=args.spread))
        except epd.AssemblyError:
            misses += 1
            if misses > 10 * args.states:
                raise
    dynamics = {f: epd.Dynamics(mech, f) for f in EXACT}

    worst = dict.fromkeys(EXACT, 0.0)
    worst_cut = 0.0
    for q, qd, tau in states:
        ref = dynamics["lda"].accelerations(q, qd, tau)
        for f in EXACT:
            worst[f] = max(worst[f], relative(dynamics[f].accelerations(q, qd, tau), ref))
        worst_cut = max(worst_cut, relative(dynamics["scdd"].cut_force, dynamics["multipliers"].cut_force))

    print(f"{mech.model.name}: {mech.n} tree joints, {mech.m} closure equations; "
          f"{args.states} random states ({misses} draws out of reach)")
    print(f"{'formulation':12s} {'max rel. diff. vs lda':>22s} {'us per call':>12s}")
    for f, dyn in dynamics.items():  # every formulation has run above: compiled code only is timed
        start = time.perf_counter()
        for q, qd, tau in states:
            dyn.accelerations(q, qd, tau)
        per_call = (time.perf_counter() - start) / len(states)
        print(f"{f:12s} {worst[f]:22.2e} {per_call * 1e6:12.1f}")
    print(f"cut forces, scdd vs multipliers: max rel. diff. {worst_cut:.2e}")

    agree = max(*worst.values(), worst_cut) <= args.tolerance
    print("the formulations agree" if agree else f"DISAGREEMENT above {args.tolerance:g}")
    return 0 if agree else 1


if __name__ == "__main__":
    raise SystemExit(main())
