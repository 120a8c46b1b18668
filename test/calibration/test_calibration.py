"""Calibration from recordings (``elastic-pm-dyn calibrate`` / ``excite``, elastic_pm_dyn.calibration).

The truth is a perturbed copy of the model file, recorded as a user would (the excitation table on
a holding loop, noisy sensors, an unknown disturbance); calibrate starts from the file and must
find the truth's parameters and elastic modes (by eigen-analysis), never numbers copied from its
own output. Short recordings and few parameters keep this file fast.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.calibration.api import calibrate, modes_of
from elastic_pm_dyn.calibration.excitation import excitation
from elastic_pm_dyn.calibration.identifiability import identifiability
from elastic_pm_dyn.calibration.parameters import ModelFile, available, select
from elastic_pm_dyn.cli import main as cli_main
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer.testing.excited import excited_recording
from elastic_pm_dyn.observer.testing.recordings import write_bag
from elastic_pm_dyn.sim.torque import load_torque_csv

CONFIG = Path(__file__).resolve().parents[1].parent / "config"
MODEL = CONFIG / "five_bar.yaml"
SENSORS = ["encoders", "imu", "branch_forces"]
# not a case the method was developed on (bench/calibration's A); payload +25 %, springs -9 % / +11 %
TRUE = {"stiffness.left_spring": 0.91, "stiffness.right_spring": 1.11, "payload.mass": 1.25}


@pytest.fixture(scope="module")
def perturbed(tmp_path_factory):
    """A 0.6 s recording of the perturbed five-bar and the calibration of the file's model on it."""
    mf = ModelFile.read(MODEL)
    params = available(mf)
    truth = mf.model(params, [p.nominal * TRUE.get(p.name, 1.0) for p in params])
    ex = excitation(Mechanism(load_model(MODEL)), ("stiffness", "payload"), [6.0], duration=0.6, seed=5)
    rec = excited_recording(Mechanism(truth), ex.torque, 1000.0, seed=4242, truth_dt=5e-5)
    tmp = tmp_path_factory.mktemp("calib")
    bag = write_bag(rec, tmp / "bag", use=tuple(SENSORS))
    out = tmp / "calibrated.yaml"
    res = calibrate(MODEL, [bag], out, params=list(TRUE), sensors=SENSORS, log=lambda s: None)
    return truth, res, out, bag


def test_recovers_a_known_perturbation_and_the_modes(perturbed) -> None:
    truth, res, _, _ = perturbed
    fitted = {p.name: v / p.nominal for p, v in zip(res.params, res.values, strict=True)}
    for name, factor in TRUE.items():
        assert fitted[name] == pytest.approx(factor, rel=0.01), name
    true_modes, file_modes = modes_of(truth), res.modes_before
    assert np.max(np.abs(file_modes / true_modes - 1)) > 0.03  # the file's machine is not the true one
    assert np.max(np.abs(res.modes_after / true_modes - 1)) < 0.01
    # the innovations whiten: the sensors that see the springs come down to about 1 NIS per dof
    for s in SENSORS:
        if s != "encoders":  # motor angles hardly see a spring (1e-8 rad per N)
            assert res.after.per_sensor[s]["mean_nis_per_dof"] < 0.5 * res.before.per_sensor[s]["mean_nis_per_dof"]
        assert res.after.per_sensor[s]["mean_nis_per_dof"] < 3.0


def test_standard_deviations_and_correlations_are_reported(perturbed) -> None:
    _, res, _, _ = perturbed
    assert np.all(np.isfinite(res.ident.std)) and np.all(res.ident.std > 0)
    c = res.ident.correlation
    assert np.allclose(np.diag(c), 1.0) and np.allclose(c, c.T) and np.all(np.abs(c) <= 1 + 1e-9)


def test_the_calibrated_file_loads_everywhere_with_the_fitted_values(perturbed, tmp_path) -> None:
    _, res, out, bag = perturbed
    model = load_model(out)
    assert model.joints[model.joint_index("left_spring")].stiffness == pytest.approx(res.values[0], rel=1e-12)
    assert np.allclose(modes_of(model), res.modes_after, rtol=1e-9)
    assert cli_main(["check", str(out)]) == 0
    table = tmp_path / "zero.csv"
    table.write_text("t,left_motor,right_motor\n0,0,0\n0.01,0,0\n")
    assert cli_main(["simulate", "--model", str(out), "--torques", str(table), "--duration", "0.01",
                     "--out", str(tmp_path / "run.csv")]) == 0
    assert cli_main(["observe", "--model", str(out), "--bag", str(bag), "--out", str(tmp_path / "obs"),
                     "--sensors", *SENSORS]) == 0
    # calibrating the calibrated file again keeps it (the file is the likeliest model already)
    again = calibrate(out, [bag], None, params=list(TRUE), sensors=SENSORS, max_passes=16, log=lambda s: None)
    assert np.allclose(again.values, res.values, rtol=2e-3)


