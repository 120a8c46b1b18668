"""The independent test recordings (observer/testing/recordings.py): their physics and their bags."""

from __future__ import annotations

import numpy as np
import pytest

from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.dynamics.direct import Dynamics
from elastic_pm_dyn.observer.config import ObserverConfig
from elastic_pm_dyn.observer.drivers.bag_input import Topics, read_events
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.testing.evaluation import offline_run, score
from elastic_pm_dyn.observer.testing.recordings import (
    EPOCH,
    RECEIVE_DELAY_NS,
    RECEIVE_JITTER_NS,
    RecordingSpec,
    generate,
    write_bag,
)
from elastic_pm_dyn.observer.testing.scenarios import PERIOD
from elastic_pm_dyn.sim.disturbances import BANDS, SPECTRA, SpectrumDisturbance


@pytest.fixture
def mech(five_bar):
    return five_bar


def _specific_force(mech, q, qd, tau):
    """The end effector's specific force (world axes) at (q, qd) under the motor torques tau."""
    qdd = Dynamics(mech, "scdd").accelerations(q, qd, tau)
    t = mech.terms(q, qd)
    chain = int(mech.model.end_effector_chain)
    return t.J[chain] @ qdd + t.a_tip[chain] - np.asarray(mech.model.gravity, dtype=float)


def test_truth_is_converged(mech):
    """RK4 at 25 us against 12.5 us and against DOP853 (rtol 1e-10): differences far below the noise."""
    spec = RecordingSpec(duration=0.1, disturbance_rms=0.1, seed=3)
    a, b = generate(mech, spec), generate(mech, spec.with_(truth_dt=1.25e-5))
    c = generate(mech, spec.with_(integrator="dop853"))
    n, act = spec.noise, mech.active
    for other in (b, c):
        assert np.abs(a.q[:, act] - other.q[:, act]).max() < 1e-3 * n.encoder
        assert np.abs(a.F - other.F).max() < 1e-3 * n.branch_force
        assert np.abs(a.accel_true - other.accel_true).max() < 1e-2 * n.accelerometer
    # the noise draws do not depend on the integrator
    np.testing.assert_allclose(a.encoder - a.q[:, act], c.encoder - c.q[:, act], atol=1e-12)


def test_after_command_sample_is_taken_under_the_new_command(mech):
    spec = RecordingSpec(duration=0.3, disturbance_rms=0.05, seed=4)
    before, after = generate(mech, spec), generate(mech, spec.with_(accel_timing="after_command"))
    np.testing.assert_array_equal(before.q, after.q)  # the timing changes the sample only
    tau = after.acting
    jumps = 0
    for k in range(1, len(after.t)):
        q, qd, d = after.q[k], after.qd[k], after.disturbance[k]
        new = _specific_force(mech, q, qd, tau[k] + d)
        np.testing.assert_allclose(after.accel_true[k], new, atol=1e-9)
        np.testing.assert_allclose(before.accel_true[k], _specific_force(mech, q, qd, tau[k - 1] + d), atol=1e-9)
        jump = after.accel_true[k] - before.accel_true[k]
        if np.array_equal(tau[k], tau[k - 1]):
            np.testing.assert_allclose(jump, 0.0, atol=1e-9)
        else:
            jumps += np.abs(jump).max() > 1e-6
    assert jumps > 100  # the manoeuvre's command changes every period while it moves
    np.testing.assert_allclose(after.accel - after.accel_true, before.accel - before.accel_true, atol=1e-14)


def test_command_delay_shifts_the_response_by_one_period(mech):
    spec = RecordingSpec(duration=0.25, disturbance_rms=0.0, seed=5)
    now, late = generate(mech, spec), generate(mech, spec.with_(command_delay=1))
    np.testing.assert_array_equal(now.tau_cmd, late.tau_cmd)  # the same commands, stamped alike
    np.testing.assert_array_equal(late.acting[1:], now.tau_cmd[:-1])
    np.testing.assert_array_equal(late.acting[0], 0.0)
    np.testing.assert_allclose(late.q[1:], now.q[:-1], atol=1e-12)
    np.testing.assert_allclose(late.F[1:], now.F[:-1], atol=1e-9)
    assert np.abs(late.q[1:] - now.q[1:]).max() > spec.noise.encoder  # the shift is far from negligible


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_epoch_stamps_round_trip_exactly(mech, tmp_path, storage):
    spec = RecordingSpec(duration=0.05, t0=EPOCH, seed=6)
    rec = generate(mech, spec)
    assert rec.stamp_ns[0] == 1_700_000_000 * 10**9 and np.all(np.diff(rec.stamp_ns) == 1_000_000)
    bag = write_bag(rec, tmp_path / "bag", storage)
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu", "branch_forces"]})
    events, counts = read_events(bag, Topics(), cfg)
    assert counts == {"command": len(rec.t), "joint_state": len(rec.t), "imu": len(rec.t),
                      "branch_forces": len(rec.t)}
    for kind in counts:
        stamps = np.array([e.stamp_ns for e in events if e.kind == kind], dtype=np.int64)
        np.testing.assert_array_equal(np.sort(stamps), rec.stamp_ns)
    with open_bag(bag) as reader:
        for _conn, t_recv, _raw in reader.messages(reader.connections):
            stamp = rec.stamp_ns[np.searchsorted(rec.stamp_ns, t_recv, side="right") - 1]
            assert 0 < t_recv - stamp < max(RECEIVE_DELAY_NS.values()) + RECEIVE_JITTER_NS < PERIOD * 1e9
    cmd = [e for e in events if e.kind == "command"]
    np.testing.assert_array_equal(np.array([e.data[1] for e in cmd]), rec.tau_cmd)


