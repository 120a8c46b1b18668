"""``observe --smoother rts``: the Rauch-Tung-Striebel pass over the filter's rows (observer/tuning/smoother.py)."""

from __future__ import annotations

import argparse
import csv
import json

import numpy as np
import pytest
from scipy.stats import chi2

from elastic_pm_dyn.bags.series import read_series
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.cli import register_cli
from elastic_pm_dyn.observer.drivers.bag_input import Topics, read_events
from elastic_pm_dyn.observer.drivers.event_filter import run_events
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.testing.evaluation import offline_run, score
from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag
from elastic_pm_dyn.observer.tuning.smoother import predictions, rts

pytest.importorskip("rosbags")

SENSORS = ["encoders", "imu"]


def _cfg(**params) -> ObserverConfig:
    return ObserverConfig.from_parameters({"sensors": SENSORS, **params})


# ---------------------------------------------------------------- linear-Gaussian reference
def _linear_case(seed: int, n: int = 40, nx: int = 4, ny: int = 2):
    rng = np.random.default_rng(seed)
    Phi = np.eye(nx) + 0.1 * rng.standard_normal((nx, nx))
    G = rng.standard_normal((nx, nx))
    Q = 0.01 * G @ G.T + 1e-3 * np.eye(nx)
    H = rng.standard_normal((ny, nx))
    R = 0.05 * np.eye(ny)
    m0, P0 = rng.standard_normal(nx), np.eye(nx)
    x = rng.multivariate_normal(m0, P0)
    ys = []
    for _ in range(n):
        ys.append(H @ x + rng.multivariate_normal(np.zeros(ny), R))
        x = Phi @ x + rng.multivariate_normal(np.zeros(nx), Q)
    return Phi, Q, H, R, m0, P0, np.array(ys)


def _kalman(Phi, Q, H, R, m0, P0, ys):
    """Filtered x_k, P_k and the predictions to k+1 (index k)."""
    n, nx = len(ys), len(m0)
    xf, Pf = np.zeros((n, nx)), np.zeros((n, nx, nx))
    xp, Pp, Ph = np.zeros((n, nx)), np.zeros((n, nx, nx)), np.zeros((n, nx, nx))
    m, P = m0, P0
    for k, y in enumerate(ys):
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        m = m + K @ (y - H @ m)
        P = (np.eye(nx) - K @ H) @ P
        xf[k], Pf[k] = m, P
        m, P = Phi @ m, Phi @ P @ Phi.T + Q
        xp[k], Pp[k], Ph[k] = m, P, Phi
    return xf, Pf, xp, Pp, Ph


def _batch(Phi, Q, H, R, m0, P0, ys):
    """The joint Gaussian posterior of x_0..x_N-1 by batch least squares (information form):
    its mean and the marginal covariances."""
    n, nx = len(ys), len(m0)
    Qi, Ri, P0i = np.linalg.inv(Q), np.linalg.inv(R), np.linalg.inv(P0)
    A = np.zeros((n * nx, n * nx))
    b = np.zeros(n * nx)
    A[:nx, :nx] += P0i
    b[:nx] += P0i @ m0
    for k in range(n):
        s = slice(k * nx, (k + 1) * nx)
        A[s, s] += H.T @ Ri @ H
        b[s] += H.T @ Ri @ ys[k]
        if k + 1 < n:
            t = slice((k + 1) * nx, (k + 2) * nx)
            A[s, s] += Phi.T @ Qi @ Phi
            A[t, t] += Qi
            A[s, t] -= Phi.T @ Qi
            A[t, s] -= Qi @ Phi
    cov = np.linalg.inv(A)
    mean = np.linalg.solve(A, b).reshape(n, nx)
    return mean, np.array([cov[k * nx:(k + 1) * nx, k * nx:(k + 1) * nx] for k in range(n)])


