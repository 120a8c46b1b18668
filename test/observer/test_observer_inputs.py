"""The observer's real inputs: YAML 1.2 numbers, epoch stamps, joint-state names, far-future stamps."""

import argparse
import csv
import math
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model import yaml12
from elastic_pm_dyn.model.loader import parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.observer.cli import _config, register_cli
from elastic_pm_dyn.observer.config import ObserverConfig, load_config
from elastic_pm_dyn.observer.drivers.bag_input import Event, Topics, recording_to_bag
from elastic_pm_dyn.observer.drivers.event_filter import filter_all, run_events
from elastic_pm_dyn.observer.drivers.results import estimates_equal, seconds_text, summary
from elastic_pm_dyn.observer.drivers.stream import ObserverStream
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording
from elastic_pm_dyn.ros.observer.session import ObserverSession

CONFIG = Path(__file__).resolve().parents[1].parent / "config"


# ---------------------------------------------------------------- YAML 1.2 numbers
@pytest.mark.parametrize(("text", "value"), [("5e-5", 5e-5), ("1e3", 1e3), ("-2E+4", -2e4), ("+.5", 0.5),
                                             ("1.5e-3", 1.5e-3), ("7", 7), ("0x10", 16)])
def test_yaml12_numbers(text, value) -> None:
    got = yaml12.load(text)
    assert got == value and type(got) is type(value)


def test_yaml12_keeps_inf_nan_and_quoted_strings() -> None:
    assert yaml12.load(".inf") == math.inf and yaml12.load("-.Inf") == -math.inf
    assert math.isnan(yaml12.load(".nan"))
    assert yaml12.load('"5e-5"') == "5e-5" and yaml12.load("'1e3'") == "1e3"
    assert yaml12.load("1e") == "1e" and yaml12.load("e5") == "e5" and yaml12.load("abc") == "abc"
    assert yaml12.load("[1e3, 2, x]") == [1000.0, 2, "x"]


