"""Which integrator, at which step: accuracy against DOP853 and cost per simulated second.

    .venv/bin/python bench/benchmarks/bench_integrators.py                 # all machines, ~15-25 min
    .venv/bin/python bench/benchmarks/bench_integrators.py --machines five_bar:1 triglide:2 --quick
    .venv/bin/python bench/benchmarks/bench_integrators.py --simulate-rtf --repeats 3   # offline simulate: RK4 vs ETD2
    .venv/bin/python bench/benchmarks/bench_integrators.py --simulate-profile --repeats 3   # where its time goes
    .venv/bin/python bench/benchmarks/bench_integrators.py --held-out --methods etd2 etd2rk   # random energy cases

Methods: RK4 (the baseline, at steps up to its stability limit), ETD2 (sim/exponential.py:
an exponential integrator with the elastic springs integrated on sub-steps of their frozen
linear system, the rest evaluated on the exponential Euler predictor's average over the step),
and two candidates it was chosen over: ETD2RK (the same with the rest sampled at the step's ends,
Cox and Matthews' exponential Runge-Kutta) and the impulse splitting (r-RESPA: kick H/2 with
everything but the springs, the springs alone over H on the same sub-steps, kick H/2).
SCDD + projection throughout.

Per machine (five-bar; Triglide and Hexa at n_ek = 1, 2, 4) and scenario:
- ``manoeuvre``: the rigid feedforward of a quintic line (the five-bar's reference manoeuvre;
  on the Triglide a 4.7 cm line from the start pose; the Hexa, whose platform position does
  not fix its six motors, a torque sine on its holding torque: :func:`manoeuvre`), ZOH at
  1 kHz, over the move and 50 ms of the hold;
- ``chirp``: the start pose's holding torque plus a linear chirp 50 -> 1200 Hz (through the
  five-bar's, the Triglide's lower and the Hexa's lower modes; the Triglide's and Hexa's kHz
  rod modes at n_ek >= 2 lie above what a 1 kHz controller drives), a smooth function, 0.2 s.
Accuracy: branch forces sampled every 1 ms against DOP853 at rtol 1e-10 (a Python
right-hand side: the references take minutes, hence the short windows), as
RMS(F - F_ref) / RMS(F_ref - F_qs) and max |F - F_ref| / RMS(F_ref - F_qs), F_qs the
quasi-static branch force (elastic joints locked, observer/testing/evaluation.py). The criterion is the
max ratio <= 1 %.
Energy: damping, friction and gravity off, zero torque, elastic joints deflected by twice
the manoeuvre's peak branch force (:func:`energy_case`): total energy
(kinetic + gravity + springs - tau . q_a) drift over 10 s relative to the deflection's energy.
Cost: wall time per simulated second of the manoeuvre (median of repeats, methods
interleaved), compiled kernels warm.
Writes bench/results/integrators.json and integrators.md.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from elastic_pm_dyn.dynamics.inverse import tree_inverse_dynamics  # noqa: E402
from elastic_pm_dyn.errors import SingularConfigurationError  # noqa: E402
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.layout import JF_DAMPING, JF_FRICTION  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.motion.feedforward import line_torques  # noqa: E402
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE  # noqa: E402
from elastic_pm_dyn.motion.trajectory import QuinticLine  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import quasi_static_branch_forces  # noqa: E402
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator  # noqa: E402
from elastic_pm_dyn.sim.torque import FunctionTorque, TorqueTable  # noqa: E402

SAMPLE = 1e-3  # [s] comparison grid (a macro step must end on it)
RATE = 1000.0  # [Hz] control rate of the ZOH torques
CRITERION = 0.01  # max branch-force error / elastic RMS
ENERGY_CRITERION = 0.01
STEPS = {"rk4": [1e-4, 5e-5, 2.5e-5, 1.25e-5], "etd2": [1e-3, 5e-4, 2.5e-4, 1e-4],
         "etd2rk": [1e-3, 5e-4, 2.5e-4, 1e-4], "impulse": [1e-3, 5e-4, 2.5e-4, 1e-4]}
NAMES = {"rk4": "RK4", "etd2": "ETD2", "etd2rk": "ETD2RK", "impulse": "impulse"}
SPATIAL_LINE = {"triglide": (0.03, 0.02, 0.03)}


def machine(name: str, n_ek: int) -> Mechanism:
    return Mechanism(load_model(REPO / "config" / f"{name}.yaml", n_ek))


def hold_torque(mech: Mechanism) -> np.ndarray:
    """Motor torques that hold the rigid machine at the start pose (gravity), eq 17 at rest."""
    rigid = Mechanism(mech.model.locked())
    q0 = initial_state(mech)
    q = np.array([q0[mech.joint_names.index(n)] for n in rigid.joint_names])
    return tree_inverse_dynamics(rigid, q, np.zeros(rigid.n), np.zeros(rigid.n))


def manoeuvre(mech: Mechanism, name: str) -> tuple[TorqueTable, float]:
    """ZOH torques at 1 kHz and the window compared (the move and 50 ms of the hold).

    Five-bar: the reference manoeuvre's rigid feedforward; Triglide: the same quintic time
    law on a 4.7 cm line from the start pose. The Hexa's end effector is the platform's
    position alone, which does not fix its six motors: it gets the holding torque plus one
    period of a sine of 20 % of it (alternating signs per motor) over the move time.
    """
    ref = REFERENCE_MANOEUVRE
    if name == "hexa":
        hold = hold_torque(mech)
        times = np.arange(round((ref.move + ref.hold) * RATE) + 1) / RATE
        sign = np.where(np.arange(len(hold)) % 2 == 0, 1.0, -1.0)
        bump = np.where(times < ref.move, np.sin(2 * np.pi * times / ref.move), 0.0)
        torques = hold + 0.2 * np.abs(hold).max() * sign * bump[:, None]
        return TorqueTable(times, torques, "zoh"), ref.move + 0.05
    if name == "five_bar":
        a, b = np.array(ref.start), np.array(ref.end)
    else:
        a = mech.end_effector(initial_state(mech))
        b = a + np.array(SPATIAL_LINE[name])
    line = QuinticLine(a, b, ref.move, ref.hold)
    times, torques, _ = line_torques(mech.model, line, RATE)
    return TorqueTable(times, torques, "zoh"), ref.move + 0.05


def chirp(mech: Mechanism, table: TorqueTable, duration: float = 0.2, f0: float = 50.0,
          f1: float = 1200.0) -> tuple[FunctionTorque, float]:
    """Holding torque plus a chirp of 20 % of the manoeuvre's peak torque per motor."""
    hold = table.value(0.0)
    amp = 0.2 * np.abs(table.values).max(axis=0)
    sign = np.where(np.arange(len(hold)) % 2 == 0, 1.0, -1.0)  # motors in opposition excite more modes
    k = (f1 - f0) / duration

    def tau(t: float) -> np.ndarray:
        return hold + amp * sign * np.sin(2 * np.pi * (f0 * t + 0.5 * k * t * t))

    return FunctionTorque(tau), duration


