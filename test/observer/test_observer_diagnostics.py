"""The observer says what is wrong: timing choices reported, far-off sensors named with a cause.

Recordings of observer/testing/recordings.py (another simulator's conventions: receive times after
the stamps) with one cause planted each, run through ``observe`` (summary.json, its log) or
the live node's session (/diagnostics):
- a consistent run: the sample timing auto chose is logged once and in summary.json, no cause;
- the accelerometer's noise level set too low, a disturbance far stronger than the model's,
  the noise level set too high;
- a mis-set accelerometer frame on the vertical five-bar (gravity in the plane);
- the accelerometer's sample timing changing under ``auto`` (it keeps its choice until the
  next check), and fixed to the wrong one.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

import pytest

from elastic_pm_dyn.observer import ObserverConfig
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag
from elastic_pm_dyn.ros.observer.session import ObserverSession

USE = ("encoders", "imu")
BASE = RecordingSpec(duration=0.2, spectrum="pink", disturbance_rms=0.02)  # the manoeuvre's move
CHIRP = RecordingSpec(motion="chirp", duration=0.6, spectrum="pink", disturbance_rms=0.02)  # commands jump all along
TOO_HIGH = r"(imu: NIS ([\d.]+)x its dof|imu: \d+ % of samples gated out, NIS ([\d.]+)x its dof)"


@pytest.fixture(scope="module")
def plain(five_bar):
    return generate(five_bar, BASE)


@pytest.fixture(scope="module")
def chirps(five_bar):
    """The same chirp recorded with the accelerometer before and after the command (one noise draw)."""
    return generate(five_bar, CHIRP), generate(five_bar, CHIRP.with_(accel_timing="after_command"))


def observe(mech: Any, rec: Any, out: Path, pipeline: bool = True, **params: Any) -> tuple[dict, list[str]]:
    """``observe`` over the recording's bag: summary.json and the lines it logged."""
    bag = write_bag(rec, out / "bag", use=USE)
    cfg = ObserverConfig.from_parameters({"sensors": list(USE), **{k.replace("__", "."): v for k, v in params.items()}})
    lines: list[str] = []
    observe_bag(mech, cfg, bag, out / "out", log=lines.append, pipeline=pipeline, write_estimates_bag=False)
    return json.loads((out / "out" / "summary.json").read_text()), lines


def live(mech: Any, rec: Any, **params: Any) -> tuple[int, str, dict[str, str]]:
    """The live node's session over the recording (samples, then the command): its report."""
    session = ObserverSession(mech, ObserverConfig.from_parameters(
        {"sensors": list(USE), **{k.replace("__", "."): v for k, v in params.items()}}))
    names = rec.active_names
    for k in range(len(rec.t)):
        ns = int(rec.stamp_ns[k])
        session.joint_state(ns, names, rec.encoder[k])
        session.imu(ns, rec.accel[k])
        session.torque_command(ns, names, rec.tau_cmd[k])
    return session.report()


@pytest.mark.parametrize("pipeline", [True, False])
def test_timing_choice_logged_and_in_summary_no_cause(five_bar, plain, tmp_path, pipeline) -> None:
    summary, lines = observe(five_bar, plain, tmp_path, pipeline)
    timing = summary["sample_timing"]
    assert timing["imu_sample_timing"] == "auto" and timing["in_use"] == "before_command"
    (decision,) = timing["decisions"]
    assert decision["choice"] == "before_command" and not decision["switched"]
    logged = [line for line in lines if "sample timing" in line]
    assert logged == [decision["text"]] and logged[0].startswith("accelerometer sample timing: chose before_command")
    assert all(s["diagnosis"] == "" for s in summary["sensors"].values())
    assert summary["health"] == [0, "tracking"]


