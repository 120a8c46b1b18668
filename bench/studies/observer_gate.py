"""The observer's NIS gate: what gating.probability 0.9999 (the old default) cost, against 1 - 1e-9.

    .venv/bin/python bench/studies/observer_gate.py                 # ~10 min on 2 cores
    .venv/bin/python bench/studies/observer_gate.py --held-out      # only the recordings never looked at
    .venv/bin/python bench/studies/observer_gate.py --gates 0.9999 0.999999 0.999999999 0.999999999999

A sample whose normalised innovation squared (NIS) exceeds the chi-square quantile
``gating.probability`` of its dof is not used. Under a perfect model the NIS is chi-square and
0.9999 throws away one sample in 10^4. The observer's model is not perfect (its linearisation is
up to ``process.relinearize_every`` periods old, its disturbance model has a spectrum of its own),
and the NIS has a heavier tail: at 0.9999 (3.9 standard deviations for one entry) the default
filter gated 7-16 % of the accelerometer samples on chirps and manoeuvres, and lost up to half
its accuracy with them. Sensor faults (a glitch, a bump, a NaN) lie far beyond either gate.

Per recording and gate, encoders + accelerometer, the default configuration otherwise: the
branch-force error over the open loop's, the fraction of samples whose NEES of [q_ae, qd_ae]
lies in its 95 % band (after 50 ms), and the samples gated. Recordings:

- development (looked at while choosing the gate): the five-bar's reference manoeuvre (seeds 3,
  7302) and the chirp of bench_observer_loop.py (tools/observer_runs.py) on the five-bar, the
  Triglide and the Hexa at n_ek = 2 (their seeds and 7301); recordings.py's flat 0.02 N m
  manoeuvre and chirp, seed 9711, the accelerometer before and after the command;
- held out (``--held-out``; seeds used nowhere else, run once after the choice): recordings.py's
  pink (1/f) and tones spectra at 0.02 and 0.1 N m, seeds 9811-9814, and the chirps of the Triglide and
  the Hexa with seed 7311.

Writes bench/results/observer_gate.json and prints one line per run.
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
from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate  # noqa: E402
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording  # noqa: E402

SENSORS = ("encoders", "imu")


def chirp(spec: str, seed: int, duration: float):
    name, mech = runs.machine(spec)
    saved, runs.SEEDS[name] = runs.SEEDS[name], seed
    try:
        return mech, runs.recording(name, mech, duration)
    finally:
        runs.SEEDS[name] = saved


def development(duration: float):
    _, fb = runs.machine("five_bar")
    for seed in (3, 7302):
        yield f"five_bar manoeuvre s{seed}", fb, manoeuvre_recording(fb, seed=seed)
    yield "five_bar chirp s7101", fb, runs.recording("five_bar", fb, duration)
    for motion in ("manoeuvre", "chirp"):
        for timing in ("before_command", "after_command"):
            spec = RecordingSpec(motion=motion, spectrum="flat", disturbance_rms=0.02, seed=9711, accel_timing=timing)
            yield f"five_bar {spec.name}", fb, generate(fb, spec)
    for spec in ("triglide:2", "hexa:2"):
        for seed in (runs.SEEDS[spec.partition(":")[0]], 7301):
            yield (f"{spec} chirp s{seed}", *chirp(spec, seed, duration))


def held_out(duration: float):
    _, fb = runs.machine("five_bar")
    for k, (motion, spectrum, rms, timing) in enumerate((("manoeuvre", "pink", 0.02, "after_command"),
                                                         ("chirp", "tones", 0.1, "before_command"),
                                                         ("manoeuvre", "tones", 0.1, "before_command"),
                                                         ("chirp", "pink", 0.02, "after_command"))):
        spec = RecordingSpec(motion=motion, spectrum=spectrum, disturbance_rms=rms, seed=9811 + k,
                             accel_timing=timing)
        yield f"five_bar {spec.name}", fb, generate(fb, spec)
    for spec in ("triglide:2", "hexa:2"):
        yield (f"{spec} chirp s7311", *chirp(spec, 7311, duration))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gates", nargs="+", type=float, default=[0.9999, 1 - 1e-9])
    ap.add_argument("--held-out", action="store_true", help="only the held-out recordings")
    ap.add_argument("--duration", type=float, default=0.6, help="[s] of the machines' chirps")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results"))
    a = ap.parse_args()
    sets = [("held out", held_out)] if a.held_out else [("development", development), ("held out", held_out)]
    rows = []
    for kind, make in sets:
        for label, mech, rec in make(a.duration):
            ol, F_qs = open_loop(rec, dt=2.5e-5), quasi_static_series(rec)
            for gate in a.gates:
                obs = Observer(mech, ObserverConfig.from_parameters({"sensors": list(SENSORS),
                                                                     "gating.probability": gate}))
                s = score(rec, feed(obs, rec, SENSORS), ol, F_qs, settle=0.05)
                row = {"set": kind, "recording": label, "gate": gate,
                       "vs_open_loop": s["F_ratio"] / s["F_ratio_open_loop"], "nees_in_band": s["nees_in_band"],
                       "gated": {k: obs.stats[k].rejected for k in SENSORS}, "samples": len(rec.t)}
                rows.append(row)
                print(f"{kind}: {label}, gate 1 - {1 - gate:.0e}: F error / open loop {row['vs_open_loop']:.4f}, "
                      f"NEES in band {row['nees_in_band']:.3f}, gated {row['gated']}", flush=True)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "observer_gate.json").write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