def test_the_fisher_information_names_what_is_not_determined() -> None:
    """A parameter without information and two that act only together are named; an informed one is not."""
    B = np.array([[4e6, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1e4, 1e4], [0.0, 0.0, 1e4, 1e4]])
    ident = identifiability(B, np.ones(4), ["a", "b", "c", "d"])
    text = "\n".join(ident.findings)
    assert "rank-deficient" in text and "log c" in text and "log d" in text and "log b" in text
    assert "a:" not in text and ident.std_log[0] == pytest.approx(5e-4)
    fixed = identifiability(np.diag([1e4, 1e6]), np.array([2.0, 3.0]), ["x", "y"], fixed=[0])
    assert "x: not excited" in fixed.findings[0] and fixed.std[1] == pytest.approx(3.0 * 1e-3)


def test_parameters_of_flexible_links_and_platforms() -> None:
    """The Triglide's rods (EA), the Hexa's arms (EI) and the platform's mass are parameters, and
    setting one changes the loaded model's springs as the file's own discretisation does."""
    mf = ModelFile.read(CONFIG / "triglide.yaml")
    names = [p.name for p in available(mf)]
    assert "stiffness.leg1_rod" in names and "payload.mass" in names and "friction.leg1_drive" in names
    params = select(available(mf), ["stiffness.leg1_rod"])
    base, doubled = mf.model(params, [params[0].nominal]), mf.model(params, [2 * params[0].nominal])
    k0 = [j.stiffness for j in base.joints if j.role == "elastic"]
    k1 = [j.stiffness for j in doubled.joints if j.role == "elastic"]
    assert k1[0] == pytest.approx(2 * k0[0]) and k1[1:] == k0[1:]
    hexa = [p.name for p in available(ModelFile.read(CONFIG / "hexa.yaml"))]
    assert any(n.startswith("stiffness.") for n in hexa) and "payload.inertia" in hexa
    with pytest.raises(InputError, match="no such parameter"):
        select(available(mf), ["stiffness.nosuch"])


def test_excitation_stays_within_the_limits_and_reaches_the_modes(tmp_path) -> None:
    mech = Mechanism(load_model(MODEL))
    ex = excitation(mech, ("stiffness", "payload"), [4.0, 2.0], duration=1.0, rate=1000.0, peak_fraction=0.5)
    assert np.abs(ex.torque[:, 0]).max() <= 2.0 + 1e-12 and np.abs(ex.torque[:, 1]).max() <= 1.0 + 1e-12
    assert np.abs(ex.torque[[0, -1]]).max() < 1e-9  # starts and ends at rest
    # the modes lie above 500 Hz: reached through the hold's images rate - f
    for f in ex.modes_hz:
        assert np.min(np.abs(1000.0 - ex.lines_hz - f)) < 0.02 * f
    out = tmp_path / "ex.csv"
    assert cli_main(["excite", "--model", str(MODEL), "--out", str(out), "--max-torque", "4", "--duration", "1"]) == 0
    assert load_torque_csv(out, mech.active_names).values.shape == (1001, 2)


