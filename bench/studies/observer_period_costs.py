"""Where one observer period goes: the compiled parts, and what a call from Python adds.

    .venv/bin/python bench/studies/observer_period_costs.py                  # five-bar, Triglide n_ek = 2
    .venv/bin/python bench/studies/observer_period_costs.py --machines hexa:2

For each machine, an observer (encoders + accelerometer, default configuration) is run over
0.1 s of the chirp recording of bench_observer_loop.py (tools/observer_runs.py), then each
part of a period is timed in a compiled loop on that filter state (the state restored before
each call, so every call does the same work; min over 15 repeats of N calls, so that a busy
machine's slow repeats drop out): the prediction over 1 ms without and with a new
linearisation, with one ETD2 step instead of the rule's, the encoder and the accelerometer
corrections, the estimate output, the snapshot a compiled step takes, and the allocation of
ETD2's work arrays that every prediction makes. Beside them, what a call from Python costs
before any work: numba's dispatch on the argument types and the unboxing of the bundles a
per-message call passes (per bundle, and for all ten at once through the dispatcher and
through the compiled entry point that skips the dispatch).

Writes bench/results/observer_period_costs.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
from tools.observer_runs import machine, recording  # noqa: E402

from elastic_pm_dyn.observer import Observer, ObserverConfig  # noqa: E402
from elastic_pm_dyn.observer.core.correction import encoder_correct, imu_correct, imu_correct_auto  # noqa: E402
from elastic_pm_dyn.observer.core.kernels import FX_TRANSMISSION, estimate_flat, predict_checked  # noqa: E402
from elastic_pm_dyn.observer.core.period import _snapshot, snapshot_buffers  # noqa: E402
from elastic_pm_dyn.observer.testing.evaluation import feed  # noqa: E402
from elastic_pm_dyn.sim.exponential import etd2_workspace  # noqa: E402

SENSORS = ("encoders", "imu")


@njit
def _restore(state, saved):
    state[0][:] = saved[0]
    state[1][:] = saved[1]
    state[2][:] = saved[2]
    state[3][:, :] = saved[3]


@njit
def _saved(state):
    return state[0].copy(), state[1].copy(), state[2].copy(), state[3].copy()


@njit
def _restored_calls(kernel, args, state, n):
    """``kernel(*args)`` n times, ``state`` (among the args) restored before each call."""
    saved = _saved(state)
    for _ in range(n):
        _restore(state, saved)
        kernel(*args)
    _restore(state, saved)


@njit
def _calls(kernel, args, n):
    for _ in range(n):
        kernel(*args)


@njit
def _restores(state, n):
    saved = _saved(state)
    for _ in range(n):
        _restore(state, saved)


@njit
def _take(x):
    return 0


@njit
def _take10(a, b, c, d, e, f, g, h, i, j):
    return 0


def per_call(f, *args, n: int = 300, repeats: int = 15) -> float:
    """[us] per call of ``f(*args, n)``'s loop body: min over ``repeats``."""
    f(*args, 2)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        f(*args, n)
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def call_cost(f, *args, n: int = 1000, repeats: int = 15) -> float:
    """[us] per call of ``f(*args)`` from Python: min over ``repeats``."""
    f(*args)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            f(*args)
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def study(spec: str) -> dict:
    name, mech = machine(spec)
    rec = recording(name, mech, 0.1)
    obs = Observer(mech, ObserverConfig.from_parameters({"sensors": list(SENSORS)}))
    feed(obs, rec, SENSORS)
    ma, fixed, proc, state = mech.arrays, obs.model.fixed, obs._proc, obs._state()
    n = ma.jf.shape[0]
    tree_b = fixed[FX_TRANSMISSION] @ obs.tau_hold  # tree forces of the holding input, tau_t = B u
    tree_a = 1.01 * tree_b
    n_sub = max(1, int(np.ceil(1e-3 / obs.dt - 1e-9)))
    plan = obs.encoders.fast_plan(rec.active_names, obs.nx)
    enc = plan[1:5]
    enc_meas = state[0][enc[2]] + 1e-5
    imu_meas = np.zeros(obs._imu_bundle[0].shape[0])
    cmd, ctl = obs._kernel_control(0, np.inf)
    save = snapshot_buffers(state, cmd, obs.evidence, ctl)
    restore = per_call(_restores, state)

    def restored(kernel, *args, n=300):
        return per_call(_restored_calls, kernel, args, state, n=n)

    parts = {
        "predict 1 ms (the rule's ETD2 steps)": restored(predict_checked, ma, fixed, proc, state, tree_b, False, 1e-3,
                                                         n_sub),
        "predict 1 ms (1 ETD2 step)": restored(predict_checked, ma, fixed, proc, state, tree_b, False, 1e-3, 1),
        "predict 1 ms with a new linearisation": restored(predict_checked, ma, fixed, proc, state, tree_b, True, 1e-3,
                                                          n_sub, n=60),
        "encoder correction": restored(encoder_correct, ma, state, enc, enc_meas, 1e9),
        "accelerometer correction (one hypothesis)": restored(imu_correct, ma, fixed, proc, state, obs._imu_bundle,
                                                              tree_b, imu_meas, 1e9, np.empty(3)),
        "accelerometer correction (auto: both hypotheses)": restored(imu_correct_auto, ma, fixed, proc, state,
                                                                     obs._imu_bundle, tree_b, tree_a, False, imu_meas,
                                                                     1e9, obs.evidence.copy()),
        "estimate output": per_call(_calls, estimate_flat, (ma, fixed, proc, state, obs.tau_last, 0.0,
                                                           np.empty(obs.flat_layout()["P"].stop))),
        "snapshot of a compiled step (with Phi, Qd: a step that may relinearise)":
            per_call(_calls, _snapshot, (state, cmd, obs.evidence, ctl, save, np.bool_(True))),
        "snapshot of a compiled step (without Phi, Qd)":
            per_call(_calls, _snapshot, (state, cmd, obs.evidence, ctl, save, np.bool_(False))),
        "ETD2 work arrays (made in every prediction)": per_call(_calls, etd2_workspace, (ma,)),
    }
    parts = {k: (v - restore if k.startswith(("predict", "encoder", "accelerometer")) else v) for k, v in parts.items()}
    bundles = {"mech.arrays (a NamedTuple)": ma, "mech.arrays as a plain tuple": tuple(ma), "fixed": fixed,
               "proc": proc, "state": state, "cmd": cmd, "work": obs._work, "save": obs._save,
               "ETD2 work arrays": etd2_workspace(ma)}
    boundary = {f"unbox {k}": call_cost(_take, v) for k, v in bundles.items()}
    ten = (ma, fixed, proc, state, cmd, ctl, obs._timing, obs.evidence, obs._work, obs._save)
    _take10(*ten)
    entry = _take10.overloads[_take10.signatures[0]].entry_point
    boundary["ten bundles, through the dispatcher"] = call_cost(_take10, *ten)
    boundary["ten bundles, through the entry point"] = call_cost(entry, *ten)
    boundary["a Python call doing nothing"] = call_cost(lambda: None)
    return {"machine": spec, "n_tree": int(n), "nx": int(obs.nx), "etd2_steps": n_sub,
            "parts_us": parts, "boundary_us": boundary}


def markdown(results: list[dict]) -> str:
    names = [r["machine"] for r in results]
    lines = ["| compiled part [us] | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names),
             "| (state size n_x; ETD2 steps per 1 ms) | " + " | ".join(f"{r['nx']}; {r['etd2_steps']}" for r in results)
             + " |"]
    for key in results[0]["parts_us"]:
        lines.append(f"| {key} | " + " | ".join(f"{r['parts_us'][key]:.1f}" for r in results) + " |")
    lines += ["", "| a call from Python [us] | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for key in results[0]["boundary_us"]:
        lines.append(f"| {key} | " + " | ".join(f"{r['boundary_us'][key]:.2f}" for r in results) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", nargs="+", default=["five_bar", "triglide:2"])
    a = ap.parse_args()
    results = [study(m) for m in a.machines]
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    meta = {"date": time.strftime("%Y-%m-%d %H:%M"), "machine": platform.node(), "cpus": platform.processor()}
    (out / "observer_period_costs.json").write_text(json.dumps({"meta": meta, "results": results}, indent=2))
    md = markdown(results)
    (out / "observer_period_costs.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
