"""What the physics allows: a lower bound on the observer's branch-force error.

    .venv/bin/python bench/studies/observer_bound.py        # ~2 min

The test recordings of the observer (``elastic_pm_dyn.observer.testing.scenarios``) add an
unknown multisine torque d(t) = sum_i a (alpha_i sin w_i t + beta_i cos w_i t) to each motor
(24 log-spaced tones in 2-200 Hz, 0.02 N m RMS per motor). Around the recorded motion the
machine answers linearly to so small a torque, so every sample of every sensor and every
branch force is (nominal) + G c, c the 96 tone coefficients. G is measured here column by
column with the core simulator (the recorded commands held, one tone at a time).

A *genie* estimator knows the model, the start state, the commands and the 48 tone
frequencies per motor; only the coefficients are unknown (prior: random phase, so each
has variance a^2 / 2). Its best mean-square error is the linear MMSE:

    P_c = (Sigma_c^-1 + G_s^T R^-1 G_s)^-1,   error of F_k = H_k P_c H_k^T,

with G_s the sensors' rows and H_k the branch forces' rows at sample k. Two versions:
``smoother`` uses every sample of the record (non-causal, the best any offline pass can
do), ``causal`` only the samples up to k (the best a live filter can do). The open loop
(the model driven by the commands, no sensors) errs by H_k Sigma_c H_k^T. No real observer
knows the tone frequencies, so its error is larger than the genie's: the ratios below are
lower bounds for the goal "branch-force error at most half of the open loop's".

Writes ``bench/results/observer_bound.json`` and ``observer_bound.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import (  # noqa: E402
    Multisine,
    Noise,
    chirp_recording,
    manoeuvre_recording,
    simulate,
)

SENSORS = {"encoders": ("enc",), "encoders+imu": ("enc", "imu"), "encoders+gauges": ("enc", "gauge")}


def sensitivities(mech: Mechanism, rec, freqs: np.ndarray, truth_dt: float, unit: float = 1e-3) -> dict:
    """Columns of G: change of each signal per unit tone coefficient (central differences)."""
    table = rec.tau_cmd
    n_a = len(mech.active)

    def command(k: int, t: float, enc: np.ndarray) -> np.ndarray:
        return table[min(k, len(table) - 1)]

    duration = rec.t[-1] - rec.t[0]
    rng = np.random.default_rng(0)
    zero = Noise(0.0, 0.0, 0.0)
    cols: dict[str, list] = {"enc": [], "imu": [], "gauge": []}
    for ch in range(n_a):
        for f in freqs:
            for kind in (np.sin, np.cos):
                out = []
                for sign in (1.0, -1.0):
                    def tone(t, f=f, kind=kind, ch=ch, sign=sign):
                        d = np.zeros(n_a)
                        d[ch] = sign * unit * kind(2 * np.pi * f * t)
                        return d
                    out.append(simulate(mech, command, duration, tone, zero, rng, truth_dt))
                p, m = out
                cols["enc"].append((p.q[:, mech.active] - m.q[:, mech.active]) / (2 * unit))
                cols["imu"].append((p.accel_true[:, :2] - m.accel_true[:, :2]) / (2 * unit))
                cols["gauge"].append((p.F - m.F) / (2 * unit))
    return {k: np.stack(v, axis=-1) for k, v in cols.items()}  # (N, channels, n_coef)


def bounds(G: dict, keep: np.ndarray, var: float, noise: dict, sensors: tuple[str, ...]) -> dict:
    H = G["gauge"]
    N, _, nc = H.shape
    Gs = np.concatenate([G[s] / noise[s] for s in sensors], axis=1)  # whitened rows per sample
    prior = np.eye(nc) / var
    ol = float(np.mean(np.einsum("kbc,kbc->kb", H, H)[keep]) * var)
    Pc = np.linalg.inv(prior + np.einsum("krc,krd->cd", Gs, Gs))
    smooth = float(np.mean(np.einsum("kbc,cd,kbd->kb", H, Pc, H)[keep]))
    info = prior.copy()
    causal = []
    for k in range(N):
        info += Gs[k].T @ Gs[k]
        if keep[k]:
            Pk = np.linalg.inv(info)
            causal.append(np.mean(np.einsum("bc,cd,bd->b", H[k], Pk, H[k])))
    return {"open_loop_rms_N": np.sqrt(ol), "smoother_rms_N": np.sqrt(smooth),
            "causal_rms_N": float(np.sqrt(np.mean(causal))),
            "smoother_vs_open_loop": np.sqrt(smooth / ol), "causal_vs_open_loop": float(np.sqrt(np.mean(causal) / ol))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    ap.add_argument("--truth-dt", type=float, default=1e-4, help="simulation step of the sensitivities [s]")
    ap.add_argument("--settle", type=float, default=0.05, help="samples before this time are not scored [s]")
    args = ap.parse_args()
    mech = Mechanism(load_model(ROOT / "config" / "five_bar.yaml"))
    n = Noise()
    noise = {"enc": n.encoder, "imu": n.accelerometer, "gauge": n.branch_force}
    result = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "noise": noise, "scenarios": {}}
    lines = ["Genie bounds on the branch-force error (unknown 2-200 Hz multisine, 0.02 N m RMS per motor; "
             f"noise: encoders {n.encoder:g} rad, accelerometer {n.accelerometer:g} m/s^2, gauges "
             f"{n.branch_force:g} N). Ratios to the open loop's error; the goal is <= 0.5.", "",
             "| scenario | sensors | open loop [mN] | causal genie [mN] | ratio | smoother genie [mN] | ratio |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for rec in (manoeuvre_recording(mech, seed=1), chirp_recording(mech, seed=101)):
        t0 = time.perf_counter()
        ms = Multisine(np.random.default_rng(0), len(mech.active), rec.info["disturbance_rms"])
        var = float(ms.amp[0, 0] ** 2 / 2)  # random phase: each sin/cos coefficient
        G = sensitivities(mech, rec, ms.f, args.truth_dt)
        keep = rec.t >= rec.t[0] + args.settle - 1e-12
        rows = {}
        for name, sensors in SENSORS.items():
            b = bounds(G, keep, var, noise, sensors)
            rows[name] = b
            lines.append(f"| {rec.label} | {name} | {b['open_loop_rms_N'] * 1e3:.2f} | {b['causal_rms_N'] * 1e3:.2f} | "
                         f"{b['causal_vs_open_loop']:.2f} | {b['smoother_rms_N'] * 1e3:.2f} | "
                         f"{b['smoother_vs_open_loop']:.2f} |")
        result["scenarios"][rec.label] = {"bounds": rows, "seconds": time.perf_counter() - t0}
    lines += ["", "The genie's model is exact. On the chirp the open loop's error is dominated by the slow tones' "
              "drift, which the encoders see well; a real filter's error there is its RK4 integrator's phase "
              "error at the 550 Hz resonance (1e-4 s substeps), which neither the encoders nor this bound see."]
    md = "\n".join(lines)
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer_bound.json").write_text(json.dumps(result, indent=2, default=float))
    (out / "observer_bound.md").write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
