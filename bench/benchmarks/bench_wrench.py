"""Sensorless force sensing (issue 43): the wrench states and contact detection on every machine.

    .venv/bin/python bench/benchmarks/bench_wrench.py --parts steps contact            # ~3 min, 2 cores
    .venv/bin/python bench/benchmarks/bench_wrench.py --parts steps --seed-base 7301   # held-out seeds
    .venv/bin/python bench/benchmarks/bench_wrench.py --parts quiet --quiet-seconds 20 # ~11 min

Lockstep plant + observer (``observer.testing.wrench_runs``: the plant's ETD2 at 0.1 ms with the
wrench evaluated per step, PD hold, encoders + accelerometer a(t_k-), a flat 2-200 Hz multisine of
0.02 N m (N on the Triglide's linear motors) on every motor, seeds 4301+), the five-bar, the
Triglide and the Hexa at n_ek = 2, ``process.wrench: random_walk`` with ``wrench_runs.FORCE_SENSING``
(the disturbance model that goes with the wrench states; bench/benchmarks/README_wrench.md):

- steps: 2 N along x, y, z (the five-bar: x, y) and 0.2 N m about x, y, z on the Hexa's platform
  at t = 0.2 s: |error| / step 20 ms after it, the mean |error| / step over the last 30 % of
  the 0.4 s after it, the fraction of samples (after 50 ms) whose NEES of the wrench states
  (full covariance block) lies in its two-sided 95 % band;
- contact: the motors moved at constant rates into a 1e4 N/m wall (damping 10 N s/m) placed
  where the free move passes at 0.15 s, normal against the motion: the delay from the first
  period inside the wall to the detection (chi-square threshold, 1e-7 per sample);
- normal motion: repeated 1 s chirps 20-800 Hz on the PD loop (the observer benches' motion)
  with the disturbance, ``--quiet-seconds`` long per machine: false detections, the largest
  statistic over its threshold;
- the observer's cost per period in those runs (median, p99) with the wrench states.

Writes bench/results/wrench_<machines>.{json,md}.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
import common  # noqa: E402

from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.observer.core.contact import ContactDetector  # noqa: E402
from elastic_pm_dyn.observer.testing.wrench_runs import run, step_scores, wrench_config  # noqa: E402
from elastic_pm_dyn.sim.wrench import ExternalWrench, StepWrench, Wall  # noqa: E402

MACHINES = {"five_bar": 0, "triglide": 2, "hexa": 2}
# the PD hold's gains [N m/rad or N/m, N m s/rad or N s/m] (None: wrench_runs' defaults); the Hexa's
# light motors (0.009 kg m^2 reduced) need a stiffer hold, else a 0.2 N m couple walks the platform away
HOLD = {"hexa": (60.0, 0.5)}
PARTS = ("steps", "contact", "quiet", "cost")
CHIRP_AMPLITUDE = {"five_bar": 3.0, "triglide": 0.375 * 3.34, "hexa": 3.75 * 0.0493}  # bench/tools/observer_runs.py


def mech_of(name: str) -> Mechanism:
    nek = MACHINES[name]
    path = ROOT / "config" / f"{name}.yaml"
    return Mechanism(load_model(path, elastic_dof_per_chain=nek) if nek else load_model(path))


def detector_stop(det: dict, peak: list | None = None, stop_on_event: bool = True):
    def stop(k, row, layout):
        d = det.setdefault("d", ContactDetector(layout))
        if peak is not None and k > 50:
            peak[0] = max(peak[0], d.statistic(row))
        return d.update(row) is not None and stop_on_event
    return stop


def hold(name: str) -> dict:
    kp, kd = HOLD.get(name, (None, None))
    return {"kp": kp, "kd": kd}


def steps(name: str, mech: Mechanism, seed_base: int = 4301) -> list[dict]:
    out = []
    comps = [(0, 2.0), (1, 2.0)] + ([(2, 2.0)] if name != "five_bar" else []) \
        + ([(3, 0.2), (4, 0.2), (5, 0.2)] if name == "hexa" else [])
    for comp, size in comps:
        w = np.zeros(6)
        w[comp] = size
        r = run(mech, ExternalWrench([StepWrench(0.2, w)]), 0.6, seed=seed_base + comp, **hold(name))
        s = step_scores(r, 0.2, comp, size)
        out.append({"component": r.names[comp], "size": size, **s,
                    "period_median_us": float(np.median(r.period_s[5:]) * 1e6),
                    "period_p99_us": float(np.percentile(r.period_s[5:], 99) * 1e6)})
    return out


def contact(name: str, mech: Mechanism) -> dict:
    rate = np.full(len(mech.active), 1e-3)
    rate[0] *= -1.0  # not the common mode alone (on the five-bar it only turns the arms apart)
    free = run(mech, ExternalWrench(), 0.2, ref_rate=rate, **hold(name))
    v = (free.ee[200] - free.ee[100]) / 0.1
    rate *= 0.1 / max(np.linalg.norm(v), 1e-12)  # about 0.1 m/s at the end effector
    free = run(mech, ExternalWrench(), 0.2, ref_rate=rate, **hold(name))
    v = (free.ee[200] - free.ee[100]) / 0.1
    wall = Wall(free.ee[150], -v / np.linalg.norm(v), 1e4, 10.0)
    det = {}
    r = run(mech, ExternalWrench([wall]), 0.3, ref_rate=rate, stop=detector_stop(det), **hold(name))
    inside = np.flatnonzero([wall.depth(p) > 0 for p in r.ee])
    touch = float(r.t[inside[0]]) if len(inside) else float("nan")
    return {"speed_m_s": float(np.linalg.norm(v)), "touch_s": touch, "detected_s": r.stopped_at,
            "delay_ms": (r.stopped_at - touch) * 1e3 if r.stopped_at is not None else None,
            "true_force_at_detection_N": float(np.linalg.norm(r.true[-1][:3]))}


def quiet(name: str, mech: Mechanism, seconds: float) -> dict:
    amp = CHIRP_AMPLITUDE[name]
    sign = np.array([1.0, -1.0] + [1.0] * (len(mech.active) - 2))

    def chirp(t):
        tt = t % 1.0
        return amp * np.sin(2 * np.pi * (20 * tt + 390 * tt * tt)) * sign * min(1.0, tt / 0.02, (1 - tt) / 0.02)

    det, peak = {}, [0.0]
    start = time.perf_counter()
    r = run(mech, ExternalWrench(), seconds, extra=chirp, stop=detector_stop(det, peak, stop_on_event=False),
            seed=4399, **hold(name))
    return {"seconds": seconds, "false_detections": sum(e.kind == "contact" for e in det["d"].events),
            "peak_statistic_over_threshold": peak[0] / det["d"].threshold, "wall_s": time.perf_counter() - start,
            "period_median_us": float(np.median(r.period_s[5:]) * 1e6),
            "period_p99_us": float(np.percentile(r.period_s[5:], 99) * 1e6)}


def cost(name: str, mech: Mechanism, seconds: float = 2.0) -> dict:
    """The observer's wall time per period with and without the wrench states, the same hold run
    (paired: the machine's load moves both alike); median and p99 [us]."""
    out = {}
    for label, wrench in (("with", "random_walk"), ("without", "none")):
        r = run(mech, ExternalWrench(), seconds, config=wrench_config(process__wrench=wrench), seed=4398,
                **hold(name))
        out[label] = {"median_us": float(np.median(r.period_s[5:]) * 1e6),
                      "p99_us": float(np.percentile(r.period_s[5:], 99) * 1e6)}
    return out


def run_part(part: str, name: str, mech: Mechanism, quiet_seconds: float, seed_base: int = 4301) -> Any:
    if part == "steps":
        return steps(name, mech, seed_base)
    if part == "contact":
        return contact(name, mech)
    if part == "quiet":
        return quiet(name, mech, quiet_seconds)
    return cost(name, mech)


def markdown(result: dict) -> str:
    lines = [f"Measured {result['date']} on {result['machine']}, commit {result['commit']} (`{result['command']}`).",
             "", "| machine | step | error 20 ms after | steady-state bias | steady-state mean abs. error "
             "| NEES in band | observer period median / p99 [us] |",
             "|---|---|---|---|---|---|---|"]
    for m, res in result["machines"].items():
        for s in res.get("steps", []):
            unit = "N m" if s["component"].startswith("torque") else "N"
            lines.append(f"| {m} | {s['size']:g} {unit} {s['component']} | {100 * s['error_at_20ms']:.1f} % | "
                         f"{100 * s['steady_error']:.1f} % | {100 * s['steady_abs_error']:.1f} % | "
                         f"{100 * s['nees_in_band']:.0f} % | "
                         f"{s['period_median_us']:.0f} / {s['period_p99_us']:.0f} |")
    lines += ["", "| machine | wall contact: speed | detection delay | force at detection | normal motion "
              "| false detections | peak statistic / threshold |", "|---|---|---|---|---|---|---|"]
    for m, res in result["machines"].items():
        c, q = res.get("contact"), res.get("quiet")
        delay = "-" if c is None else "not detected" if c["delay_ms"] is None else f"{c['delay_ms']:.0f} ms"
        contact_cells = (f"{c['speed_m_s']:.3f} m/s | {delay} | {c['true_force_at_detection_N']:.1f} N" if c
                         else "- | - | -")
        quiet_cells = (f"{q['seconds']:g} s chirps | {q['false_detections']} | {q['peak_statistic_over_threshold']:.2f}"
                       if q else "- | - | -")
        lines.append(f"| {m} | {contact_cells} | {quiet_cells} |")
    lines += ["", "| machine | observer period with wrench states: median / p99 [us] | without |", "|---|---|---|"]
    for m, res in ((m, r) for m, r in result["machines"].items() if "cost" in r):
        w, wo = res["cost"]["with"], res["cost"]["without"]
        lines.append(f"| {m} | {w['median_us']:.0f} / {w['p99_us']:.0f} | {wo['median_us']:.0f} / {wo['p99_us']:.0f} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", nargs="+", default=list(MACHINES))
    ap.add_argument("--quiet-seconds", type=float, default=60.0)
    ap.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS, help="what to run (default: all)")
    ap.add_argument("--seed-base", type=int, default=4301,
                    help="the steps' seeds: this + the component's index (4301: the seeds the settings were chosen on; "
                         "others are held out)")
    args = ap.parse_args()
    result = {"date": str(date.today()), "machine": platform.node(), "commit": common.commit(),
              "command": "python bench/benchmarks/bench_wrench.py " + " ".join(sys.argv[1:]), "machines": {}}
    for name in args.machines:
        mech = mech_of(name)
        result["machines"][name] = {part: run_part(part, name, mech, args.quiet_seconds, args.seed_base)
                                    for part in args.parts}
        print(name, result["machines"][name], flush=True)
    stem = "wrench_" + "_".join(args.machines) + ("" if len(args.parts) == len(PARTS) else "_" + "_".join(args.parts)) \
        + ("" if args.seed_base == 4301 else f"_seeds{args.seed_base}")
    common.write(common.RESULTS, stem, result, markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
