"""The observer's real inputs: YAML 1.2 numbers, epoch stamps, joint-state names, far-future stamps."""

import argparse
import csv
import math
from decimal import Decimal
from pathlib import Path

import pytest

from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model import yaml12
from elastic_pm_dyn.model.loader import parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.observer.bag_input import recording_to_bag
from elastic_pm_dyn.observer.cli import _config, register_cli
from elastic_pm_dyn.observer.config import ObserverConfig, load_config
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.results import estimates_equal, seconds_text
from elastic_pm_dyn.observer.scenarios import manoeuvre_recording
from elastic_pm_dyn.ros.observer_session import ObserverSession

CONFIG = Path(__file__).resolve().parent.parent / "config"


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
    assert epoch.summary["time_origin_ns"] == T0_NS and zero.summary["time_origin_ns"] == 0
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
