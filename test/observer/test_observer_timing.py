"""The observer's timing: accelerometer sample timing (before/after the command, or learnt) and command delay.

Recordings (``observer.testing.scenarios``, the reference manoeuvre with its 2-200 Hz unknown torque)
are made with the accelerometer sampled just before the command of t_k acts (a(t_k-)) or
just after (a(t_k+)), and with commands acting one period after their stamp. A filter whose
timing does not match diverges (the encoders end up gated out); the matching one, and
``auto``, track. The offline fast path stays bit for bit the per-message API with every
new option.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_observer_fastpath import _events
from test_observer_robustness import feed_in_order

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.drivers.event_filter import run_events
from elastic_pm_dyn.observer.drivers.stream import ObserverStream
from elastic_pm_dyn.observer.schedule.sample_timing import TIMING_SWITCH_EVIDENCE
from elastic_pm_dyn.observer.testing.evaluation import feed, open_loop, score
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording
from elastic_pm_dyn.ros.observer.session import ObserverSession

USE = ("encoders", "imu")


def _run(mech, rec, **params):
    cfg = ObserverConfig.from_parameters({k.replace("__", "."): v for k, v in params.items()})
    obs = Observer(mech, cfg)
    return obs, score(rec, feed(obs, rec, USE), open_loop(rec), settle=0.05)


@pytest.fixture(scope="module")
def after_rec(five_bar):
    return manoeuvre_recording(five_bar, accel_timing="after_command")


@pytest.fixture(scope="module")
def before_rec(five_bar):
    return manoeuvre_recording(five_bar)


@pytest.fixture(scope="module")
def delayed_rec(five_bar):
    return manoeuvre_recording(five_bar, command_delay=1)


# ---------------------------------------------------------------------------- accuracy
@pytest.mark.parametrize("timing", ["after_command", "auto"])
def test_after_command_recording_tracked(five_bar, after_rec, timing) -> None:
    obs, s = _run(five_bar, after_rec, imu__sample_timing=timing)
    assert s["F_ratio"] <= 0.5 * s["F_ratio_open_loop"], s
    assert s["motor_rmse_rad"] < 2e-5, s
    assert s["rejected"]["encoders"] == 0 and s["rejected"]["imu"] <= 0.02 * len(after_rec.t), s
    assert obs.sample_timing() == "after_command"
    if timing == "auto":
        (d,) = obs.timing_decisions
        assert d.choice == "after_command" and not d.switched and d.loglik_after > d.loglik_before
        assert d.samples >= 90


def test_mismatched_sample_timing_diverges(five_bar, after_rec) -> None:
    # What the filter did before it knew the timing: a(t_k+) read as a(t_k-) (and without
    # the fall-back of gating.recover_after: test_observer_recovery has it)
    _, s = _run(five_bar, after_rec, imu__sample_timing="before_command", gating__recover_after=0)
    assert s["F_ratio"] > s["F_ratio_open_loop"], s
    assert s["rejected"]["encoders"] > 0.5 * len(after_rec.t), s


def test_auto_picks_before_command_on_before_command_recordings(five_bar, before_rec) -> None:
    obs, s = _run(five_bar, before_rec)  # the default: auto
    assert obs.cfg.imu.sample_timing == "auto"
    (d,) = obs.timing_decisions
    assert d.choice == "before_command" and d.loglik_before > d.loglik_after, d
    assert obs.sample_timing() == "before_command"
    assert s["F_ratio"] <= 0.5 * s["F_ratio_open_loop"], s
    # Reported for /diagnostics and summary.json
    diag = obs.diagnostics()
    assert diag["imu.sample_timing"] == "before_command" and "log-likelihood" in diag["imu.sample_timing_check"]
    summary = obs.timing_summary()
    assert summary["in_use"] == "before_command" and summary["decisions"][0]["choice"] == "before_command"


def test_matching_command_delay_beats_a_mismatched_one(five_bar, delayed_rec) -> None:
    _, matched = _run(five_bar, delayed_rec, command_delay=1e-3)
    _, mismatched = _run(five_bar, delayed_rec, command_delay=0.0)
    assert matched["F_ratio"] <= 0.5 * matched["F_ratio_open_loop"], matched
    assert matched["F_ratio"] < 0.5 * mismatched["F_ratio"], (matched, mismatched)
    assert matched["rejected"]["encoders"] == 0 and matched["motor_rmse_rad"] < 2e-5, matched


# ---------------------------------------------------------------------------- message order
@pytest.mark.parametrize(("recorded", "timing", "delay"), [
    ("after_command", "after_command", 0), ("after_command", "auto", 0), ("before_command", "auto", 0),
    ("after_command", "after_command", 1), ("before_command", "before_command", 1)])
def test_command_and_samples_at_one_stamp_commute(five_bar, recorded, timing, delay) -> None:
    """The command of t_k before or after the samples of t_k: the same estimates (an
    after_command sample waits for its command; auto under before_command weighs it then)."""
    rec = manoeuvre_recording(five_bar, duration=0.15, seed=3, accel_timing=recorded, command_delay=delay)
    cfg = ObserverConfig.from_parameters({"imu.sample_timing": timing, "command_delay": delay * 1e-3})
    a, b = (feed_in_order(Observer(five_bar, cfg), rec, command_first) for command_first in (False, True))
    assert np.array_equal(a.x(), b.x()) and np.array_equal(a.P, b.P)
    assert a.stats["imu"].accepted == b.stats["imu"].accepted > 140
    assert np.array_equal(a.evidence, b.evidence) and a.sample_timing() == b.sample_timing()


def test_a_held_sample_without_its_command_is_used_at_the_next_stamp(five_bar, after_rec) -> None:
    obs = Observer(five_bar, ObserverConfig.from_parameters({"imu.sample_timing": "after_command"}))
    stream = ObserverStream(obs)
    names = after_rec.active_names
    for k in range(3):
        ns = int(after_rec.stamp_ns[k])
        stream.on_joint_state(ns, names, after_rec.encoder[k])
        assert stream.on_imu(ns, after_rec.accel[k]) == []  # waits for the command of t_k
        if k < 2:
            stream.on_torque_command(ns, names, after_rec.tau_cmd[k])
            assert [r.sensor for r in obs.released] == ["imu"] and obs.released[0].accepted
    assert obs.stats["imu"].accepted == 2
    r = stream.on_joint_state(int(after_rec.stamp_ns[3]), names, after_rec.encoder[3])
    # Weighed at t_2 first, under the command still acting (here not the one the sample saw: gated out)
    assert r[0].accepted and obs.stats["imu"].accepted + obs.stats["imu"].rejected == 3
    assert [x.t for x in obs.released] == [pytest.approx(after_rec.t[2])]


# ---------------------------------------------------------------------------- fast path = per-message API
def _same(a, b) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def _compare(mech, params, events, order="stamp"):
    cfg = ObserverConfig.from_parameters(params)
    runs = []
    for fast in (False, True):
        obs = Observer(mech, cfg, t0=events[0].stamp_ns * 1e-9)
        rows, _, fault = run_events(obs, events, order, fast=fast)
        runs.append((obs, rows, fault))
    (o1, r1, f1), (o2, r2, f2) = runs
    assert f1 == f2 and r1.t == r2.t and len(r1.t) > 0
    assert np.array_equal(r1.table(), r2.table(), equal_nan=True)
    assert np.array_equal(np.array(r1.nis), np.array(r2.nis), equal_nan=True)
    for name in o1.stats:
        x, y = o1.stats[name], o2.stats[name]
        for key in ("accepted", "rejected", "late", "nan", "other", "consecutive_rejections", "last_reason"):
            assert getattr(x, key) == getattr(y, key), (name, key)
        assert _same(x.last_nis, y.last_nis) and list(x.window) == list(y.window), name
    for key in ("q", "qd", "z", "P", "Phi", "Qd", "tau_hold", "tau_last", "Hpt", "evidence"):
        assert np.array_equal(getattr(o1, key), getattr(o2, key), equal_nan=True), key
    assert (o1.t, o1.t_command, o1._lin_age, o1._lin_T) == (o2.t, o2.t_command, o2._lin_age, o2._lin_T)
    assert [(t, list(tau)) for t, tau in o1._pending] == [(t, list(tau)) for t, tau in o2._pending]
    assert o1.timing_decisions == o2.timing_decisions and o1.sample_timing() == o2.sample_timing()
    assert o1.diagnostics() == o2.diagnostics()
    return o2


@pytest.fixture(scope="module")
def short_after(five_bar):
    """0.2 s with a(t_k+) (or a(t_k-)), commands acting at their stamp (0) or 1 or 2 periods later."""
    out = {delay: manoeuvre_recording(five_bar, duration=0.2, seed=5, accel_timing="after_command",
                                      command_delay=delay) for delay in (0, 1, 2)}
    out["before"] = manoeuvre_recording(five_bar, duration=0.2, seed=5)
    return out


@pytest.mark.parametrize(("params", "rec_delay", "min_fast"), [
    ({"imu.sample_timing": "after_command"}, 0, 0.8),
    ({"imu.sample_timing": "auto"}, 0, 0.8),
    ({"imu.sample_timing": "auto"}, "before", 0.8),  # corrected at once, weighed with the command
    ({"imu.sample_timing": "after_command", "command_delay": 1e-3}, 1, 0.8),
    ({"imu.sample_timing": "auto", "command_delay": 1e-3}, 1, 0.8),
    ({"imu.sample_timing": "auto", "command_delay": 2e-3}, 2, 0.8),
    # Half a period: two prediction pieces per period, no command starts at a sample (the
    # hypotheses agree); 2.5 periods. Neither is the recording's: the filter is off, gates
    # many samples, and those periods are the per-message API's.
    ({"imu.sample_timing": "auto", "command_delay": 5e-4}, 1, 0.0),
    ({"imu.sample_timing": "before_command", "command_delay": 2.5e-3}, 1, 0.0),
])
def test_fast_path_equals_per_message_api_with_timing_options(five_bar, short_after, count_fast, params, rec_delay,
                                                               min_fast) -> None:
    rec = short_after[rec_delay]
    bad = {30: {"encoder": rec.encoder[30] + [0.5, 0.0]},  # gated
           50: {"accel": rec.accel[50] + [50.0, 0.0, 0.0]},  # gated
           60: {"accel": [np.nan, 0.0, 0.0]}}
    # skip_cmd: a sample that waits for a command that never comes; reorder: the command first
    events = _events(rec, corrupt=bad, skip=(70, 71), skip_cmd=(120, 121), bad_cmd=(80,), reorder=(100,),
                     branch_at=(90,))
    obs = _compare(five_bar, dict(params, sensors=["encoders", "imu", "branch_forces"]), events)
    assert sum(count_fast) > min_fast * len(rec.stamp_ns)
    assert obs.stats["imu"].rejected >= 1 and obs.stats["encoders"].rejected >= 1


def test_fast_path_with_delay_in_arrival_order_and_timeout(five_bar, short_after, count_fast) -> None:
    rec = short_after[1]
    events = _events(rec, late=((50, 47), (51, 20)), frame="ee_imu")
    for order in ("arrival", "stamp"):
        _compare(five_bar, {"imu.sample_timing": "auto", "command_delay": 1e-3}, events, order=order)
    gappy = _events(rec, skip=tuple(range(60, 66)), skip_cmd=tuple(range(60, 66)))
    _compare(five_bar, {"imu.sample_timing": "after_command", "command_delay": 1e-3,
                        "timing.command_timeout": 0.0025}, gappy)
    assert sum(count_fast) > 0


# ---------------------------------------------------------------------------- auto: later checks
def test_auto_switches_only_on_strong_evidence(five_bar, before_rec) -> None:
    obs = Observer(five_bar, ObserverConfig.from_parameters({"initial.source": "model"}))
    stream = ObserverStream(obs)
    names = before_rec.active_names
    for k in range(120):
        ns = int(before_rec.stamp_ns[k])
        stream.on_joint_state(ns, names, before_rec.encoder[k])
        stream.on_imu(ns, before_rec.accel[k])
        stream.on_torque_command(ns, names, before_rec.tau_cmd[k])
    assert obs.sample_timing() == "before_command" and len(obs.timing_decisions) == 1
    # A check a second later: evidence for the other hypothesis below the margin keeps the choice,
    # above it switches (logged).
    t = obs.t + 1.0
    obs.evidence[:] = [100.0, 100.0 - 2 * (TIMING_SWITCH_EVIDENCE - 1.0), 0.0, 500.0]
    obs._timing_check(t)
    assert obs.sample_timing() == "before_command" and len(obs.timing_decisions) == 1
    assert obs.timing_last.t == t and not obs.timing_last.switched
    obs.evidence[:] = [100.0, 100.0 - 2 * (TIMING_SWITCH_EVIDENCE + 1.0), 0.0, 500.0]
    obs._timing_check(t + 1.0)
    assert obs.sample_timing() == "after_command"
    assert obs.timing_decisions[-1].switched and "switched to after_command" in obs.timing_decisions[-1].text()
    assert not obs.evidence.any()


def test_diagnostics_of_the_live_node_carry_the_choice(five_bar, after_rec) -> None:
    session = ObserverSession(five_bar, ObserverConfig.from_parameters({}))
    names = after_rec.active_names
    for k in range(130):
        ns = int(after_rec.stamp_ns[k])
        session.joint_state(ns, names, after_rec.encoder[k])
        session.imu(ns, after_rec.accel[k])
        session.torque_command(ns, names, after_rec.tau_cmd[k])
    _, _, values = session.report()
    assert values["imu.sample_timing"] == "after_command"
    assert "chose after_command" in values["imu.sample_timing_check"]
    assert values["command_delay"] == "0"


def test_timing_parameters_checked() -> None:
    with pytest.raises(InputError, match=r"observer\.imu\.sample_timing: expected one of"):
        ObserverConfig.from_parameters({"imu.sample_timing": "during"}, "test.yaml")
    with pytest.raises(InputError, match=r"observer\.command_delay: must be >= 0"):
        ObserverConfig.from_parameters({"command_delay": -1e-3}, "test.yaml")


# ---------------------------------------------------------------------------- a foreign recording, offline
@pytest.mark.parametrize(("delay", "order"), [(0, "stamp"), (1, "arrival")])
def test_observe_learns_the_timing_of_a_bag(five_bar, tmp_path, delay, order) -> None:
    """A bag of another simulator's recording (epoch stamps, receive times after the stamps,
    a(t_k+)): ``observe`` with the default auto and the drive's delay tracks, far better than
    the open loop; with the delay left out it does not."""
    from elastic_pm_dyn.observer.offline import observe_bag
    from elastic_pm_dyn.observer.testing.recordings import EPOCH, RecordingSpec, generate, write_bag
    spec = RecordingSpec(duration=0.5, spectrum="pink", disturbance_rms=0.02, accel_timing="after_command",
                         command_delay=delay, t0=EPOCH)
    rec = generate(five_bar, spec)
    bag = write_bag(rec, tmp_path / "bag")
    keep = rec.t >= 0.05
    ol = open_loop(rec)
    ol_err = np.sqrt(np.mean((ol.F - rec.F)[keep] ** 2))
    errors = {}
    for cd in sorted({0.0, delay * 1e-3}):
        cfg = ObserverConfig.from_parameters({"command_delay": cd, "sensors": ["encoders", "imu"]})
        res = observe_bag(five_bar, cfg, bag, tmp_path / f"out{cd}", order=order, log=lambda _: None)
        assert res.rows.t == [int(ns) for ns in rec.stamp_ns]
        F = np.array([e.branch_force for e in res.rows.est])
        errors[cd] = (np.sqrt(np.mean((F - rec.F)[keep] ** 2)), res)
    err, res = errors[delay * 1e-3]
    assert res.observer.sample_timing() == "after_command"
    assert res.summary.sensors["encoders"].rejected == 0 and not res.summary.fault
    assert err < 0.5 * ol_err, (err, ol_err)
    if delay:
        assert errors[0.0][0] > ol_err  # the command delay left out: worse than the open loop
