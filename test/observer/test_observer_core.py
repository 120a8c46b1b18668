"""Observer building blocks: configuration, discretisation, linearisation, correction, observability."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.assembly import initial_state
from elastic_pm_dyn.observer import Observer, ObserverConfig, load_config
from elastic_pm_dyn.observer.core import correction, kernels
from elastic_pm_dyn.observer.core.observability import analyse
from elastic_pm_dyn.sim import kernels as sim_kernels

CONFIG = Path(__file__).resolve().parents[1].parent / "config"


def make(mech, **params) -> Observer:
    p = {"initial.source": "model"}
    p.update({k.replace("__", "."): v for k, v in params.items()})
    return Observer(mech, ObserverConfig.from_parameters(p))


# ---------------------------------------------------------------------------- configuration
def test_config_file_equals_defaults() -> None:
    # config/observer.yaml documents exactly the defaults the node declares.
    assert load_config(CONFIG / "observer.yaml").parameters == ObserverConfig.from_parameters().parameters


@pytest.mark.parametrize(("params", "message"), [
    ({"observer.sensors": ["encoders", "sonar"]}, "unknown sensor 'sonar'"),
    ({"observer.process.dt": "fast"}, "observer.process.dt: expected a number"),
    ({"observer.process.dt": 2e-3}, "exceeds process.max_interval"),
    ({"observer.no_such": 1}, "unknown observer parameter observer.no_such"),
    ({"observer.imu.axes": ["x", "w"]}, "observer.imu.axes"),
    ({"observer.gating.probability": 1.5}, "gating.probability"),
])
def test_config_errors_name_the_parameter(params, message) -> None:
    with pytest.raises(InputError, match=message):
        ObserverConfig.from_parameters(params, "test.yaml")


def test_unknown_joint_and_noise_length_rejected(five_bar) -> None:
    with pytest.raises(InputError, match="unknown joint 'left_wrist'"):
        make(five_bar, encoders__position_joints=["left_wrist"])
    with pytest.raises(InputError, match="3 values for 2 entries"):
        make(five_bar, encoders__position_stddev=[1e-5, 1e-5, 1e-5])


def test_load_config_from_a_node_section(tmp_path) -> None:
    f = tmp_path / "plant.yaml"
    f.write_text("plant:\n  ros__parameters:\n    dt: 1.0e-4\n    observer:\n      sensors: [encoders]\n"
                 "      imu:\n        stddev: [0.05]\n")
    cfg = load_config(f, node="plant")
    assert cfg.sensors == ["encoders"] and cfg.imu.stddev == [0.05]


# ---------------------------------------------------------------------------- discretisation
def test_van_loan_discretization_matches_scipy() -> None:
    rng = np.random.default_rng(3)
    n = 7
    # A stiff, badly scaled oscillator pair plus integrators, like the observer's model.
    A = np.zeros((n, n))
    A[0, 1] = 1.0
    A[1, 0], A[1, 1] = -1.2e7, -130.0
    A[2, 3] = 1.0
    A[3, 2], A[3, 4] = -3e5, 14.0
    A[4, 5] = 1.0
    A[5, 4], A[5, 5] = -1e5, -440.0
    A[6, 6] = -50.0
    A += 1e-3 * rng.standard_normal((n, n)) * (np.abs(A) > 0)
    G = rng.standard_normal((n, n)) * np.array([1e-9, 1e-3, 1e-6, 1e-2, 1e-3, 1.0, 1e-2])[:, None]
    Qc = G @ G.T
    T = 1e-3
    Phi, Qd = np.empty((n, n)), np.empty((n, n))
    kernels.discretize(A, Qc, T, Phi, Qd)
    M = np.block([[-A, Qc], [np.zeros((n, n)), A.T]]) * T
    E = scipy.linalg.expm(M)
    Phi_ref = scipy.linalg.expm(A * T)
    Q_ref = E[n:, n:].T @ E[:n, n:]
    s = np.sqrt(np.diag(Q_ref))
    assert np.allclose(Phi, Phi_ref, rtol=1e-9, atol=1e-12 * np.abs(Phi_ref).max())
    assert np.max(np.abs((Qd - Q_ref) / np.outer(s, s))) < 1e-8


def test_transition_matches_the_nonlinear_map(five_bar) -> None:
    """Phi of the linearisation equals central differences of the exact 1-ms prediction."""
    mech = five_bar
    q = initial_state(mech)
    q[mech.active] += [0.05, -0.04]
    q[mech.elastic] += [2e-7, -1e-7]
    qd = np.zeros(mech.n)
    qd[mech.ae] = [1.0, -0.7, 1e-3, -2e-3]
    sim_kernels.partition(mech.arrays, q, qd, 1e-14, 6)
    obs = make(mech, sensors=["encoders", "imu"])
    obs.reset(0.0, q, qd)
    obs.z[:] = 0.01
    tau = mech.split_tau(np.array([0.4, -0.3]))

    def step(x):
        qq, vv = q.copy(), qd.copy()
        qq[mech.ae], vv[mech.ae] = x[:4], x[4:8]
        sim_kernels.partition(mech.arrays, qq, vv, 1e-14, 6)
        z = x[8:].copy()
        P, Phi, Qd, H = np.eye(obs.nx), np.empty((obs.nx, obs.nx)), np.empty((obs.nx, obs.nx)), np.empty((3, obs.nx))
        status = kernels.predict(mech.arrays, obs.model.fixed, obs._proc, (qq, vv, z, P, Phi, Qd, H, np.zeros(2)),
                                 tau, True, 1e-3, 10)
        assert status == 0
        return np.concatenate([qq[mech.ae], vv[mech.ae], z]), Phi

    x0 = obs.x()
    _, Phi = step(x0)
    scale = np.array([1e-6] * 2 + [1e-9] * 2 + [1e-4] * 2 + [1e-6] * 2 + [1e-3] * (obs.nx - 8))
    fd = np.empty_like(Phi)
    for j in range(obs.nx):
        e = np.zeros(obs.nx)
        e[j] = scale[j]
        fd[:, j] = (step(x0 + e)[0] - step(x0 - e)[0]) / (2 * scale[j])
    S = np.diag(1 / scale)
    err = S @ (Phi - fd) @ np.linalg.inv(S)
    assert np.abs(err).max() < 1e-3 * np.abs(S @ fd @ np.linalg.inv(S)).max()


# ---------------------------------------------------------------------------- correction
def test_kalman_update_matches_textbook_and_gates() -> None:
    rng = np.random.default_rng(1)
    n, m = 6, 3
    L = rng.standard_normal((n, n))
    P0 = L @ L.T + n * np.eye(n)
    H = rng.standard_normal((m, n))
    R = np.array([0.5, 1.0, 2.0])
    r = rng.standard_normal(m)
    P = P0.copy()
    dx = np.zeros(n)
    nis = correction.kalman_update(P, H, R, r, 1e9, dx)
    S = H @ P0 @ H.T + np.diag(R)
    K = P0 @ H.T @ np.linalg.inv(S)
    assert nis == pytest.approx(r @ np.linalg.solve(S, r), rel=1e-12)
    assert np.allclose(dx, K @ r, rtol=1e-10)
    assert np.allclose(P, (np.eye(n) - K @ H) @ P0, rtol=1e-9, atol=1e-12)
    # A gated sample leaves everything unchanged.
    P = P0.copy()
    dx[:] = 0.0
    nis = correction.kalman_update(P, H, R, 100 * r, 1.0, dx)
    assert nis > 1.0 and np.all(dx == 0.0) and np.all(P == P0)
    assert kernels.covariance_ok(P0) and not kernels.covariance_ok(P0 - 100 * np.eye(n))



@pytest.mark.parametrize("n", [1, 6, 18, 33, 66])
def test_covariance_check_agrees_with_eigenvalues(n: int) -> None:
    # The check factors with reassociated (vectorised) sums: its yes/no must still be the
    # eigenvalues' on well-posed matrices, on barely definite and barely indefinite ones,
    # with NaN, Inf and wildly different scales (the observer's positions vs its rates).
    rng = np.random.default_rng(8100 + n)
    for trial in range(40):
        Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
        lam = rng.uniform(0.1, 10.0, n)
        if trial % 4 == 1:
            lam[rng.integers(n)] = -1e-6  # one eigenvalue just below zero
        elif trial % 4 == 2:
            lam[rng.integers(n)] = 1e-6  # one just above (1e-14 is the floor of the correlation's pivots)
        scale = 10.0 ** rng.uniform(-8, 2, n)
        P = (Q * lam) @ Q.T * np.outer(scale, scale)
        P = 0.5 * (P + P.T)
        expected = bool(np.all(lam > 0.0))
        assert kernels.covariance_ok(P) == expected, (trial, lam.min())
        if trial % 4 == 3:
            i, j = rng.integers(n, size=2)
            for bad in (np.nan, np.inf):
                B = P.copy()
                B[i, j] = B[j, i] = bad
                assert not kernels.covariance_ok(B)


# ---------------------------------------------------------------------------- observability
def test_observability_report_per_sensor_set(five_bar) -> None:
    enc = analyse(make(five_bar, sensors=["encoders"]))
    imu = analyse(make(five_bar, sensors=["encoders", "imu"]))
    gauges = analyse(make(five_bar, sensors=["encoders", "branch_forces"], branch_forces__stddev=[0.05]))
    i = enc.state_names.index("left_spring")
    # The spring is radial to the motor: encoders barely see it; an accelerometer or gauges do.
    assert enc.ratio[i] > 0.5
    assert imu.classes[i] == "observable" and gauges.classes[i] == "observable"
    assert enc.classes[enc.state_names.index("left_motor")] == "observable"
    assert imu.steady_branch_std is not None and np.all(imu.steady_branch_std < 0.05)
    text = imu.text()
    assert "left_spring" in text and "steady-state branch-force std" in text
    # An accelerometer alone cannot see a constant motor offset: no steady-state filter.
    acc = analyse(make(five_bar, sensors=["imu"]))
    assert acc.steady_std is None and "not detectable" in acc.note
    assert acc.classes[acc.state_names.index("left_motor")] == "not observable"


# ---------------------------------------------------------------------------- start at static equilibrium
def _potential_with_motors_clamped(mech, q, elastic_offsets) -> float:
    from elastic_pm_dyn.kinematics.assembly import solve_pose
    qq = q.copy()
    qq[mech.elastic] += elastic_offsets
    qq = solve_pose(mech, qq, mech.passive)
    return mech.energy(qq, np.zeros(mech.n))[1]


def test_start_from_encoders_puts_the_springs_in_static_equilibrium(five_bar_vertical) -> None:
    # Under gravity the springs of a machine at rest carry its weight: the observer starts there
    # (with the motors where the encoders say), not at the unloaded springs' rest length.
    mech = five_bar_vertical
    q0 = initial_state(mech)
    obs = Observer(mech, ObserverConfig.from_parameters({"sensors": ["encoders"]}))
    assert obs.update_joint_states(0.0, mech.active_names, q0[mech.active])[0].reason == "initialised"
    q = obs.q
    assert np.allclose(q[mech.active], q0[mech.active], atol=0.0)
    # Equilibrium = stationary potential (gravity + springs) along the elastic coordinates, the
    # motors clamped: its slope there is round-off against the slope at the unloaded springs.
    h = 1e-9
    def slopes(at):
        return [(_potential_with_motors_clamped(mech, at, h * e) - _potential_with_motors_clamped(mech, at, -h * e))
                / (2 * h) for e in np.eye(len(mech.elastic))]
    slope, slope_rest = slopes(q), slopes(q0)
    assert np.max(np.abs(slope)) < 1e-3 * np.max(np.abs(slope_rest)), (slope, slope_rest)
    F = obs.estimate().branch_force
    assert np.abs(F).max() > 0.4  # the weight's share, not zero


def test_measurement_noise_changes_in_a_running_filter(five_bar) -> None:
    """set_measurement_noise: a noisier encoder pulls the estimate less (the Kalman gain
    R-weighted, as for a filter built with that noise), the state stays; other settings refused."""
    names = list(five_bar.joint_names)
    q0 = initial_state(five_bar)
    meas = q0.copy()
    meas[five_bar.active] += 1e-4  # one sample 1e-4 rad off the start

    def pulled(stddev: float, runtime: bool) -> float:
        obs = make(five_bar) if runtime else make(five_bar, encoders__position_stddev=[stddev])
        if runtime:
            obs.set_measurement_noise(obs.cfg.with_overrides(encoders__position_stddev=[stddev]))
        obs.update_joint_states(0.0, names, meas)
        return float(np.max(np.abs(obs.q[five_bar.active] - q0[five_bar.active])))

    for stddev in (2e-5, 1e-3):
        assert pulled(stddev, runtime=True) == pytest.approx(pulled(stddev, runtime=False), rel=1e-12)
    assert pulled(1e-3, runtime=True) < 0.5 * pulled(2e-5, runtime=True)
    obs = make(five_bar)
    with pytest.raises(InputError, match="only the noise levels and the gate"):
        obs.set_measurement_noise(obs.cfg.with_overrides(process__max_interval=2e-3))