def _observe_args(*extra: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    register_cli(parser.add_subparsers(dest="command"))
    return parser.parse_args(["observe", "--model", "m.yaml", "--bag", "b", "--out", "o", *extra])


def test_observe_set_takes_yaml12_numbers() -> None:
    cfg = _config(_observe_args("--set", "process.dt=5e-5", "--set", "observer.process.max_interval=1e-3",
                                "--set", "imu.stddev=[2E-2]"))
    assert cfg.process.dt == 5e-5 and cfg.process.max_interval == 1e-3 and cfg.imu.stddev == [0.02]
    with pytest.raises(InputError, match="expected a number"):  # quoted: a string, as in any YAML
        _config(_observe_args("--set", 'process.dt="5e-5"'))


def test_observer_parameter_file_takes_yaml12_numbers(tmp_path) -> None:
    text = (CONFIG / "observer.yaml").read_text().replace("stamp_tolerance: 1.0e-6", "stamp_tolerance: 2e-6")
    assert "stamp_tolerance: 2e-6" in text
    (tmp_path / "obs.yaml").write_text(text)
    assert load_config(tmp_path / "obs.yaml").timing.stamp_tolerance == 2e-6


def test_model_file_takes_yaml12_numbers_with_lines() -> None:
    text = (CONFIG / "five_bar.yaml").read_text()
    assert text.count("stiffness: 5.464e6") == 2  # no sign in the exponent: a string to YAML 1.1
    text = text.replace("stiffness: 5.464e6", "stiffness: 1e5", 1)
    src = YamlSource(text, "five_bar.yaml")
    spring = ("chains", 0, "joints", 1, "stiffness")
    assert src.data["chains"][0]["joints"][1]["stiffness"] == 1e5
    assert type(src.data["chains"][1]["joints"][1]["stiffness"]) is float
    assert src.line(spring) == text.splitlines().index(
        next(s for s in text.splitlines() if "stiffness: 1e5" in s)) + 1
    assert [j.stiffness for j in parse_model(src).joints if j.role == "elastic"] == [1e5, 5.464e6]
    quoted = YamlSource(text.replace("stiffness: 1e5", 'stiffness: "1e5"'), "five_bar.yaml")
    assert quoted.data["chains"][0]["joints"][1]["stiffness"] == "1e5"
    assert math.isinf(YamlSource("a: .inf\nb: -.inf\n", "x.yaml").data["b"])


# ---------------------------------------------------------------- epoch stamps
T0_NS = 1_700_000_000 * 10**9  # an epoch stamp: a double there has a spacing of 0.24 us


@pytest.fixture(scope="module")
def recordings(five_bar):
    """The same recording stamped from 0 and from T0 (the same simulation, other stamps)."""
    return {t0: manoeuvre_recording(five_bar, duration=0.15, seed=7, stamp0_ns=t0) for t0 in (0, T0_NS)}


def _cfg(**params) -> ObserverConfig:
    return ObserverConfig.from_parameters({"sensors": ["encoders", "imu"], **params})


def _csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open() as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def _bag_stamps(path: Path, topic: str) -> list[int]:
    with open_bag(path) as bag:
        conns = [c for c in bag.connections if c.topic == topic]
        return [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, _, m in bag.decoded(conns)]


@pytest.mark.parametrize("pipeline", [True, False])
def test_epoch_stamps_keep_the_time_axis(five_bar, recordings, tmp_path, pipeline) -> None:
    results = {}
    for t0, rec in recordings.items():
        bag = tmp_path / f"in_{t0}"
        recording_to_bag(rec, bag, use=("encoders", "imu"))
        out = tmp_path / f"out_{t0}"
        results[t0] = (observe_bag(five_bar, _cfg(), bag, out, log=lambda s: None, pipeline=pipeline), out)
    (zero, out0), (epoch, out1) = results[0], results[T0_NS]
    rec = recordings[T0_NS]
    # The filter ran on the same relative times: the same estimates.
    assert len(epoch.rows.t) == len(rec.t)
    assert estimates_equal(zero.rows.est, epoch.rows.est) <= 1e-12
    assert epoch.rows.t == [int(ns) for ns in rec.stamp_ns]
    assert epoch.summary.time_origin_ns == T0_NS and zero.summary.time_origin_ns == 0
    # estimates.csv: t since the first stamp (exact), stamp_ns the header stamp (exact).
    header, rows = _csv(out1 / "estimates.csv")
    assert header[:2] == ["t", "stamp_ns"] and _csv(out0 / "estimates.csv")[0] == header
    assert [int(r[1]) for r in rows] == [int(ns) for ns in rec.stamp_ns]
    assert [r[0] for r in rows] == [r[0] for r in _csv(out0 / "estimates.csv")[1]]
    assert [Decimal(r[0]) for r in rows] == [Decimal(int(ns) - T0_NS) / 10**9 for ns in rec.stamp_ns]
    assert len({r[0] for r in rows}) == len(rows)  # no two rows at one time
    # The bag of estimates keeps the exact header stamps.
    assert _bag_stamps(out1 / "estimates", "/joint_states") == [int(ns) for ns in rec.stamp_ns]


def test_epoch_stamps_live_equal_zero_stamps(five_bar, recordings) -> None:
    estimates = {}
    for t0, rec in recordings.items():
        session = ObserverSession(five_bar, _cfg())
        est = []
        for k, ns in enumerate(rec.stamp_ns):
            ns = int(ns)
            session.imu(ns, rec.accel[k])
            out = session.joint_state(ns, rec.active_names, rec.encoder[k])
            assert out.publish and not out.problems
            est.append(session.estimate())
            session.torque_command(ns, rec.active_names, rec.tau_cmd[k])
        estimates[t0] = est
        assert session.stream.origin_ns == int(rec.stamp_ns[0])
        assert session.report()[2]["time_origin_ns"] == str(int(rec.stamp_ns[0]))
    assert estimates_equal(estimates[0], estimates[T0_NS]) <= 1e-12


def test_seconds_text_is_exact() -> None:
    assert [seconds_text(ns) for ns in (0, 1, 1_000_000, 1_500_000_000, -2_000_000_001, 123_000_000_000)] == \
        ["0", "0.000000001", "0.001", "1.5", "-2.000000001", "123"]


# ---------------------------------------------------------------- joint-state names and outlier stamps
def _events(rec, names_at=None, extra=()):
    """Lockstep events (joint state, accelerometer, command per stamp); ``names_at``: k -> the
    joint state's (names, positions) instead; ``extra``: (after k, stamp, kind, data) events."""
    names_at = names_at or {}
    out = []

    def add(ns, kind, data):
        out.append(Event(int(ns), kind, data, len(out)))

    for k, ns in enumerate(rec.stamp_ns):
        names, pos = names_at.get(k, (list(rec.active_names), rec.encoder[k]))
        add(ns, "joint_state", (names, np.asarray(pos, dtype=float), np.zeros(0), np.zeros(0)))
        add(ns, "imu", (rec.accel[k], ""))
        add(ns, "command", (list(rec.active_names), rec.tau_cmd[k]))
        for after, stamp, kind, data in extra:
            if after == k:
                add(stamp, kind, data)
    return out


def _fast_equals_slow(mech, cfg, events, order="stamp"):
    runs = []
    for fast in (False, True):
        obs = Observer(mech, cfg)
        rows, stream, fault = run_events(obs, events, order, fast=fast)
        runs.append((obs, rows, stream, fault))
    (o1, r1, s1, f1), (o2, r2, s2, f2) = runs
    assert f1 == f2 and r1.t == r2.t and len(r1.t) > 0
    assert np.array_equal(r1.table(), r2.table(), equal_nan=True)
    for name in o1.stats:
        for key in ("accepted", "rejected", "late", "future", "nan", "other", "consecutive_rejections"):
            assert getattr(o1.stats[name], key) == getattr(o2.stats[name], key), (name, key)
    assert s1.joint_state_rejections == s2.joint_state_rejections
    assert o1.t == o2.t
    return o2, r2, s2


def test_joint_states_with_bad_names_are_counted_not_used(five_bar, recordings) -> None:
    rec = recordings[0]
    a, b = rec.active_names
    bad = {30: ([a, b, a], [*rec.encoder[30], 0.3]),  # a name twice
           40: ([a], rec.encoder[40][:1]),  # a measured motor missing
           50: (["robot/" + a, "robot/" + b], rec.encoder[50]),  # another machine's names
           51: ([b, a], rec.encoder[51][::-1]),  # any order is fine
           60: ([a, "gripper", b], [rec.encoder[60][0], 7.0, rec.encoder[60][1]])}  # extras ignored
    events = _events(rec, bad)
    obs, rows, stream = _fast_equals_slow(five_bar, _cfg(), events)
    assert dict(stream.joint_state_rejections) == {"duplicate": 1, "missing": 1, "unknown": 1}
    # all but the three and the first (which set the pose)
    assert obs.stats["encoders"].accepted == len(rec.t) - 4 and obs.stats["encoders"].rejected == 0
    assert "not used (unknown names)" in stream.last_joint_state_problem
    # One check per distinct name list, however often it comes.
    assert len(stream._name_checks) == 6
    # Without the bad ones the estimates equal those of a clean run whose three samples are missing.
    clean = _events(rec)
    drop = {int(rec.stamp_ns[k]) for k in (30, 40, 50)}
    clean = [e for e in clean if not (e.kind == "joint_state" and e.stamp_ns in drop)]
    _, rows2, _ = _fast_equals_slow(five_bar, _cfg(), clean)
    assert np.array_equal(rows.table(), rows2.table(), equal_nan=True)


def test_bad_names_in_summary_cli_and_live_diagnostics(five_bar, recordings, tmp_path, capsys) -> None:
    rec = recordings[0]
    a, b = rec.active_names
    run = filter_all(five_bar, _cfg(), _events(rec, {20: ([a, a], rec.encoder[20]), 21: ([b], [0.0])}), "stamp",
                     log=lambda s: None)
    s = summary(tmp_path, Topics.from_config(_cfg()), {}, "stamp", _events(rec), run, 0.0)
    assert s.joint_states_rejected == {"duplicate": 1, "missing": 1, "unknown": 0}
    assert "missing" in s.last_joint_state_problem and s.sensors["encoders"].future == 0
    # The live node: one line naming the reason per message, counts in the diagnostics.
    session = ObserverSession(five_bar, _cfg())
    for k in range(10):
        ns = int(rec.stamp_ns[k])
        names, pos = ([a, b, b], [*rec.encoder[k], 0.0]) if k == 5 else (rec.active_names, rec.encoder[k])
        out = session.joint_state(ns, names, pos)
        assert out.publish == (k != 5)
        if k == 5:
            assert len(out.problems) == 1 and "(duplicate names)" in out.problems[0] and "'right_motor'" in \
                out.problems[0]
        session.torque_command(ns, rec.active_names, rec.tau_cmd[k])
    level, message, values = session.report()
    assert level == 1 and "joint states with duplicate names 1" in message
    assert values["joint_states_rejected.duplicate"] == "1" and values["joint_states_rejected.missing"] == "0"
    assert "duplicate" in values["last_joint_state_problem"]


def test_observe_cli_warns_about_bad_names(five_bar, recordings, tmp_path, capsys, monkeypatch) -> None:
    from elastic_pm_dyn.observer import cli
    rec = recordings[0]
    a = rec.active_names[0]
    events = _events(rec, {20: ([a, a], rec.encoder[20])})
    monkeypatch.setattr("elastic_pm_dyn.observer.offline.read_events", lambda bag, topics, cfg: (events, {}))
    args = _observe_args("--model", str(five_bar.model.source), "--sensors", "encoders", "imu", "--no-bag")
    args.out = str(tmp_path / "o")
    args.bag = str(tmp_path)
    monkeypatch.setattr(cli, "_config", lambda args: _cfg())
    monkeypatch.setattr("elastic_pm_dyn.observer.offline.observe_pipelined",
                        lambda *a, **k: (_ for _ in ()).throw(AssertionError("not pipelined here")))
    from elastic_pm_dyn.observer import offline
    real = offline.observe_bag
    monkeypatch.setattr(offline, "observe_bag", lambda *a, **k: real(*a, **{**k, "pipeline": False}))
    assert args.func(args) == 0
    err = capsys.readouterr().err
    assert "warning: joint states not used: 1 with duplicate names (last: joint state at t = 0.020000 s" in err


def test_far_future_stamp_is_rejected_and_counted(five_bar, recordings) -> None:
    rec = recordings[T0_NS]
    far = int(rec.stamp_ns[40]) + 1000 * 10**9
    outlier = [(40, far, "joint_state", (list(rec.active_names), rec.encoder[40], np.zeros(0), np.zeros(0))),
               (40, far, "imu", (rec.accel[40], "")), (40, far, "command", (list(rec.active_names), rec.tau_cmd[40]))]
    events = _events(rec, extra=outlier)
    obs, rows, _ = _fast_equals_slow(five_bar, _cfg(), events, order="arrival")
    assert [obs.stats[s].future for s in ("encoders", "imu", "command")] == [1, 1, 1]
    assert rows.t == [int(ns) for ns in rec.stamp_ns]  # no row at the outlier, none lost after it
    assert obs.t == pytest.approx((int(rec.stamp_ns[-1]) - T0_NS) * 1e-9, abs=1e-12)
    # Without it: the same estimates (the outlier left nothing behind)
    _, clean, _ = _fast_equals_slow(five_bar, _cfg(), _events(rec), order="arrival")
    assert np.array_equal(rows.table(), clean.table())
    # .inf: no limit (as before timing.max_future): the filter predicts 1000 s to the outlier and faults
    obs = Observer(five_bar, _cfg(**{"timing.max_future": math.inf}))
    rows, _, fault = run_events(obs, events, "arrival")
    assert fault and obs.stats["encoders"].future == 0 and len(rows.t) == 41


def test_observer_reset_restarts_the_clock_at_the_next_sample(five_bar, recordings) -> None:
    rec = recordings[0]
    obs = Observer(five_bar, _cfg())
    stream = ObserverStream(obs)
    for k in range(20):
        stream.on_joint_state(int(rec.stamp_ns[k]), rec.active_names, rec.encoder[k])
        stream.on_torque_command(int(rec.stamp_ns[k]), rec.active_names, rec.tau_cmd[k])
    assert obs.t == pytest.approx(0.019)
    # An outlier leaves the time alone; health says what happened.
    r = stream.on_joint_state(int(rec.stamp_ns[20]) + 5 * 10**9, rec.active_names, rec.encoder[20])
    assert r[0].reason == "future" and obs.t == pytest.approx(0.019)
    assert "ahead of the filter" in obs.stats["encoders"].last_reason
    # reset() without a time: the next stamp sets it, even one before the old time (a restarted clock)
    obs.reset(q=obs.q, qd=obs.qd)
    assert obs.time_pending
    back = 14 * 10**6  # the clock restarted 14 ms earlier: sample 19 again, stamped 0.005 s
    r = stream.on_joint_state(int(rec.stamp_ns[19]) - back, rec.active_names, rec.encoder[19])
    assert r[0].accepted and obs.t == pytest.approx(0.005) and not obs.time_pending
    assert stream.on_torque_command(int(rec.stamp_ns[19]) - back, rec.active_names, rec.tau_cmd[19])
    r = stream.on_joint_state(int(rec.stamp_ns[20]) - back, rec.active_names, rec.encoder[20])
    assert r[0].accepted and obs.t == pytest.approx(0.006)


@pytest.mark.parametrize("t0", [0, T0_NS])
def test_live_far_future_sample_then_reset_recovers(five_bar, recordings, t0) -> None:
    """Normal samples, one far in the future, more normal ones, ~/reset, normal ones: tracking throughout."""
    rec = recordings[t0]
    session = ObserverSession(five_bar, _cfg())

    def sample(k: int, shift_ns: int = 0) -> tuple:
        ns = int(rec.stamp_ns[k]) + shift_ns
        session.imu(ns, rec.accel[k])
        out = session.joint_state(ns, rec.active_names, rec.encoder[k])
        session.torque_command(ns, rec.active_names, rec.tau_cmd[k])
        return out

    def error(k: int) -> float:
        e = session.estimate()
        return float(np.abs(e.q[five_bar.active] - rec.q[k, five_bar.active]).max())

    for k in range(60):
        assert sample(k).publish
    out = sample(60, 1000 * 10**9)  # a sample stamped 1000 s ahead
    assert not out.publish and "not used (future)" in out.problems[0] and session.faults == 0
    for k in range(60, 100):
        assert sample(k).publish
    assert error(99) < 1e-4
    stats = session.obs.stats
    assert (stats["encoders"].future, stats["imu"].future, stats["command"].future) == (1, 1, 1)
    _, message, values = session.report()
    assert "samples stamped too far ahead 1" in message and values["encoders.future"] == "1"
    text = session.reset()
    assert "re-initialised from the measured joint state at t = 0.099000 s" in text  # not from the outlier
    for k in range(100, len(rec.t)):
        out = sample(k)
        assert out.publish and not out.problems, out.problems
    assert error(len(rec.t) - 1) < 1e-4 and session.obs.fault is None
    # A reset before any joint state is kept (initial.source model): the next message's stamp sets the time.
    session = ObserverSession(five_bar, _cfg(**{"initial.source": "model"}))
    assert "next message" in session.reset()
    sample(0)
    assert session.obs.t == 0.0 and session.stream.origin_ns == int(rec.stamp_ns[0])