def test_bad_input_is_one_line(tmp_path, capsys) -> None:
    assert cli_main(["calibrate", "--model", str(MODEL), "--bag", str(tmp_path), "--out", str(tmp_path / "c.yaml"),
                     "--params", "stiffness.nosuch"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no such parameter" in err
    urdf = Path(__file__).resolve().parents[1] / "robots" / "five_bar_urdf" / "robot.urdf"
    assert cli_main(["calibrate", "--model", str(urdf), "--bag", str(tmp_path), "--out", str(tmp_path / "c.yaml")]) == 2
    assert "model YAML" in capsys.readouterr().err
    assert cli_main(["excite", "--model", str(MODEL), "--out", str(tmp_path / "e.csv"), "--max-torque", "-1"]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_the_per_sample_terms_are_the_filters_likelihood(perturbed) -> None:
    """The terms calibration differentiates sum to the NLL the filter's statistics keep (fast path and
    per-message path alike), one per sensor sample."""
    from elastic_pm_dyn.calibration.likelihood import read_recording, score
    from elastic_pm_dyn.observer.config import ObserverConfig
    _, _, out, bag = perturbed
    cfg = ObserverConfig.from_parameters({"sensors": SENSORS})
    s = score(load_model(out), cfg, [read_recording(bag, cfg)])
    assert s.terms.size == sum(d["samples"] for d in s.per_sensor.values())
    assert s.terms.sum() == pytest.approx(sum(d["nll"] for d in s.per_sensor.values()), rel=1e-12)
    assert np.all(s.nis >= 0)


def test_a_motor_torque_scale_is_calibrated_back(tmp_path) -> None:
    """A recording of the five-bar whose left motor gives 8 % less torque per command than its file
    says and the right 5 % more (``torque_scale``, every other parameter the file's): calibrating
    ``--params torque_scale`` from the file finds both scales within 3 of their reported standard
    deviations and within 0.5 %, and writes the key into the calibrated file."""
    true_scale = {"torque_scale.left_motor": 0.92, "torque_scale.right_motor": 1.05}
    mf = ModelFile.read(MODEL)
    params = available(mf)
    truth = mf.model(params, [p.nominal * true_scale.get(p.name, 1.0) for p in params])
    ex = excitation(Mechanism(load_model(MODEL)), ("payload",), [6.0], duration=0.6, seed=9)
    rec = excited_recording(Mechanism(truth), ex.torque, 1000.0, seed=777, truth_dt=5e-5)
    bag = write_bag(rec, tmp_path / "bag", use=tuple(SENSORS))
    out = tmp_path / "calibrated.yaml"
    res = calibrate(MODEL, [bag], out, params=["torque_scale"], sensors=SENSORS, log=lambda s: None)
    for p, v, s in zip(res.params, res.values, res.ident.std, strict=True):
        assert abs(v - true_scale[p.name]) < 3 * s, (p.name, v, s)
        assert v == pytest.approx(true_scale[p.name], rel=5e-3), p.name
    model = load_model(out)
    left = model.joints[model.joint_index("left_motor")]
    assert left.torque_scale == pytest.approx(res.values[0], rel=1e-12)


def test_the_sandwich_covers_mis_scaled_and_correlated_innovations() -> None:
    """The robust covariance A^-1 S A^-1 (identifiability.sandwich, score_covariance) against the
    closed form of a regression y_k = theta + e_k whose noise the model gets wrong: the model says
    white with variance 1; the data's is AR(1), rho = 0.9, marginal variance 2. The least-squares
    estimate's variance is then 2 (1 + rho) / (1 - rho) / N (large N), 38x the Fisher B^-1 = 1 / N;
    the sandwich must find it within 25 % over recordings of 20 s at 1 kHz, and B^-1 must not."""
    from scipy.signal import lfilter

    from elastic_pm_dyn.calibration.identifiability import sandwich, score_covariance
    rng = np.random.default_rng(12)
    n, rho, var = 20_000, 0.9, 2.0
    truth = var * (1 + rho) / (1 - rho) / n
    ratios, fisher = [], []
    for _ in range(20):
        w = rng.standard_normal(n) * np.sqrt(var * (1 - rho ** 2))
        w[0] = rng.standard_normal() * np.sqrt(var)  # stationary from the start
        e = lfilter([1.0], [1.0, -rho], w)  # e_k = rho e_k-1 + w_k
        theta = e.mean()  # the estimate of theta = 0
        g = -(e - theta)[:, None]  # per-sample scores of l_k = (y_k - theta)^2 / 2 at the estimate
        A = np.array([[float(n)]])  # the NLL's Hessian
        cov = sandwich(A, score_covariance(g, [(0, 20.0, n)]), [0])
        ratios.append(cov[0, 0] / truth)
        fisher.append(1.0 / float(g[:, 0] @ g[:, 0]) / truth)
    assert 0.75 < np.mean(ratios) < 1.25
    assert np.mean(fisher) < 0.1


def test_scores_of_sensors_at_different_rates_share_one_time_axis() -> None:
    """A 1 kHz sensor and a 250 Hz one over the same second: the slow one's k-th sample falls into
    the fast one's bin 4 k (identifiability.time_scores)."""
    from elastic_pm_dyn.calibration.identifiability import time_scores
    fast, slow = np.ones((1000, 1)), np.arange(250, dtype=float)[:, None]
    (S,) = time_scores(np.vstack([fast, slow]), [(0, 1.0, 1000), (0, 1.0, 250)])
    assert S.shape == (1000, 1)
    assert np.array_equal(S[::4, 0], 1.0 + np.arange(250)) and np.all(S[1::4, 0] == 1.0)


def test_the_hessian_by_second_differences_is_a_quadratics_own() -> None:
    """fit.hessian_at on a likelihood whose Hessian is known: per-sample terms l_k = (a_k . theta
    - y_k)^2 / 2, so A = sum a_k a_k^T exactly; a fixed parameter's row and column stay zero."""
    from elastic_pm_dyn.calibration.fit import hessian_at, scores_at
    from elastic_pm_dyn.calibration.likelihood import Score
    rng = np.random.default_rng(5)
    a, y = rng.standard_normal((400, 3)), rng.standard_normal(400)

    def run(points):
        out = []
        for t in points:
            terms = 0.5 * (a @ t - y) ** 2
            out.append(Score(terms, 2 * terms, float(terms.sum()), {}, ""))
        return out

    theta, free = np.array([0.1, -0.2, 0.3]), np.array([0, 2])
    here, G = scores_at(run, theta, free, 3)
    A = hessian_at(run, theta, free, 3, here, G)
    exact = a.T @ a
    np.testing.assert_allclose(A[np.ix_(free, free)], exact[np.ix_(free, free)], rtol=1e-4)
    assert np.all(A[1] == 0) and np.all(A[:, 1] == 0)
