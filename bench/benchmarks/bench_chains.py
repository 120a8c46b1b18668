"""Per-chain parallelism of one SCDD evaluation, measured: what 2 threads gain on the spatial machines.

    .venv/bin/python bench/benchmarks/bench_chains.py            # ~1 min
    .venv/bin/python bench/benchmarks/bench_chains.py --quick

SCDD's point (eqs 33-34): each chain's terms and its direct dynamics are independent of the
others'; only the coupling through the cut forces (here the platform system of
``scdd_platform``) needs them all. This prototype (bench only; the core's default path is
unchanged) splits one evaluation of a platform machine into
- ``chain_block(c)``: chain c's tree terms (the core's compiled ``serial_chain_terms``) and, for a
  leg, its solves M_i^-1 [tau_i - h_i, A_i^T], its end-point inertia Lambda_i =
  (A_i M_i^-1 A_i^T)^-1 and A_i x_i (as ``scdd_platform`` does leg by leg), each chain on
  its own scratch;
- ``couple``: the serial rest: closure rows, the n_H x n_H platform system, cut forces and
  the legs' accelerations;
and runs the chain blocks
- ``serial``: one after the other, in one compiled call (the split's own overhead);
- ``threads``: two halves on 2 threads, a ``ThreadPoolExecutor`` worker and the caller,
  both in numba ``nogil`` functions;
- ``prange``: numba ``parallel=True`` over the chains, with 1 and 2 numba threads;
against ``accelerations`` (the core's serial SCDD evaluation, pinned, the reference). Every
variant's accelerations are checked against it. Times are medians over rounds that visit
the variants in random order (batches of ~2 ms); the serial fraction for Amdahl's law is
``couple``'s time over the serial split's. Writes bench/results/chains.json and chains.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numba
import numpy as np
from numba import njit, prange

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common
import common
from common import REPO

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.kernels import Tree, TreeSweep, TreeTerms, closure_rows, serial_chain_terms
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.pinned_kernels import PinnedKernel
from elastic_pm_dyn.small_linalg import cholesky_recip, cholesky_solve_rows

CASES = [("hexa", 1), ("hexa", 2), ("hexa", 4), ("triglide", 1), ("triglide", 2)]


@njit(nogil=True)
def chain_block(c, jf, ji, chain_start, points, point_body, grav, closure_pairs, comps, leg_pair, q, qd, tau,
                M, h, J, a_pt, p_pt, wz, wo, jv, jw, XY, L3, dinv2, Lam, Ax, Li3, dinvc2):
    """Chain c alone: its terms, and for a leg (leg_pair[c] = k >= 0) its solves, Lambda_k, A_k x_k.
    Writes only chain c's rows/columns and its own scratch (L3[c], dinv2[c], Li3[c], dinvc2[c])."""
    s = chain_start[c]
    e = chain_start[c + 1]
    ne = e - s
    for i in range(s, e):  # the chain's block of the tree terms (tree_terms_into zeroes the whole)
        h[i] = 0.0
        for j in range(s, e):
            M[i, j] = 0.0
        for p in range(J.shape[0]):
            J[p, 0, i] = 0.0
            J[p, 1, i] = 0.0
            J[p, 2, i] = 0.0
    serial_chain_terms(Tree(jf, ji, chain_start, points, point_body, grav), s, e, q, qd, TreeTerms(M, h, J, a_pt, p_pt),
                       TreeSweep(wz, wo, jv, jw, np.empty((0, 18))))
    k = leg_pair[c]
    if k == -2:  # the platform: coupled in couple()
        return True
    nc = comps.shape[0]
    L = L3[c]
    for i in range(ne):
        for j in range(ne):
            L[i, j] = M[s + i, s + j]
        XY[s + i, 0] = tau[s + i] - h[s + i]
    if not cholesky_recip(L, ne, dinv2[c]):
        return False
    if k < 0:  # a chain outside the closure moves freely
        cholesky_solve_rows(L, dinv2[c], ne, XY, s, 1)
        return True
    pa = closure_pairs[k, 0]
    for i in range(ne):  # A_k on the leg's columns: the leg end's Jacobian (the platform point has none there)
        for t in range(nc):
            XY[s + i, 1 + t] = J[pa, comps[t], s + i]
    cholesky_solve_rows(L, dinv2[c], ne, XY, s, 1 + nc)
    Li = Li3[c]
    for i in range(nc):
        acc = 0.0
        for t in range(ne):
            acc += J[pa, comps[i], s + t] * XY[s + t, 0]
        Ax[k, i] = acc
        for j in range(nc):
            acc = 0.0
            for t in range(ne):
                acc += J[pa, comps[i], s + t] * XY[s + t, 1 + j]
            Li[i, j] = acc
    if not cholesky_recip(Li, nc, dinvc2[c]):
        return False
    Lk = Lam[k]
    for i in range(nc):
        for j in range(nc):
            Lk[i, j] = 1.0 if i == j else 0.0
    cholesky_solve_rows(Li, dinvc2[c], nc, Lk, 0, nc)
    return True


