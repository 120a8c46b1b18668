"""Count the floating-point operations of the compiled kernels, as they actually run.

    .venv/bin/python bench/tools/opcount.py [--machines five_bar_rigid,five_bar,triglide,hexa]
                                      [--n-ek 1,2,3,4] [--forms scdd,lda,...] [--out FILE]

Method: the kernels are the ordinary ``@njit`` functions of ``elastic_pm_dyn``; with
``NUMBA_DISABLE_JIT=1`` (set before numba is imported) every one of them is its plain
Python source. We run that source on numpy object arrays of :class:`F`, a float that
counts its own arithmetic (+, -, unary -, *, /, sqrt, sin, cos; comparisons, abs, copies
and index arithmetic are free), after replacing the ``np`` the kernel modules see by a
thin shim whose ``empty``/``zeros``/``eye`` build such arrays, so every internal
temporary counts too. Nothing is re-implemented: the counted code is the code that runs.

Three counts per section (tree terms, closure rows, the formulation's solve, its
factorizations, the whole evaluation):

- ``raw``: every operation the generic kernel executes (on zeros and ones as well: what
  the machine does);
- ``folded``: the operations left after constant folding (model parameters are constants,
  q, qd and the motor torques are symbols) and the trivial identities x*0, x*1, x+0,
  x-0, x/1, -(-x), x-x: what a code generator that knows the model's numbers would emit
  for the same algorithm, without common-subexpression elimination;
- ``cse``: the folded operations after hash-consing identical operations (CSE) and
  dropping everything the accelerations do not depend on (dead code: pivot ratios, the
  gap): the size of a straight-line program for qdd, i.e. what Mathematica's
  simplify + optimise of the paper comes closest to (without algebraic rewriting).

The branch decisions (pivoting, positive-definiteness checks) follow the numbers of one
concrete state, carried along in every F.

From a process where numba compiles (the bench, the tests), call :func:`count_in_subprocess`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import types
from contextlib import contextmanager
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
OPS = ("add", "sub", "neg", "mul", "div", "sqrt", "sin", "cos")  # what counts as a flop
FREE = ("abs",)  # recorded, not a flop
FORMS = ("scdd", "scdd_stacked", "lda", "multipliers", "scdd_one_pass")


# ------------------------------------------------------------------------ the counter
class Counter:
    """Counts per section; sections nest (an operation counts in every open section)."""

    def __init__(self):
        self.stack: list[str] = []
        self.raw: dict[str, dict[str, int]] = {}
        self.folded: dict[str, dict[str, int]] = {}
        # the expression graph: node id -> (op, argument node ids, sections open at creation)
        self.node_op: list[str] = []
        self.node_args: list[tuple[int, ...]] = []
        self.node_sec: list[tuple[str, ...]] = []
        self.table: dict[tuple, int] = {}
        self.calls: list[tuple[str, int, dict[str, int]]] = []  # (factorization kind, size, raw counts)

    def _bump(self, book: dict, op: str):
        for s in self.stack:
            d = book.setdefault(s, {})
            d[op] = d.get(op, 0) + 1

    @contextmanager
    def section(self, name: str):
        self.stack.append(name)
        try:
            yield
        finally:
            self.stack.pop()

    def leaf(self, label) -> int:
        return self._node("var", (), key=("var", label))

    def _node(self, op: str, args: tuple[int, ...], key: tuple) -> int:
        nid = self.table.get(key)
        if nid is None:
            nid = len(self.node_op)
            self.table[key] = nid
            self.node_op.append(op)
            self.node_args.append(args)
            self.node_sec.append(tuple(self.stack))
        return nid

    def reachable(self, outputs: list[int]) -> dict[str, dict[str, int]]:
        """Operations the outputs depend on, per section open when each was first created."""
        seen = set()
        todo = [o for o in outputs if o is not None]
        while todo:
            n = todo.pop()
            if n in seen:
                continue
            seen.add(n)
            todo.extend(self.node_args[n])
        out: dict[str, dict[str, int]] = {}
        for n in seen:
            op = self.node_op[n]
            if op == "var":
                continue
            for s in self.node_sec[n]:
                d = out.setdefault(s, {})
                d[op] = d.get(op, 0) + 1
        return out


_C = Counter()


def counter() -> Counter:
    return _C


def reset() -> Counter:
    global _C
    _C = Counter()
    return _C


class F:
    """A float that counts its arithmetic. ``n`` is its expression node (None: a constant)."""

    __slots__ = ("n", "v")

    def __init__(self, v, n=None):
        self.v = float(v)
        self.n = n

    def __repr__(self):
        return f"F({self.v!r}{'' if self.n is None else f', #{self.n}'})"

    def __float__(self):
        return self.v

    # arithmetic
    def __add__(self, o):
        return _op("add", self, o)

    def __radd__(self, o):
        return _op("add", o, self)

    def __sub__(self, o):
        return _op("sub", self, o)

    def __rsub__(self, o):
        return _op("sub", o, self)

    def __mul__(self, o):
        return _op("mul", self, o)

    def __rmul__(self, o):
        return _op("mul", o, self)

    def __truediv__(self, o):
        return _op("div", self, o)

    def __rtruediv__(self, o):
        return _op("div", o, self)

    def __neg__(self):
        return _unary("neg", self)

    def __pos__(self):
        return self

    def __abs__(self):
        return _unary("abs", self)

    def __pow__(self, k):
        if k == 2:
            return _op("mul", self, self)
        raise NotImplementedError("only x**2 is counted")

    def sqrt(self):  # numpy's object ufunc calls this
        return _unary("sqrt", self)

    # comparisons are free and use the value
    def __lt__(self, o):
        return self.v < float(o)

    def __le__(self, o):
        return self.v <= float(o)

    def __gt__(self, o):
        return self.v > float(o)

    def __ge__(self, o):
        return self.v >= float(o)

    def __eq__(self, o):
        return self.v == float(o)

    def __ne__(self, o):
        return self.v != float(o)

    def __hash__(self):
        return hash(self.v)

    def __bool__(self):
        return self.v != 0.0


def _f(x) -> F:
    return x if isinstance(x, F) else F(x)


def _key(x: F):
    return ("c", x.v) if x.n is None else x.n


def _div(a: float, b: float) -> float:
    try:
        return a / b
    except ZeroDivisionError:  # IEEE semantics, as in the compiled code
        return math.nan if a == 0.0 or math.isnan(a) else math.copysign(math.inf, a) * math.copysign(1.0, b)


_EVAL = {"add": lambda a, b: a + b, "sub": lambda a, b: a - b, "mul": lambda a, b: a * b, "div": _div}


def _op(op: str, a, b) -> F:
    a, b = _f(a), _f(b)
    _C._bump(_C.raw, op)
    return _build(op, a, b, True)


def _build(op: str, a: F, b: F, top: bool) -> F:
    """The result's value and expression node. ``top``: an executed operation (counts as
    folded when it survives the identities); False for the rewrites that move signs."""
    c = _C
    v = _EVAL[op](a.v, b.v)
    # constant folding and trivial identities (what a generator knowing the constants drops)
    if a.n is None and b.n is None:
        return F(v)
    if op == "add":
        if a.n is None and a.v == 0.0:
            return F(v, b.n)
        if b.n is None and b.v == 0.0:
            return F(v, a.n)
    elif op == "sub":
        if b.n is None and b.v == 0.0:
            return F(v, a.n)
        if a.n is None and a.v == 0.0:
            return _neg(b, v, top)
        if a.n == b.n:
            return F(0.0)
    elif op == "mul":
        for x, y in ((a, b), (b, a)):
            if x.n is None:
                if x.v == 0.0:
                    return F(0.0)
                if x.v == 1.0:
                    return F(v, y.n)
                if x.v == -1.0:
                    return _neg(y, v, top)
    elif op == "div":
        if a.n is None and a.v == 0.0:
            return F(0.0)
        if b.n is None and b.v == 1.0:
            return F(v, a.n)
        if b.n is None and b.v == -1.0:
            return _neg(a, v, top)
    if top:
        c._bump(c.folded, op)
    # signs travel to where an add/sub absorbs them: a + (-b) = a - b, (-a) b = -(a b)
    if op in ("add", "sub") and b.n is not None and c.node_op[b.n] == "neg":
        return _build("sub" if op == "add" else "add", a, F(-b.v, c.node_args[b.n][0]), False)
    if op == "add" and a.n is not None and c.node_op[a.n] == "neg":
        return _build("sub", b, F(-a.v, c.node_args[a.n][0]), False)
    if op in ("mul", "div"):
        na = a.n is not None and c.node_op[a.n] == "neg"
        nb = b.n is not None and c.node_op[b.n] == "neg"
        if na or nb:
            r = _build(op, F(-a.v, c.node_args[a.n][0]) if na else a, F(-b.v, c.node_args[b.n][0]) if nb else b,
                       False)
            return r if na == nb or r.n is None else _neg(r, -r.v, False)
    ka, kb = _key(a), _key(b)
    if op in ("add", "mul") and str(ka) > str(kb):
        ka, kb = kb, ka
    args = tuple(k for k in (ka, kb) if not isinstance(k, tuple))
    return F(v, c._node(op, args, (op, ka, kb)))


def _neg(x: F, v: float, top: bool) -> F:
    """-x (x symbolic): free if x is itself a negation."""
    c = _C
    if c.node_op[x.n] == "neg":
        return F(v, c.node_args[x.n][0])
    if top:
        c._bump(c.folded, "neg")
    return F(v, c._node("neg", (x.n,), ("neg", x.n)))


def _unary(op: str, a) -> F:
    a = _f(a)
    c = _C
    c._bump(c.raw, op)
    v = {"neg": lambda x: -x, "abs": abs, "sqrt": lambda x: math.sqrt(x) if x >= 0.0 else math.nan,
         "sin": math.sin, "cos": math.cos}[op](a.v)
    if a.n is None:
        return F(v)
    if op == "neg":
        return _neg(a, v, True)
    c._bump(c.folded, op)
    return F(v, c._node(op, (a.n,), (op, a.n)))


def _csin(x):
    return _unary("sin", x)


def _ccos(x):
    return _unary("cos", x)


# --------------------------------------------------------------------- object arrays
class CArray(np.ndarray):
    """An object array of F; stores plain numbers as constant F (so `M[:] = 0.0` stays counted)."""

    def __setitem__(self, key, value):
        if isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(value, (bool, np.bool_)):
            value = F(value)
        elif isinstance(value, np.ndarray) and value.dtype != object:
            value = carray(value)
        super().__setitem__(key, value)


def carray(a, symbols: str | None = None, mask=None) -> CArray:
    """Object array of F from a float array: constants, or leaves named symbols[i] where mask[i]."""
    a = np.asarray(a, dtype=float)
    out = np.empty(a.shape, dtype=object)
    flat = out.reshape(-1)
    vals = a.reshape(-1)
    for i, x in enumerate(vals):
        if symbols is not None and (mask is None or mask[i]):
            flat[i] = F(x, _C.leaf((symbols, i)))
        else:
            flat[i] = F(x)
    return out.view(CArray)


def _filled(shape, x) -> CArray:
    out = np.empty(shape, dtype=object)
    out.fill(None)
    flat = out.reshape(-1)
    for i in range(flat.size):
        flat[i] = F(x)
    return out.view(CArray)


class NumpyShim(types.ModuleType):
    """What the kernel modules see as ``np``: float arrays become CArray, the rest is numpy."""

    def __init__(self):
        super().__init__("numpy_counting_shim")

    def __getattr__(self, name):
        return getattr(np, name)

    @staticmethod
    def _is_float(dtype):
        return dtype is None or dtype is float or np.dtype(dtype).kind == "f"

    def empty(self, shape, dtype=None):
        return _filled(shape, math.nan) if self._is_float(dtype) else np.empty(shape, dtype=dtype)

    def zeros(self, shape, dtype=None):
        return _filled(shape, 0.0) if self._is_float(dtype) else np.zeros(shape, dtype=dtype)

    def eye(self, n, dtype=None):
        out = _filled((n, n), 0.0)
        for i in range(n):
            out[i, i] = F(1.0)
        return out

    @staticmethod
    def sqrt(x):
        return x.sqrt() if isinstance(x, F) else np.sqrt(x)

    @staticmethod
    def isnan(x):
        return math.isnan(x.v) if isinstance(x, F) else np.isnan(x)


# ------------------------------------------------------------------------- patching
_PATCHED = False
SECTION_WRAPS = {  # (module, function name) -> section label
    ("elastic_pm_dyn.dynamics.evaluate", "tree_terms_into"): "tree_terms",
    ("elastic_pm_dyn.dynamics.evaluate", "all_closure_rows"): "closure_rows",
    ("elastic_pm_dyn.dynamics.evaluate", "scdd_into"): "solve",
    ("elastic_pm_dyn.dynamics.evaluate", "scdd_platform"): "solve",
    ("elastic_pm_dyn.dynamics.evaluate", "lagrange_dalembert"): "solve",
    ("elastic_pm_dyn.dynamics.evaluate", "multipliers"): "solve",
    ("elastic_pm_dyn.dynamics.evaluate", "scdd_one_pass"): "solve",
    ("elastic_pm_dyn.dynamics.kernels", "cholesky_solve"): "factor_solve",
    ("elastic_pm_dyn.dynamics.kernels", "cholesky_solve_rows"): "factor_solve",
    ("elastic_pm_dyn.dynamics.kernels", "lu_solve"): "factor_solve",
    ("elastic_pm_dyn.dynamics.kernels", "lu_solve_columns"): "factor_solve",
    ("elastic_pm_dyn.dynamics.kernels", "lu_solve_transposed"): "factor_solve",
    ("elastic_pm_dyn.dynamics.kernels", "matmul"): "products",
    ("elastic_pm_dyn.dynamics.kernels", "matmul_tn"): "products",
    ("elastic_pm_dyn.dynamics.kernels", "matvec"): "products",
    ("elastic_pm_dyn.dynamics.kernels", "matvec_t"): "products",
}
FACTOR_WRAPS = {("elastic_pm_dyn.dynamics.kernels", "cholesky"): "cholesky",
                # cholesky_recip(L, n, dinv) factors L[:n, :n] of a larger scratch array
                ("elastic_pm_dyn.dynamics.kernels", "cholesky_recip"): "cholesky",
                ("elastic_pm_dyn.dynamics.kernels", "lu_factor"): "lu"}


def _wrap_section(f, label):
    def wrapped(*args):
        with _C.section(label):
            return f(*args)
    wrapped.__wrapped__ = f
    return wrapped


def _wrap_factor(f, kind):
    def wrapped(A, *args):
        c = _C
        before = dict(c.raw.get("factor", {}))
        with c.section("factor"):
            r = f(A, *args)
        after = c.raw.get("factor", {})
        size = int(args[0]) if f.__name__ == "cholesky_recip" else int(A.shape[0])
        c.calls.append((kind, size, {k: after.get(k, 0) - before.get(k, 0) for k in after}))
        return r
    wrapped.__wrapped__ = f
    return wrapped


def install():
    """Patch the kernel modules (idempotent). Requires NUMBA_DISABLE_JIT=1 before numba's import."""
    global _PATCHED
    if _PATCHED:
        return
    from numba.core import config

    if not config.DISABLE_JIT:
        raise RuntimeError("opcount needs NUMBA_DISABLE_JIT=1 before numba is imported; "
                           "use count_in_subprocess() from a compiling process")
    import importlib

    shim = NumpyShim()
    for name in ("elastic_pm_dyn.small_linalg", "elastic_pm_dyn.kinematics.kernels",
                 "elastic_pm_dyn.dynamics.kernels", "elastic_pm_dyn.dynamics.evaluate"):
        importlib.import_module(name).np = shim
    vec3 = importlib.import_module("elastic_pm_dyn.kinematics.vec3")
    vec3.cos, vec3.sin = _ccos, _csin
    kk = importlib.import_module("elastic_pm_dyn.kinematics.kernels")
    kk.IDENTITY = tuple(F(x) for x in kk.IDENTITY)
    kk.ZERO = tuple(F(x) for x in kk.ZERO)
    for (mod, fn), label in SECTION_WRAPS.items():
        m = importlib.import_module(mod)
        setattr(m, fn, _wrap_section(getattr(m, fn), label))
    for (mod, fn), kind in FACTOR_WRAPS.items():
        m = importlib.import_module(mod)
        setattr(m, fn, _wrap_factor(getattr(m, fn), kind))
    _PATCHED = True


