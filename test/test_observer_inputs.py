"""The observer's real inputs: YAML 1.2 numbers, epoch stamps, joint-state names, far-future stamps."""

import argparse
import math
from pathlib import Path

import pytest

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.model import yaml12
from elastic_pm_dyn.model.loader import parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource
from elastic_pm_dyn.observer.cli import _config, register_cli
from elastic_pm_dyn.observer.config import load_config

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