@njit(nogil=True)
def couple(chain_start, point_chain, closure_pairs, comps, hub, leg_pair, tau, M, h, J, a_pt, p_pt, XY, Lam, Ax,
           A, gamma, res, qdd, lam):
    """The serial part: closure rows, the platform system (M_H + sum B^T Lambda B) xdd = ..., cut
    forces and the legs' accelerations (scdd_platform's second half)."""
    closure_rows(closure_pairs, comps, J, a_pt, p_pt, A, gamma, res)
    c = comps.shape[0]
    hs = chain_start[hub]
    nh = chain_start[hub + 1] - hs
    N = np.empty((nh, nh))
    R = np.empty((nh, 1))
    g = np.empty(c)
    LB = np.empty((c, nh))
    Lg = np.empty(c)
    dinv = np.empty(nh)
    for i in range(nh):
        R[i, 0] = tau[hs + i] - h[hs + i]
        for j in range(nh):
            N[i, j] = M[hs + i, hs + j]
    n_pairs = closure_pairs.shape[0]
    G = np.empty((n_pairs, c))
    for k in range(n_pairs):
        r0 = k * c
        for i in range(c):
            G[k, i] = gamma[r0 + i] - Ax[k, i]
        for i in range(c):
            for j in range(nh):
                LB[i, j] = 0.0
            acc = 0.0
            for t in range(c):
                lit = Lam[k, i, t]
                for j in range(nh):
                    LB[i, j] -= lit * A[r0 + t, hs + j]
                acc += lit * G[k, t]
            Lg[i] = acc
        for t in range(c):
            for i in range(nh):
                ati = A[r0 + t, hs + i]
                for j in range(nh):
                    N[i, j] -= ati * LB[t, j]
                R[i, 0] += ati * Lg[t]
    if not cholesky_recip(N, nh, dinv):
        return False
    cholesky_solve_rows(N, dinv, nh, R, 0, 1)
    for i in range(nh):
        qdd[hs + i] = R[i, 0]
    for k in range(n_pairs):
        leg = point_chain[closure_pairs[k, 0]]
        r0 = k * c
        for t in range(c):
            acc = G[k, t]
            for j in range(nh):
                acc -= A[r0 + t, hs + j] * R[j, 0]
            g[t] = acc
        for i in range(c):
            acc = 0.0
            for t in range(c):
                acc += Lam[k, i, t] * g[t]
            Lg[i] = acc
            lam[r0 + i] = acc
        for i in range(chain_start[leg], chain_start[leg + 1]):
            acc = XY[i, 0]
            for j in range(c):
                acc += XY[i, 1 + j] * Lg[j]
            qdd[i] = acc
    for ch in range(chain_start.shape[0] - 1):
        if leg_pair[ch] == -1:
            for i in range(chain_start[ch], chain_start[ch + 1]):
                qdd[i] = XY[i, 0]
    return True


@njit(nogil=True)
def blocks(lo, hi, *a):
    """Chain blocks lo..hi-1 in one compiled call (the GIL released)."""
    ok = True
    for ch in range(lo, hi):
        ok &= chain_block(ch, *a)
    return ok


@njit(nogil=True, parallel=True)
def blocks_prange(n_ch, *a):
    ok = np.empty(n_ch, dtype=np.bool_)
    for ch in prange(n_ch):
        ok[ch] = chain_block(ch, *a)
    return ok.all()


