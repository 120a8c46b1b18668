"""Bad input: NaN, outliers, late and missing samples, divergence, reset; message order."""

from __future__ import annotations

import numpy as np
import pytest

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.drivers.stream import ObserverStream
from elastic_pm_dyn.observer.schedule.sensor_stats import ERROR, OK
from elastic_pm_dyn.observer.testing.evaluation import feed
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

SENSORS = ("encoders", "imu", "branch_forces")


def make(mech, **params) -> Observer:
    p = {"sensors": list(SENSORS)}
    p.update({k.replace("__", "."): v for k, v in params.items()})
    return Observer(mech, ObserverConfig.from_parameters(p))


@pytest.fixture(scope="module")
def rec(five_bar):
    return manoeuvre_recording(five_bar, duration=0.15, seed=5)


@pytest.fixture(scope="module")
def clean(five_bar, rec):
    return feed(make(five_bar), rec, SENSORS)


def test_outliers_and_nan_are_gated_and_reported(five_bar, rec, clean) -> None:
    k_jump, k_nan, k_acc, k_bf = 60, 70, 80, 90
    bad = {k_jump: {"encoder": rec.encoder[k_jump] + [0.5, 0.0]},  # a 0.5 rad glitch
           k_nan: {"encoder": [np.nan, rec.encoder[k_nan][1]]},  # one NaN entry: the other is used
           k_acc: {"accel": rec.accel[k_acc] + [50.0, 0.0, 0.0]},
           k_bf: {"branch": [np.nan, np.nan]}}
    obs = make(five_bar)
    run = feed(obs, rec, SENSORS, corrupt=bad)
    st = obs.stats
    # Exactly the injected glitches on top of what the clean run gated (its NIS tail).
    assert st["encoders"].rejected == clean.rejected["encoders"] + 1
    assert st["imu"].rejected == clean.rejected["imu"] + 1
    assert st["encoders"].nan == 1 and st["branch_forces"].nan == 2
    assert "NaN" in st["branch_forces"].last_reason or "gated" in st["encoders"].last_reason
    # The estimate hardly notices: the glitch was never applied.
    assert np.abs(run.q - clean.q).max() < 2e-5
    assert np.abs(run.F - clean.F).max() < 0.05
    assert obs.health()[0] != ERROR
    diag = obs.diagnostics()
    assert diag["encoders.rejected"] == str(clean.rejected["encoders"] + 1) and "imu.nis_mean" in diag


def test_late_and_missing_samples(five_bar, rec, clean) -> None:
    obs = make(five_bar)
    stream = ObserverStream(obs)
    names = rec.active_names
    skipped = set(range(40, 46))  # 5 ms without any sample: prediction only
    for k, ns in enumerate(rec.stamp_ns):
        if k not in skipped:
            stream.on_joint_state(int(ns), names, rec.encoder[k])
            stream.on_imu(int(ns), rec.accel[k])
            stream.on_branch_forces(int(ns), rec.branch_names, rec.branch[k])
        stream.on_torque_command(int(ns), names, rec.tau_cmd[k])
        if k == 100:  # a sample from 3 ms ago arrives now: dropped, counted
            r = stream.on_joint_state(int(rec.stamp_ns[97]), names, rec.encoder[97])
            assert not r[0].accepted and r[0].reason == "late"
    e = obs.estimate()
    assert obs.stats["encoders"].late == 1
    assert np.abs(e.q[five_bar.active] - rec.q[-1, five_bar.active]).max() < 3e-5
    assert np.abs(e.q - clean.q[-1]).max() < 3e-5


def feed_in_order(obs: Observer, rec, command_first: bool, n: int | None = None) -> Observer:
    """The first ``n`` stamps of ``rec`` (encoders, accelerometer, command) into ``obs`` through
    an ObserverStream, the command of t_k before or after the samples of t_k."""
    stream = ObserverStream(obs)
    names = rec.active_names
    for k, ns in enumerate(rec.stamp_ns[:n]):
        ns = int(ns)
        if command_first:
            stream.on_torque_command(ns, names, rec.tau_cmd[k])
        stream.on_joint_state(ns, names, rec.encoder[k])
        stream.on_imu(ns, rec.accel[k])
        if not command_first:
            stream.on_torque_command(ns, names, rec.tau_cmd[k])
    return obs


def test_command_and_samples_at_one_stamp_commute(five_bar, rec) -> None:
    """A live node gets the command of t_k before or after the samples of t_k: same estimates."""
    runs = [feed_in_order(make(five_bar), rec, command_first, 60).estimate() for command_first in (False, True)]
    assert np.array_equal(runs[0].x, runs[1].x) and np.array_equal(runs[0].P, runs[1].P)


def test_divergence_is_reported_and_reset_recovers(five_bar, rec) -> None:
    obs = make(five_bar, sensors=["encoders"], gating__max_consecutive_rejections=10, gating__recover_after=0)
    stream = ObserverStream(obs)
    names = rec.active_names
    for k in range(40):
        stream.on_joint_state(int(rec.stamp_ns[k]), names, rec.encoder[k])
        stream.on_torque_command(int(rec.stamp_ns[k]), names, rec.tau_cmd[k])
    assert obs.health()[0] == OK or obs.health()[0] == 1
    # The encoders now say something the model cannot explain (e.g. the robot was pushed).
    for k in range(40, 60):
        stream.on_joint_state(int(rec.stamp_ns[k]), names, rec.encoder[k] + 0.2)
        stream.on_torque_command(int(rec.stamp_ns[k]), names, rec.tau_cmd[k])
    level, message = obs.health()
    assert level == ERROR and "diverged" in message
    # Reset at the measured pose (moving: rates unknown): tracking again.
    k = 60
    assert obs.initialise_from_joint_state(rec.t[k], names, rec.encoder[k] + 0.2, velocity_stddev=1.0)
    for k in range(60, 80):
        r = stream.on_joint_state(int(rec.stamp_ns[k]), names, rec.encoder[k] + 0.2)
        stream.on_torque_command(int(rec.stamp_ns[k]), names, rec.tau_cmd[k])
        assert r[0].accepted
    assert obs.health()[0] != ERROR


def test_bad_commands_and_states_are_refused(five_bar) -> None:
    obs = make(five_bar)
    stream = ObserverStream(obs)
    assert not stream.on_torque_command(0, ["left_motor"], [0.1])  # right motor missing
    assert stream.bad_commands == 1 and "right_motor" in stream.last_error
    with pytest.raises(InputError):
        obs.command(0.0, [np.nan, 0.0])
    with pytest.raises(InputError, match="6 tree coordinates"):
        obs.reset(0.0, np.zeros(3))
    # Float64MultiArray form: the model's active order.
    assert stream.on_torque_command(1_000_000, [], [0.1, -0.1])
    assert np.allclose(obs.tau_hold, [0.1, -0.1])


def test_filter_fault_is_loud(five_bar, rec) -> None:
    """A state the model cannot integrate (here: NaN forced in) raises and stays faulted until reset."""
    from elastic_pm_dyn.observer.core.ekf import ObserverFault
    obs = make(five_bar, initial__source="model")
    obs.qd[0] = np.nan
    with pytest.raises(ObserverFault):
        obs.predict(np.zeros(2), 1e-3)
    assert obs.health()[0] == ERROR
    with pytest.raises(ObserverFault):
        obs.command(2e-3, np.zeros(2))
    obs.reset(2e-3)
    obs.predict(np.zeros(2), 3e-3)
    assert obs.health()[0] != ERROR
