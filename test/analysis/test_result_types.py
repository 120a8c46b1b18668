"""Typed results: ``epd.analyze``'s :class:`AnalysisReport` and ``epd.observe``'s :class:`ObserveSummary`
are ``summary.json`` as objects: what the file holds reads back into an equal object, ``to_dict``
gives the file's content key for key and in its order, and the attributes hold typed parts."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from bag_factory import MODEL, run_messages, synthetic_run, write_bag

from elastic_pm_dyn.analysis.report import analyze
from elastic_pm_dyn.analysis.report_types import (
    AnalysisReport,
    BagInfo,
    BranchForces,
    Comparison,
    Gap,
    HoldPhase,
    Note,
    PathMetrics,
    RunMetrics,
    StreamStats,
    TimeZero,
    Torques,
    VibrationFit,
)
from elastic_pm_dyn.bags.typestore import make_typestore
from elastic_pm_dyn.observer import ObserverConfig
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag
from elastic_pm_dyn.observer.drivers.results import ObserveSummary, SensorCounts
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

pytest.importorskip("rosbags")


# ---------------------------------------------------------------------------- analyze
@pytest.fixture(scope="module")
def analysed(tmp_path_factory) -> tuple[AnalysisReport, Path, object]:
    tmp = tmp_path_factory.mktemp("typed_analysis")
    run = synthetic_run()
    a = write_bag(tmp / "a", run_messages(run, make_typestore()))
    b = write_bag(tmp / "b", run_messages(synthetic_run(offset=(0.0, 3e-4), amplitude=1.0), make_typestore()))
    return analyze(MODEL, [a, b], tmp / "out", plots_on=False), tmp / "out", run


def test_analysis_report_reads_back_from_summary_json(analysed) -> None:
    report, out, _ = analysed
    text = (out / "summary.json").read_text()
    assert AnalysisReport.from_dict(json.loads(text)) == report
    assert json.dumps(report.to_dict(), indent=2) == text  # same keys, same order, same numbers
    assert "plots" not in json.loads(text) and report.plots is None  # plots off: no key


def test_analysis_report_attributes_are_typed(analysed) -> None:
    report, out, run = analysed
    assert list(report.runs) == ["a", "b"] and all(isinstance(r, RunMetrics) for r in report.runs.values())
    m = report.runs["a"]
    assert isinstance(m.time_zero, TimeZero) and isinstance(m.hold_phase, HoldPhase)
    assert isinstance(m.path, PathMetrics) and isinstance(m.branch_forces, BranchForces)
    assert isinstance(m.gap, Gap) and isinstance(m.torques, Torques)
    assert all(isinstance(v, VibrationFit) for v in m.vibration.values()) and set(m.vibration) == {"left", "right"}
    assert isinstance(m.bag, BagInfo) and m.bag.storage == "mcap" and m.bag.path.endswith("a")
    forces = m.streams["branch_forces"]
    assert isinstance(forces, StreamStats) and forces.messages == len(run.t_force)
    assert forces.rate_hz == pytest.approx(5000.0) and m.streams["joint_states"].gaps == 0
    # the injected truth, through the attributes
    assert m.path.max_error_m == pytest.approx(np.linalg.norm(run.truth["offset"]), rel=1e-6)
    assert m.hold_phase.start_s == pytest.approx(run.truth["hold_start"], abs=1e-9)
    assert isinstance(m.path.samples, int) and isinstance(m.vibration["left"].aliased, bool)
    assert isinstance(m.gap.at_hold_start_m, float)  # the run has a hold phase: the key is there
    (comp,) = report.comparison
    assert isinstance(comp, Comparison) and (comp.baseline, comp.other) == ("a", "b")
    written = json.loads((out / "summary.json").read_text())
    assert written["runs"]["a"]["hold_phase"] == {"start_s": m.hold_phase.start_s, "from": m.hold_phase.source}
    assert written["comparison"][0]["metric_difference"] == comp.metric_difference


def test_run_metrics_keep_absent_and_null_apart() -> None:
    """A key the file lacks stays absent, a null stays null (NaN gap at the hold start, a note)."""
    gap = {"source": "s", "max_m": 1e-6, "t_max_s": 0.1, "final_m": None}
    assert Gap.from_dict(gap).to_dict() == gap and Gap.from_dict(gap).at_hold_start_m is None
    with_null = gap | {"at_hold_start_m": None}
    assert math.isnan(Gap.from_dict(with_null).at_hold_start_m) and Gap.from_dict(with_null).to_dict() == with_null
    run = {"label": "x", "time_zero": {"stamp_s": 1.5, "from": "first stamp"},
           "hold_phase": {"start_s": None, "from": None}, "path": {"note": "no overlap"},
           "vibration": {"left": {"note": "constant"}}, "command_age": {}, "streams": {}, "warnings": ["w"]}
    m = RunMetrics.from_dict(run)
    assert m.path == Note("no overlap") and m.vibration["left"] == Note("constant") and m.gap is None
    assert m.to_dict() == run and list(m.to_dict()) == list(run)
    extra = {"model": "m.yaml", "model_natural_hz": [550.0], "natural_hz_at": "start pose", "runs": {"x": run},
             "manoeuvre": {"move_s": 0.1}, "plots": {}}
    r = AnalysisReport.from_dict(extra)
    assert r.extra == {"manoeuvre": {"move_s": 0.1}} and r.plots == {} and r.comparison is None
    assert list(r.to_dict()) == list(extra)


def test_parts_are_json_ready_when_made_and_name_what_was_not_finite() -> None:
    """Made from computations (numpy values, NaN, Inf): Python values, None for the non-finite ones
    and their key paths in the file's order; a NaN gap at the hold start stays NaN (null in JSON)."""
    torques = Torques(source="t", peak_Nm={"left": np.float64(np.inf), "right": np.float64(1.5)})
    assert torques.peak_Nm == {"left": None, "right": 1.5} and type(torques.peak_Nm["right"]) is float
    assert torques.non_finite == ["peak_Nm.left"]
    gap = Gap("g", np.float64(1e-6), 0.1, float("nan"), at_hold_start_m=np.float64("nan"))
    assert gap.final_m is None and math.isnan(gap.at_hold_start_m)
    assert gap.non_finite == ["final_m", "at_hold_start_m"]
    assert gap.to_dict() == {"source": "g", "max_m": 1e-6, "t_max_s": 0.1, "final_m": None, "at_hold_start_m": None}
    assert Gap("g", 1.0, 0.1, 1.0, at_hold_start_m=math.inf).to_dict()["at_hold_start_m"] is None  # as NaN
    run = RunMetrics(label="x", time_zero=TimeZero(np.float64(2.0), "first stamp"), hold_phase=HoldPhase(0.2, "h"),
                     path=None, vibration={"left": Note("constant")}, command_age={"from_stamps": {"max_s": np.nan}},
                     streams={}, warnings=["w"], gap=gap, torques=torques, diagnostics={"values": np.array([1, 2])})
    assert run.non_finite == ["gap.final_m", "gap.at_hold_start_m", "torques.peak_Nm.left",
                              "command_age.from_stamps.max_s"]
    assert run.diagnostics == {"values": [1, 2]} and type(run.time_zero.stamp_s) is float
    run.warn_non_finite()
    assert run.warnings[-1] == ("not finite, null in summary.json: gap.final_m, gap.at_hold_start_m, "
                                "torques.peak_Nm.left, command_age.from_stamps.max_s (NaN or Inf in the bag?)")
    content = json.loads(json.dumps(run.to_dict()))
    assert RunMetrics.from_dict(content) == run and content["command_age"] == {"from_stamps": {"max_s": None}}