class Split:
    """One machine's arrays and scratch for the split evaluation (allocated once)."""

    def __init__(self, mech: Mechanism, q: np.ndarray, qd: np.ndarray, tau: np.ndarray):
        ma = mech.arrays
        n, npt, m = mech.n, ma.points.shape[0], ma.p_index.shape[0]
        n_ch = ma.chain_start.shape[0] - 1
        # the prototype indexes world components: the shipped machines' closure axes are base axes
        comps = np.array([int(np.argmax(a)) for a in ma.closure_axes], dtype=np.int64)
        nc = comps.shape[0]
        nmax = int(np.max(np.diff(ma.chain_start)))
        self.n_ch, self.ma = n_ch, ma
        leg_pair = np.full(n_ch, -1, dtype=np.int64)
        leg_pair[ma.hub] = -2
        for k, (pa, _, _) in enumerate(ma.closure_pairs):
            leg_pair[ma.point_chain[pa]] = k
        self.leg_pair = leg_pair
        self.M, self.h = np.zeros((n, n)), np.zeros(n)
        self.J, self.a_pt, self.p_pt = np.zeros((npt, 3, n)), np.zeros((npt, 3)), np.zeros((npt, 3))
        scratch = [np.zeros((n, 3)) for _ in range(4)]
        self.XY = np.zeros((n, 1 + nc))
        self.Lam, self.Ax = np.zeros((len(ma.closure_pairs), nc, nc)), np.zeros((len(ma.closure_pairs), nc))
        self.A, self.gamma, self.res = np.zeros((m, n)), np.zeros(m), np.zeros(m)
        self.qdd, self.lam = np.zeros(n), np.zeros(m)
        self.args = (ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, ma.closure_pairs,
                     comps, leg_pair, q, qd, tau, self.M, self.h, self.J, self.a_pt, self.p_pt,
                     *scratch, self.XY, np.zeros((n_ch, nmax, nmax)), np.zeros((n_ch, nmax)), self.Lam, self.Ax,
                     np.zeros((n_ch, nc, nc)), np.zeros((n_ch, nc)))
        self.couple_args = (ma.chain_start, ma.point_chain, ma.closure_pairs, comps, ma.hub,
                            leg_pair, tau, self.M, self.h, self.J, self.a_pt, self.p_pt, self.XY, self.Lam,
                            self.Ax, self.A, self.gamma, self.res, self.qdd, self.lam)
        # halves with about equal joint counts (the platform and the legs differ in size)
        sizes = np.diff(ma.chain_start)
        self.cut = int(np.searchsorted(np.cumsum(sizes), sizes.sum() / 2.0)) + 1

    def serial(self) -> bool:
        return blocks(0, self.n_ch, *self.args) and couple(*self.couple_args)

    def blocks_only(self) -> bool:
        return blocks(0, self.n_ch, *self.args)

    def couple_only(self) -> bool:
        return couple(*self.couple_args)

    def threads(self, pool: ThreadPoolExecutor) -> bool:
        other = pool.submit(blocks, self.cut, self.n_ch, *self.args)
        ok = blocks(0, self.cut, *self.args)
        return other.result() and ok and couple(*self.couple_args)

    def prange(self) -> bool:
        return blocks_prange(self.n_ch, *self.args) and couple(*self.couple_args)


def case_state(machine: str, n_ek: int, seed: int) -> tuple[Mechanism, np.ndarray, np.ndarray, np.ndarray]:
    mech = Mechanism(load_model(REPO / "config" / f"{machine}.yaml", elastic_dof_per_chain=n_ek))
    rng = np.random.default_rng(seed)
    q = initial_state(mech)
    qd = 0.1 * rng.standard_normal(mech.n)  # any rates: the evaluation does not need consistent ones
    tau = np.zeros(mech.n)
    tau[mech.active] = rng.uniform(-1.0, 1.0, len(mech.active))
    return mech, q, qd, tau


def timed(f, k: int) -> float:
    t0 = time.perf_counter()
    for _ in range(k):
        f()
    return (time.perf_counter() - t0) / k


