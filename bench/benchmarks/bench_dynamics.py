"""Direct-dynamics and RK4 benchmark of the reference five-bar, with peers in the same run.

    .venv/bin/python bench/benchmarks/bench_dynamics.py [--rounds N] [--long-rounds N] [--quick] [--out DIR]

Measures (per call, median over many interleaved batches, see bench/README.md):
- ``ours.kernel.<form>``: the compiled ``accelerations`` called from Python (like for like
  with Pinocchio's ``constraintDynamics`` called from Python), for every formulation;
- ``ours.facade.<form>``: ``Dynamics(mech, form).accelerations`` (Python overhead on top);
- ``ours.rk4_1.<form>.<stab>``: ``kernels.rk4_steps(..., n_steps=1)`` per call, and
  ``ours.rk4_long.<form>.<stab>``: per step inside one call of 10000 steps (dt = 1e-4 s);
- peers, if installed: ``pin.constraintDynamics`` (bare, and with the spring/damper
  torques computed in numpy), an RK4 step around it in Python, MuJoCo ``mj_step`` with
  its RK4 integrator (per call, and per step of a 10000-step ``rollout``);
- ``profile.*``: where one evaluation's time goes (numba dispatch vs kernel work).

Every item is timed in batches; the rounds visit all items in a fresh random order, so
load from other users of the machine hits all items alike, and ratios (ours / peer) are
taken in this one run, also per round (paired). Writes <out>/dynamics.json and
<out>/dynamics.md and prints the table.
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
from numba import njit  # noqa: E402

from elastic_pm_dyn.dynamics.direct import Dynamics  # noqa: E402
from elastic_pm_dyn.dynamics.evaluate import (  # noqa: E402
    FORMULATION_CODES,
    SINGULAR_TOL,
    accelerations,
)
from elastic_pm_dyn.dynamics.kernels import scdd  # noqa: E402
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose  # noqa: E402
from elastic_pm_dyn.kinematics.kernels import closure_rows, tree_terms  # noqa: E402
from elastic_pm_dyn.kinematics.mechanism import Mechanism  # noqa: E402
from elastic_pm_dyn.model.loader import load_model  # noqa: E402
from elastic_pm_dyn.pinned_kernels import PinnedKernel  # noqa: E402
from elastic_pm_dyn.sim import integrators, kernels  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common, tools
from common import REPO, RESULTS  # noqa: E402
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

DT = 1e-4
LONG_STEPS = 10_000
TAU_ACTIVE = np.array([0.5, -0.3])  # [N m] motor torques of the short items
QD_AE = np.array([1.0, -0.8, 0.01, -0.02])  # [rad/s, rad/s, m/s, m/s], order of mech.ae
PRESTRETCH = np.array([2e-5, -1e-5])  # [m] springs of the free-vibration state (long runs)
STABS = {"none": 0, "projection": kernels.STAB_PROJECTION}
ALPHA = BETA = 200.0  # unused (no Baumgarte here); the simulator's defaults
CLOSURE_TOL = 1e-14  # the simulator's defaults
BATCH_TARGET_S = 1e-3  # one timed batch of a short item lasts about this long


# ------------------------------------------------------------------ profile kernels
@njit(cache=True)
def _noop_one(x):
    return 1.0


@njit(cache=True)
def _noop_arrays(q, qd, tau, qdd_prev, qdd, lam):
    return 1.0, 0.0


@njit(cache=True)
def _noop():
    return 1.0


@njit(cache=True)
def _loop_tree_terms(ma, q, qd, n):
    nt = q.shape[0]
    npt = ma.points.shape[0]
    M, h = np.empty((nt, nt)), np.empty(nt)
    J, a_pt, p_pt = np.empty((npt, 3, nt)), np.empty((npt, 3)), np.empty((npt, 3))
    for _ in range(n):
        tree_terms(ma.jf, ma.ji, ma.chain_start, ma.points, ma.point_body, ma.gravity, q, qd, M, h, J, a_pt, p_pt)
    return M[0, 0]


@njit(cache=True)
def _loop_scdd_solve(ma, q, qd, tau, qdd, lam, n):
    """SCDD's solve alone (eqs 34-41) on fixed tree terms."""
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
        s += scdd(M, h, A, gamma, tau, ma.chain_start, qdd, lam)
    return s