def sampled(torque: FunctionTorque, duration: float) -> TorqueTable:
    """The chirp as a 1 kHz controller commands it (ZOH samples): what the plant node gets."""
    times = np.arange(round(duration * RATE) + 1) / RATE
    return TorqueTable(times, np.array([torque.value(t) for t in times]), "zoh")


PHASE_STEP = SimulationOptions().phase_step


def options(integrator: str, dt: float, sample: float = SAMPLE) -> SimulationOptions:
    # etd2rk and impulse (ETD2 with another exponential scheme) are in sim/integrators.py's table
    return SimulationOptions(integrator=integrator, dt=dt, sample=sample, phase_step=PHASE_STEP)


def simulator(mech: Mechanism, integrator: str, opts: SimulationOptions) -> Simulator:
    return Simulator(mech, opts)


def simulate(mech: Mechanism, integrator: str, dt: float, torque, duration: float):
    opts = options(integrator, dt)
    sim = simulator(mech, integrator, opts)
    return sim.run(torque, duration)


def elastic_rms(mech: Mechanism, ref, torque) -> float:
    F_qs = np.array([quasi_static_branch_forces(mech, ref.q[k], ref.qd[k], torque.value(float(ref.t[k])))
                     for k in range(len(ref.t))])
    return float(np.sqrt(np.mean((ref.branch_forces - F_qs) ** 2)))


