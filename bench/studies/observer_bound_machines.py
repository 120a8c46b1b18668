"""What the physics allows on every machine: the genie bound of ``observer_bound.py`` for the
closed loop's disturbance on the five-bar, the Triglide and the Hexa.

    .venv/bin/python bench/studies/observer_bound_machines.py                       # ~5 min on 2 cores
    .venv/bin/python bench/studies/observer_bound_machines.py --machines triglide:2 --duration 0.5

The loop acceptance (``bench/studies/loop_acceptance.py``) puts a flat 2-200 Hz unknown torque of
0.02 N m (0.02 N on the Triglide's linear drives) on every motor and asks the observer for
half the open loop's branch-force error. Whether any observer can do that depends on how
much the sensors see of so small a force, which differs by machine: 0.02 N accelerates the
Triglide's ~3 kg sliders by ~7 mm/s^2, a third of the accelerometer's noise in one sample.

Here, per machine: the machine held at rest against gravity (the hold torque from the rigid
inverse dynamics, the springs deflected by it: the loop's start), the unknown torque a sum of
``--tones`` sines per motor spread evenly over 2-200 Hz (flat: equal power per Hz, as the
plant's) with ``--rms`` per motor. Around the held pose the machine answers linearly to so
small a torque, so every sensor sample and every branch force is (nominal) + G c, c the sine
and cosine coefficients; G is measured column by column with the core simulator (RK4). A
*genie* that knows the model, the start state, the commands and the tone frequencies and only
has to find the coefficients has the linear-MMSE error (``observer_bound.bounds``): ``causal``
from the samples up to now (the best a live filter can do), ``smoother`` from the whole record.
Its ratio to the open loop's error is a lower bound for any real observer's.

Writes bench/results/observer_bound_machines.{json,md}.
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
sys.path.insert(0, str(Path(__file__).resolve().parent))

from observer_bound import bounds  # noqa: E402

from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import Noise, simulate  # noqa: E402

SENSORS = {"encoders": ("enc",), "encoders+imu": ("enc", "imu")}
TRUTH_DT = {"five_bar": 5e-5, "triglide": 2.5e-5, "hexa": 5e-5}  # [s] RK4, stable with a margin


def machine(spec: str) -> tuple[str, Mechanism]:
    name, _, nek = spec.partition(":")
    path = ROOT / "config" / f"{name}.yaml"
    return name, Mechanism(load_model(path, elastic_dof_per_chain=int(nek)) if nek else load_model(path))


def sensitivities(mech: Mechanism, freqs: np.ndarray, duration: float, truth_dt: float, unit: float) -> dict:
    """Columns of G (one-sided differences from the undisturbed hold: the response is linear)."""
    q0 = rest_state(mech)
    hold = holding_torques(mech, q0)
    n_a = len(mech.active)
    zero = Noise(0.0, 0.0, 0.0)
    rng = np.random.default_rng(0)
    axes = 3 if len(mech.ee_components) == 3 else 2

    def run(dist):
        return simulate(mech, lambda k, t, enc: hold, duration, dist, zero, rng, truth_dt, q0=q0)

    base = run(None)
    cols: dict[str, list] = {"enc": [], "imu": [], "gauge": []}
    for ch in range(n_a):
        for f in freqs:
            for kind in (np.sin, np.cos):
                def tone(t, f=f, kind=kind, ch=ch):
                    d = np.zeros(n_a)
                    d[ch] = unit * kind(2 * np.pi * f * t)
                    return d
                p = run(tone)
                cols["enc"].append((p.q[:, mech.active] - base.q[:, mech.active]) / unit)
                cols["imu"].append((p.accel_true[:, :axes] - base.accel_true[:, :axes]) / unit)
                cols["gauge"].append((p.F - base.F) / unit)
    return {k: np.stack(v, axis=-1) for k, v in cols.items()}, base.t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", nargs="+", default=["five_bar", "triglide:2", "hexa:2"])
    ap.add_argument("--duration", type=float, default=0.5, help="[s] of held pose")
    ap.add_argument("--tones", type=int, default=16, help="sines per motor in 2-200 Hz (the genie knows them)")
    ap.add_argument("--rms", type=float, nargs="+", default=[0.02],
                    help="[N m or N] unknown torque per motor; several: one row each (the same G: linear)")
    ap.add_argument("--settle", type=float, default=0.05, help="[s] samples before are not scored")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    args = ap.parse_args()
    n = Noise()
    noise = {"enc": n.encoder, "imu": n.accelerometer, "gauge": n.branch_force}
    freqs = np.linspace(2.0, 200.0, args.tones)
    result = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "noise": noise, "rms": args.rms,
              "tones": args.tones, "duration_s": args.duration, "machines": {}}
    lines = [f"Genie bounds, machine held at rest against gravity, flat 2-200 Hz unknown torque (RMS per motor, "
             f"N m or N on linear drives) as {args.tones} known tones, {args.duration:g} s; noise: "
             f"encoders {n.encoder:g} rad (m), accelerometer {n.accelerometer:g} m/s^2. The acceptance wants "
             "a real observer at <= 0.5 of the open loop.", "",
             "| machine | unknown torque RMS | sensors | open loop [mN] | causal genie [mN] | ratio "
             "| smoother genie [mN] | ratio |", "|---|---:|---|---:|---:|---:|---:|---:|"]
    for spec in args.machines:
        name, mech = machine(spec)
        t0 = time.perf_counter()
        G, t = sensitivities(mech, freqs, args.duration, TRUTH_DT[name], unit=1e-3)
        keep = t >= t[0] + args.settle - 1e-12
        rows = {}
        for rms in args.rms:
            var = (rms * np.sqrt(2.0 / args.tones)) ** 2 / 2  # each sin/cos coefficient (random phase)
            for label, sensors in SENSORS.items():
                b = bounds(G, keep, var, noise, sensors)
                rows[f"{rms:g} {label}"] = b
                lines.append(f"| {spec} | {rms:g} | {label} | {b['open_loop_rms_N'] * 1e3:.2f} | "
                             f"{b['causal_rms_N'] * 1e3:.2f} | {b['causal_vs_open_loop']:.2f} | "
                             f"{b['smoother_rms_N'] * 1e3:.2f} | {b['smoother_vs_open_loop']:.2f} |")
        result["machines"][spec] = {"bounds": rows, "seconds": time.perf_counter() - t0}
        print(lines[-1], f"({time.perf_counter() - t0:.0f} s)", flush=True)
    md = "\n".join(lines)
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer_bound_machines.json").write_text(json.dumps(result, indent=2, default=float))
    (out / "observer_bound_machines.md").write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