# ------------------------------------------------------------------------- machines
def load_mechanism(spec: str):
    """'five_bar', 'five_bar_rigid', 'triglide:2', 'hexa_rigid', ... -> Mechanism."""
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model

    name, _, n = spec.partition(":")
    rigid = name.endswith("_rigid")
    base = name.removesuffix("_rigid")
    path = REPO / "config" / f"{base}.yaml"
    model = load_model(path, elastic_dof_per_chain=int(n)) if n else load_model(path)
    return Mechanism(model.locked() if rigid else model)


def random_state(mech, rng, spread):
    """A consistent q, qd near the start pose and motor torques (the tests' states)."""
    from elastic_pm_dyn.kinematics.assembly import random_consistent_state

    return random_consistent_state(mech, rng, spread)


def _sum(d: dict | None) -> int:
    return int(sum(v for k, v in (d or {}).items() if k in OPS))


def count_evaluation(mech, form: str, q, qd, tau_active) -> dict:
    """Counts of one ``accelerations`` call of formulation ``form`` at (q, qd, tau)."""
    install()
    from elastic_pm_dyn.dynamics import evaluate

    code = evaluate.FORMULATION_CODES[form]
    n, m = mech.n, mech.m
    tau = mech.split_tau(tau_active)
    c = reset()
    ma = mech.arrays
    ma_c = ma._replace(jf=carray(ma.jf), points=carray(ma.points), gravity=carray(ma.gravity))
    qc = carray(q, "q")
    qdc = carray(qd, "qd")
    tc = carray(tau, "tau", mask=np.isin(np.arange(n), mech.active))
    qdd = carray(np.zeros(n))
    lam = carray(np.zeros(m))
    qdd_prev = carray(np.zeros(n), "qdd_prev")
    with c.section("evaluation"):
        cond, gap = evaluate.accelerations(code, ma_c, qc, qdc, tc, 0.0, 0.0, qdd_prev, qdd, lam)
    qdd_val = np.array([x.v for x in qdd])
    outputs = [x.n for x in qdd]
    reach = c.reachable(outputs)
    factor_sizes: dict[str, int] = {}
    for kind, size, _ in c.calls:
        k = f"{kind}{size}"
        factor_sizes[k] = factor_sizes.get(k, 0) + 1
    sections = ("evaluation", "tree_terms", "closure_rows", "solve", "factor", "factor_solve", "products")
    out = {
        "form": form, "n_t": n, "m": m, "n_ae": len(mech.ae), "n_p": len(mech.passive),
        "chain_sizes": np.diff(ma.chain_start).tolist(), "cond": float(cond), "gap": float(gap),
        "qdd": qdd_val.tolist(),
        "raw": {s: c.raw.get(s, {}) for s in sections},
        "folded": {s: c.folded.get(s, {}) for s in sections},
        "cse": {s: reach.get(s, {}) for s in sections},
        "factorizations": factor_sizes,
        "factorization_calls": [[k, s, d] for k, s, d in c.calls],
        "graph_nodes": len(c.node_op),
    }
    for kind in ("raw", "folded", "cse"):
        out[f"{kind}_flops"] = {s: _sum(out[kind][s]) for s in sections}
    return out


