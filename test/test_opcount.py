"""The operation counter of bench/tools/opcount.py: exact on known factorizations, stable on the five-bar.

The counter runs the kernels' Python source (NUMBA_DISABLE_JIT=1) in a subprocess, so
these tests start one (about 1 s each).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations

BENCH = Path(__file__).resolve().parent.parent / "bench" / "tools"
sys.path.insert(0, str(BENCH))

from opcount import OPS as FLOPS  # noqa: E402
from opcount import count_in_subprocess, load_mechanism  # noqa: E402

# The known sizes, counted in the small_linalg kernels as they are written.
_SCRIPT = r"""
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import opcount as oc
oc.install()
from elastic_pm_dyn import small_linalg as sl

rng = np.random.default_rng(3)
out = {}
for n in (1, 2, 5, 8):
    B = rng.standard_normal((n, n))
    S = B @ B.T + n * np.eye(n)
    c = oc.reset()
    A = oc.carray(S, "S")
    with c.section("x"):
        assert sl.cholesky(A)
    L = np.array([[x.v for x in row] for row in A])
    out[f"chol{n}"] = c.raw["x"]
    out[f"chol{n}_ok"] = bool(np.allclose(np.tril(L), np.linalg.cholesky(S)))
    c = oc.reset()
    b = oc.carray(rng.standard_normal(n), "b")
    Lc = oc.carray(np.linalg.cholesky(S))
    with c.section("x"):
        sl.cholesky_solve(Lc, b)
    out[f"cholsolve{n}"] = c.raw["x"]
    c = oc.reset()
    G = rng.standard_normal((n, n))
    A = oc.carray(G, "G")
    piv = np.empty(n, dtype=np.int64)
    with c.section("x"):
        sl.lu_factor(A, piv)
    out[f"lu{n}"] = c.raw["x"]
for (n, k, m) in ((3, 4, 5), (6, 6, 2)):
    c = oc.reset()
    X = oc.carray(rng.standard_normal((n, k)), "X")
    Y = oc.carray(rng.standard_normal((k, m)), "Y")
    Z = oc.carray(np.zeros((n, m)))
    with c.section("x"):
        sl.matmul(X, Y, Z)
    reach = c.reachable([z.n for z in Z.ravel()])
    out[f"matmul{n}x{k}x{m}"] = {"raw": c.raw["x"], "folded": c.folded["x"], "cse": reach["x"]}
# CSE and dead code: x*y computed twice, and an unused product
c = oc.reset()
x, y = oc.carray(np.array([2.0, 3.0]), "v")
with c.section("x"):
    a = x * y
    b = x * y
    _ = x * x
    z = a + b
out["cse"] = {"raw": c.raw["x"], "cse": c.reachable([z.n])["x"], "value": z.v}
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def known() -> dict:
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    r = subprocess.run([sys.executable, "-c", _SCRIPT, str(BENCH)], env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout)


@pytest.mark.parametrize("n", [1, 2, 5, 8])
def test_cholesky_and_lu_counts_are_the_textbook_ones(known: dict, n: int) -> None:
    chol = known[f"chol{n}"]
    assert known[f"chol{n}_ok"]
    assert chol.get("mul", 0) == (n**3 - n) // 6  # ~ n^3/6 multiplications
    assert chol.get("sub", 0) == (n**3 - n) // 6
    assert chol.get("div", 0) == n * (n - 1) // 2
    assert chol["sqrt"] == n
    cs = known[f"cholsolve{n}"]  # two triangular solves
    assert cs.get("mul", 0) == n * (n - 1) and cs.get("sub", 0) == n * (n - 1) and cs["div"] == 2 * n
    lu = known[f"lu{n}"]  # ~ n^3/3 multiplications + n^3/3 subtractions = 2 n^3 / 3
    assert lu.get("mul", 0) == (n - 1) * n * (2 * n - 1) // 6
    assert lu.get("sub", 0) == (n - 1) * n * (2 * n - 1) // 6
    assert lu["div"] == n * (n - 1) // 2 + 1  # the multipliers, and the pivot ratio it returns
    assert "add" not in lu  # abs and comparisons of the pivot search are free


def test_matmul_counts_and_the_folding_of_the_zero_accumulator(known: dict) -> None:
    for (n, k, m) in ((3, 4, 5), (6, 6, 2)):
        c = known[f"matmul{n}x{k}x{m}"]
        assert c["raw"] == {"mul": n * k * m, "add": n * k * m}  # the loop starts from 0.0
        assert c["folded"] == {"mul": n * k * m, "add": n * (k - 1) * m}  # 0.0 + x is free
        assert c["cse"] == c["folded"]


def test_cse_and_dead_code(known: dict) -> None:
    c = known["cse"]
    assert c["raw"] == {"mul": 3, "add": 1}
    assert c["cse"] == {"mul": 1, "add": 1}
    assert c["value"] == 12.0


def test_rigid_five_bar_counts_are_deterministic_and_reproduce_the_compiled_run() -> None:
    runs = [count_in_subprocess(["five_bar_rigid"], ["scdd", "lda"], seed=s, timeout=120) for s in (0, 1)]
    for form in ("scdd", "lda"):
        a, b = (r["five_bar_rigid"]["forms"][form] for r in runs)
        assert a["raw_flops"] == b["raw_flops"], form  # the same operations at any state (abs of the pivot
        for sec in a["raw"]:  # search is free and follows the data)
            assert {k: v for k, v in a["raw"][sec].items() if k in FLOPS} == \
                {k: v for k, v in b["raw"][sec].items() if k in FLOPS}, (form, sec)
        ca, cb = a["cse_flops"]["evaluation"], b["cse_flops"]["evaluation"]
        assert abs(ca - cb) <= 0.02 * ca, form  # the straight-line program follows the pivot order
        assert a["factorizations"] == {"scdd": {"cholesky2": 2, "lu2": 1}, "lda": {"lu2": 1, "cholesky2": 1}}[form]
        assert a["cse_flops"]["evaluation"] < a["raw_flops"]["evaluation"] / 4
    # the counted (object-array) run gives the compiled kernel's accelerations
    mech = load_mechanism("five_bar_rigid")
    for r in runs:
        st = r["five_bar_rigid"]["state"]
        q, qd = np.array(st["q"]), np.array(st["qd"])
        tau = mech.split_tau(np.array(st["tau_active"]))
        for form in ("scdd", "lda"):
            qdd, lam = np.empty(mech.n), np.zeros(mech.m)
            accelerations(FORMULATION_CODES[form], mech.arrays, q, qd, tau, 0.0, 0.0, np.zeros(mech.n), qdd,
                          lam)
            counted = np.array(r["five_bar_rigid"]["forms"][form]["qdd"])
            assert np.max(np.abs(counted - qdd)) <= 1e-12 * np.max(np.abs(qdd))
            assert r["five_bar_rigid"]["forms"][form]["max_rel_diff_vs_float_run"] == 0.0
