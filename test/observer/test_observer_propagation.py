"""The observer's structured prediction against the dense computations it replaces and a fine integrator.

- ``linearize_springs`` (gains for Bf and Ef, the springs for the elastic position columns)
  against ``linearize`` (every column a one-sided difference of full evaluations);
- ``discretize_structured`` (mechanical block, thin coupling, cached z block, Simpson for the
  noise z picks up within the interval) against the dense Van Loan of the whole state;
- the ETD2 mean over one interval at the observer's automatic step against RK4 at 1/400 of
  the interval, in the unit that matters to the filter: the accelerometer's prediction
  against its noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.dynamics.evaluate import SCDD
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.core import kernels as K
from elastic_pm_dyn.observer.core.propagation import discretize_structured
from elastic_pm_dyn.observer.testing.scenarios import chirp_recording, manoeuvre_recording
from elastic_pm_dyn.sim.exponential import AVERAGED, DEFAULT_PHASE_STEP, exponential_steps
from elastic_pm_dyn.sim.kernels import STAB_PROJECTION, partition, rk4_steps

CONFIG = Path(__file__).resolve().parents[1].parent / "config"
ACCEL_NOISE = 0.02  # [m/s^2] the observer's default accelerometer noise


@pytest.fixture(scope="module")
def machines(five_bar) -> dict[str, Mechanism]:
    return {"five_bar": five_bar,
            "triglide:2": Mechanism(load_model(CONFIG / "triglide.yaml", elastic_dof_per_chain=2)),
            "hexa:2": Mechanism(load_model(CONFIG / "hexa.yaml", elastic_dof_per_chain=2))}


def _moving_state(mech: Mechanism):
    """A state in motion: the five-bar mid-manoeuvre (1 m/s, 20 m/s^2), a spatial machine 40 ms into a chirp."""
    if mech.n == 6:
        rec = manoeuvre_recording(mech, duration=0.12)
        k = 100
    else:
        m = 3.34 if len(mech.active) == 3 else 0.0493
        rec = chirp_recording(mech, duration=0.05, amplitude=0.375 * m, kp=500.0 * m, kd=0.0, truth_dt=2.5e-5)
        k = 40
    tau = np.zeros(mech.n)
    tau[mech.active] = rec.tau_cmd[k]
    return rec.q[k].copy(), rec.qd[k].copy(), tau


def _linearization(mech, obs, q, qd, tau, springs: bool):
    nae, n, f = obs.nae, mech.n, obs.model.fixed
    out = [np.empty((nae, nae)) for _ in range(3)] + [np.empty((3, nae)) for _ in range(3)]
    qdd0, a0 = np.empty(n), np.empty(3)
    if springs:
        K.linearize_springs(mech.arrays, q, qd, tau, f[2], True, f[0], f[1], *out, qdd0, a0,
                            K.linearization_workspace(mech.arrays))
    else:
        K.linearize(mech.arrays, q, qd, tau, f[2], True, f[0], f[1], *out, qdd0, a0)
    return out


@pytest.mark.parametrize("name", ["five_bar", "triglide:2", "hexa:2"])
def test_the_springs_linearisation_equals_differences_of_the_full_model(machines, name) -> None:
    mech = machines[name]
    obs = Observer(mech, ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]}))
    q, qd, tau = _moving_state(mech)
    Aq, Av, Bf, _, Ev, Ef = _linearization(mech, obs, q, qd, tau, springs=False)
    Aq2, Av2, Bf2, Eq2, Ev2, Ef2 = _linearization(mech, obs, q, qd, tau, springs=True)
    # unit forces enter linearly: one factorisation gives the differences' columns to round-off
    np.testing.assert_allclose(Bf2, Bf, rtol=0, atol=1e-9 * np.abs(Bf).max())
    np.testing.assert_allclose(Ef2, Ef, rtol=0, atol=1e-9 * np.abs(Ef).max())
    # A spring column leaves out only the geometric change of a deflection. The reference: central
    # differences of the full model over 0.1 um, the closure solved to round-off (the filter's own
    # one-sided differences close it to 1e-10 m only, as noisy as the effect on the stiff rods).
    dyn = Dynamics(mech, "scdd")
    chain = int(mech.model.end_effector_chain)
    W, _ = mech.passive_map(mech.terms(q, qd))
    ae = list(mech.ae)

    def accelerations(qq):
        qq, vv = qq.copy(), qd.copy()
        partition(mech.arrays, qq, vv, 1e-15, 8)
        qdd = dyn.accelerations(qq, vv, tau[mech.active])
        t = mech.terms(qq, vv)
        return qdd[ae], t.J[chain] @ qdd + t.a_tip[chain]

    e = 1e-7
    for j, jt in enumerate(ae):
        if jt not in set(mech.elastic):
            continue
        (qdd_p, a_p), (qdd_m, a_m) = accelerations(q + W[:, j] * e), accelerations(q - W[:, j] * e)
        for got, ref in ((Aq2[:, j], (qdd_p - qdd_m) / (2 * e)), (Eq2[:, j], (a_p - a_m) / (2 * e))):
            # the geometric term, O(|qdd| / l) against c / m: 2.3e-4 of the column on the Triglide
            # 40 ms into a chirp, 1e-5 on the five-bar mid-manoeuvre
            assert np.abs(got - ref).max() <= 1e-3 * np.abs(ref).max(), (name, j, got, ref)
    # rates: the same one-sided differences, here from the velocity terms and the reduced
    # inertia at the fixed pose, there from two full evaluations: equal to the round-off of a
    # difference over eps_v (the full evaluations' cancel tau and gravity; these do not)
    for got, ref in ((Av2, Av), (Ev2, Ev)):
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-7 * np.abs(ref).max())
        assert np.abs(ref).max() > 0
    elastic = [i for i, j in enumerate(mech.ae) if j in set(mech.elastic)]
    assert elastic and np.all(np.abs(Aq[:, elastic]).max(axis=0) > 0)  # the columns compared are not empty


@pytest.mark.parametrize("name", ["five_bar", "triglide:2", "hexa:2"])
def test_the_structured_discretisation_equals_the_dense_van_loan(machines, name) -> None:
    mech = machines[name]
    obs = Observer(mech, ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]}))
    q, qd, tau = _moving_state(mech)
    Aq, Av, Bf, *_ = _linearization(mech, obs, q, qd, tau, springs=True)
    _, dist_col, Lz, Fz, psd_ae, _, psd_z = obs._proc[:7]
    nx, nae, nz, T = obs.nx, obs.nae, obs.nz, 1e-3
    Ac, Qc = np.empty((nx, nx)), np.empty((nx, nx))
    K.continuous_model(Aq, Av, Bf, dist_col, Lz, Fz, psd_ae, psd_z, Ac, Qc)
    Phi, Qd = np.empty((nx, nx)), np.empty((nx, nx))
    K.discretize(Ac, Qc, T, Phi, Qd)
    zkey, Phi_z, Qd_z = np.full(1 + nz, np.nan), np.empty((4, nz, nz)), np.empty((nz, nz))
    K.z_block(Fz, psd_z, T, zkey, Phi_z, Qd_z)
    Phi2, Qd2 = np.empty((nx, nx)), np.empty((nx, nx))
    discretize_structured(Aq, Av, Bf, dist_col, Lz, Fz, psd_ae, psd_z, T, Phi_z, Qd_z, Phi2, Qd2)
    m = 2 * nae
    assert np.abs(Phi2[:m, :m] - Phi[:m, :m]).max() <= 1e-11 * np.abs(Phi[:m, :m]).max()
    assert np.abs(Phi2[:m, m:] - Phi[:m, m:]).max() <= 1e-5 * np.abs(Phi[:m, m:]).max()
    np.testing.assert_array_equal(Phi2[m:, :m], 0.0)
    assert np.abs(Phi2[m:, m:] - Phi[m:, m:]).max() <= 1e-12 * np.abs(Phi[m:, m:]).max()
    sd = np.sqrt(np.diag(Qd))
    rel = np.abs(Qd2 - Qd) / np.outer(sd, sd)
    assert rel.max() <= 0.03, (name, np.unravel_index(rel.argmax(), rel.shape), rel.max())
    assert np.all(np.linalg.eigvalsh(Qd2) > -1e-12 * np.abs(Qd2).max())


@pytest.mark.parametrize("name", ["five_bar", "triglide:2", "hexa:2"])
def test_the_etd2_mean_predicts_the_accelerometer_within_a_tenth_of_its_noise(machines, name) -> None:
    mech = machines[name]
    obs = Observer(mech, ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]}))
    h = obs.dt
    steps = round(1e-3 / h)
    assert 2 <= steps <= 8  # from the model's fastest spring (observer_model.etd2_step)
    q0, qd0, tau = _moving_state(mech)
    ma, n = mech.arrays, mech.n
    coef = np.zeros((3, n))
    coef[0] = tau
    dyn = Dynamics(mech, "scdd")
    chain = int(mech.model.end_effector_chain)

    def after(step) -> np.ndarray:
        q, qd = q0.copy(), qd0.copy()
        assert step(q, qd) == 0
        partition(ma, q, qd, 1e-14, 4)
        t = mech.terms(q, qd)
        return t.J[chain] @ dyn.accelerations(q, qd, tau[mech.active]) + t.a_tip[chain]

    fine = after(lambda q, qd: rk4_steps(SCDD, ma, q, qd, coef, 1e-3 / 400, 400, 0, 0.0, 0.0, 1e-14, 1e-8,
                                         np.zeros(n), np.empty(mech.m), np.zeros(3)))
    etd2 = after(lambda q, qd: exponential_steps(AVERAGED, SCDD, ma, q, qd, coef, h, steps, STAB_PROJECTION, 0.0, 0.0,
                                                 1e-14, 1e-8, DEFAULT_PHASE_STEP, np.zeros(n), np.empty(mech.m),
                                                 np.zeros(3)))
    assert np.abs(etd2 - fine).max() < 0.1 * ACCEL_NOISE, (name, etd2 - fine)