def float_reference(mech, form: str, q, qd, tau_active) -> np.ndarray:
    """The same kernels (plain Python here) on float arrays: the values the counted run must give."""
    from elastic_pm_dyn.dynamics import evaluate

    n, m = mech.n, mech.m
    qdd, lam = np.empty(n), np.zeros(m)
    evaluate.accelerations(evaluate.FORMULATION_CODES[form], mech.arrays, q, qd, mech.split_tau(tau_active), 0.0, 0.0,
                           np.zeros(n), qdd, lam)
    return qdd


def count_machines(specs: list[str], forms: list[str], seed: int = 0) -> dict:
    """{spec: {"state": ..., form: counts}}; the float reference is computed before patching."""
    spread = {"five_bar": 0.2, "triglide": 0.05, "hexa": 0.05}
    states, refs = {}, {}
    mechs = {}
    for spec in specs:
        mech = load_mechanism(spec)
        mechs[spec] = mech
        base = spec.partition(":")[0].removesuffix("_rigid")
        rng = np.random.default_rng(seed)
        states[spec] = random_state(mech, rng, spread[base])
        refs[spec] = {f: float_reference(mech, f, *states[spec]) for f in forms if _applies(mech, f)}
    out = {}
    for spec in specs:
        mech = mechs[spec]
        q, qd, tau = states[spec]
        res = {"n_chains": mech.n_chains, "n_a": len(mech.active), "n_e": len(mech.elastic),
               "n_pk": _passive_in_first_chain(mech), "state_seed": seed,
               "state": {"q": q.tolist(), "qd": qd.tolist(), "tau_active": tau.tolist()}, "forms": {}}
        for f in forms:
            if not _applies(mech, f):
                continue
            r = count_evaluation(mech, f, q, qd, tau)
            ref = refs[spec][f]
            r["max_rel_diff_vs_float_run"] = float(np.max(np.abs(np.array(r["qdd"]) - ref))
                                                   / max(np.max(np.abs(ref)), 1e-300))
            res["forms"][f] = r
        out[spec] = res
    return out