def measure(machine: str, n_ek: int, rounds: int, pool: ThreadPoolExecutor, seed: int) -> dict:
    mech, q, qd, tau = case_state(machine, n_ek, seed)
    ma = mech.arrays
    code = FORMULATION_CODES["scdd"]
    qdd_ref, lam_ref, prev = np.zeros(mech.n), np.zeros(mech.m), np.zeros(mech.n)

    evaluate = PinnedKernel(accelerations)  # as Dynamics calls it

    def reference() -> None:
        evaluate(code, ma, q, qd, tau, 0.0, 0.0, prev, qdd_ref, lam_ref)

    split = Split(mech, q, qd, tau)

    def with_threads(n: int):
        def run() -> bool:
            numba.set_num_threads(n)
            return split.prange()
        return run

    variants = {"reference": reference, "serial_split": split.serial, "blocks_only": split.blocks_only,
                "couple_only": split.couple_only, "threads_2": lambda: split.threads(pool),
                "prange_1": with_threads(1), "prange_2": with_threads(2)}
    reference()
    errors = {}
    for name in ("serial_split", "threads_2", "prange_1", "prange_2"):
        split.qdd[:] = np.nan
        assert variants[name](), name
        errors[name] = float(np.max(np.abs(split.qdd - qdd_ref)) / np.max(np.abs(qdd_ref)))
    assert max(errors.values()) < 1e-10, errors
    batch = {name: max(1, int(2e-3 / max(timed(f, 50), 1e-7))) for name, f in variants.items()}
    rng = np.random.default_rng(seed)
    samples: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(rounds):
        for name in rng.permutation(list(variants)):
            samples[name].append(timed(variants[name], batch[name]))
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    med = {name: float(np.median(t)) * 1e6 for name, t in samples.items()}
    serial_fraction = med["couple_only"] / med["serial_split"]
    out = {"machine": machine, "n_ek": n_ek, "n_t": mech.n, "chains": split.n_ch, "median_us": med,
           "iqr_us": {name: [float(np.percentile(t, 25)) * 1e6, float(np.percentile(t, 75)) * 1e6]
                      for name, t in samples.items()},
           "relative_error": errors, "serial_fraction": serial_fraction}
    out["speedup_vs_reference"] = {name: med["reference"] / med[name]
                                   for name in ("serial_split", "threads_2", "prange_1", "prange_2")}
    out["amdahl"] = {str(p): 1.0 / (serial_fraction + (1.0 - serial_fraction) / p) for p in (2, 4, 8)}
    # what a dispatch costs: 2-thread time minus the ideal split of the blocks
    out["dispatch_overhead_us"] = {name: med[name] - med["couple_only"] - med["blocks_only"] / 2.0
                                   for name in ("threads_2", "prange_2")}
    return out


def table(results: list[dict]) -> str:
    lines = ["| machine | n_ek | n_t | reference | serial split | 2 threads (pool) | prange 1 / 2 threads | "
             "serial fraction | Amdahl 2 / 4 / 8 | dispatch overhead pool / prange |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results:
        m, a, o = r["median_us"], r["amdahl"], r["dispatch_overhead_us"]
        lines.append(f"| {r['machine']} | {r['n_ek']} | {r['n_t']} | {m['reference']:.1f} | {m['serial_split']:.1f} | "
                     f"{m['threads_2']:.1f} | {m['prange_1']:.1f} / {m['prange_2']:.1f} | {r['serial_fraction']:.2f} | "
                     f"{a['2']:.2f} / {a['4']:.2f} / {a['8']:.2f} | {o['threads_2']:.0f} / {o['prange_2']:.0f} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=200)
    parser.add_argument("--quick", action="store_true", help="30 rounds")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    args = parser.parse_args()
    rounds = 30 if args.quick else args.rounds
    results = []
    with ThreadPoolExecutor(max_workers=1) as pool:
        for machine, n_ek in CASES:
            print(f"{machine} n_ek = {n_ek} ...", flush=True)
            results.append(measure(machine, n_ek, rounds, pool, seed=5))
    meta = {"cpus": os.cpu_count(), "numba": numba.__version__, "threading_layer": numba.threading_layer(),
            "platform": platform.platform(), "python": platform.python_version(), "load_after": os.getloadavg(),
            "commit": common.commit()}
    common.write(args.out, "chains", {"machine": meta, "cases": results}, table(results))
    print(f"numba threading layer {meta['threading_layer']}; load average {meta['load_after']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