@njit(cache=True)
def _loop_project(ma, q, qd, tol, n):
    """kernels.project from the same (slightly off-manifold) state, n times."""
    qq, vv = q.copy(), qd.copy()
    s = 0.0
    for _ in range(n):
        qq[:] = q
        vv[:] = qd
        s += kernels.project(ma, qq, vv, tol, 3)
    return s


@njit(cache=True)
def _loop_alloc(n, k, size):
    """n x k allocations of a float array of `size` (what a kernel's np.empty costs)."""
    s = 0.0
    for _ in range(n):
        for j in range(k):
            a = np.empty(size)
            a[0] = j
            s += a[size - 1] * 0.0 + a[0]
    return s


# --------------------------------------------------------------------------- items


def _py_noop(*args):
    return None


class Setup:
    """The five-bar, its states and all items."""

    def __init__(self):
        self.mech = mech = Mechanism(load_model(REPO / "config" / "five_bar.yaml"))
        self.ma = mech.arrays
        self.q0 = initial_state(mech)
        self.qd0 = mech.tree_velocity(self.q0, QD_AE)
        self.tau = mech.split_tau(TAU_ACTIVE)
        qv = self.q0.copy()
        qv[mech.elastic] = PRESTRETCH
        self.qv = solve_pose(mech, qv, mech.passive)
        self.n, self.m = mech.n, mech.m
        self.items: list[Item] = []
        self.long_items: list[Item] = []
        self.peers: dict[str, str] = {}
        self.sanity: dict[str, float] = {}

    # ---------------------------------------------------------------- ours
    def add_ours(self):
        mech, ma, n, m = self.mech, self.ma, self.n, self.m
        q, qd, tau = self.q0.copy(), self.qd0.copy(), self.tau.copy()
        qdd, lam, qdd_prev = np.empty(n), np.zeros(m), np.zeros(n)
        for form, code in FORMULATION_CODES.items():
            self.items.append(Item(f"ours.kernel.{form}",
                                   _calls(PinnedKernel(accelerations), code, ma, q, qd, tau, 0.0, 0.0, qdd_prev,
                                          qdd, lam),
                                   group="direct dynamics", note="pinned entry point, as Dynamics calls it"))
        self.items.append(Item("ours.kernel_namedtuple.scdd",
                               _calls(accelerations, FORMULATION_CODES["scdd"], ma, q, qd, tau, 0.0, 0.0, qdd_prev,
                                      qdd, lam),
                               group="direct dynamics", note="through numba's dispatcher: its typing of every array"))
        for form in FORMULATION_CODES:
            dyn = Dynamics(mech, form)
            self.items.append(Item(f"ours.facade.{form}", _calls(dyn.accelerations, q, qd, TAU_ACTIVE.copy()),
                                   group="direct dynamics"))
        args = (FORMULATION_CODES["scdd"], ma, q, qd, tau, 0.0, 0.0, qdd_prev, qdd, lam)
        self.items.append(Item("ours.entry_point.scdd", _calls(_entry_point(accelerations, *args), *args),
                               group="direct dynamics",
                               note="compiled overload's entry_point: no numba argument typing (what-if)"))
        # RK4: one step per call from Python, and per step inside one long call.
        for form in ("scdd", "lda"):
            code = FORMULATION_CODES[form]
            for stab_name, stab in STABS.items():
                self.items.append(self._rk4_item(f"ours.rk4_1.{form}.{stab_name}", code, stab, self.q0, self.qd0,
                                                 self.tau, 1))
                self.long_items.append(self._rk4_item(f"ours.rk4_long.{form}.{stab_name}", code, stab, self.qv,
                                                      np.zeros(n), np.zeros(n), LONG_STEPS))

    def _rk4_item(self, name, code, stab, q_init, qd_init, tau, n_steps):
        n, m = self.n, self.m
        q, qd = q_init.copy(), qd_init.copy()
        coef = np.zeros((3, n))
        coef[0] = tau
        qdd_prev, lam, info = np.zeros(n), np.zeros(m), np.zeros(3)
        ma = self.ma
        status = [kernels.OK]
        settings = integrators.StepSettings(stab, ALPHA, BETA, CLOSURE_TOL, SINGULAR_TOL, 0.0)  # RK4: no phase step
        steps = PinnedKernel(integrators.fixed_steps)  # as Simulator calls it

        def reset():
            q[:] = q_init
            qd[:] = qd_init
            qdd_prev[:] = 0.0

        def run(k):
            for _ in range(k):
                r = steps(integrators.RK4, 0, code, ma, q, qd, coef, DT, n_steps, settings, qdd_prev, lam, info)
                status[0] = max(status[0], r)  # worst over the run: a failed step would bias the timing
            return k * n_steps

        item = Item(name, run, reset, group="rk4", unit="step", k=1 if n_steps > 1 else None)
        item.status, item.info, item.state = status, info, (q, qd)
        return item

    # ----------------------------------------------------------- profile
    def add_profile(self):
        ma, n, m = self.ma, self.n, self.m
        q, qd, tau = self.q0.copy(), self.qd0.copy(), self.tau.copy()
        qdd, lam, qdd_prev = np.empty(n), np.zeros(m), np.zeros(n)
        code = FORMULATION_CODES["scdd"]
        args = (code, ma, q, qd, tau, 0.0, 0.0, qdd_prev, qdd, lam)
        g = "profile"
        self.items += [
            Item("profile.python_call.same_args", _calls(_py_noop, *args), group=g,
                 note="a Python no-op function with the same arguments (the loop + call floor)"),
            Item("profile.njit_noop.no_args", _calls(_noop), group=g, note="numba dispatch floor"),
            Item("profile.njit_noop.one_array", _calls(_noop_one, q), group=g),
            Item("profile.njit_noop.six_arrays", _calls(_noop_arrays, q, qd, tau, qdd_prev, qdd, lam), group=g),
            Item("profile.njit_noop.model_namedtuple", _calls(_noop_one, ma), group=g,
                 note="the ModelArrays namedtuple (9 arrays) alone"),
            Item("profile.njit_noop.model_plain_tuple", _calls(_noop_one, tuple(ma)), group=g,
                 note="the same 9 arrays as a plain tuple"),
            Item("profile.njit_noop.same_args", _calls(_noop_same_args, *args), group=g,
                 note="trivial njit function, accelerations' exact arguments"),
            Item("profile.njit_noop.same_args_entry_point", _calls(_entry_point(_noop_same_args, *args), *args),
                 group=g, note="the same through the compiled entry point (unboxing only, no typing)"),
        ]
        for form, c in FORMULATION_CODES.items():
            self.items.append(Item(f"profile.in_njit.accelerations.{form}",
                                   _inner(_loop_accelerations, c, ma, q, qd, tau, qdd_prev, qdd, lam),
                                   group=g, unit="call", note="the kernel called from compiled code: no dispatch"))
        self.items += [
            Item("profile.in_njit.tree_terms", _inner(_loop_tree_terms, ma, q, qd), group=g,
                 note="M, h, chain-end J, Jdot qd of both chains"),
            Item("profile.in_njit.scdd_solve", _inner(_loop_scdd_solve, ma, q, qd, tau, qdd, lam), group=g,
                 note="SCDD's solve on given tree terms (eqs 34-41)"),
            Item("profile.in_njit.project", _inner(_loop_project, ma, *self._after_one_step(), CLOSURE_TOL), group=g,
                 note=f"RK4's projection after one unprojected step (tol {CLOSURE_TOL:g} m)"),
            Item("profile.in_njit.np_empty", lambda k: (_loop_alloc(k, 1, 6), k)[1], group=g, unit="alloc",
                 note="one small np.empty inside compiled code"),
        ]

    def _after_one_step(self):
        """The free-vibration state after one unprojected SCDD RK4 step (gap ~1e-14 m)."""
        q, qd = self.qv.copy(), np.zeros(self.n)
        kernels.rk4_steps(FORMULATION_CODES["scdd"], self.ma, q, qd, np.zeros((3, self.n)), DT, 1, 0, ALPHA, BETA,
                          CLOSURE_TOL, SINGULAR_TOL, np.zeros(self.n), np.zeros(self.m), np.zeros(3))
        self.sanity["gap_after_one_unprojected_step_m"] = float(self.mech.gap(q))
        return q, qd

    # ------------------------------------------------------------- peers
    def add_pinocchio(self):
        try:
            import pinocchio as pin
        except ImportError:
            self.peers["pinocchio"] = "not installed"
            return
        from tools.peers_five_bar import PinFiveBar

        self.peers["pinocchio"] = pin.__version__
        pf = PinFiveBar()
        q, qd, tau = self.q0.copy(), self.qd0.copy(), self.tau.copy()
        tau_joint = pf.joint_torque(q, qd, tau)
        ours = np.empty(self.n)
        accelerations(FORMULATION_CODES["scdd"], self.ma, q, qd, tau, 0.0, 0.0, np.zeros(self.n), ours,
                      np.zeros(self.m))
        a = pf.accelerations(q, qd, tau)
        self.sanity["pin_vs_scdd_max_rel_err"] = float(np.abs(a - ours).max() / np.abs(ours).max())
        self.sanity["pin_prox_iterations"] = int(pf.prox.iter)
        self.items += [
            Item("pin.constraintDynamics", _calls(pf.accelerations_raw, q, qd, tau_joint), group="direct dynamics",
                 note="bare C++ call, spring/damper torques precomputed"),
            Item("pin.constraintDynamics+springs", _calls(pf.accelerations, q, qd, tau), group="direct dynamics",
                 note="with -c u - d du/dt computed in numpy per call"),
        ]
        qs, vs = self.q0.copy(), self.qd0.copy()

        def reset():
            qs[:] = self.q0
            vs[:] = self.qd0

        self.items.append(Item("pin.rk4_1", _calls(pf.rk4_step, qs, vs, tau, DT), reset, group="rk4", unit="step",
                               note="RK4 in Python around constraintDynamics+springs"))

    def add_mujoco(self):
        try:
            import mujoco
        except ImportError:
            self.peers["mujoco"] = "not installed"
            return
        from tools.peers_five_bar import MjFiveBar

        self.peers["mujoco"] = mujoco.__version__
        mj = MjFiveBar(dt=DT)
        mm, md = mj.model, mj.data
        mj.set_state(self.q0, self.qd0, self.tau)
        ours = np.empty(self.n)
        accelerations(FORMULATION_CODES["scdd"], self.ma, self.q0, self.qd0, self.tau, 0.0, 0.0, np.zeros(self.n),
                      ours, np.zeros(self.m))
        self.sanity["mujoco_vs_scdd_max_rel_err"] = float(np.abs(md.qacc - ours).max() / np.abs(ours).max())
        self.items.append(Item("mujoco.mj_step_rk4", _calls(mujoco.mj_step, mm, md),
                               lambda: mj.set_state(self.q0, self.qd0, self.tau), group="rk4", unit="step",
                               note="mj_step (integrator RK4) called from Python"))
        try:
            from mujoco import rollout
        except ImportError:
            return
        mjv = MjFiveBar(dt=DT)
        mjv.set_state(self.qv, np.zeros(self.n), np.zeros(self.n))
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        s0 = np.empty(mujoco.mj_stateSize(mjv.model, spec))
        mujoco.mj_getState(mjv.model, mjv.data, s0, spec)
        out = np.empty((1, LONG_STEPS, s0.size))

        def run(k):
            for _ in range(k):
                rollout.rollout(mjv.model, mjv.data, s0[None, :], nstep=LONG_STEPS, state=out)
            return k * LONG_STEPS

        item = Item("mujoco.rollout_rk4", run, group="rk4", unit="step", k=1,
                    note=f"per step of one rollout of {LONG_STEPS} steps (C loop)")
        item.mj = (mjv, out)
        self.long_items.append(item)


