"""ETD2 (sim/exponential.py): accuracy against DOP853, undamped energy, the kernel contract, the plant.

The accuracy criterion is the one of bench/benchmarks/bench_integrators.py: branch forces within 1 % of
the RMS of their elastic part (F minus the quasi-static force of the locked machine) of a
DOP853 run at rtol 1e-10.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import InputError, SingularConfigurationError
from elastic_pm_dyn.kinematics.assembly import initial_state, solve_pose
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.layout import JF_DAMPING, JF_FRICTION, JF_STIFFNESS
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.motion.feedforward import line_torques
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.trajectory import QuinticLine
from elastic_pm_dyn.observer.testing.evaluation import quasi_static_branch_forces
from elastic_pm_dyn.sim import exponential, kernels
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque, TorqueTable

CONFIG = Path(__file__).resolve().parents[2] / "config"
SAMPLE = 1e-3


@pytest.fixture(scope="module")
def five_bar() -> tuple[Mechanism, TorqueTable]:
    model = load_model(CONFIG / "five_bar.yaml")
    times, torques, _ = line_torques(model, REFERENCE_MANOEUVRE.line, REFERENCE_MANOEUVRE.control_rate)
    return Mechanism(model), TorqueTable(times, torques, "zoh")


@pytest.fixture(scope="module")
def triglide() -> tuple[Mechanism, TorqueTable]:
    """Triglide at 2 elastic DOF per rod (rod modes at 4.75 kHz: RK4 needs dt ~2.5e-5 s)."""
    model = load_model(CONFIG / "triglide.yaml", 2)
    mech = Mechanism(model)
    a = mech.end_effector(initial_state(mech))
    line = QuinticLine(a, a + np.array([0.03, 0.02, 0.03]), 0.2, 0.1)
    times, torques, _ = line_torques(model, line, 1000.0)
    return mech, TorqueTable(times, torques, "zoh")


def run(mech: Mechanism, integrator: str, dt: float, torque, duration: float, q0=None):
    return Simulator(mech, SimulationOptions(integrator=integrator, dt=dt, sample=SAMPLE)).run(torque, duration, q0)


def elastic_rms(mech: Mechanism, ref, torque) -> float:
    F_qs = np.array([quasi_static_branch_forces(mech, ref.q[k], ref.qd[k], torque.value(float(ref.t[k])))
                     for k in range(len(ref.t))])
    return float(np.sqrt(np.mean((ref.branch_forces - F_qs) ** 2)))


@pytest.mark.parametrize(("machine", "duration"), [("five_bar", 0.15), ("triglide", 0.1)])
def test_etd2_at_half_a_millisecond_matches_dop853(machine: str, duration: float, request) -> None:
    """A 0.5 ms step (5x RK4's stability limit on the Triglide) keeps the branch forces within
    1 % of their elastic part; RK4 at 1e-4 s, stable on the five-bar, misses it on the Triglide."""
    mech, torque = request.getfixturevalue(machine)
    ref = run(mech, "dop853", 1e-4, torque, duration)
    scale = elastic_rms(mech, ref, torque)
    etd2 = run(mech, "etd2", 5e-4, torque, duration)
    err = np.abs(etd2.branch_forces - ref.branch_forces).max() / scale
    print(f"{machine}: elastic RMS {scale:.3g} N, ETD2 0.5 ms max error {err:.3g} of it")
    assert err < 0.01
    if machine == "triglide":
        with pytest.raises(SingularConfigurationError, match="diverged"):
            run(mech, "rk4", 1e-4, torque, duration)


def test_etd2_agrees_with_rk4_at_a_small_step(triglide) -> None:
    mech, torque = triglide
    fine = run(mech, "rk4", 1.25e-5, torque, 0.05)
    etd2 = run(mech, "etd2", 2.5e-4, torque, 0.05)
    scale = np.abs(fine.branch_forces).max()
    assert np.abs(etd2.branch_forces - fine.branch_forces).max() < 1e-3 * scale
    assert np.abs(etd2.q - fine.q).max() < 1e-7


def undamped_deflected(mech: Mechanism, force: float) -> tuple[Mechanism, np.ndarray, np.ndarray, float]:
    """A copy without damping, friction and gravity, its elastic joints deflected by
    force / stiffness (alternating signs) from the start pose (zero torque then holds it);
    returns (mechanism, q0, E(q0), the deflection's energy)."""
    undamped = Mechanism(mech.model)
    undamped.arrays.gravity[:] = 0.0
    undamped.arrays.jf[:, JF_DAMPING] = 0.0
    undamped.arrays.jf[:, JF_FRICTION] = 0.0
    q_start = initial_state(undamped)
    q = q_start.copy()
    el = undamped.elastic
    q[el] += force / undamped.stiffness[el] * np.where(np.arange(len(el)) % 2 == 0, 1.0, -1.0)
    q = solve_pose(undamped, q, undamped.passive)
    e0 = sum(undamped.energy(q, np.zeros(undamped.n)))
    return undamped, q, e0, e0 - sum(undamped.energy(q_start, np.zeros(undamped.n)))


def energy_drift(mech: Mechanism, q0: np.ndarray, e0: float, e_modes: float, integrator: str, dt: float,
                 horizon: float) -> float:
    sim = Simulator(mech, SimulationOptions(integrator=integrator, dt=dt, sample=0.01))
    r = sim.run(ConstantTorque(np.zeros(len(mech.active))), horizon, q0)
    e = np.array([sum(mech.energy(r.q[k], r.qd[k])) for k in range(len(r.t))])
    return float(np.abs(e - e0).max() / e_modes)


def test_undamped_rod_modes_keep_their_energy(triglide) -> None:
    """The Triglide's rods deflected against each other ring at 4.75-4.8 kHz. Over 0.3 s
    (1400 periods) RK4 at its accurate step loses a measurable part of that energy (its
    amplitude shrinks by (h omega)^6 / 144 per step); ETD2 at a 1 ms step keeps it to 0.1 %."""
    mech, _ = triglide
    undamped, q0, e0, e_modes = undamped_deflected(mech, 10.0)
    rk4 = energy_drift(undamped, q0, e0, e_modes, "rk4", 2.5e-5, 0.3)
    etd2 = energy_drift(undamped, q0, e0, e_modes, "etd2", 1e-3, 0.3)
    print(f"energy drift over 0.3 s: RK4 2.5e-5 s {rk4:.3g}, ETD2 1 ms {etd2:.3g} of the deflection's energy")
    assert rk4 > 0.05  # the horizon is long enough to show a loss
    assert etd2 < 1e-3


def test_projection_keeps_the_springs_energy() -> None:
    """The projection after each step moves positions in the metric M + H^2 K: in the mass
    metric alone its 1e-11-rad corrections moved the Hexa's stiff elastic joints too, and at
    1 ms steps (omega H ~ 10 on its arm modes) the undamped Hexa at n_ek = 2 lost 1.9 % of its
    modes' energy over 3 s (8.4 % over 10 s); with the springs in the metric 0.16 % (ETD2RK's
    forcing), 0.014 % (ETD2's)."""
    mech = Mechanism(load_model(CONFIG / "hexa.yaml", 2))
    undamped, q0, e0, e_modes = undamped_deflected(mech, 1.1)  # twice the manoeuvre's peak branch force
    drift = energy_drift(undamped, q0, e0, e_modes, "etd2", 1e-3, 3.0)
    print(f"Hexa n_ek = 2, undamped, ETD2 1 ms: energy drift over 3 s {drift:.3g} of the deflection's energy")
    assert drift < 5e-3


def test_projection_step_is_the_least_w_norm_correction() -> None:
    """One position correction of the ETD2 projection, with its factors at the pose itself,
    equals the least W-norm step (W = M + dt^2 K) onto A dq = -h solved as one KKT system by
    numpy: the rank-n_f form through G (no factorisation of W) is that step."""
    mech = Mechanism(load_model(CONFIG / "hexa.yaml", 2))
    rng = np.random.default_rng(5)
    q = initial_state(mech)
    q[mech.elastic] += rng.normal(scale=1e-4, size=len(mech.elastic))
    q = solve_pose(mech, q, mech.passive)
    q_off = q + rng.normal(scale=1e-6, size=mech.n)  # a closure gap of ~1e-6
    ma, n, dt = mech.arrays, mech.n, 1e-3
    fast = exponential.fast_joints(ma)
    t = mech.terms(q_off)
    gws = exponential.gains_workspace(ma, fast)
    G = np.empty((n, len(fast) + 2))
    exponential.elastic_gains(ma, fast, t.M, t.A, np.zeros((2, n)), G, gws)
    k = ma.jf[fast, JF_STIFFNESS]
    nf = len(fast)
    sw = (np.empty((nf, nf)), np.empty(nf), np.empty(nf), np.empty(n))
    q_new, qd = q_off.copy(), np.zeros(n)
    kernels.project_springs(ma, q_new, qd, 0.0, 1, kernels.projection_workspace(ma), fast, dt * np.sqrt(k), G,
                            gws[1], gws[2], gws[7], gws[8], gws[9], sw)
    W = t.M.copy()
    W[fast, fast] += dt * dt * k
    m = mech.m
    kkt = np.block([[W, t.A.T], [t.A, np.zeros((m, m))]])
    dq = np.linalg.solve(kkt, np.concatenate([np.zeros(n), -t.residual]))[:n]
    print(f"gap {np.linalg.norm(t.residual):.2g}, |dq| {np.abs(dq).max():.3g}, "
          f"difference {np.abs(q_new - q_off - dq).max():.3g}")
    np.testing.assert_allclose(q_new - q_off, dq, rtol=0, atol=1e-9 * np.abs(dq).max())


@pytest.mark.parametrize("dt, horizon", [(1e-3, 10.0), (2.5e-4, 8.0)])
def test_unresolved_arm_modes_gain_no_energy(dt: float, horizon: float) -> None:
    """The Hexa at n_ek = 4 has arm modes up to 11.5 kHz: omega H = 18-72 at these steps.
    Sampled at the step's ends (ETD2RK), the nonlinear rest's products of those oscillations
    alias into a forcing in phase with them: undamped, the machine gained 5 % of its
    deflection's energy over 10 s at 1 ms, more than all of it from 7 s on at 0.25 ms.
    Evaluated on the predictor's average over the step (ETD2) it keeps it to 0.2 %."""
    mech = Mechanism(load_model(CONFIG / "hexa.yaml", 4))
    undamped, q0, e0, e_modes = undamped_deflected(mech, 1.38)  # twice the manoeuvre's peak branch force
    averaged = energy_drift(undamped, q0, e0, e_modes, "etd2", dt, horizon)
    sampled = energy_drift(undamped, q0, e0, e_modes, "etd2rk", dt, horizon)
    print(f"Hexa n_ek = 4, undamped, {dt:g} s: energy drift over {horizon:g} s ETD2 {averaged:.3g}, "
          f"ETD2RK {sampled:.3g} of the deflection's energy")
    assert averaged < 5e-3
    assert sampled > 2e-2  # the case tells the two apart


def test_step_averages_are_the_responses_mean() -> None:
    """The predictor's average over the step (aq, av from the closed form and the integral rho
    of the Taylor sub-steps) equals the time average of the responses xq(t), xv(t) themselves,
    for every forcing term (bq, bv, the torque's u1 t and u2 t^2) and on a coordinate that is
    not an elastic joint."""
    from scipy.integrate import simpson
    rng = np.random.default_rng(5)
    fast = np.array([0, 2])
    nf, n = 2, 3
    kf, df = np.array([4e8, 9e8]), np.array([3e3, 1e3])  # ~5 kHz, lightly damped
    G = np.zeros((n, nf + 2))
    G[:, :nf] = [[2.0, 0.5], [0.3, -0.7], [0.5, 1.0]]
    bq, bv, u1, u2 = (rng.normal(size=n) * s for s in (1.0, 1e3, 1e6, 1e9))
    rate = exponential.fastest_rate(G, fast, np.sqrt(kf), df)

    def response(H: float, want_average: bool):
        n_sub = max(1, int(np.ceil(H * rate / exponential.DEFAULT_PHASE_STEP)))
        m = n if want_average else 0
        xq, xv, aq, av = np.empty(n), np.empty(n), np.empty(m), np.empty(m)
        exponential.phi_response(G, fast, kf, df, H, n_sub, exponential.taylor_order(H * rate / n_sub), bq, bv, u1,
                                 u2, xq, xv, np.empty((5, 5, nf)), np.empty((nf, nf)), aq, av)
        return xq, xv, aq, av

    H = 1e-3
    _, _, aq, av = response(H, True)
    times = np.linspace(0.0, H, 2001)
    path = np.array([np.concatenate(response(t, False)[:2]) if t > 0 else np.zeros(2 * n) for t in times])
    mean = simpson(path, x=times, axis=0) / H
    np.testing.assert_allclose(np.concatenate([aq, av]), mean, rtol=1e-7, atol=1e-7 * np.abs(mean).max())


def test_taylor_terms_follow_the_sub_step() -> None:
    """A sub-step's series keeps the truncation of 20 terms at 3 rad (the old fixed rule) at any
    phase, with at least the terms the quadratic torque forcing needs; the response of the
    frozen spring system at the default (9 rad) sub-steps equals the matrix exponential's."""
    from math import factorial

    import scipy.linalg
    for theta in (0.0, 0.5, 3.0, 6.0, 9.0):
        k = exponential.taylor_order(theta)
        assert theta ** (k + 1) / factorial(k + 1) <= exponential.TAYLOR_TOL
        assert k == 6 or theta ** k / factorial(k) > exponential.TAYLOR_TOL
    assert exponential.taylor_order(3.0) == 20
    # two springs (k, d) coupled through B: q'' = B f + bv, f = -K q - D q', from rest, 1 ms
    rng = np.random.default_rng(3)
    nf = 2
    B = np.array([[2.0, 0.5], [0.5, 1.0]])
    kf, df = np.array([4e8, 9e8]), np.array([3e3, 1e3])  # ~5 kHz, lightly damped
    G = np.zeros((nf, nf + 2))
    G[:, :nf] = B
    fast = np.arange(nf)
    bv = rng.normal(size=nf)
    rate = exponential.fastest_rate(G, fast, np.sqrt(kf), df)
    H = 1e-3
    n_sub = max(1, int(np.ceil(H * rate / exponential.DEFAULT_PHASE_STEP)))
    xq, xv = np.empty(nf), np.empty(nf)
    z = np.zeros(nf)
    exponential.phi_response(G, fast, kf, df, H, n_sub, exponential.taylor_order(H * rate / n_sub), z, bv, z, z,
                             xq, xv, np.empty((5, 5, nf)), np.empty((nf, nf)), z[:0], z[:0])
    J = np.block([[np.zeros((nf, nf)), np.eye(nf)], [-B * kf, -B * df]])
    aug = np.zeros((2 * nf + 1, 2 * nf + 1))
    aug[:2 * nf, :2 * nf] = J * H
    aug[nf:2 * nf, -1] = bv * H
    exact = scipy.linalg.expm(aug)[:2 * nf, -1]
    assert n_sub < int(np.ceil(H * rate / 3.0))  # fewer sub-steps than at 3 rad
    np.testing.assert_allclose(np.concatenate([xq, xv]), exact, rtol=1e-9, atol=1e-9 * np.abs(exact).max())


def test_reference_judges_conditioning_where_it_went() -> None:
    """DOP853 checks the conditioning at its accepted steps: the Triglide at n_ek = 4 under a
    1 kHz-sampled chirp (20 % of the manoeuvre's peak torque, 50 -> 1200 Hz over 0.2 s) was
    stopped at 48 ms by a conditioning of 5e-9 seen at a stage of a rejected trial step, on a
    path whose conditioning stays at 0.65. It now runs, and ETD2 at 0.25 ms follows it."""
    model = load_model(CONFIG / "triglide.yaml", 4)
    mech = Mechanism(model)
    a = mech.end_effector(initial_state(mech))
    line = QuinticLine(a, a + np.array([0.03, 0.02, 0.03]), 0.2, 0.1)
    _, torques, _ = line_torques(model, line, 1000.0)
    hold = torques[0]
    amp = 0.2 * np.abs(torques).max(axis=0) * np.where(np.arange(len(hold)) % 2 == 0, 1.0, -1.0)
    t = np.arange(61) / 1000.0
    chirp = hold + amp * np.sin(2 * np.pi * (50.0 * t + 0.5 * 5750.0 * t * t))[:, None]
    table = TorqueTable(t, chirp, "zoh")
    ref = Simulator(mech, SimulationOptions(integrator="dop853", sample=SAMPLE)).run(table, 0.06)
    etd2 = run(mech, "etd2", 2.5e-4, table, 0.06)
    err = np.abs(etd2.branch_forces - ref.branch_forces).max() / np.abs(ref.branch_forces).max()
    print(f"Triglide n_ek = 4, sampled chirp to 60 ms: ETD2 0.25 ms max branch-force error {err:.2g} of the peak")
    assert err < 1e-3


def kernel_args(mech: Mechanism, torque: np.ndarray, dt: float, n_steps: int, singular_tol: float = 1e-8):
    o = SimulationOptions()
    coef = np.zeros((3, mech.n))
    coef[0, mech.active] = torque
    return (exponential.AVERAGED, 0, mech.arrays), (coef, dt, n_steps, kernels.STAB_PROJECTION, 0.0, 0.0,
                                                 o.closure_tol, singular_tol, o.phase_step, np.zeros(mech.n),
                                                 np.zeros(mech.m), np.zeros(3))


def test_a_diverged_step_leaves_the_last_good_state(five_bar) -> None:
    mech, _ = five_bar
    tau = np.array([2e4, -2e4])  # drives the motors to > 1 rad per step within a few steps
    q, qd = initial_state(mech), np.zeros(mech.n)
    head, tail = kernel_args(mech, tau, 5e-4, 50)
    status = exponential.exponential_steps(*head, q, qd, *tail)
    info = tail[-1]
    assert status == kernels.DIVERGED and 0 < info[0] < 50
    q2, qd2 = initial_state(mech), np.zeros(mech.n)
    head, tail2 = kernel_args(mech, tau, 5e-4, int(info[0]))
    assert exponential.exponential_steps(*head, q2, qd2, *tail2) == kernels.OK
    np.testing.assert_array_equal(q, q2)  # exactly the state after the good steps
    np.testing.assert_array_equal(qd, qd2)
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(qd))


def test_singular_conditioning_stops_before_the_step(five_bar) -> None:
    mech, _ = five_bar
    q, qd = initial_state(mech), np.zeros(mech.n)
    q_before = q.copy()
    head, tail = kernel_args(mech, np.zeros(2), 5e-4, 3, singular_tol=2.0)  # above any pivot ratio
    assert exponential.exponential_steps(*head, q, qd, *tail) == kernels.SINGULAR
    assert tail[-1][0] == 0
    np.testing.assert_array_equal(q, q_before)


def test_lda_is_refused_with_one_line(five_bar) -> None:
    mech, _ = five_bar
    with pytest.raises(InputError, match="etd2 needs a tree formulation"):
        Simulator(mech, SimulationOptions(formulation="lda", integrator="etd2"))


def test_plant_with_etd2_equals_offline_simulate(triglide) -> None:
    mech, table = triglide
    opts = SimulationOptions(integrator="etd2", dt=5e-4, sample=1e-3)
    plant = Plant(mech, opts, 1e-3)
    sim = Simulator(mech, SimulationOptions(integrator="etd2", dt=5e-4, sample=1e-3))
    q, qd = plant.q0.copy(), np.zeros(mech.n)
    for k in range(20):
        tau = table.value(k * 1e-3)
        plant.step(tau)
        sim.advance(q, qd, ConstantTorque(tau), k * 1e-3, k * 1e-3 + 1e-3)  # the plant's period bounds
    np.testing.assert_array_equal(plant.q, q)
    np.testing.assert_array_equal(plant.qd, qd)


def test_the_integrator_table_reaches_each_kernel(five_bar) -> None:
    """Simulator.fixed_steps goes through sim/integrators.py's one dispatch: each name of its
    table steps exactly as its kernel called directly, and the comparison schemes are others."""
    mech, _ = five_bar
    tau = np.array([0.4, -0.3])
    ends = {}
    for name, scheme in (("etd2", exponential.AVERAGED), ("etd2rk", exponential.ETD2RK),
                         ("impulse", exponential.IMPULSE), ("rk4", None)):
        sim = Simulator(mech, SimulationOptions(integrator=name, dt=5e-4))
        q, qd = initial_state(mech), np.zeros(mech.n)
        head, tail = kernel_args(mech, tau, 5e-4, 20)
        assert sim.fixed_steps(q, qd, tail[0], 5e-4, 20) == kernels.OK
        q2, qd2 = initial_state(mech), np.zeros(mech.n)
        if scheme is None:
            status = kernels.rk4_steps(0, mech.arrays, q2, qd2, *tail[:8], *tail[9:])  # no phase step
        else:
            status = exponential.exponential_steps(scheme, *head[1:], q2, qd2, *tail)
        assert status == kernels.OK
        np.testing.assert_array_equal(q, q2)
        np.testing.assert_array_equal(qd, qd2)
        ends[name] = q
    assert not np.array_equal(ends["etd2"], ends["etd2rk"]) and not np.array_equal(ends["etd2"], ends["impulse"])


def test_the_comparison_schemes_are_not_offered_on_the_command_line() -> None:
    from elastic_pm_dyn.sim.simulator import INTEGRATORS
    assert set(INTEGRATORS) == {"rk4", "etd2", "dop853"}
    with pytest.raises(InputError, match="unknown integrator"):
        SimulationOptions(integrator="etd3").validate()