def accuracy(mech: Mechanism, scenario: str, torque, duration: float, methods: dict[str, list[float]]) -> dict:
    t = time.perf_counter()
    try:
        ref = simulate(mech, "dop853", 1e-4, torque, duration)
    except SingularConfigurationError as exc:  # the input drove the machine near a singular pose
        print(f"    {scenario:9s} reference failed: {exc}", flush=True)
        return {"reference_failed": str(exc)[:200], "methods": {}}
    out = {"reference_wall_s": time.perf_counter() - t, "duration_s": duration,
           "peak_branch_force_N": float(np.abs(ref.branch_forces).max()),
           "elastic_rms_N": elastic_rms(mech, ref, torque),
           "branch_force_rms_N": float(np.sqrt(np.mean(ref.branch_forces ** 2))), "methods": {}}
    for method, steps in methods.items():
        for dt in steps:
            key = f"{method}@{dt:g}"
            try:
                r = simulate(mech, method, dt, torque, duration)
                err = r.branch_forces - ref.branch_forces
                out["methods"][key] = {"rms": float(np.sqrt(np.mean(err ** 2))) / out["elastic_rms_N"],
                                       "max": float(np.abs(err).max()) / out["elastic_rms_N"]}
            except Exception as exc:  # a diverged step is a result
                out["methods"][key] = {"failed": type(exc).__name__ + ": " + str(exc)[:120]}
            print(f"    {scenario:9s} {key:16s} {out['methods'][key]}", flush=True)
    return out


def energy_case(mech: Mechanism, table: TorqueTable, force: float, rng: np.random.Generator | None = None
                ) -> tuple[Mechanism, np.ndarray, np.ndarray, float, float]:
    """Undamped copy of the machine, its torque (zero), a deflected start and its energies.

    Gravity off (held by its constant rigid holding torque the Hexa is an unstable
    equilibrium: every method, RK4 at 1.25e-5 s too, falls into a singular pose within
    7-10 s), zero torque holds the start pose; every elastic joint is then deflected by
    force / stiffness, signs alternating (2x the manoeuvre's peak branch force: the size of
    vibration the machine sees; a preload far above it brings in the geometric stiffness,
    which the frozen J leaves to the explicit part), passive joints from the closure.
    With ``rng`` a held-out case: the motors moved by up to 0.05 rad from the start pose,
    the force scaled by 0.5-2, each joint's deflection by 0.3-1 with a random sign.
    Returns the mechanism, tau, q0, E(q0) and the deflection's energy E(q0) - E(start pose).
    """
    undamped = Mechanism(mech.model)
    undamped.arrays.gravity[:] = 0.0  # under gravity a held Hexa is an unstable equilibrium
    undamped.arrays.jf[:, JF_DAMPING] = 0.0
    undamped.arrays.jf[:, JF_FRICTION] = 0.0
    undamped.damping[:] = 0.0
    tau = np.zeros(len(undamped.active))  # holds the start pose without gravity
    q_start = initial_state(undamped)
    el = undamped.elastic
    pattern = np.where(np.arange(len(el)) % 2 == 0, 1.0, -1.0)
    if rng is not None:
        q_start[undamped.active] += rng.uniform(-0.05, 0.05, len(undamped.active))
        q_start = solve_pose(undamped, q_start, undamped.passive)
        force *= rng.uniform(0.5, 2.0)
        pattern = rng.choice([-1.0, 1.0], len(el)) * rng.uniform(0.3, 1.0, len(el))
    q = q_start.copy()
    q[el] += force / undamped.stiffness[el] * pattern
    q = solve_pose(undamped, q, undamped.passive)
    e0 = total_energy(undamped, q, np.zeros(undamped.n), tau)
    return undamped, tau, q, e0, e0 - total_energy(undamped, q_start, np.zeros(undamped.n), tau)