@pytest.mark.parametrize("spectrum", SPECTRA)
def test_spectra_have_the_asked_rms_and_band(spectrum):
    rms, duration, channels = 0.07, 2.0, 2
    d = SpectrumDisturbance(spectrum, channels, rms, duration, np.random.default_rng(9))
    t = np.arange(0.0, duration + 1e-12, 1e-4)
    x = np.array([d(s) for s in t])
    np.testing.assert_allclose(np.sqrt(np.mean(x ** 2, axis=0)), rms, rtol=1e-9)
    lo, hi = BANDS[spectrum]
    assert np.all((d.f >= lo) & (d.f <= hi))
    if spectrum == "drift":
        assert np.abs(x[0]).max() < 1e-12  # starts from zero
        return
    steady = x[t >= d.fade]
    f = np.fft.rfftfreq(len(steady), 1e-4)
    power = np.abs(np.fft.rfft(steady, axis=0)) ** 2
    df = 1.0 / (len(steady) * 1e-4)
    inside = (f >= lo - 3 * df) & (f <= hi + 3 * df)
    assert np.all(power[inside].sum(axis=0) / power.sum(axis=0) > 0.98)
    if spectrum in ("flat", "pink"):
        low, high = (f >= lo) & (f < 20.0), (f >= 20.0) & (f <= hi)
        ratio = power[high].sum(axis=0) / power[low].sum(axis=0)
        # flat: power grows with the bandwidth (180 / 18 Hz); 1/f: equal power per decade
        expect = 10.0 if spectrum == "flat" else 1.0
        assert np.all((ratio > 0.6 * expect) & (ratio < 1.6 * expect))


def test_observe_runs_on_a_generated_bag_and_is_scored_by_stamp(mech, tmp_path):
    rec = generate(mech, RecordingSpec(duration=0.1, disturbance_rms=0.02, t0=EPOCH, seed=8))
    bag = write_bag(rec, tmp_path / "bag", "sqlite3")
    res = observe_bag(mech, ObserverConfig.from_parameters({"sensors": ["encoders"]}), bag, log=lambda s: None)
    run = offline_run(rec, res.rows)
    assert len(run.q) == len(rec.t)
    s = score(rec, run, settle=0.02)
    assert s["motor_rmse_over_noise"] < 3.0


def test_the_applied_torque_replaces_late_commands(mech, tmp_path):
    """A realtime plant applies a command that comes late from its next period on, and says what it
    applied on /applied_torque. Offline observe takes that as the torque input: a bag whose commands
    are three periods late and wrong gives the estimates of a bag with the right commands, exactly."""
    rec = generate(mech, RecordingSpec(duration=0.05, disturbance_rms=0.02, t0=EPOCH, seed=11))
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
    right = write_bag(rec, tmp_path / "right", "mcap")
    late = np.vstack([np.zeros((3, rec.tau_cmd.shape[1])), rec.tau_cmd[:-3]])
    from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag
    stamps = np.asarray(rec.stamp_ns, dtype=np.int64)
    recording_to_bag(rec, tmp_path / "applied", ("encoders", "imu"), commands=late, applied=True,
                     receive_ns={"command": stamps + 3 * 1_000_000})
    a = observe_bag(mech, cfg, right, log=lambda s: None)
    b = observe_bag(mech, cfg, tmp_path / "applied", log=lambda s: None)
    assert len(a.rows.table()) == len(b.rows.table()) == len(rec.t)
    np.testing.assert_array_equal(a.rows.table(), b.rows.table())
    wrong = tmp_path / "late_only"
    recording_to_bag(rec, wrong, ("encoders", "imu"), commands=late, receive_ns={"command": stamps + 3 * 1_000_000})
    c = observe_bag(mech, cfg, wrong, log=lambda s: None)
    assert not np.array_equal(a.rows.table(), c.rows.table())  # the test can fail: late commands differ
