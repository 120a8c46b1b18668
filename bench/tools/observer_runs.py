"""The machines and recordings of the observer's speed runs, shared by
bench/benchmarks/bench_observer_loop.py and bench/studies/observer_live_paired.py (moved here
from bench_observer_loop.py unchanged, so that no bench script imports another).
"""

from __future__ import annotations

from pathlib import Path

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer.testing.scenarios import chirp_recording

ROOT = Path(__file__).resolve().parents[2]
SEEDS = {"five_bar": 7101, "triglide": 7102, "hexa": 7103}
TRUTH_DT = {}  # [s] RK4 step of the truth per machine (default 2.5e-5)


def machine(spec: str) -> tuple[str, Mechanism]:
    name, _, nek = spec.partition(":")
    path = ROOT / "config" / f"{name}.yaml"
    model = load_model(path, elastic_dof_per_chain=int(nek)) if nek else load_model(path)
    return name, Mechanism(model)


def recording(name: str, mech: Mechanism, duration: float, period: float = 1e-3):
    """The chirp on a PD loop, its gains scaled with the motors' reduced inertia (the
    five-bar's own: 40 N m/rad, 1 N m s/rad, 3 N m). The Hexa's motors carry light hubs
    behind the arm springs: a differenced D term at 1 kHz destabilises them, so P only.
    ``period``: the loop's (commands held, samples taken), 1 ms or 0.5 ms."""
    if name == "five_bar":
        return chirp_recording(mech, seed=SEEDS[name], duration=duration, truth_dt=2.5e-5, period=period)
    m = {"triglide": 3.34, "hexa": 0.0493}[name]  # [kg or kg m^2] a motor's reduced inertia
    kd = 0.0 if name == "hexa" else 12.5 * m
    amplitude = (0.375 if name == "triglide" else 3.75) * m  # the Triglide's platform mode rings easily
    return chirp_recording(mech, seed=SEEDS[name], duration=duration, amplitude=amplitude, kp=500.0 * m, kd=kd,
                           truth_dt=TRUTH_DT.get(name, 2.5e-5), period=period)
