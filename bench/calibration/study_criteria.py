"""Which criterion to calibrate by: output error or the observer's innovation likelihood (measured).

On the first 0.5 s of bench case five_bar_A (the left spring 16 % softer than its file), every
other parameter at its true value, the left stiffness is scanned from 0.70 to 1.00 of the file's:
- output error (OE): the candidate simulated open loop from rest under the recorded commands
  (RK4, 1e-4 s), sum of squared normalised errors of the encoders, accelerometer and strain gauges;
- prediction error (PEM): the filter's NLL (calibration.likelihood), as calibrate minimises it.
Prints both curves and the local minima of each, writes results/criteria_<S>s.json and criteria_<S>s.png.

    PYTHONPATH=. python bench/calibration/study_criteria.py [SECONDS (default 0.5)]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO))

from elastic_pm_dyn.calibration.likelihood import read_recording, score  # noqa: E402
from elastic_pm_dyn.calibration.parameters import ModelFile, available  # noqa: E402
from elastic_pm_dyn.dynamics.direct import Dynamics  # noqa: E402
from elastic_pm_dyn.dynamics.statics import rest_state  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.observer.config import ObserverConfig, load_config  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import Noise  # noqa: E402
from elastic_pm_dyn.sim.sensors import ee_acceleration  # noqa: E402
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator  # noqa: E402
from elastic_pm_dyn.sim.torque import HeldPlusSmooth  # noqa: E402

SECONDS = 0.5
TRUE = {"stiffness.left_spring": 0.84, "stiffness.right_spring": 1.13, "damping.left_spring": 1.4,
        "damping.right_spring": 0.6, "payload.mass": 1.3}
FACTORS = np.linspace(0.70, 1.00, 16)


def output_error(mech: Mechanism, rec, noise: Noise) -> float:
    """Open loop from rest under the recorded commands; samples against the bag's."""
    cmd = [e for e in rec.events if e.kind == "command"]
    js = {e.stamp_ns: e for e in rec.events if e.kind == "joint_state"}
    imu = {e.stamp_ns: e for e in rec.events if e.kind == "imu"}
    br = {e.stamp_ns: e for e in rec.events if e.kind == "branch_forces"}
    sim = Simulator(mech, SimulationOptions(formulation="scdd", integrator="rk4", dt=1e-4, stabilization="projection"))
    dyn = Dynamics(mech, "scdd")
    q, qd = rest_state(mech), np.zeros(mech.n)
    t0 = cmd[0].stamp_ns
    cost = 0.0
    for k, c in enumerate(cmd):
        tau = np.asarray(c.data[1], dtype=float)
        prev = np.asarray(cmd[k - 1].data[1], dtype=float) if k else np.zeros_like(tau)
        ns = c.stamp_ns
        if ns in js:
            cost += np.sum(((np.asarray(js[ns].data[1]) - q[mech.active]) / noise.encoder) ** 2)
        if ns in br:
            cost += np.sum(((np.asarray(br[ns].data[1]) - mech.branch_forces(q, qd)) / noise.branch_force) ** 2)
        if ns in imu:
            a = ee_acceleration(mech, dyn, q, qd, prev, int(mech.model.end_effector_chain)) - mech.model.gravity
            cost += np.sum(((np.asarray(imu[ns].data[0])[:2] - a[:2]) / noise.accelerometer) ** 2)
        t = (ns - t0) * 1e-9
        try:
            sim.advance(q, qd, HeldPlusSmooth(tau, None), t, t + 1e-3)
        except Exception:  # a diverged open loop
            return float("inf")
    return 0.5 * cost


def main() -> None:
    mf = ModelFile.read(REPO / "config/five_bar.yaml")
    params = available(mf)
    cfg = load_config(REPO / "config/observer.yaml")
    cfg = ObserverConfig.from_parameters(dict(cfg.parameters, sensors=["encoders", "imu", "branch_forces"]), "bench")
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else SECONDS
    rec = read_recording(HERE / "recordings" / "five_bar_A", cfg, seconds)
    rows = []
    for f in FACTORS:
        values = [p.nominal * (f if p.name == "stiffness.left_spring" else TRUE.get(p.name, 1.0)) for p in params]
        model = mf.model(params, values)
        pem = score(model, cfg, [rec]).nll
        oe = output_error(Mechanism(model), rec, Noise())
        rows.append((float(f), pem, oe))
        print(f"{f:.3f}  PEM NLL {pem:.7g}  OE {oe:.7g}", flush=True)
    arr = np.array(rows)

    def minima(y: np.ndarray) -> list[float]:
        return [float(arr[i, 0]) for i in range(1, len(y) - 1) if y[i] < y[i - 1] and y[i] < y[i + 1]]

    # the residual level: each criterion's minimum over what white noise of the assumed levels gives
    # (half the number of sample entries): 1 for a model that explains the samples to their noise
    entries = sum(len(e.data[1]) if e.kind != "imu" else 2 for e in rec.events if e.kind != "command")
    out = {"seconds": seconds, "noise_level_oe": float(arr[:, 2].min() / (entries / 2)),
           "factors": arr[:, 0].tolist(), "pem_nll": arr[:, 1].tolist(), "output_error": arr[:, 2].tolist(),
           "pem_minima": minima(arr[:, 1]), "oe_minima": minima(arr[:, 2]), "true_factor": 0.84}
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"criteria_{seconds:g}s.json").write_text(json.dumps(out, indent=1) + "\n")
    print("PEM local minima at", out["pem_minima"], "; OE local minima at", out["oe_minima"],
          f"; OE's minimum is {out['noise_level_oe']:.3g} x its noise level")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    for a, y, name in ((ax[0], arr[:, 1], "prediction error: filter NLL"), (ax[1], arr[:, 2], "output error")):
        a.plot(arr[:, 0], y - np.min(y) + 1.0, ".-")
        a.set_yscale("log")
        a.axvline(0.84, color="k", lw=0.8, ls="--")
        a.set_xlabel("left stiffness / file's")
        a.set_title(name)
    ax[0].set_ylabel("criterion - its minimum + 1")
    fig.tight_layout()
    fig.savefig(HERE / f"criteria_{seconds:g}s.png", dpi=110)


if __name__ == "__main__":
    main()