# ---------------------------------------------------------------------------- observe
@pytest.fixture(scope="module")
def observed(five_bar, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("typed_observe")
    bag = tmp / "in"
    recording_to_bag(manoeuvre_recording(five_bar, duration=0.06, seed=3), bag, use=("encoders", "imu"))
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
    quiet = {"log": lambda line: None, "write_estimates_bag": False}
    return {smoother: (observe_bag(five_bar, cfg, bag, tmp / f"out_{smoother}", smoother=smoother, **quiet),
                       tmp / f"out_{smoother}") for smoother in (None, "rts")}


@pytest.mark.parametrize("smoother", [None, "rts"])
def test_observe_summary_reads_back_from_summary_json(observed, smoother) -> None:
    result, out = observed[smoother]
    text = (out / "summary.json").read_text()
    back = ObserveSummary.from_dict(json.loads(text))
    assert json.dumps(back.to_dict(), indent=2, default=float) == text  # NaN (mean NIS) is not == itself
    assert json.dumps(result.summary.to_dict(), indent=2, default=float) == text
    keys = list(json.loads(text))  # the file's order
    assert keys[:3] == ["bag", "topics", "messages"] and list(result.summary.to_dict()) == keys
    assert keys[-3:] == ["wall_write_s", "wall_total_s", "speed_factor"]
    assert ("smoothing" in keys) == (smoother is not None)


def test_observe_summary_attributes_are_typed(observed) -> None:
    result, out = observed[None]
    s = result.summary
    csv_rows = len((out / "estimates.csv").read_text().splitlines()) - 1
    assert isinstance(s.rows, int) and s.rows == csv_rows == len(result.rows.t) > 0
    assert isinstance(s.health, tuple) and isinstance(s.health[0], int) and isinstance(s.health[1], str)
    assert json.loads((out / "summary.json").read_text())["health"] == list(s.health)
    assert set(s.sensors) >= {"encoders", "imu"} and all(isinstance(v, SensorCounts) for v in s.sensors.values())
    assert s.sensors["encoders"].accepted > 0 and isinstance(s.sensors["encoders"].mean_nis, float)
    assert s.smoother is None and s.smoothing is None and not s.fault
    assert s.duration_s == pytest.approx(0.06, abs=2e-3) and s.speed_factor == pytest.approx(
        s.duration_s / s.wall_total_s)
    smoothed = observed["rts"][0].summary
    assert smoothed.smoother == "rts" and smoothed.smoothing["rows"] == smoothed.rows