# --------------------------------------------------------------------------- timing


RATIOS = [  # (ours, peer, is it a design goal: ratio <= 1)
    ("ours.kernel.scdd", "pin.constraintDynamics", True),
    ("ours.facade.scdd", "pin.constraintDynamics", False),
    ("ours.kernel.scdd", "pin.constraintDynamics+springs", False),
    ("ours.entry_point.scdd", "pin.constraintDynamics", False),
    ("ours.kernel.lda", "pin.constraintDynamics", False),
    ("ours.kernel.multipliers", "pin.constraintDynamics", False),
    ("ours.kernel.scdd_one_pass", "pin.constraintDynamics", False),
    ("ours.facade.scdd", "pin.constraintDynamics+springs", False),
    ("ours.rk4_1.scdd.none", "mujoco.mj_step_rk4", True),
    ("ours.rk4_1.scdd.projection", "mujoco.mj_step_rk4", True),
    ("ours.rk4_1.lda.none", "mujoco.mj_step_rk4", False),
    ("ours.rk4_1.lda.projection", "mujoco.mj_step_rk4", False),
    ("ours.rk4_1.scdd.none", "pin.rk4_1", False),
    ("ours.rk4_long.scdd.none", "mujoco.rollout_rk4", False),
    ("ours.rk4_long.scdd.projection", "mujoco.rollout_rk4", False),
    ("ours.rk4_long.lda.projection", "mujoco.rollout_rk4", False),
    ("ours.rk4_long.scdd.none", "mujoco.mj_step_rk4", True),
    ("ours.rk4_long.scdd.projection", "mujoco.mj_step_rk4", True),
]
RTF_TARGET = 7.0  # design goal: real-time factor >= 7 at dt = 1e-4 s
RTF_ITEMS = ["ours.rk4_long.scdd.none", "ours.rk4_long.scdd.projection", "ours.rk4_long.lda.projection",
             "ours.rk4_1.scdd.none", "ours.rk4_1.scdd.projection"]