def total_energy(mech: Mechanism, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> float:
    kinetic, potential = mech.energy(q, qd)
    return kinetic + potential - float(tau @ q[mech.active])


def energy_drift(mech: Mechanism, table: TorqueTable, force: float, method: str, dt: float, horizon: float,
                 seed: int | None = None) -> dict:
    from elastic_pm_dyn.sim.torque import ConstantTorque
    rng = None if seed is None else np.random.default_rng(seed)
    undamped, tau, q0, e0, e_modes = energy_case(mech, table, force, rng)
    opts = options(method, dt, 0.05)
    sim = simulator(undamped, method, opts)
    try:
        r = sim.run(ConstantTorque(tau), horizon, q0=q0)
    except Exception as exc:
        return {"failed": type(exc).__name__ + ": " + str(exc)[:120]}
    e = np.array([total_energy(undamped, r.q[k], r.qd[k], tau) for k in range(len(r.t))])
    return {"drift": float(np.abs(e - e0).max() / e_modes), "end": float((e[-1] - e0) / e_modes),
            "mode_energy_J": e_modes}


# Held-out energy cases (--held-out): seeds and steps nothing was tuned on
HELD_OUT_SEEDS = [31, 32, 33]
HELD_OUT_STEPS = {"hexa:4": [1e-3, 2.5e-4, 1e-4]}


def held_out_energy(specs: list[str], methods: list[str], seeds: list[int], horizon: float) -> dict:
    """Undamped energy drift from random poses and deflection patterns (:func:`energy_case`
    with a seed), the force from the manoeuvre's peak branch force (ETD2 at 0.25 ms, within
    1e-3 of DOP853's); ETD2 steps 1 and 0.5 ms (the Hexa at n_ek = 4: 1, 0.25, 0.1 ms)."""
    out: dict = {}
    for spec in specs:
        name, n_ek = spec.split(":")
        mech = machine(name, int(n_ek))
        table, window = manoeuvre(mech, name)
        force = 2 * float(np.abs(simulate(mech, "etd2", 2.5e-4, table, window).branch_forces).max())
        out[spec] = {"force_N": force, "runs": {}}
        for seed in seeds:
            for dt in HELD_OUT_STEPS.get(spec, [1e-3, 5e-4]):
                for m in methods:
                    key = f"{m}@{dt:g} seed {seed}"
                    res = energy_drift(mech, table, force, m, dt, horizon, seed)
                    out[spec]["runs"][key] = res
                    print(f"  held-out {spec} {key}: {res.get('drift', res.get('failed'))}", flush=True)
        for m in methods:
            drifts = [r.get("drift", np.inf) for k, r in out[spec]["runs"].items() if k.startswith(m + "@")]
            print(f"held-out {spec} {m}: max drift {max(drifts):.3g}, above 1 %: "
                  f"{sum(d > ENERGY_CRITERION for d in drifts)} of {len(drifts)}", flush=True)
    return out


def integrate(mech: Mechanism, integrator: str, dt: float, torque: TorqueTable, duration: float) -> None:
    """The integration alone, one torque piece (control period) per call as the plant node steps."""
    sim = simulator(mech, integrator, options(integrator, dt))
    q, qd = initial_state(mech), np.zeros(mech.n)
    grid = torque.breakpoints()
    for t0, t1 in itertools.pairwise(grid):
        if t0 >= duration:
            break
        sim.advance(q, qd, torque, t0, t1)


def cost(mech: Mechanism, torque: TorqueTable, duration: float, methods: list[tuple[str, float]],
         repeats: int) -> dict:
    """Median wall time per simulated second of the integration alone (Simulator.advance per
    1 ms torque piece, no output rows), methods interleaved (A, B, A, B ...)."""
    walls: dict[str, list[float]] = {f"{m}@{dt:g}": [] for m, dt in methods}
    for m, dt in methods:  # compile / warm
        try:
            integrate(mech, m, dt, torque, 0.01)
        except Exception:
            walls.pop(f"{m}@{dt:g}")
    for _ in range(repeats):
        for m, dt in methods:
            key = f"{m}@{dt:g}"
            if key not in walls:
                continue
            t = time.perf_counter()
            try:
                integrate(mech, m, dt, torque, duration)
            except Exception:
                walls.pop(key)
                continue
            walls[key].append((time.perf_counter() - t) / duration)
    return {k: {"wall_per_sim_s": float(np.median(v)), "rtf": float(1.0 / np.median(v))} for k, v in walls.items()}


# Offline `simulate` comparison: RK4 at the step it needs for the criterion on ZOH inputs
# (this bench's table), ETD2 at RECOMMENDED_STEP and, where it meets the criteria (ZOH inputs and
# the undamped energy), at 1 ms (the Hexa at n_ek = 2).
SIMULATE_STEPS = {"five_bar:1": [("rk4", 5e-5), ("etd2", 5e-4)], "triglide:2": [("rk4", 2.5e-5), ("etd2", 5e-4)],
                  "hexa:2": [("rk4", 5e-5), ("etd2", 5e-4), ("etd2", 1e-3)]}


def simulate_rtf(repeats: int, duration: float = 2.0) -> dict:
    """What ``elastic-pm-dyn simulate`` does after start-up (Simulator.run over the manoeuvre's
    torques held to ``duration``, output every 1 ms, CSV written), interleaved over the methods.
    Real-time factors from the median wall time and, less sensitive to other users' load on a
    shared machine, from the median CPU time of this process."""
    import tempfile
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for spec, steps in SIMULATE_STEPS.items():
            name, n_ek = spec.split(":")
            mech = machine(name, int(n_ek))
            table, _ = manoeuvre(mech, name)
            keys = [f"{m}@{dt:g}" for m, dt in steps]
            walls: dict[str, list[float]] = {k: [] for k in keys}
            cpus: dict[str, list[float]] = {k: [] for k in keys}
            for m, dt in steps:
                simulate(mech, m, dt, table, 0.01)  # compile / warm
            for _ in range(repeats):
                for key, (m, dt) in zip(keys, steps, strict=True):
                    t, c = time.perf_counter(), time.process_time()
                    simulate(mech, m, dt, table, duration).to_csv(Path(tmp) / "run.csv")
                    walls[key].append(time.perf_counter() - t)
                    cpus[key].append(time.process_time() - c)
            out[spec] = {k: {"rtf": duration / float(np.median(walls[k])),
                             "rtf_cpu": duration / float(np.median(cpus[k])),
                             "wall_s": walls[k], "cpu_s": cpus[k]} for k in keys}
            print(f"simulate {spec}: " + ", ".join(f"{k} RTF {v['rtf']:.1f} (CPU {v['rtf_cpu']:.1f})"
                                                   for k, v in out[spec].items()), flush=True)
    return out


def simulate_profile(repeats: int, duration: float = 2.0) -> dict:
    """Where the CPU time of an offline ETD2 run (as :func:`simulate_rtf`) goes, min of repeats:
    the compiled steps (timed around their calls), the derived outputs (the result rebuilt from
    its samples), the CSV, and the rest of Simulator.run (its Python loop, records, set-up)."""
    import tempfile

    from elastic_pm_dyn.sim import simulator
    from elastic_pm_dyn.sim.result import SimulationResult
    owner, name = simulator.Simulator, "run_pieces"  # the compiled pieces, through their pinned entry point
    if not hasattr(owner, name):  # an older tree (a comparison): batch's flat twin, or one call per piece
        try:
            from elastic_pm_dyn.sim import batch
            owner, name = batch, "run_pieces_flat"
        except ImportError:
            owner, name = simulator.Simulator, "fixed_steps"
    compiled = getattr(owner, name)
    spent = [0.0]

    def timed(*args, **kwargs):
        c = time.process_time()
        try:
            return compiled(*args, **kwargs)
        finally:
            spent[0] += time.process_time() - c

    setattr(owner, name, timed)
    out: dict = {}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for spec, steps in SIMULATE_STEPS.items():
                m_name, n_ek = spec.split(":")
                mech = machine(m_name, int(n_ek))
                table, _ = manoeuvre(mech, m_name)
                for dt in [dt for m, dt in steps if m == "etd2"]:
                    simulate(mech, "etd2", dt, table, 0.01).to_csv(Path(tmp) / "run.csv")
                    best: dict | None = None
                    for _ in range(repeats):
                        spent[0] = 0.0
                        c0 = time.process_time()
                        r = simulate(mech, "etd2", dt, table, duration)
                        c1 = time.process_time()
                        r.to_csv(Path(tmp) / "run.csv")
                        c2 = time.process_time()
                        SimulationResult(mech, r.t, r.q, r.qd, r.tau, r.formulation, r.info)
                        outputs = time.process_time() - c2
                        row = {"total_s": c2 - c0, "compiled_steps_s": spent[0], "derived_outputs_s": outputs,
                               "csv_s": c2 - c1, "rest_of_run_s": c1 - c0 - spent[0] - outputs}
                        if best is None or row["total_s"] < best["total_s"]:
                            best = row
                    out[f"{spec} etd2@{dt:g}"] = best
                    print(f"profile {spec} etd2@{dt:g}: "
                          + ", ".join(f"{k[:-2]} {v * 1e3:.1f} ms" for k, v in best.items()), flush=True)
    finally:
        setattr(owner, name, compiled)
    return out


def load() -> float:
    return os.getloadavg()[0]


def main() -> None:
    global PHASE_STEP
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--machines", nargs="+", default=["five_bar:1", "triglide:1", "triglide:2", "triglide:4",
                                                       "hexa:1", "hexa:2", "hexa:4"])
    p.add_argument("--quick", action="store_true", help="shorter windows (0.1 s)")
    p.add_argument("--methods", nargs="+", choices=tuple(STEPS), default=list(STEPS),
                   help="integrators to compare (each at its steps in STEPS)")
    p.add_argument("--energy-horizon", type=float, default=10.0, help="[s]; 0: no energy runs")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--phase-step", type=float, default=SimulationOptions().phase_step,
                   help="etd2 sub-step [rad of the fastest mode]")
    p.add_argument("--out", default=str(REPO / "bench" / "results" / "integrators.json"))
    p.add_argument("--append", action="store_true", help="add the machines to the results already in --out")
    p.add_argument("--energy-only", action="store_true", help="with --append: redo only the energy runs")
    p.add_argument("--simulate-rtf", action="store_true",
                   help="only the offline simulate comparison (five-bar, Triglide and Hexa at n_ek = 2)")
    p.add_argument("--simulate-profile", action="store_true",
                   help="only where an offline ETD2 simulate run's CPU time goes (the same three machines)")
    p.add_argument("--held-out", action="store_true",
                   help="only the undamped energy from random poses and deflections (seeds --seeds) of --machines")
    p.add_argument("--seeds", nargs="+", type=int, default=HELD_OUT_SEEDS)
    p.add_argument("--steps", nargs="+", type=float, help="[s] these steps for every method instead of STEPS")
    args = p.parse_args()
    if args.held_out:
        methods = [m for m in args.methods if m not in ("rk4", "impulse")]
        res = {"load_start": load(), "seeds": args.seeds, "energy_horizon_s": args.energy_horizon,
               "held_out": held_out_energy(args.machines, methods, args.seeds, args.energy_horizon),
               "load_end": load()}
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).with_name("integrators_held_out.json").write_text(json.dumps(res, indent=1))
        return
    if args.simulate_profile:
        res = {"load_start": load(), "profile": simulate_profile(args.repeats), "load_end": load()}
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).with_name("integrators_simulate_profile.json").write_text(json.dumps(res, indent=1))
        return
    if args.simulate_rtf:
        res = {"load_start": load(), "simulate": simulate_rtf(args.repeats), "load_end": load()}
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).with_name("integrators_simulate.json").write_text(json.dumps(res, indent=1))
        print(f"load average {res['load_start']:.2f} at start, {res['load_end']:.2f} at end")
        return
    PHASE_STEP = args.phase_step
    methods = {m: args.steps or STEPS[m] for m in args.methods}  # what this run measures
    results = {"load_start": load(), "machines": {}, "criterion": CRITERION, "phase_step": PHASE_STEP, "steps": {}}
    if args.append and Path(args.out).exists():  # machines measured by an earlier run (its load kept)
        results = json.loads(Path(args.out).read_text())
    measured = steps_of(results)  # the table shows every step measured, this run's added
    for m, steps in methods.items():
        measured[m] = sorted(set(measured.get(m, [])) | set(steps), reverse=True)
    results["steps"] = measured
    for spec in args.machines:
        name, n_ek = spec.split(":")
        mech = machine(name, int(n_ek))
        print(f"== {name} n_ek={n_ek} (n_t {mech.n}, elastic {len(mech.elastic)})", flush=True)
        table, window = manoeuvre(mech, name)
        fn, chirp_window = chirp(mech, table)
        if args.quick:
            window = chirp_window = 0.1
        entry: dict = {"n_t": mech.n, "n_elastic": len(mech.elastic)}
        if args.energy_only:
            entry = results["machines"][spec]
        else:
            entry["manoeuvre"] = accuracy(mech, "manoeuvre", table, window, methods)
            entry["chirp"] = accuracy(mech, "chirp", fn, chirp_window, methods)
            entry["chirp_zoh"] = accuracy(mech, "chirp_zoh", sampled(fn, chirp_window), chirp_window, methods)
            entry["cost"] = cost(mech, table, window, [(m, dt) for m, steps in methods.items() for dt in steps],
                                 args.repeats)
            for k, v in entry["cost"].items():
                print(f"    cost {k:16s} rtf {v['rtf']:.2f}", flush=True)
        if args.energy_horizon > 0:
            entry.setdefault("energy", {})  # an appended run's steps join those measured before
            for m, steps in methods.items():
                if m == "impulse":  # not a contender (see the accuracy)
                    continue
                for dt in steps:
                    entry["energy"][f"{m}@{dt:g}"] = energy_drift(
                        mech, table, 2 * entry["manoeuvre"]["peak_branch_force_N"], m, dt, args.energy_horizon)
                    print(f"    energy {m}@{dt:g} {entry['energy'][f'{m}@{dt:g}']}", flush=True)
        results["machines"][spec] = entry
        results["load_end"] = load()
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(results, indent=1))
    Path(args.out).with_suffix(".md").write_text(table_md(results))
    print(table_md(results))


