"""The cost claim of the paper on real code: Tables 1 and 2 counted, and timed.

    .venv/bin/python bench/benchmarks/bench_cost.py [--rounds N] [--budget S] [--quick] [--out DIR] [--seed K]

For Five-Bar, Triglide and Hexa with n_ek = 1..4 (five-bar: its model's n_ek = 1):
- Table 1: the paper's formula (SCDD n_a (1 + n_pk + n_ek)^3, L-D'A (n_a + n_a n_ek)^3),
  the paper's rows, and the floating-point operations counted in our kernels as they run
  (bench/tools/opcount.py): the factorizations each formulation does, and the whole evaluation;
- Table 2: +, -, *, / of the rigid five-bar's direct dynamics (``model.locked()``) by SCDD
  and L-D'A, whole and after the tree terms, against the paper's 192/80/432/38 and
  670/302/2482/36;
- time per direct-dynamics evaluation for every formulation and machine: the compiled
  ``accelerations`` called from Python through its pinned entry point, as ``Dynamics`` calls
  it (``py.*``), and the kernel called from compiled code (``nj.*``, no dispatch), with its
  parts (``nj.*.terms``: allocation, tree terms, closure rows; ``nj.*.solve.<form>``: the
  formulation on given tree terms) and the prototypes of bench/prototypes/proto_cost.py (``proto.*``).

Timing method (as bench/benchmarks/bench_dynamics.py, whose helpers it reuses): batches of about 1 ms,
every round visits all items in a fresh random order, medians over batches, IQR as the
noise, ratios per round (paired) in this one run; gc off. Writes <out>/cost.json,
<out>/cost.md and <out>/cost_scaling.png, and prints the tables.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import gc
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

T_START = time.perf_counter()
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common, tools, prototypes
from common import RESULTS  # noqa: E402
from numba import njit  # noqa: E402
from prototypes.proto_cost import (  # noqa: E402
    accelerations_proto,
    closure_rows_noalloc,
    scdd_platform_fast,
    scdd_platform_ws,
)
from tools.opcount import count_in_subprocess, load_mechanism, random_state  # noqa: E402
from tools.timing import (  # noqa: E402
    Item,
    _calls,
    _entry_point,
    _inner,
    _loop_accelerations,
    _noop_same_args,
    calibrate,
    git_commit,
    machine_info,
    run_rounds,
    stats,
)

from elastic_pm_dyn.dynamics.evaluate import (  # noqa: E402
    FORMULATION_CODES,
    LDA,
    MULTIPLIERS,
    SCDD,
    SCDD_STACKED,
    accelerations,
)
from elastic_pm_dyn.dynamics.kernels import (  # noqa: E402
    lagrange_dalembert,
    multipliers,
    scdd,
    scdd_one_pass,
    scdd_platform,
)
from elastic_pm_dyn.kinematics.kernels import closure_rows, tree_terms  # noqa: E402
from elastic_pm_dyn.pinned_kernels import PinnedKernel  # noqa: E402

BATCH_TARGET_S = 1e-3
MACHINES = ("five_bar", "triglide", "hexa")
N_EK = (1, 2, 3, 4)
SPREAD = {"five_bar": 0.2, "triglide": 0.05, "hexa": 0.05}
FORMS = ("scdd", "scdd_stacked", "lda", "multipliers", "scdd_one_pass")
PAPER_TABLE1 = {  # machine: (n_a, n_pk, n_ek, SCDD, L-D'A, reduction)
    "five_bar": (2, 1, 1, 54, 64, "16 %"), "hexa": (6, 2, 1, 384, 1728, "78 %"),
    "triglide": (3, 2, 1, 162, 729, "78 %")}
PAPER_TABLE2 = {"scdd": {"+": 192, "-": 80, "*": 432, "/": 38}, "lda": {"+": 670, "-": 302, "*": 2482, "/": 36}}
TARGET_RATIO = 1.0 / 3.0  # design goal: SCDD <= 1/3 of L-D'A's time on Hexa, n_ek = 2


# ------------------------------------------------------------------ profile kernels
@njit(cache=True)
def _loop_terms(ma, q, qd, n):
    """What accelerations() does before the formulation: allocation, tree terms, closure rows, gap."""
    nt = q.shape[0]
    npt = ma.points.shape[0]
    m = ma.p_index.shape[0]
    s = 0.0
    for _ in range(n):
        M = np.empty((nt, nt))
        h = np.empty(nt)
        J = np.empty((npt, 3, nt))
        a_pt = np.empty((npt, 3))
        p_pt = np.empty((npt, 3))
        tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
        A = np.empty((m, nt))
        gamma = np.empty(m)
        res = np.empty(m)
        closure_rows(ma.closure_pairs, ma.closure_axes, J, a_pt, p_pt, A, gamma, res)
        s += np.sqrt(np.sum(res * res)) + M[0, 0] + A[0, 0] + h[0]
    return s


@njit(cache=True)
def _loop_tree_only(ma, q, qd, n):
    """tree_terms alone on preallocated arrays."""
    nt = q.shape[0]
    npt = ma.points.shape[0]
    M, h = np.empty((nt, nt)), np.empty(nt)
    J, a_pt, p_pt = np.empty((npt, 3, nt)), np.empty((npt, 3)), np.empty((npt, 3))
    for _ in range(n):
        tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    return M[0, 0]


@njit(cache=True)
def _loop_solve(form, ma, q, qd, tau, qdd_prev, qdd, lam, n):
    """The formulation alone on fixed tree terms (the dispatch of evaluate.accelerations)."""
    nt = q.shape[0]
    npt = ma.points.shape[0]
    m = ma.p_index.shape[0]
    M, h = np.empty((nt, nt)), np.empty(nt)
    J, a_pt, p_pt = np.empty((npt, 3, nt)), np.empty((npt, 3)), np.empty((npt, 3))
    A, gamma, res = np.empty((m, nt)), np.empty(m), np.empty(m)
    tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    closure_rows(ma.closure_pairs, ma.closure_axes, J, a_pt, p_pt, A, gamma, res)
    s = 0.0
    for _ in range(n):
        if form == SCDD and ma.hub >= 0:
            s += scdd_platform(M, h, A, gamma, tau, ma.chain_start, ma.point_chain, ma.closure_pairs,
                               ma.closure_axes.shape[0], ma.hub, qdd, lam)
        elif form in (SCDD, SCDD_STACKED):
            s += scdd(M, h, A, gamma, tau, ma.chain_start, qdd, lam)
        elif form == LDA:
            s += lagrange_dalembert(M, h, A, gamma, tau, ma.ae_index, ma.p_index, qdd)
        elif form == MULTIPLIERS:
            s += multipliers(M, h, A, gamma, tau, qdd, lam)
        else:
            s += scdd_one_pass(M, h, A, gamma, tau, ma.ae_index, ma.p_index, ma.chain_start, qdd_prev, qdd, lam)
    return s


@njit(cache=True)
def _loop_terms_proto(ma, q, qd, n):
    """_loop_terms with closure_rows_noalloc and the gap as a loop (proto_cost.accelerations_proto's first half)."""
    nt = q.shape[0]
    npt = ma.points.shape[0]
    m = ma.p_index.shape[0]
    s = 0.0
    for _ in range(n):
        M = np.empty((nt, nt))
        h = np.empty(nt)
        J = np.empty((npt, 3, nt))
        a_pt = np.empty((npt, 3))
        p_pt = np.empty((npt, 3))
        tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
        A = np.empty((m, nt))
        gamma = np.empty(m)
        res = np.empty(m)
        closure_rows_noalloc(ma.closure_pairs, ma.closure_axes, J, a_pt, p_pt, A, gamma, res)
        acc = 0.0
        for i in range(m):
            acc += res[i] * res[i]
        s += np.sqrt(acc) + M[0, 0] + A[0, 0] + h[0]
    return s


@njit(cache=True)
def _loop_solve_proto(ma, q, qd, tau, qdd, lam, variant, n):
    """The prototype SCDD solves alone on fixed tree terms: 0 ws, 1 ws + recip, 2 fast."""
    nt = q.shape[0]
    npt = ma.points.shape[0]
    m = ma.p_index.shape[0]
    M, h = np.empty((nt, nt)), np.empty(nt)
    J, a_pt, p_pt = np.empty((npt, 3, nt)), np.empty((npt, 3)), np.empty((npt, 3))
    A, gamma, res = np.empty((m, nt)), np.empty(m), np.empty(m)
    tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    closure_rows(ma.closure_pairs, ma.closure_axes, J, a_pt, p_pt, A, gamma, res)
    s = 0.0
    for _ in range(n):
        if variant == 2:
            s += scdd_platform_fast(M, h, A, gamma, tau, ma.chain_start, ma.point_chain, ma.closure_pairs,
                                    ma.closure_axes.shape[0], ma.hub, qdd, lam)
        else:
            s += scdd_platform_ws(M, h, A, gamma, tau, ma.chain_start, ma.point_chain, ma.closure_pairs,
                                  ma.closure_axes.shape[0], ma.hub, qdd, lam, variant == 1)
    return s


@njit(cache=True)
def _loop_proto(form, ma, q, qd, tau, qdd, lam, n):
    s = 0.0
    for _ in range(n):
        c, g = accelerations_proto(form, ma, q, qd, tau, qdd, lam)
        s += c + g
    return s


# --------------------------------------------------------------------------- set-up
class Config:
    """One machine at one n_ek: mechanism, a random consistent state, buffers."""

    def __init__(self, machine: str, n_ek: int, seed: int):
        self.machine, self.n_ek = machine, n_ek
        self.spec = machine if machine == "five_bar" else f"{machine}:{n_ek}"
        self.key = f"{machine}.{n_ek}"
        self.mech = mech = load_mechanism(self.spec)
        self.ma = mech.arrays
        q, qd, tau_a = random_state(mech, np.random.default_rng(seed), SPREAD[machine])
        self.q, self.qd, self.tau = q, qd, mech.split_tau(tau_a)
        self.forms = [f for f in FORMS if not (f == "scdd_stacked" and self.ma.hub < 0)]
        self.n, self.m = mech.n, mech.m

    def buffers(self):
        return np.empty(self.n), np.zeros(self.m), np.zeros(self.n)

    def reference(self, form: str) -> np.ndarray:
        qdd, lam, prev = self.buffers()
        accelerations(FORMULATION_CODES[form], self.ma, self.q, self.qd, self.tau, 0.0, 0.0, prev, qdd, lam)
        return qdd


def build_items(configs: list[Config], sanity: dict) -> list[Item]:
    items: list[Item] = []
    for cf in configs:
        ma, q, qd, tau = cf.ma, cf.q, cf.qd, cf.tau
        ref = cf.reference("lda")
        for form in cf.forms:
            code = FORMULATION_CODES[form]
            qdd, lam, prev = cf.buffers()
            if form != "scdd_one_pass":
                got = cf.reference(form)
                sanity[f"{cf.key}.{form}_vs_lda_max_rel"] = float(np.abs(got - ref).max() / np.abs(ref).max())
            items.append(Item(f"py.{cf.key}.{form}",
                              _calls(PinnedKernel(accelerations), code, ma, q, qd, tau, 0.0, 0.0, prev, qdd, lam),
                              group="py", note="accelerations called from Python, pinned (as Dynamics calls it)"))
            qdd, lam, prev = cf.buffers()
            items.append(Item(f"nj.{cf.key}.{form}", _inner(_loop_accelerations, code, ma, q, qd, tau, prev, qdd, lam),
                              group="nj", note="accelerations called from compiled code (no dispatch)"))
            qdd, lam, prev = cf.buffers()
            items.append(Item(f"nj.{cf.key}.solve.{form}", _inner(_loop_solve, code, ma, q, qd, tau, prev, qdd, lam),
                              group="part", note="the formulation alone on given tree terms"))
        items.append(Item(f"nj.{cf.key}.terms", _inner(_loop_terms, ma, q, qd), group="part",
                          note="allocation + tree_terms + closure_rows + gap (shared by all formulations)"))
        items.append(Item(f"nj.{cf.key}.tree", _inner(_loop_tree_only, ma, q, qd), group="part",
                          note="tree_terms alone, preallocated"))
        if ma.hub >= 0:
            for form, pcode in (("scdd", 0), ("scdd_recip", 2), ("scdd_fast", 3), ("lda", 1)):
                qdd, lam, _ = cf.buffers()
                accelerations_proto(pcode, ma, q, qd, tau, qdd, lam)
                sanity[f"{cf.key}.proto_{form}_vs_core_max_rel"] = float(
                    np.abs(qdd - cf.reference("lda" if form == "lda" else "scdd")).max() / np.abs(ref).max())
                items.append(Item(f"proto.{cf.key}.{form}", _inner(_loop_proto, pcode, ma, q, qd, tau, qdd, lam),
                                  group="proto",
                                  note="bench/prototypes/proto_cost.py accelerations_proto, from compiled code"))
            for form, variant in (("scdd", 0), ("scdd_recip", 1), ("scdd_fast", 2)):
                qdd, lam, _ = cf.buffers()
                items.append(Item(f"proto.{cf.key}.solve.{form}",
                                  _inner(_loop_solve_proto, ma, q, qd, tau, qdd, lam, variant), group="proto",
                                  note="proto_cost.scdd_platform_ws / _fast alone on given tree terms"))
            items.append(Item(f"proto.{cf.key}.terms", _inner(_loop_terms_proto, ma, q, qd), group="proto",
                              note="nj.*.terms with closure_rows_noalloc"))
    cf = configs[-1]
    qdd, lam, prev = cf.buffers()
    args = (FORMULATION_CODES["scdd"], cf.ma, cf.q, cf.qd, cf.tau, 0.0, 0.0, prev, qdd, lam)
    items.append(Item("py.dispatch.noop", _calls(_noop_same_args, *args), group="py",
                      note="a trivial njit function with accelerations' arguments through numba's dispatcher"))
    items.append(Item("py.dispatch.noop_entry_point", _calls(_entry_point(_noop_same_args, *args), *args),
                      group="py", note="the same through the compiled entry point (unboxing only): the floor"))
    return items


# ----------------------------------------------------------------------- the tables
def formula(n_a: int, n_pk: int, n_ek: int) -> tuple[int, int]:
    return n_a * (1 + n_pk + n_ek) ** 3, (n_a + n_a * n_ek) ** 3


def _flops(d: dict) -> int:
    return int(sum(v for k, v in d.items() if k in ("add", "sub", "neg", "mul", "div", "sqrt", "sin", "cos")))


def _minus(a: dict, *bs: dict) -> dict:
    out = dict(a)
    for b in bs:
        for k, v in b.items():
            out[k] = out.get(k, 0) - v
    return out


def paper_ops(d: dict) -> dict:
    """Our op names -> the paper's +, -, *, / (unary minus counted as -; sqrt, sin, cos listed apart)."""
    return {"+": d.get("add", 0), "-": d.get("sub", 0) + d.get("neg", 0), "*": d.get("mul", 0),
            "/": d.get("div", 0), "sqrt": d.get("sqrt", 0), "sin/cos": d.get("sin", 0) + d.get("cos", 0)}


def table1(counts: dict) -> list[dict]:
    rows = []
    for spec, r in counts.items():
        if spec.endswith("_rigid"):
            continue
        machine, _, k = spec.partition(":")
        n_ek = int(k) if k else r["n_e"] // r["n_a"]
        f_scdd, f_lda = formula(r["n_a"], r["n_pk"], n_ek)
        row = {"machine": machine, "n_ek": n_ek, "n_a": r["n_a"], "n_pk": r["n_pk"], "n_t": None,
               "formula_scdd": f_scdd, "formula_lda": f_lda, "formula_reduction": 1 - f_scdd / f_lda, "forms": {}}
        if n_ek == PAPER_TABLE1[machine][2]:
            row["paper_scdd"], row["paper_lda"] = PAPER_TABLE1[machine][3:5]
        for form, x in r["forms"].items():
            row["n_t"] = x["n_t"]
            row["forms"][form] = {
                "factorizations": x["factorizations"],
                "factor": x["raw_flops"]["factor"],
                "factor_and_solves": x["raw_flops"]["factor"] + x["raw_flops"]["factor_solve"],
                "solve": x["raw_flops"]["solve"],
                "evaluation": x["raw_flops"]["evaluation"],
                "tree_terms": x["raw_flops"]["tree_terms"] + x["raw_flops"]["closure_rows"],
                "cse_evaluation": x["cse_flops"]["evaluation"],
                "cse_solve": x["cse_flops"]["solve"],
                "cse_factor": x["cse_flops"]["factor"],
                "max_rel_diff_vs_float_run": x["max_rel_diff_vs_float_run"],
            }
        rows.append(row)
    order = {m: i for i, m in enumerate(MACHINES)}
    rows.sort(key=lambda r: (order[r["machine"]], r["n_ek"]))
    return rows


def table2(counts: dict) -> dict:
    r = counts["five_bar_rigid"]["forms"]
    out = {"paper": PAPER_TABLE2}
    for form in ("scdd", "lda", "scdd_one_pass"):
        x = r[form]
        tree_raw = [x["raw"]["tree_terms"], x["raw"]["closure_rows"]]
        tree_cse = [x["cse"]["tree_terms"], x["cse"]["closure_rows"]]
        out[form] = {
            "raw_whole": paper_ops(x["raw"]["evaluation"]),
            "raw_after_tree": paper_ops(_minus(x["raw"]["evaluation"], *tree_raw)),
            "folded_whole": paper_ops(x["folded"]["evaluation"]),
            "cse_whole": paper_ops(x["cse"]["evaluation"]),
            "cse_after_tree": paper_ops(_minus(x["cse"]["evaluation"], *tree_cse)),
            "factorizations": x["factorizations"],
        }
    return out


# ----------------------------------------------------------------------- markdown
def _fmt_fact(d: dict) -> str:
    return " + ".join(f"{v}x{k}" if v > 1 else k for k, v in sorted(d.items()))


def markdown(res: dict) -> str:
    L = []
    m = res["machine"]
    L.append(f"One run {res['timestamp']} (commit {res['git']}) on {m['cpu']} ({m['cores']} cores, load "
             f"{res['loadavg_start'][0]:.2f} -> {res['loadavg_end'][0]:.2f}); numba {m['numba']}. "
             f"{res['rounds']} rounds, {res['total_s']:.0f} s in all.")
    L += ["", "### Table 1: inversion cost, the paper's formula against the operations our kernels do", "",
          "Formula: SCDD n_a (1 + n_pk + n_ek)^3, L-D'A (n_a + n_a n_ek)^3 (the paper's rows in brackets). "
          "Counted: floating-point operations (+ - * / sqrt) of all factorizations of one evaluation "
          "(Cholesky/LU only; their solves in the next table).", "",
          "| machine | n_ek | n_t | formula SCDD [paper] | formula L-D'A [paper] | reduction | counted: SCDD | "
          "SCDD stacked | L-D'A | multipliers | counted reduction (SCDD vs L-D'A) | what SCDD / L-D'A factorize |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in res["table1"]:
        f = r["forms"]
        ps = f" [{r['paper_scdd']}]" if "paper_scdd" in r else ""
        pl = f" [{r['paper_lda']}]" if "paper_lda" in r else ""
        st = f["scdd_stacked"]["factor"] if "scdd_stacked" in f else "= SCDD"
        red = 1 - f["scdd"]["factor"] / f["lda"]["factor"]
        L.append(f"| {r['machine']} | {r['n_ek']} | {r['n_t']} | {r['formula_scdd']}{ps} | {r['formula_lda']}{pl} | "
                 f"{r['formula_reduction']:.0%} | {f['scdd']['factor']} | {st} | {f['lda']['factor']} | "
                 f"{f['multipliers']['factor']} | {red:.0%} | {_fmt_fact(f['scdd']['factorizations'])} / "
                 f"{_fmt_fact(f['lda']['factorizations'])} |")
    L += ["", "### Table 1b: operations of the whole evaluation (counted as run, and as a straight-line program)", "",
          "raw: every flop the generic kernel executes; cse: after constant folding, x*0/x*1 identities, CSE and "
          "dead-code elimination (a lower bound for generated code of the same algorithm). "
          "Tree terms (tree_terms + closure_rows) are shared by all formulations.", "",
          "| machine | n_ek | tree terms (raw) | SCDD raw | L-D'A raw | multipliers raw | SCDD/L-D'A raw | "
          "factor+solves SCDD | factor+solves L-D'A | SCDD cse | L-D'A cse | SCDD/L-D'A cse |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in res["table1"]:
        f = r["forms"]
        L.append(f"| {r['machine']} | {r['n_ek']} | {f['scdd']['tree_terms']} | {f['scdd']['evaluation']} | "
                 f"{f['lda']['evaluation']} | {f['multipliers']['evaluation']} | "
                 f"{f['scdd']['evaluation'] / f['lda']['evaluation']:.2f} | {f['scdd']['factor_and_solves']} | "
                 f"{f['lda']['factor_and_solves']} | {f['scdd']['cse_evaluation']} | {f['lda']['cse_evaluation']} | "
                 f"{f['scdd']['cse_evaluation'] / f['lda']['cse_evaluation']:.2f} |")
    t2 = res["table2"]
    L += ["", "### Table 2: rigid five-bar (`model.locked()`), operations of one direct-dynamics evaluation", "",
          "raw: as the generic kernels run; cse: straight-line program (folding, CSE, dead code). 'after tree': "
          "without tree_terms and closure_rows (M, h, A, gamma), i.e. the formulation's own work. "
          "Unary minus counted as -.", "",
          "| | SCDD paper | SCDD raw whole | SCDD raw after tree | SCDD cse whole | SCDD cse after tree | "
          "L-D'A paper | L-D'A raw whole | L-D'A raw after tree | L-D'A cse whole | L-D'A cse after tree | "
          "one-pass SCDD raw whole | one-pass cse whole | one-pass cse after tree |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    keys = ("raw_whole", "raw_after_tree", "cse_whole", "cse_after_tree")
    keys_op = ("raw_whole", "cse_whole", "cse_after_tree")
    for op in ("+", "-", "*", "/", "sqrt", "sin/cos", "all"):
        cells = []
        for form in ("scdd", "lda"):
            paper = PAPER_TABLE2[form]
            cells.append(str(sum(paper.values()) if op == "all" else paper.get(op, "")))
            for k in keys:
                cells.append(str(sum(t2[form][k].values()) if op == "all" else t2[form][k][op]))
        for k in keys_op:
            d = t2["scdd_one_pass"][k]
            cells.append(str(sum(d.values()) if op == "all" else d[op]))
        L.append(f"| {op} | " + " | ".join(cells) + " |")

    it = res["items"]
    L += ["", "### Time per direct-dynamics evaluation [us], median [IQR] over batches, one run", "",
          "py: `accelerations` called from Python, pinned (as `Dynamics` calls it); nj: called from compiled code "
          "(no dispatch).", "",
          "| machine | n_ek | n_t | SCDD py | SCDD stacked py | L-D'A py | multipliers py | one-pass py | SCDD nj | "
          "L-D'A nj | SCDD/L-D'A py (paired) | SCDD/L-D'A nj (paired) |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]

    def cell(name):
        s = it.get(name)
        return f"{s['median_us']:.2f} [{s['iqr_us']:.2f}]" if s else "-"

    for key, rr in res["ratios"].items():
        machine, n_ek = key.split(".")
        L.append(f"| {machine} | {n_ek} | {rr['n_t']} | {cell(f'py.{key}.scdd')} | {cell(f'py.{key}.scdd_stacked')} | "
                 f"{cell(f'py.{key}.lda')} | {cell(f'py.{key}.multipliers')} | {cell(f'py.{key}.scdd_one_pass')} | "
                 f"{cell(f'nj.{key}.scdd')} | {cell(f'nj.{key}.lda')} | {_r(rr.get('py'))} | {_r(rr.get('nj'))} |")
    L += ["", "### Where the time goes (from compiled code) [us], and the prototypes of "
          "bench/prototypes/proto_cost.py", "",
          "| machine | n_ek | terms: alloc + tree + closure rows | tree_terms alone | SCDD solve | L-D'A solve | "
          "solve ratio (paired) | SCDD nj | proto terms | proto SCDD solve: ws | ws+recip | fast |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for key, rr in res["ratios"].items():
        machine, n_ek = key.split(".")
        L.append(f"| {machine} | {n_ek} | {cell(f'nj.{key}.terms')} | {cell(f'nj.{key}.tree')} | "
                 f"{cell(f'nj.{key}.solve.scdd')} | {cell(f'nj.{key}.solve.lda')} | {_r(rr.get('solve'))} | "
                 f"{cell(f'nj.{key}.scdd')} | {cell(f'proto.{key}.terms')} | {cell(f'proto.{key}.solve.scdd')} | "
                 f"{cell(f'proto.{key}.solve.scdd_recip')} | {cell(f'proto.{key}.solve.scdd_fast')} |")
    L += ["", "Prototype evaluations (compiled code, bench/prototypes/proto_cost.py): SCDD with a workspace (ws), "
          "+ reciprocal diagonals (recip), + multi-column solves (fast); L-D'A with block-diagonal M_t and W's "
          "unit rows exploited (blocks). Ratios paired per round.", "",
          "| machine | n_ek | proto SCDD ws | ws+recip | fast | proto L-D'A blocks | core SCDD nj | core L-D'A nj | "
          "fast / core SCDD | fast / core L-D'A | fast / block L-D'A | core SCDD / block L-D'A |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for key, rr in res["ratios"].items():
        if f"proto.{key}.scdd" not in it:
            continue
        machine, n_ek = key.split(".")
        L.append(f"| {machine} | {n_ek} | {cell(f'proto.{key}.scdd')} | {cell(f'proto.{key}.scdd_recip')} | "
                 f"{cell(f'proto.{key}.scdd_fast')} | {cell(f'proto.{key}.lda')} | {cell(f'nj.{key}.scdd')} | "
                 f"{cell(f'nj.{key}.lda')} | {_r(rr.get('proto_fast_vs_nj_scdd'))} | "
                 f"{_r(rr.get('proto_fast_vs_nj_lda'))} | {_r(rr.get('proto_fast_vs_proto_lda'))} | "
                 f"{_r(rr.get('nj_scdd_vs_proto_lda'))} |")
    L += ["", f"Dispatch floor: a no-op njit function with `accelerations`' arguments "
          f"{cell('py.dispatch.noop')} us; through its compiled entry point {cell('py.dispatch.noop_entry_point')} us.",
          "", "### Target: SCDD <= 1/3 of L-D'A's time on Hexa, n_ek = 2", ""]
    tg = res["target"]
    L.append(f"- from Python (`accelerations`, pinned): SCDD / L-D'A = {_r(tg['py'])} -> "
             f"**{'met' if tg['py']['paired_median'] <= TARGET_RATIO else 'MISSED'}**")
    verdict = "met" if tg["nj"]["paired_median"] <= TARGET_RATIO else "missed"
    L.append(f"- from compiled code: {_r(tg['nj'])} -> {verdict}")
    if tg.get("proto_fast_vs_nj_lda"):
        L.append(f"- prototype SCDD (fast) vs core L-D'A (compiled): {_r(tg['proto_fast_vs_nj_lda'])}; "
                 f"vs block L-D'A: {_r(tg['proto_fast_vs_proto_lda'])}; core SCDD vs block L-D'A: "
                 f"{_r(tg['nj_scdd_vs_proto_lda'])}")
    L.append("- SCDD / L-D'A (py, paired) by n_ek on Hexa: " + ", ".join(
        f"{k}: {res['ratios'][f'hexa.{k}']['py']['paired_median']:.2f}" for k in N_EK if f"hexa.{k}" in res["ratios"]))
    return "\n".join(L) + "\n"


def _r(x) -> str:
    if not x:
        return "-"
    return f"{x['paired_median']:.2f} [{x['paired_q25']:.2f}, {x['paired_q75']:.2f}]"


def paired(by_name: dict, a: str, b: str) -> dict | None:
    if a not in by_name or b not in by_name:
        return None
    sa, sb = np.asarray(by_name[a].samples), np.asarray(by_name[b].samples)
    n = min(sa.size, sb.size)
    r = sa[:n] / sb[:n]
    q25, q50, q75 = np.percentile(r, [25, 50, 75])
    return {"paired_median": float(q50), "paired_q25": float(q25), "paired_q75": float(q75),
            "ratio_of_medians": float(np.median(sa) / np.median(sb))}


# ----------------------------------------------------------------------------- plot
def plot(res: dict, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"scdd": "C0", "scdd_stacked": "C2", "lda": "C3", "multipliers": "C1", "scdd_one_pass": "C4"}
    styles = {"five_bar": ("s", ":"), "triglide": ("^", "--"), "hexa": ("o", "-")}
    it = res["items"]
    fig, axes = plt.subplots(1, 2, figsize=(14, 6.4))
    ax = axes[0]

    def series(name_of):
        xs, ys, lo, hi = [], [], [], []
        for k in N_EK:
            s = it.get(name_of(k))
            if s:
                xs.append(k)
                ys.append(s["median_us"])
                lo.append(s["median_us"] - s["q25_us"])
                hi.append(s["q75_us"] - s["median_us"])
        return xs, ys, [lo, hi]

    for machine in MACHINES:
        mk, ls = styles[machine]
        for form in FORMS:
            xs, ys, err = series(lambda k, f=form, mc=machine: f"py.{mc}.{k}.{f}")
            if xs:
                ax.errorbar(xs, ys, yerr=err, marker=mk, ls=ls, color=colors[form], capsize=2,
                            label=f"{machine} {form}")
    for name, color, label in (("scdd_fast", "C9", "hexa proto SCDD fast (compiled call)"),
                               ("lda", "C6", "hexa proto L-D'A blocks (compiled call)")):
        xs, ys, err = series(lambda k, n=name: f"proto.hexa.{k}.{n}")
        if xs:
            ax.errorbar(xs, ys, yerr=err, marker="o", ls="-.", lw=1, color=color, capsize=2, label=label)
    ax.set(xscale="log", yscale="log", xlabel="elastic DOF per chain n_ek", ylabel="time per evaluation [us]",
           title="time per evaluation, from Python (median, IQR bars)")
    ax.set_xticks(N_EK, [str(k) for k in N_EK])
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6.5, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.12))
    ax = axes[1]
    rows = res["table1"]
    for machine in MACHINES:
        rs = [r for r in rows if r["machine"] == machine]
        mk, ls = styles[machine]
        xs = [r["n_ek"] for r in rs]
        for form in ("scdd", "lda"):
            ax.plot(xs, [r["forms"][form]["evaluation"] for r in rs], marker=mk, ls=ls, color=colors[form],
                    label=f"{machine} {form}: whole evaluation")
            ax.plot(xs, [r["forms"][form]["factor"] for r in rs], marker=mk, ls=ls, color=colors[form], alpha=0.4,
                    lw=1, label=f"{machine} {form}: its factorizations")
        ax.plot(xs, [r["formula_scdd"] for r in rs], marker=mk, ls=ls, color="k", lw=0.8, mfc="none",
                label=f"{machine} formula n_a(1+n_pk+n_ek)^3")
        ax.plot(xs, [r["formula_lda"] for r in rs], marker=mk, ls=ls, color="0.55", lw=0.8, mfc="none",
                label=f"{machine} formula (n_a+n_a n_ek)^3")
    ax.set(xscale="log", yscale="log", xlabel="elastic DOF per chain n_ek", ylabel="floating-point operations",
           title="counted flops of our kernels (raw) vs the paper's formula")
    ax.set_xticks(N_EK, [str(k) for k in N_EK])
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6.5, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.12))
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


# ----------------------------------------------------------------------------- main
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=600, help="rounds over all timed items (default 600)")
    p.add_argument("--budget", type=float, default=100.0, help="stop the rounds after this many seconds (default 100)")
    p.add_argument("--quick", action="store_true", help="smoke run: 15 rounds")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    if a.quick:
        a.rounds = 15
    load0 = os.getloadavg()

    # 1. counted operations (a subprocess with numba disabled runs the kernels' Python source)
    t0 = time.perf_counter()
    specs = ["five_bar_rigid", "five_bar"] + [f"{mch}:{k}" for mch in ("triglide", "hexa") for k in N_EK]
    counts = count_in_subprocess(specs, list(FORMS), seed=a.seed)
    count_s = time.perf_counter() - t0

    # 2. timing
    t1 = time.perf_counter()
    configs = [Config("five_bar", 1, a.seed)] + [Config(mch, k, a.seed) for mch in ("triglide", "hexa") for k in N_EK]
    sanity: dict[str, float] = {}
    items = build_items(configs, sanity)
    gc_was = gc.isenabled()
    gc.disable()
    try:
        for it in items:
            calibrate(it, BATCH_TARGET_S)
        setup_s = time.perf_counter() - t1
        rng = np.random.default_rng(a.seed)
        t2 = time.perf_counter()
        rounds = run_rounds(items, a.rounds, rng, a.budget)
        rounds_s = time.perf_counter() - t2
    finally:
        if gc_was:
            gc.enable()
    by_name = {it.name: it for it in items}
    item_stats = {}
    for it in items:
        st = stats(it.samples)
        st.update(group=it.group, k=it.k, note=it.note)
        item_stats[it.name] = st
    ratios = {}
    for cf in configs:
        k = cf.key
        ratios[k] = {"n_t": cf.n, "py": paired(by_name, f"py.{k}.scdd", f"py.{k}.lda"),
                     "nj": paired(by_name, f"nj.{k}.scdd", f"nj.{k}.lda"),
                     "solve": paired(by_name, f"nj.{k}.solve.scdd", f"nj.{k}.solve.lda"),
                     "proto_scdd_vs_nj_lda": paired(by_name, f"proto.{k}.scdd", f"nj.{k}.lda"),
                     "proto_recip_vs_nj_lda": paired(by_name, f"proto.{k}.scdd_recip", f"nj.{k}.lda"),
                     "proto_recip_vs_proto_lda": paired(by_name, f"proto.{k}.scdd_recip", f"proto.{k}.lda"),
                     "proto_recip_vs_nj_scdd": paired(by_name, f"proto.{k}.scdd_recip", f"nj.{k}.scdd"),
                     "proto_fast_vs_nj_lda": paired(by_name, f"proto.{k}.scdd_fast", f"nj.{k}.lda"),
                     "proto_fast_vs_proto_lda": paired(by_name, f"proto.{k}.scdd_fast", f"proto.{k}.lda"),
                     "proto_fast_vs_nj_scdd": paired(by_name, f"proto.{k}.scdd_fast", f"nj.{k}.scdd"),
                     "proto_scdd_vs_proto_lda": paired(by_name, f"proto.{k}.scdd", f"proto.{k}.lda"),
                     "nj_scdd_vs_proto_lda": paired(by_name, f"nj.{k}.scdd", f"proto.{k}.lda"),
                     "proto_scdd_vs_nj_scdd": paired(by_name, f"proto.{k}.scdd", f"nj.{k}.scdd"),
                     "py_scdd_vs_nj_scdd": paired(by_name, f"py.{k}.scdd", f"nj.{k}.scdd")}
    res = {
        "timestamp": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "machine": machine_info({}), "git": git_commit(),
        "loadavg_start": list(load0), "loadavg_end": list(os.getloadavg()),
        "seed": a.seed, "rounds": rounds, "batch_target_s": BATCH_TARGET_S,
        "count_s": count_s, "setup_s": setup_s, "rounds_s": rounds_s,
        "table1": table1(counts), "table2": table2(counts),
        "items": item_stats, "ratios": ratios, "target": ratios.get("hexa.2"),
        "sanity": sanity, "counts": counts,
    }
    res["total_s"] = time.perf_counter() - T_START
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "cost.json").write_text(json.dumps(res, indent=1) + "\n")
    md = markdown(res)
    (a.out / "cost.md").write_text(md)
    plot(res, a.out / "cost_scaling.png")
    print(md)
    worst = max(sanity.values()) if sanity else 0.0
    print(f"sanity: worst relative difference between formulations/prototypes {worst:.1e}")
    if worst > 1e-9:
        print("WARNING: a formulation or prototype disagrees with L-D'A: "
              + ", ".join(k for k, v in sanity.items() if v > 1e-9))
    print(f"total {res['total_s']:.0f} s (counting {count_s:.0f} s, set-up {setup_s:.0f} s, {rounds} rounds "
          f"{rounds_s:.0f} s); wrote {a.out / 'cost.json'}, {a.out / 'cost.md'}, {a.out / 'cost_scaling.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