def ratio_rows(by_name: dict[str, Item]) -> list[dict]:
    rows = []
    for a, b, target in RATIOS:
        if a not in by_name or b not in by_name:
            continue
        sa, sb = np.asarray(by_name[a].samples), np.asarray(by_name[b].samples)
        row = {"ours": a, "peer": b, "ratio_of_medians": float(np.median(sa) / np.median(sb)), "target": target}
        if by_name[a].phase == by_name[b].phase:  # timed in the same rounds: paired per-round ratios
            r = sa / sb
            q25, q50, q75 = np.percentile(r, [25, 50, 75])
            row.update(paired_median=float(q50), paired_q25=float(q25), paired_q75=float(q75))
        rows.append(row)
    return rows


def markdown(result: dict) -> str:
    items = result["items"]
    lines = [f"Five-bar, one run {result['timestamp']} (commit {result['git']}) on {result['machine']['cpu']} "
             f"({result['machine']['cores']} cores, load {result['loadavg_start'][0]:.2f} -> "
             f"{result['loadavg_end'][0]:.2f}); numpy {result['machine']['numpy']}, numba "
             f"{result['machine']['numba']}, pinocchio {result['peers'].get('pinocchio')}, mujoco "
             f"{result['peers'].get('mujoco')}. {result['rounds']} rounds of short items, "
             f"{result['long_rounds']} of long ones; dt = {DT:g} s.", "",
             "| item | median [us] | IQR [us] | batches x calls | real-time factor |",
             "|---|---:|---:|---:|---:|"]
    for group in ("direct dynamics", "rk4", "profile"):
        for name, s in items.items():
            if s["group"] != group:
                continue
            rtf = f"{s['rtf']:.1f}" if "rtf" in s else ""
            lines.append(f"| `{name}` | {s['median_us']:.2f} | {s['iqr_us']:.2f} | {s['n_batches']} x {s['k']} "
                         f"| {rtf} |")
    lines += ["", "| ours / peer (same run) | ratio of medians | paired per-round median [IQR] | target <= 1 |",
              "|---|---:|---:|---|"]
    for r in result["ratios"]:
        paired = (f"{r['paired_median']:.2f} [{r['paired_q25']:.2f}, {r['paired_q75']:.2f}]"
                  if "paired_median" in r else "")
        target = ("met" if r["ratio_of_medians"] <= 1.0 else "MISSED") if r["target"] else ""
        lines.append(f"| `{r['ours']}` / `{r['peer']}` | {r['ratio_of_medians']:.2f} | {paired} | {target} |")
    lines += ["", f"| real-time factor at dt = {DT:g} s (target >= {RTF_TARGET:g}) | median | worst quartile | |",
              "|---|---:|---:|---|"]
    for name in RTF_ITEMS:
        if name in items:
            it = items[name]
            rtf, rtf_q75 = it["rtf"], DT / (it["q75_us"] * 1e-6)
            lines.append(f"| `{name}` | {rtf:.1f} | {rtf_q75:.1f} | {'met' if rtf >= RTF_TARGET else 'MISSED'} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=1000, help="rounds over the short items (default 1000)")
    p.add_argument("--long-rounds", type=int, default=20, help="rounds over the 10000-step items (default 20)")
    p.add_argument("--budget", type=float, default=45.0,
                   help="stop each phase (short, long rounds) after this many seconds (default 45)")
    p.add_argument("--quick", action="store_true", help="a smoke run: 20 short and 2 long rounds")
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    if a.quick:
        a.rounds, a.long_rounds = 20, 2
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    s = Setup()
    # First call in this process: numba loads the cached machine code (or compiles).
    q, qd = s.q0.copy(), s.qd0.copy()
    t1 = time.perf_counter()
    accelerations(0, s.ma, q, qd, s.tau, 0.0, 0.0, np.zeros(s.n), np.empty(s.n), np.zeros(s.m))
    first_call_s = time.perf_counter() - t1
    s.add_ours()
    s.add_profile()
    s.add_pinocchio()
    s.add_mujoco()
    setup_s = time.perf_counter() - t0

    for it in s.items:
        it.phase = "short"
    for it in s.long_items:
        it.phase = "long"
    gc_was = gc.isenabled()
    gc.disable()
    try:
        for it in s.items:
            calibrate(it, BATCH_TARGET_S)
        for it in s.long_items:
            calibrate(it, 0.0)
        rng = np.random.default_rng(a.seed)
        t_short = time.perf_counter()
        rounds = run_rounds(s.items, a.rounds, rng, a.budget)
        t_long = time.perf_counter()
        long_rounds = run_rounds(s.long_items, a.long_rounds, rng, a.budget)
        t_done = time.perf_counter()
    finally:
        if gc_was:
            gc.enable()

    by_name = {it.name: it for it in s.items + s.long_items}
    items = {}
    for it in s.items + s.long_items:
        st = stats(it.samples)
        st.update(group=it.group, unit=it.unit, k=it.k, note=it.note)
        if it.unit == "step":
            st["rtf"] = DT / (st["median_us"] * 1e-6)
        if getattr(it, "status", None) is not None and it.name.startswith("ours.rk4"):
            st["worst_status"] = int(it.status[0])
            if it.status[0] != kernels.OK:
                print(f"WARNING: {it.name} returned status {it.status[0]} (not OK): its timing is not valid")
            st["last_info"] = [float(x) for x in it.info]
            st["last_gap_m"] = float(s.mech.gap(it.state[0]))
        items[it.name] = st
    if "mujoco.rollout_rk4" in by_name:
        mjv, out = by_name["mujoco.rollout_rk4"].mj
        import mujoco
        mujoco.mj_setState(mjv.model, mjv.data, out[0, -1], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_forward(mjv.model, mjv.data)
        s.sanity["mujoco_rollout_last_gap_m"] = float(np.linalg.norm(mjv.data.site_xpos[0] - mjv.data.site_xpos[1]))
    result = {
        "timestamp": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "machine": machine_info(s.peers), "peers": s.peers,
        "loadavg_start": list(load0), "loadavg_end": list(os.getloadavg()),
        "git": git_commit(), "model": "config/five_bar.yaml", "dt_s": DT, "long_steps": LONG_STEPS,
        "states": {"short": "start pose p_A, qd from q_ae rates " + str(QD_AE.tolist()) + ", motor torques "
                   + str(TAU_ACTIVE.tolist()) + " N m",
                   "long": "free vibration from rest, springs prestretched " + str(PRESTRETCH.tolist())
                   + " m, no torque"},
        "rounds": rounds, "long_rounds": long_rounds, "batch_target_s": BATCH_TARGET_S,
        "first_accelerations_call_s": first_call_s, "setup_s": setup_s,
        "short_rounds_s": t_long - t_short, "long_rounds_s": t_done - t_long,
        "total_s": time.perf_counter() - T_START,
        "items": items, "ratios": ratio_rows(by_name), "sanity": s.sanity,
    }
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "dynamics.json").write_text(json.dumps(result, indent=1) + "\n")
    md = markdown(result)
    (a.out / "dynamics.md").write_text(md)
    print(md)
    print(f"sanity: {json.dumps(s.sanity)}")
    print(f"total {result['total_s']:.1f} s (setup {setup_s:.1f} s, first accelerations call {first_call_s:.2f} s); "
          f"wrote {a.out / 'dynamics.json'} and {a.out / 'dynamics.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
