"""The paper's one-pass SCDD (``scdd_one_pass``) is refused where its iteration diverges (issue #26).

One pass maps the previous accelerations to new ones with the gain G of dynamics/one_pass.py;
where its spectral radius (the convergence factor) is >= 1 the accelerations it returns run
away from the dynamics. The Triglide and the Hexa start where it is 62.6 and 31.6, the five-bar
where it is 0.557, and the five-bar's multisine run below reaches 1 at t = 1.91 s. The factors
here are checked against what the kernel does (the error ratio of repeated passes), not taken
from the function that computes them.
"""

from __future__ import annotations

import numpy as np
import pytest

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.dynamics.evaluate import FORMULATION_CODES, accelerations
from elastic_pm_dyn.dynamics.one_pass import one_pass_convergence_factor
from elastic_pm_dyn.errors import OnePassDivergenceError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.simulator import SimulationOptions, Simulator
from elastic_pm_dyn.sim.torque import ConstantTorque, TorqueTable

CONFIG = __import__("pathlib").Path(__file__).resolve().parents[1].parent / "config"


@pytest.fixture(scope="module")
def triglide() -> Mechanism:
    return Mechanism(load_model(CONFIG / "triglide.yaml"))


def _passes(mech: Mechanism, q: np.ndarray, tau: np.ndarray, count: int) -> tuple[np.ndarray, list[float]]:
    """Exact SCDD at (q, rest, tau) and the error of ``count`` repeated one passes from a 1e-6 start error."""
    n = mech.n
    qd, lam, exact = np.zeros(n), np.zeros(mech.m), np.empty(n)
    accelerations(FORMULATION_CODES["scdd"], mech.arrays, q, qd, tau, 0.0, 0.0, np.zeros(n), exact, lam)
    prev, errors = exact + 1e-6 * np.random.default_rng(1).standard_normal(n), []
    for _ in range(count):
        out = np.empty(n)
        accelerations(FORMULATION_CODES["scdd_one_pass"], mech.arrays, q, qd, tau, 0.0, 0.0, prev, out, lam)
        errors.append(float(np.abs(out - exact).max()))
        prev = out
    return exact, errors


def test_the_factor_is_the_kernels_error_ratio_per_pass(five_bar, triglide) -> None:
    for mech in (five_bar, triglide):
        q = initial_state(mech)
        _, errors = _passes(mech, q, mech.split_tau(np.full(len(mech.active), 0.3)), 9)
        measured = (errors[8] / errors[3]) ** 0.2
        assert one_pass_convergence_factor(mech, q) == pytest.approx(measured, rel=0.02)


@pytest.mark.parametrize("integrator", ["rk4", "dop853"])
def test_refused_in_one_line_where_it_diverges_at_the_start(triglide, integrator: str) -> None:
    """The Triglide's start pose: one pass multiplies its error by ~62 per evaluation (garbage
    within a step), so a run is refused before it computes anything, naming the factor and scdd."""
    _, errors = _passes(triglide, initial_state(triglide), triglide.split_tau(np.full(3, 0.3)), 4)
    assert errors[-1] > 1e5 * errors[0]  # what the refusal prevents
    sim = Simulator(triglide, SimulationOptions(formulation="scdd_one_pass", integrator=integrator))
    with pytest.raises(OnePassDivergenceError) as err:
        sim.run(ConstantTorque(np.zeros(3)), 0.01)
    message = str(err.value)
    assert "\n" not in message and "at the start pose" in message and "use formulation scdd" in message, message
    assert f"{err.value.factor:.6g} >= 1" in message and 55 < err.value.factor < 70, message
    assert err.value.partial is None
    with pytest.raises(OnePassDivergenceError):
        Dynamics(triglide, "scdd_one_pass").accelerations(initial_state(triglide), np.zeros(triglide.n), np.zeros(3))


def test_where_it_converges_it_is_exact_scdd_to_round_off(five_bar) -> None:
    """The five-bar's start pose (factor 0.557): repeated at one state, the one pass reaches
    exact SCDD (its fixed point) to round-off, through the checked interface."""
    q = initial_state(five_bar)
    qd = five_bar.tree_velocity(q, np.linspace(0.4, -0.3, len(five_bar.ae)))
    tau = np.array([0.3, -0.2])
    exact = Dynamics(five_bar, "scdd").accelerations(q, qd, tau)
    one = Dynamics(five_bar, "scdd_one_pass")
    first = one.accelerations(q, qd, tau)
    for _ in range(120):  # 0.557^120 ~ 1e-30
        out = one.accelerations(q, qd, tau)
    scale = float(np.abs(exact).max())
    assert float(np.abs(first - exact).max()) > 1e-3 * scale  # the first pass lags (it starts from 0)
    assert float(np.abs(out - exact).max()) <= 1e-12 * scale


def test_a_run_stops_where_the_factor_reaches_one(five_bar) -> None:
    """The five-bar under a slow multisine (as test_constraint_drift.py) reaches a factor of 1 at
    t = 1.91 s: the run stops there with the samples before it, all at factors below 1."""
    t = np.arange(0.0, 3.0 + 1e-9, 1e-3)
    freqs, phases = np.array([0.7, 1.3, 2.9]), np.array([[0.3, 2.0], [1.1, 4.2], [5.0, 0.4]])
    tau = np.stack([sum(0.05 * np.sin(2 * np.pi * f * t + p[k]) for f, p in zip(freqs, phases, strict=True))
                    for k in range(2)], axis=1)
    sim = Simulator(five_bar, SimulationOptions(formulation="scdd_one_pass", stabilization="projection", sample=0.01))
    with pytest.raises(OnePassDivergenceError) as err:
        sim.run(TorqueTable(t, tau), 3.0)
    stop = err.value
    assert 1.8 < stop.time < 2.0 and f"at t = {stop.time:.6g} s" in str(stop), str(stop)
    partial = stop.partial
    assert partial.t[-1] < stop.time and len(partial.t) > 150
    factors = [one_pass_convergence_factor(five_bar, q) for q in partial.q[::10]]
    assert max(factors) < 1.0 <= stop.factor, (max(factors), stop.factor)


def test_check_prints_the_factor(capsys) -> None:
    assert main(["check", str(CONFIG / "five_bar.yaml")]) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if "scdd_one_pass" in s]
    assert len(line) == 1 and "convergence factor 0.557" in line[0] and "converges" in line[0], line
    assert main(["check", str(CONFIG / "triglide.yaml")]) == 0
    line = [s for s in capsys.readouterr().out.splitlines() if "scdd_one_pass" in s]
    assert len(line) == 1 and "convergence factor 62.6" in line[0] and "use scdd" in line[0], line


def test_simulate_cli_refuses_in_one_line(tmp_path, capsys) -> None:
    torques = tmp_path / "tau.csv"
    torques.write_text("t,leg1_drive,leg2_drive,leg3_drive\n0,0,0,0\n0.01,0,0,0\n")
    code = main(["simulate", "--model", str(CONFIG / "triglide.yaml"), "--torques", str(torques), "--duration",
                 "0.01", "--method", "scdd_one_pass", "--out", str(tmp_path / "out.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "convergence factor" in err[0] and "scdd" in err[0], err
    assert not (tmp_path / "out.csv").exists()
