"""How stale may the observer's linearisation be? Accuracy against ``process.relinearize_every``.

    .venv/bin/python bench/studies/relinearisation_age.py              # ~6 min on 2 cores
    .venv/bin/python bench/studies/relinearisation_age.py --every 8 16

A relinearisation (the springs' linearisation and the structured discretisation that gives
Phi, Qd and the accelerometer's H) is the largest single cost of an observer period: on the
Hexa at n_ek = 2 it adds ~640 us to a ~490 us period (bench/studies/observer_period_costs.py),
every ``process.relinearize_every`` prediction pieces (default 8). Spreading it over several
periods, or computing it one period late, uses a linearisation that many periods older. This
study measures what age costs: the filter's branch-force error over the open loop's, and the
fraction of samples whose NEES of [q_ae, qd_ae] lies in its 95 % band (after 50 ms), with
encoders + accelerometer (and encoders alone on the five-bar), on

- the five-bar's reference manoeuvre (the end effector moves: the pose, and with it the
  linearisation, changes), seeds 3 and 7302;
- the chirp at a held pose of bench_observer_loop.py on the Triglide and the Hexa at n_ek = 2
  (tools/observer_runs.py), its seed and 7301 (used nowhere else).

Writes bench/results/relinearisation_age.json and prints one line per run.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
import tools.observer_runs as runs  # noqa: E402

from elastic_pm_dyn.observer import Observer, ObserverConfig  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import feed, open_loop, quasi_static_series, score  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording  # noqa: E402


def cases(duration: float):
    """(machine, recording label, mechanism, recording, sensor sets)."""
    _, five_bar = runs.machine("five_bar")
    for seed in (3, 7302):
        yield "five_bar", f"manoeuvre s{seed}", five_bar, manoeuvre_recording(five_bar, seed=seed), \
            (("encoders", "imu"), ("encoders",))
    for spec in ("triglide:2", "hexa:2"):
        name, mech = runs.machine(spec)
        for seed in (runs.SEEDS[name], 7301):
            saved, runs.SEEDS[name] = runs.SEEDS[name], seed
            rec = runs.recording(name, mech, duration)
            runs.SEEDS[name] = saved
            yield spec, f"chirp s{seed}", mech, rec, (("encoders", "imu"),)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", nargs="+", type=int, default=[8, 16, 32], help="process.relinearize_every values")
    ap.add_argument("--duration", type=float, default=0.6, help="[s] of the chirps")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    a = ap.parse_args()
    rows = []
    for spec, label, mech, rec, sensor_sets in cases(a.duration):
        ol, F_qs = open_loop(rec, dt=2.5e-5), quasi_static_series(rec)
        for sensors in sensor_sets:
            for every in a.every:
                cfg = ObserverConfig.from_parameters({"sensors": list(sensors), "process.relinearize_every": every})
                s = score(rec, feed(Observer(mech, cfg), rec, sensors), ol, F_qs, settle=0.05)
                row = {"machine": spec, "recording": label, "sensors": "+".join(sensors), "every": every,
                       "vs_open_loop": s["F_ratio"] / s["F_ratio_open_loop"], "nees_in_band": s["nees_in_band"]}
                rows.append(row)
                print(f"{spec} {label} {row['sensors']} every {every}: F error / open loop "
                      f"{row['vs_open_loop']:.4f}, NEES in band {row['nees_in_band']:.3f}", flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "relinearisation_age.json").write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