@pytest.mark.parametrize("seed", [3, 17])
def test_rts_equals_batch_least_squares(seed) -> None:
    Phi, Q, H, R, m0, P0, ys = _linear_case(seed)
    xf, Pf, xp, Pp, Ph = _kalman(Phi, Q, H, R, m0, P0, ys)
    xs, Ps = rts(xf, Pf, xp, Pp, Ph, np.ones(len(ys), dtype=bool))
    mean, cov = _batch(Phi, Q, H, R, m0, P0, ys)
    np.testing.assert_allclose(xs, mean, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(Ps, cov, rtol=1e-8, atol=1e-12)
    np.testing.assert_array_equal(xs[-1], xf[-1])  # the last stamp is the filter's
    # a row not joined to the next ends a segment: each half smoothed on its own
    cut = 19
    joined = np.ones(len(ys), dtype=bool)
    joined[cut] = False
    xs2, Ps2 = rts(xf, Pf, xp, Pp, Ph, joined)
    xa, Pa = rts(xf[:cut + 1], Pf[:cut + 1], xp[:cut + 1], Pp[:cut + 1], Ph[:cut + 1], np.ones(cut + 1, dtype=bool))
    np.testing.assert_allclose(xs2[:cut + 1], xa, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(Ps2[:cut + 1], Pa, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(xs2[cut], xf[cut])
    np.testing.assert_allclose(xs2[cut + 1:], xs[cut + 1:], rtol=1e-12, atol=1e-14)


# ---------------------------------------------------------------- the filter's own prediction
class _Spy(Observer):
    """The filter, keeping the prior (x, P) of every stamp it predicts to (its Python path, where
    every prediction goes through ``_advance``; the compiled steps give the same numbers:
    test_observer_fastpath)."""

    def __init__(self, *args, **kwargs):
        self.priors: list = []
        super().__init__(*args, **kwargs)
        self.steps_compiled = False

    def _advance(self, t_to: float) -> None:
        t = self.t
        super()._advance(t_to)
        if self.t != t:
            self.priors.append((self.t, self.x(), self.P.copy()))


# (the half-period delay the recording does not have makes the filter recover: test_observer_recovery)
@pytest.mark.parametrize("params", [{}, {"command_delay": 5e-4, "gating.recover_after": 0},
                                    {"imu.sample_timing": "after_command"}])
def test_replay_is_the_filters_prediction(five_bar, tmp_path, params) -> None:
    """x_k+1|k and P_k+1|k recomputed from the rows are the filter's own (a delay of half a
    period: two prediction pieces per period; the linearisation reused as the filter did). A
    recovery of the filter (the accelerometer read after the command pulls the start-up away
    from the encoders) restarts the replay at its row, with its grown process noise after it."""
    rec = generate(five_bar, RecordingSpec(duration=0.06, disturbance_rms=0.02, spectrum="pink", seed=9411))
    bag = write_bag(rec, tmp_path / "bag", use=("encoders", "imu"))
    cfg = _cfg(**params)
    events, _ = read_events(bag, Topics.from_config(cfg), cfg)
    spy = _Spy(five_bar, cfg, t0=0.0)
    rows, _, fault = run_events(spy, events, "stamp", fast=False, origin_ns=min(e.stamp_ns for e in events))
    assert not fault and len(rows.t) == len(rec.t)
    pred = predictions(five_bar, cfg, events, "stamp", rows, spy.recoveries)
    tol = cfg.timing.stamp_tolerance
    restarts = [any(abs(rows.flat[k + 1][0] - r.t) <= tol for r in spy.recoveries) for k in range(len(rows.t) - 1)]
    assert list(pred.joined[:-1]) == [not r for r in restarts] and not pred.joined[-1]
    assert len(spy.priors) == len(rows.t) - 1
    for k, (t, x, P) in enumerate(spy.priors):
        if restarts[k]:
            continue  # the filter's prior there was replaced by the recovery's restart
        assert t == pytest.approx(rows.flat[k + 1][0], abs=1e-12)
        np.testing.assert_allclose(pred.x_pred[k], x, rtol=0, atol=1e-13)
        np.testing.assert_allclose(pred.P_pred[k], P, rtol=1e-10, atol=1e-30)
    # the fast path's rows give the same
    fast_obs = Observer(five_bar, cfg, t0=0.0)
    fast_rows, _, _ = run_events(fast_obs, events, "stamp", origin_ns=min(e.stamp_ns for e in events))
    fast = predictions(five_bar, cfg, events, "stamp", fast_rows, fast_obs.recoveries)
    np.testing.assert_allclose(fast.x_pred, pred.x_pred, rtol=0, atol=1e-13)


def test_replay_after_recoveries(five_bar, tmp_path) -> None:
    """A recovery (Observer._recover) ends a segment; after it the replay predicts with the
    grown process noise, as the filter did."""
    rec = generate(five_bar, RecordingSpec(duration=0.06, disturbance_rms=0.02, spectrum="pink", seed=9411))
    bag = write_bag(rec, tmp_path / "bag", use=("encoders", "imu"))
    cfg = _cfg(**{"command_delay": 5e-4, "gating.recover_after": 5})
    events, _ = read_events(bag, Topics.from_config(cfg), cfg)
    spy = _Spy(five_bar, cfg, t0=0.0)
    rows, _, fault = run_events(spy, events, "stamp", fast=False, origin_ns=min(e.stamp_ns for e in events))
    assert not fault and spy.recoveries
    pred = predictions(five_bar, cfg, events, "stamp", rows, spy.recoveries)
    breaks = {k for k in range(len(rows.t) - 1) if not pred.joined[k]}
    assert breaks == {k - 1 for k in range(1, len(rows.t))
                      if any(abs(r.t - rows.flat[k][0]) < 1e-9 for r in spy.recoveries)}
    for k, (_, x, P) in enumerate(spy.priors):
        if pred.joined[k]:
            np.testing.assert_allclose(pred.x_pred[k], x, rtol=0, atol=1e-13)
            np.testing.assert_allclose(pred.P_pred[k], P, rtol=1e-10, atol=1e-30)


# ---------------------------------------------------------------- recordings
SPECS = [RecordingSpec(duration=0.5, disturbance_rms=0.02, spectrum="pink", seed=9301),
         RecordingSpec(duration=0.5, disturbance_rms=0.02, spectrum="pink", seed=9302, t0=1.7e9)]


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.name)
def test_smoothed_beats_filtered_on_recordings(five_bar, tmp_path, spec) -> None:
    rec = generate(five_bar, spec)
    bag = write_bag(rec, tmp_path / "bag", use=("encoders", "imu"))
    res = observe_bag(five_bar, _cfg(), bag, tmp_path / "out", log=lambda s: None, smoother="rts")
    assert res.summary.smoother == "rts" and res.summary.smoothing["segments"] == 1
    filtered, smoothed = res.filtered, res.rows
    assert filtered is not None and smoothed.t == filtered.t
    sf = score(rec, offline_run(rec, filtered), settle=0.05)
    ss = score(rec, offline_run(rec, smoothed), settle=0.05)
    assert ss["F_error_rms_N"] < sf["F_error_rms_N"]
    assert ss["motor_rmse_rad"] < sf["motor_rmse_rad"]
    lay = res.observer.flat_layout()
    tf, ts = filtered.table(), smoothed.table()
    for key in ("branch_force_std", "q_std", "qd_std", "ee_std", "disturbance_std"):
        assert np.all(ts[:, lay[key]] <= tf[:, lay[key]] * (1 + 1e-9) + 1e-15), key
    assert np.mean(ts[:, lay["branch_force_std"]] / tf[:, lay["branch_force_std"]]) < 0.95
    np.testing.assert_array_equal(ts[-1], tf[-1])  # the last stamp is the filter's
    # NEES of the smoothed states in the chi-square band as often as the filter's, its mean near the dof
    dof = 2 * len(five_bar.ae)
    assert 0.5 * dof < ss["nees_mean"] < 1.5 * dof
    assert ss["nees_in_band"] > min(0.8, sf["nees_in_band"] - 0.05)
    assert chi2.ppf(0.025, dof) < ss["nees_mean"] < chi2.ppf(0.975, dof)


def test_cli_writes_smoothed_and_filtered_csv(five_bar, tmp_path) -> None:
    rec = generate(five_bar, RecordingSpec(duration=0.1, disturbance_rms=0.02, spectrum="pink", seed=9303))
    bag = write_bag(rec, tmp_path / "bag", use=("encoders", "imu"))
    parser = argparse.ArgumentParser()
    register_cli(parser.add_subparsers(dest="command"))

    def run(out, *extra):
        args = parser.parse_args(["observe", "--model", str(five_bar.model.source), "--bag", str(bag), "--out",
                                  str(out), "--sensors", *SENSORS, *extra])
        assert args.func(args) == 0
        with (out / "estimates.csv").open() as fh:
            rows = list(csv.reader(fh))
        return rows[0], np.array(rows[1:], dtype=float), json.loads((out / "summary.json").read_text())

    header, plain, summary = run(tmp_path / "plain")
    assert summary["smoother"] is None and "smoothing" not in summary
    assert not (tmp_path / "plain" / "filtered.csv").exists()
    out = tmp_path / "smoothed"
    header_s, smoothed, summary_s = run(out, "--smoother", "rts")
    assert summary_s["smoother"] == "rts"
    assert 0 < summary_s["smoothing"]["branch_force_std_ratio_mean"] < 1
    with (out / "filtered.csv").open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == header_s == header
    filtered = np.array(rows[1:], dtype=float)
    np.testing.assert_array_equal(filtered, plain)  # filtered.csv = what observe writes without a smoother
    assert smoothed.shape == plain.shape
    np.testing.assert_array_equal(smoothed[:, :2], plain[:, :2])  # the same stamps
    F = header.index("F_left")
    assert np.abs(smoothed[:-1, F] - plain[:-1, F]).max() > 0
    np.testing.assert_array_equal(smoothed[-1], plain[-1])
    # the estimates bag carries the smoothed estimates
    series = read_series(out / "estimates")
    np.testing.assert_allclose(series["/branch_forces"].values["force"][:, 0], smoothed[:, F], rtol=1e-11)


def test_unknown_smoother_is_an_input_error(five_bar, tmp_path) -> None:
    with pytest.raises(InputError, match="smoother"):
        observe_bag(five_bar, _cfg(), tmp_path / "nothing", None, log=lambda s: None, smoother="ukf")