SCENARIOS = ("manoeuvre", "chirp", "chirp_zoh")


def steps_of(results: dict) -> dict[str, list[float]]:
    """The steps per method a results file holds (files from before --steps: STEPS of its methods)."""
    if "steps" in results:
        return results["steps"]
    return {m: STEPS[m] for m in results.get("methods", STEPS)}


def _best(entry: dict, method: str, steps: list[float], scenarios: tuple[str, ...]
          ) -> tuple[float | None, float | None]:
    """Largest of ``method``'s ``steps`` whose max error meets the criterion in ``scenarios`` and
    whose undamped energy drift (if measured) does, and its RTF."""
    ok = []
    for dt in steps:
        key = f"{method}@{dt:g}"
        errs = [entry[s]["methods"].get(key, {}).get("max", np.inf) for s in scenarios
                if "reference_failed" not in entry[s]]  # a scenario without reference is left out (said in the table)
        en = entry.get("energy", {}).get(key)
        if en is not None:
            errs.append(en.get("drift", np.inf) * CRITERION / ENERGY_CRITERION)
        if max(errs) <= CRITERION:
            ok.append(dt)
    if not ok:
        return None, None
    dt = max(ok)
    return dt, entry["cost"].get(f"{method}@{dt:g}", {}).get("rtf")


