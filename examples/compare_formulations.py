"""The three exact formulations of the direct dynamics agree to round-off.

Multipliers (eqs 3-5), compact Lagrange-D'Alembert (eqs 19-26) and SCDD (eqs 33-41) eliminate
the same constrained equations: at random consistent states (closure met in position and
velocity, random motor torques) their accelerations, and SCDD's and the multipliers' cut forces,
agree to round-off. Run: ``python examples/compare_formulations.py`` (exit status 1 if not).
"""

from pathlib import Path

import numpy as np

import elastic_pm_dyn as epd

MODEL = Path(__file__).resolve().parents[1] / "config" / "five_bar.yaml"
STATES, SEED, TOLERANCE = 100, 1, 1e-9  # random states, generator seed, largest relative difference

mech = epd.Mechanism(epd.load_model(MODEL))
rng = np.random.default_rng(SEED)
dynamics = {f: epd.Dynamics(mech, f) for f in ("lda", "scdd", "multipliers")}


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


worst = dict.fromkeys([*dynamics, "cut forces"], 0.0)  # cut forces: scdd against the multipliers
for _ in range(STATES):
    q, qd, tau = epd.random_consistent_state(mech, rng, spread=0.2)  # motors within 0.2 rad of the start
    ref = dynamics["lda"].accelerations(q, qd, tau)
    for f, dyn in dynamics.items():
        worst[f] = max(worst[f], relative(dyn.accelerations(q, qd, tau), ref))
    worst["cut forces"] = max(worst["cut forces"], relative(dynamics["scdd"].cut_force,
                                                            dynamics["multipliers"].cut_force))
print(f"{mech.model.name}, {STATES} random states: largest relative difference from lda")
for name, value in worst.items():
    print(f"{name:12s} {value:.2e}")
print("the formulations agree" if max(worst.values()) <= TOLERANCE else f"DISAGREEMENT above {TOLERANCE:g}")
raise SystemExit(0 if max(worst.values()) <= TOLERANCE else 1)
