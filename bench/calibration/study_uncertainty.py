"""Why the five-bar's reported standard deviations were 10-40x too small (issue #42): at a point
(the TRUE parameters by default) the filter's per-sample scores, the NLL's Hessian A (forward
differences of the scores' sum), and from them the Newton offset -A^-1 g (where the likelihood's
optimum lies from that point) in units of each standard deviation: BHHH B^-1, Hessian A^-1, the
sandwich A^-1 B A^-1 and Newey-West sandwiches over L samples (hacL) or block sums (hacblkL).
Also the offset of the quadratic part alone (0.5 sum NIS, the log det S terms dropped).

    PYTHONPATH=. python bench/calibration/study_uncertainty.py --seed 101 --dur 2 [--dist 0] [--noise 0.1]
        [--set process.disturbance=none process.integrator=rk4 ...] [--bag B --fact JSON [--at result.json]]

A recording is made (five-bar, bench case A's perturbation unless --fact) from --seed with the
unknown disturbance --dist [N m RMS] and the sensors' noise times --noise, or --bag is read; --set
overrides the observer's parameters (config/observer.yaml). Prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))

from elastic_pm_dyn.calibration.excitation import excitation  # noqa: E402
from elastic_pm_dyn.calibration.fit import scores_at  # noqa: E402
from elastic_pm_dyn.calibration.likelihood import read_recording, score  # noqa: E402
from elastic_pm_dyn.calibration.parameters import ModelFile, available, select  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.observer.config import ObserverConfig, load_config  # noqa: E402
from elastic_pm_dyn.observer.testing.excited import excited_recording  # noqa: E402
from elastic_pm_dyn.observer.testing.recordings import write_bag  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import Noise  # noqa: E402

CASE_A = {"stiffness.left_spring": 0.84, "stiffness.right_spring": 1.13, "damping.left_spring": 1.4,
          "damping.right_spring": 0.6, "payload.mass": 1.3}
SENSORS = ["encoders", "imu", "branch_forces"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=101)
    ap.add_argument("--dur", type=float, default=2.0)
    ap.add_argument("--dist", type=float, default=0.02)
    ap.add_argument("--noise", type=float, default=1.0)
    ap.add_argument("--truth-dt", type=float, default=2.5e-5)
    ap.add_argument("--set", nargs="*", default=[], help="observer overrides key=yaml")
    ap.add_argument("--bag", default="")
    ap.add_argument("--fact", default="", help="the truth's factors (JSON); default case A's")
    ap.add_argument("--at", default="", help="a calibrate --json report: evaluate at its values")
    ap.add_argument("--seconds", type=float, default=None)
    a = ap.parse_args()
    factors = json.loads(a.fact) if a.fact else CASE_A
    mf = ModelFile.read(REPO / "config/five_bar.yaml")
    allp = available(mf)
    truth = mf.model(allp, [p.nominal * factors.get(p.name, 1.0) for p in allp])
    chosen = select(allp, None)
    nominal = np.array([p.nominal for p in chosen])
    theta = np.log([factors.get(p.name, 1.0) for p in chosen])
    bag = Path(a.bag) if a.bag else HERE / "recordings" / "study" / f"s{a.seed}_d{a.dur}_x{a.dist}_n{a.noise}"
    if not bag.exists():
        ex = excitation(Mechanism(mf.model(allp, [p.nominal for p in allp])), ("stiffness", "damping", "payload"),
                        [6.0], a.dur, 1000.0, seed=a.seed)
        noise = Noise(2e-5 * a.noise, 0.02 * a.noise, 0.5 * a.noise)
        rec = excited_recording(Mechanism(truth), ex.torque, 1000.0, seed=a.seed, disturbance_rms=a.dist,
                                noise=noise, truth_dt=a.truth_dt)
        bag.parent.mkdir(exist_ok=True, parents=True)
        write_bag(rec, bag, use=tuple(SENSORS))
    over = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in a.set)}
    base = load_config(REPO / "config/observer.yaml")
    cfg = ObserverConfig.from_parameters(dict(base.parameters, sensors=SENSORS, **over), "<study>")
    recs = [read_recording(bag, cfg, a.seconds)]
    out: dict = {"args": vars(a), "names": [p.name for p in chosen]}
    if a.at:
        report = json.loads(Path(a.at).read_text())
        cal = {p["name"]: p["calibrated"] / p["file"] for p in report["parameters"]}
        at = np.log([cal[p.name] for p in chosen])
        out["at_minus_truth_pct"] = (100 * (at - theta)).tolist()
        theta = at
    n = len(chosen)
    with ThreadPoolExecutor(2) as pool:
        def run(points: list[np.ndarray]) -> list:
            return list(pool.map(lambda t: score(mf.model(chosen, nominal * np.exp(t)), cfg, recs), points))
        t0 = time.perf_counter()
        here, G = scores_at(run, theta, np.arange(n), n)
        g, B = G.sum(0), G.T @ G
        h = 1e-3
        A = np.zeros((n, n))
        for j in range(n):
            tj = theta.copy()
            tj[j] += h
            A[:, j] = (scores_at(run, tj, np.arange(n), n)[1].sum(0) - g) / h
        A = 0.5 * (A + A.T)
        steps = []
        for j in range(n):
            tj = theta.copy()
            tj[j] += 1e-4
            steps.append(tj)
        nis_steps = [r.nis for r in run(steps)]
    sizes = [here.per_sensor[s]["samples"] for s in cfg.sensors]
    m = min(sizes)
    ends = np.cumsum(sizes)
    St = sum(G[e - m:e] for e in ends)  # per-time scores, the sensors' samples aligned at the end
    covs = {"bhhh": np.linalg.inv(B), "hess": np.linalg.inv(A)}
    Ai = covs["hess"]
    covs["sandwich"] = Ai @ B @ Ai
    for lags in (5, 20, 50, 200, 400):
        S = St.T @ St
        for lag in range(1, lags + 1):
            C = St[lag:].T @ St[:-lag]
            S = S + (1 - lag / (lags + 1)) * (C + C.T)
        covs[f"hac{lags}"] = Ai @ S @ Ai
    for blk in (100, 250, 500):
        k = m // blk
        sb = St[: k * blk].reshape(k, blk, n).sum(1)
        covs[f"hacblk{blk}"] = Ai @ (sb.T @ sb * (m / (k * blk))) @ Ai
    offset = -Ai @ g
    out["per_sensor_nis"] = {s: here.per_sensor[s]["mean_nis_per_dof"] for s in cfg.sensors}
    out["offset_newton"] = offset.tolist()
    for k, c in covs.items():
        sd = np.sqrt(np.diag(c))
        out["sd_" + k] = sd.tolist()
        out["z_" + k] = (offset / sd).round(2).tolist()
    # the quadratic part alone: Gauss-Newton on sqrt(NIS)
    e = np.sqrt(np.maximum(here.nis, 1e-300))
    gq = np.array([(0.5 * (v - here.nis)).sum() / 1e-4 for v in nis_steps])
    Je = np.stack([(np.sqrt(np.maximum(v, 1e-300)) - e) / 1e-4 for v in nis_steps], 1)
    out["offset_quadratic_only"] = (-np.linalg.solve(Je.T @ Je, gq)).tolist()
    out["wall_s"] = time.perf_counter() - t0
    print(json.dumps(out))


if __name__ == "__main__":
    main()
