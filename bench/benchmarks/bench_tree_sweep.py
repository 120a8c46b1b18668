"""The subtree forward sweep against the serial-chain sweep it replaced, on the shipped machines.

    .venv/bin/python bench/benchmarks/bench_tree_sweep.py [--before REV] [--rounds N] [--out DIR]

``before`` is ``elastic_pm_dyn/kinematics/kernels.py`` as it was at git revision REV
(default: the merge base with ``main``), compiled beside the current one in this process;
both get the same arrays (the old kernel reads a joint's type only, and the point's chain,
which on a serial machine is its body's chain). Per machine (config/five_bar.yaml,
triglide.yaml, hexa.yaml) two items, before and after:

- ``tree_terms``: the tree terms alone (M, h, J, bias accelerations, positions), on the
  preallocated work arrays of the simulator's and observer's workspace (``tree_terms_into``);
- ``evaluation``: those + closure rows + exact SCDD, as one RK4 stage spends it.

Timing as in bench_dynamics.py: batches of about 1 ms (k calls inside one compiled loop),
every round visits all items in a fresh random order (before and after interleaved, so load
from other users hits both alike), medians over rounds and the per-round ratio after/before
(paired). First checks that both give bit-identical terms. Writes <out>/tree_sweep.json and
prints a table.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

from elastic_pm_dyn.dynamics.kernels import scdd
from elastic_pm_dyn.kinematics import kernels as after
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

REPO = Path(__file__).resolve().parents[2]
MACHINES = ("five_bar", "triglide", "hexa")
BATCH_TARGET_S = 1e-3


def load_before(rev: str):
    """The kinematics kernels module of revision ``rev`` (or ``WORKTREE``: the current file,
    for an A/A control of the method), imported under another name."""
    path = "elastic_pm_dyn/kinematics/kernels.py"
    src = (REPO / path).read_text() if rev == "WORKTREE" else subprocess.run(
        ["git", "show", f"{rev}:{path}"], cwd=REPO, capture_output=True, text=True, check=True).stdout
    folder = Path(tempfile.mkdtemp(prefix="tree_sweep_"))
    path = folder / "kernels_before.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("kernels_before", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def make_loops(kernels, frames: bool):
    """Compiled loops of n calls around one kernels module's tree terms, on preallocated work
    arrays as the simulator's and observer's workspace has them (``frames``: the subtree
    sweep's extra (n_t x 18) array)."""
    tree_terms_into, closure_rows = kernels.tree_terms_into, kernels.closure_rows

    if frames:  # this tree's: the bundles of kinematics.kernels
        Tree, TreeTerms, TreeSweep = kernels.Tree, kernels.TreeTerms, kernels.TreeSweep

        @njit
        def terms(jf, ji, cs, pts, pidx, g, q, qd, M, h, J, a, p, wz, wo, jv, jw, fr):
            tree_terms_into(Tree(jf, ji, cs, pts, pidx, g), q, qd, TreeTerms(M, h, J, a, p),
                            TreeSweep(wz, wo, jv, jw, fr))
    else:
        @njit
        def terms(jf, ji, cs, pts, pidx, g, q, qd, M, h, J, a, p, wz, wo, jv, jw, fr):
            tree_terms_into(jf, ji, cs, pts, pidx, g, q, qd, M, h, J, a, p, wz, wo, jv, jw)

    @njit
    def loop_terms(jf, ji, cs, pts, pidx, g, q, qd, M, h, J, a, p, wz, wo, jv, jw, fr, n):
        for _ in range(n):
            terms(jf, ji, cs, pts, pidx, g, q, qd, M, h, J, a, p, wz, wo, jv, jw, fr)
        return M[0, 0]

    @njit
    def loop_eval(jf, ji, cs, pts, pidx, g, pairs, comps, q, qd, tau, M, h, J, a, p, wz, wo, jv, jw, fr,
                  A, gam, res, qdd, lam, n):
        s = 0.0
        for _ in range(n):
            terms(jf, ji, cs, pts, pidx, g, q, qd, M, h, J, a, p, wz, wo, jv, jw, fr)
            closure_rows(pairs, comps, J, a, p, A, gam, res)
            s += scdd(M, h, A, gam, tau, cs, qdd, lam)
        return s

    return loop_terms, loop_eval


class Machine:
    def __init__(self, name: str):
        self.mech = mech = Mechanism(load_model(REPO / "config" / f"{name}.yaml"))
        ma = mech.arrays
        rng = np.random.default_rng(0)
        self.q = initial_state(mech)
        self.qd = mech.tree_velocity(self.q, rng.uniform(-1.0, 1.0, len(mech.ae)))
        self.tau = mech.split_tau(rng.uniform(-1.0, 1.0, len(mech.active)))
        n, npt, m = mech.n, ma.points.shape[0], mech.m
        self.bufs = [np.empty((n, n)), np.empty(n), np.zeros((npt, 3, n)), np.empty((npt, 3)), np.empty((npt, 3)),
                     np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 18))]
        self.rows = [np.empty((m, n)), np.empty(m), np.empty(m), np.empty(n), np.empty(m)]
        self.index = {"before": ma.point_chain, "after": ma.point_body}

    def terms_args(self, which):
        ma = self.mech.arrays
        return (ma.jf, ma.ji, ma.chain_start, ma.points, self.index[which], ma.gravity, self.q, self.qd, *self.bufs)

    def eval_args(self, which):
        ma = self.mech.arrays
        b = self.bufs
        return (ma.jf, ma.ji, ma.chain_start, ma.points, self.index[which], ma.gravity, ma.closure_pairs,
                ma.closure_axes, self.q, self.qd, self.tau, *b, *self.rows[:3], *self.rows[3:])


