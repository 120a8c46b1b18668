"""``elastic-pm-dyn observe``: bag in, CSV + bag out; the offline pass equals the live path."""

from __future__ import annotations

import argparse
import csv
import json

import numpy as np
import pytest

from elastic_pm_dyn.bags.series import read_series
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.cli import register_cli
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag
from elastic_pm_dyn.observer.drivers.results import estimates_equal
from elastic_pm_dyn.observer.drivers.stream import ObserverStream
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

pytest.importorskip("rosbags")

SENSORS = ["encoders", "imu"]


@pytest.fixture(scope="module")
def rec(five_bar):
    return manoeuvre_recording(five_bar, duration=0.12, seed=7)


@pytest.fixture(scope="module")
def bag(rec, tmp_path_factory):
    path = tmp_path_factory.mktemp("obs") / "in"
    recording_to_bag(rec, path, use=("encoders", "imu", "branch_forces"))
    return path


def _cfg(**params) -> ObserverConfig:
    return ObserverConfig.from_parameters({"sensors": SENSORS, **params})


def test_offline_equals_live_lockstep(five_bar, rec, bag) -> None:
    """Same messages, same order -> bit-identical estimates whether from a bag or callbacks."""
    res = observe_bag(five_bar, _cfg(), bag, None, log=lambda s: None)
    obs = Observer(five_bar, _cfg(), t0=rec.t[0])
    stream = ObserverStream(obs)
    live = []
    for k, ns in enumerate(rec.stamp_ns):  # what the plant node's callbacks would do
        ns = int(ns)
        stream.on_joint_state(ns, rec.active_names, rec.encoder[k])
        stream.on_imu(ns, rec.accel[k], "ee_imu")
        stream.on_torque_command(ns, rec.active_names, rec.tau_cmd[k])
        if obs.initialised:
            live.append(obs.estimate())
    assert len(res.rows.est) == len(rec.t)
    assert estimates_equal(res.rows.est, live) == 0.0
    # Arrival order of this (lockstep) bag is the stamp order: the same again.
    res2 = observe_bag(five_bar, _cfg(), bag, None, order="arrival", log=lambda s: None)
    assert estimates_equal(res.rows.est, res2.rows.est) == 0.0


def test_cli_writes_csv_bag_and_summary(five_bar, rec, bag, tmp_path) -> None:
    parser = argparse.ArgumentParser()
    register_cli(parser.add_subparsers(dest="command"))
    out = tmp_path / "out"
    args = parser.parse_args(["observe", "--model", str(five_bar.model.source), "--bag", str(bag), "--out", str(out),
                              "--sensors", "encoders", "imu", "branch_forces", "--set", "branch_forces.stddev=[0.5]"])
    assert args.func(args) == 0
    with (out / "estimates.csv").open() as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    for col in ("t", "left_motor", "left_spring", "right_elbow", "F_left", "F_right", "left_spring_std",
                "F_left_std", "ee_x", "d_left_motor", "nis_imu"):
        assert col in header
    table = np.array(rows[1:], dtype=float)
    assert len(table) == len(rec.t)
    F = table[:, header.index("F_left")]
    assert np.sqrt(np.mean((F[50:] - rec.F[50:, 0]) ** 2)) < 0.02
    assert np.all(table[:, header.index("F_left_std")] > 0)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sensors"]["imu"]["accepted"] > 0.95 * len(rec.t)
    assert "left_spring" in summary["observability"]
    # The estimates bag is what `analyze` reads: joint states and branch forces with std devs.
    series = read_series(out / "estimates")
    assert {"/joint_states", "/branch_forces", "/ee_pose"} <= set(series)
    js = series["/joint_states"]
    assert js.names == list(five_bar.joint_names) and len(js.t) == len(rec.t)
    assert np.allclose(series["/branch_forces"].values["force"][:, 0], F, atol=1e-9)
    assert np.allclose(js.t, rec.t, atol=1e-9)


def test_bad_inputs_are_one_line_errors(five_bar, bag, tmp_path) -> None:
    cfg = _cfg()
    with pytest.raises(InputError, match="no such bag"):
        observe_bag(five_bar, cfg, tmp_path / "nothing", None, log=lambda s: None)
    cfg = ObserverConfig.from_parameters({"sensors": SENSORS, "topics.torque_command": "/cmd"})
    with pytest.raises(InputError, match="no topic /cmd"):
        observe_bag(five_bar, cfg, bag, None, log=lambda s: None)
    parser = argparse.ArgumentParser()
    register_cli(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["observe", "--model", str(five_bar.model.source), "--bag", str(bag), "--out",
                              str(tmp_path / "o"), "--set", "process.dt"])
    with pytest.raises(InputError, match="NAME=VALUE"):
        args.func(args)