def table_md(results: dict) -> str:
    lines = ["| machine | method @ step | manoeuvre rms / max | chirp rms / max | chirp ZOH rms / max | "
             "energy drift | RTF |", "|---|---|---:|---:|---:|---:|---:|"]
    steps = steps_of(results)
    methods = list(steps)
    for spec, entry in results["machines"].items():
        for m in methods:
            for dt in steps[m]:
                key = f"{m}@{dt:g}"
                acc = []
                for s in SCENARIOS:
                    r = entry[s]["methods"].get(key, {})
                    acc.append("no reference" if "reference_failed" in entry[s] else "-" if not r
                               else "diverged" if "failed" in r else f"{r['rms']:.2g} / {r['max']:.2g}")
                en = entry.get("energy", {}).get(key, {})
                en_s = "-" if not en else ("failed" if "failed" in en else f"{en['drift']:.2g}")
                rtf = entry["cost"].get(key, {}).get("rtf")
                lines.append(f"| {spec} | {key} | {acc[0]} | {acc[1]} | {acc[2]} | {en_s} | "
                             f"{'-' if rtf is None else f'{rtf:.1f}'} |")
    for title, scen in (("all three scenarios", SCENARIOS),
                        ("the ZOH inputs a plant node gets (manoeuvre, chirp ZOH)", ("manoeuvre", "chirp_zoh"))):
        lines += ["", f"Largest step with max error <= 1 % of the elastic RMS in {title} (and energy drift "
                  "< 1 % where measured), its RTF:", "",
                  "| machine | " + " | ".join(NAMES[m] for m in methods) + " |", "|---" * (len(methods) + 1) + "|"]
        for spec, entry in results["machines"].items():
            cells = []
            for m in methods:
                dt, rtf = _best(entry, m, steps[m], scen)
                cells.append("none" if dt is None else f"{dt:g} s, {rtf:.1f}" if rtf else f"{dt:g} s")
            lines.append(f"| {spec} | " + " | ".join(cells) + " |")
    lines.append(f"\nload average {results['load_start']:.2f} at start, {results.get('load_end', 0):.2f} at end "
                 "(2 shared cores)")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