def _passive_in_first_chain(mech) -> int:
    """n_pk of the paper: passive joints of one leg (chain 0)."""
    cs = mech.arrays.chain_start
    return int(sum(1 for i in mech.passive if cs[0] <= i < cs[1]))


def _applies(mech, form: str) -> bool:
    return not (form == "scdd_stacked" and mech.arrays.hub < 0)  # the same as scdd without a platform


def count_in_subprocess(specs: list[str], forms: list[str] = FORMS, seed: int = 0, timeout: float = 600) -> dict:
    """Run :func:`count_machines` in a fresh interpreter with numba disabled; returns its dict."""
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--machines", ",".join(specs), "--forms", ",".join(forms),
           "--seed", str(seed), "--out", "-"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, cwd=str(REPO))
    if r.returncode != 0:
        raise RuntimeError(f"opcount subprocess failed ({r.returncode}):\n{r.stderr[-4000:]}")
    return json.loads(r.stdout)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--machines", default="five_bar_rigid,five_bar,triglide,hexa",
                   help="comma list; triglide/hexa without ':n' expand to n_ek = --n-ek")
    p.add_argument("--n-ek", default="1,2,3,4")
    p.add_argument("--forms", default=",".join(FORMS))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="-", help="JSON file, '-' for stdout")
    a = p.parse_args(argv)
    specs = []
    for s in a.machines.split(","):
        base = s.partition(":")[0].removesuffix("_rigid")
        if ":" in s or base == "five_bar" or s.endswith("_rigid"):
            specs.append(s)
        else:
            specs += [f"{s}:{k}" for k in a.n_ek.split(",")]
    res = count_machines(specs, a.forms.split(","), a.seed)
    text = json.dumps(res, indent=1)
    if a.out == "-":
        print(text)
    else:
        Path(a.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("NUMBA_DISABLE_JIT", "1")
    sys.exit(main())