def identical(machine: Machine, before) -> bool:
    outs = []
    for which, mod in (("before", before), ("after", after)):
        args = machine.terms_args(which)
        mod.tree_terms(*args[:13])
        outs.append([np.copy(x) for x in machine.bufs[:5]])
    return all(np.array_equal(x, y) for x, y in zip(*outs, strict=True))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default=None, help="git revision of the serial sweep (default: merge base with main)")
    ap.add_argument("--rounds", type=int, default=300)
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = ap.parse_args(argv)
    rev = args.before or subprocess.run(["git", "merge-base", "HEAD", "main"], cwd=REPO, capture_output=True,
                                        text=True, check=True).stdout.strip()
    before = load_before(rev)
    control = args.before == "WORKTREE"
    loops = {"before": make_loops(before, control), "after": make_loops(after, True)}
    machines = {name: Machine(name) for name in MACHINES}
    items = []  # (machine, what, which, function, args)
    for name, mc in machines.items():
        if control:
            mc.index["before"] = mc.index["after"]
        if not identical(mc, before):
            print(f"{name}: before and after differ", file=sys.stderr)
            return 1
        for which in ("before", "after"):
            items.append((name, "tree_terms", which, loops[which][0], mc.terms_args(which)))
            items.append((name, "evaluation", which, loops[which][1], mc.eval_args(which)))
    reps = []
    for _, _, _, f, a in items:  # compile, then calibrate k so that one batch lasts ~1 ms
        f(*a, 10)
        t0 = time.perf_counter()
        f(*a, 1000)
        reps.append(max(1, int(BATCH_TARGET_S / ((time.perf_counter() - t0) / 1000))))
    load0 = os.getloadavg()
    rng = np.random.default_rng(1)
    per_call = np.empty((args.rounds, len(items)))
    for r in range(args.rounds):
        for i in rng.permutation(len(items)):
            _, _, _, f, a = items[i]
            t0 = time.perf_counter()
            f(*a, reps[i])
            per_call[r, i] = (time.perf_counter() - t0) / reps[i]
    load1 = os.getloadavg()
    rows = []
    for name in MACHINES:
        for what in ("tree_terms", "evaluation"):
            ib = next(i for i, it in enumerate(items) if it[:3] == (name, what, "before"))
            ia = next(i for i, it in enumerate(items) if it[:3] == (name, what, "after"))
            ratio = per_call[:, ia] / per_call[:, ib]
            rows.append({"machine": name, "item": what, "n_t": machines[name].mech.n,
                         "before_us": float(np.median(per_call[:, ib]) * 1e6),
                         "after_us": float(np.median(per_call[:, ia]) * 1e6),
                         "ratio_median": float(np.median(ratio)),
                         "ratio_iqr": [float(np.percentile(ratio, 25)), float(np.percentile(ratio, 75))]})
    result = {"before": rev, "after": subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True,
                                                     text=True).stdout.strip(),
              "rounds": args.rounds, "cores": os.cpu_count(), "loadavg_start": list(load0),
              "loadavg_end": list(load1), "rows": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "tree_sweep.json").write_text(json.dumps(result, indent=1))
    print(f"serial sweep at {rev[:10]} vs subtree sweep, {args.rounds} interleaved rounds, "
          f"{os.cpu_count()} cores, load {load0[0]:.2f} -> {load1[0]:.2f}; terms bit-identical")
    print("| machine | n_t | item | before [us] | after [us] | after/before, median [IQR] of rounds |")
    print("|---|---|---|---|---|---|")
    for x in rows:
        print(f"| {x['machine']} | {x['n_t']} | {x['item']} | {x['before_us']:.3f} | {x['after_us']:.3f} | "
              f"{x['ratio_median']:.3f} [{x['ratio_iqr'][0]:.3f}, {x['ratio_iqr'][1]:.3f}] |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