@pytest.mark.parametrize(("strong", "params"), [(False, {"imu__stddev": [0.008]}), (True, {})])
def test_noise_level_too_low_or_disturbance_too_narrow(five_bar, plain, tmp_path, strong, params) -> None:
    """The accelerometer's noise set 2.5x too low, or an unknown torque 5x the model's (the
    accelerometer then makes it worse than encoders alone): its NIS several times its dof."""
    rec = generate(five_bar, BASE.with_(disturbance_rms=0.1)) if strong else plain
    summary, _ = observe(five_bar, rec, tmp_path, **params)
    text = summary["sensors"]["imu"]["diagnosis"]
    m = re.match(TOO_HIGH + r": noise level too low \(imu\.stddev\) or disturbance model too narrow", text)
    assert m and float(m[2] or m[3]) > 2.0, text
    encoders = summary["sensors"]["encoders"]["diagnosis"]
    if strong:  # the unknown torque also pushed the encoders beyond their gate
        assert encoders.startswith("encoders: ") and "disturbance model too narrow" in encoders, encoders
    else:
        assert encoders == ""
    assert text in summary["health"][1] and summary["health"][0] >= 1


def test_noise_level_too_high(five_bar, plain, tmp_path) -> None:
    summary, _ = observe(five_bar, plain, tmp_path, imu__stddev=[0.1])
    text = summary["sensors"]["imu"]["diagnosis"]
    m = re.fullmatch(r"imu: NIS ([\d.]+)x its dof: noise level too high \(imu\.stddev\)", text)
    assert m and float(m[1]) < 0.5, text
    assert summary["health"] == [1, text]


def test_frame_offset_named_on_the_accelerometer(five_bar_vertical, tmp_path) -> None:
    """Sensor axes 10 mrad off about z on the vertical five-bar: 0.1 m/s^2 of gravity in x.
    The filter follows the precise accelerometer (nearly every sample accepted), the encoders
    disagree."""
    rec = generate(five_bar_vertical, BASE)
    summary, _ = observe(five_bar_vertical, rec, tmp_path, imu__rpy=[0.0, 0.0, 0.01])
    text = summary["sensors"]["imu"]["diagnosis"]
    assert re.fullmatch(r"imu: NIS [\d.]+x its dof, but the encoders disagree \(.*gated out.*\): "
                        r"frame / bias \(imu\.rpy, specific_force\)", text), text
    assert summary["sensors"]["encoders"]["diagnosis"] == ""
    assert text in summary["health"][1]


def test_timing_named_from_auto_evidence(five_bar, chirps) -> None:
    """The accelerometer sampled after the command from 0.2 s on: ``auto`` chose before_command
    at 0.1 s and checks again only at 1.1 s; meanwhile its evidence names the timing."""
    before, after = chirps
    changed = dataclasses.replace(before, accel=before.accel.copy())
    changed.accel[before.t >= 0.2] = after.accel[before.t >= 0.2]
    level, message, values = live(five_bar, changed)
    text = values["imu.nis_diagnosis"]
    assert values["imu.sample_timing"] == "before_command"
    m = re.fullmatch(r"imu: .*: timing: after_command fits these samples better by (\d+) nats \(imu\.sample_timing\)",
                     text)
    assert m and int(m[1]) > 20, text
    assert level >= 1 and text in message
    # The same recording before the change: nothing named.
    _, _, values = live(five_bar, dataclasses.replace(before, t=before.t[:200], stamp_ns=before.stamp_ns[:200]))
    assert "imu.nis_diagnosis" not in values


def test_wrong_fixed_timing_lists_the_candidates(five_bar, chirps, tmp_path) -> None:
    """a(t_k+) samples read as a(t_k-) (fixed): gated out; no evidence of the other timing is
    kept, so the candidates are named, the sample timing first."""
    _, after = chirps
    summary, _ = observe(five_bar, after, tmp_path, imu__sample_timing="before_command")
    text = summary["sensors"]["imu"]["diagnosis"]
    assert re.fullmatch(r"imu: \d+ (%|consecutive) .*gated out.*: sample timing \(imu\.sample_timing\), frame / bias "
                        r"\(imu\.rpy, specific_force\) or noise level far too low \(imu\.stddev\)", text), text
    assert summary["sample_timing"]["decisions"] == []
