"""Bag analysis: read (mcap, sqlite3, with/without definitions), metrics against injected truth,
two-bag comparison, bounded-memory streaming, export, errors, command line, paper figures.

The bags are written with a plain ``rosbags`` Writer the way our nodes publish (see
bag_factory.py); test_analysis_recorder.py covers bags written by the recorder node.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np
import pytest
from bag_factory import MODEL, run_messages, synthetic_run, write_bag

from elastic_pm_dyn.analysis.bags import read_bag
from elastic_pm_dyn.analysis.report import analyze
from elastic_pm_dyn.analysis.streams import SampleBuffer, StreamTimer, WindowBuffer
from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.typestore import make_typestore


@pytest.fixture(scope="module")
def run():
    return synthetic_run()


@pytest.fixture(scope="module")
def bag_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("bags")


def _bag(bag_dir: Path, name: str, run, storage: str = "mcap", definitions: bool = True, **kw) -> Path:
    path = bag_dir / name
    if not path.exists():
        write_bag(path, run_messages(run, make_typestore(), **kw), storage, definitions)
    return path


@pytest.fixture(scope="module")
def other():
    """A second run: other path offset, half the vibration amplitude."""
    return synthetic_run(offset=(0.0, 3e-4), amplitude=1.0)


@pytest.fixture(scope="module")
def summary(run, other, bag_dir, tmp_path_factory):
    """The reference bag and a second one (sqlite3 without definitions) analysed once, with plots."""
    out = tmp_path_factory.mktemp("analysis")
    bags = [_bag(bag_dir, "ref_mcap", run), _bag(bag_dir, "other_sqlite", other, "sqlite3", False)]
    return analyze(MODEL, bags, out, labels=["SCDD", "L-D'A"]), out


# ------------------------------------------------------------------------- reading
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("definitions", [True, False])
def test_reads_every_storage_with_and_without_definitions(run, bag_dir, storage, definitions):
    path = _bag(bag_dir, f"{storage}_{definitions}", run, storage, definitions)
    if not definitions:  # really without: rosbags alone cannot decode it
        from rosbags.highlevel import AnyReader, AnyReaderError
        with pytest.raises(AnyReaderError, match="no type definitions"), AnyReader([path]):
            pass
    data = read_bag(path)
    assert data.storage == storage
    assert data.roles == {"joint_states": "/joint_states", "branch_forces": "/branch_forces",
                          "torque_command": "/torque_command", "reference": "/reference_joint_states",
                          "measured": None, "ee_pose": "/ee_pose", "diagnostics": "/diagnostics",
                          "wrench": None, "wrench_stddev": None, "wrench_truth": None, "contact": None}
    bf = data.series["branch_forces"]
    assert bf.stamp_source == "header" and bf.stride == 1 and bf.count == len(run.t_force)
    np.testing.assert_array_equal(bf.fields["force"], run.forces)  # exact, through CDR
    np.testing.assert_allclose(bf.t - bf.t[0], run.t_force, atol=1e-12)
    js = data.series["joint_states"]
    np.testing.assert_array_equal(js.columns("position", run.joint_names), run.q)  # by name, not order
    assert js.timing.rate == pytest.approx(1000.0) and js.timing.gaps == 0
    assert data.diagnostics.values["plant: plant/command_age_s"][1][0] == 0.001


def test_single_storage_file_and_typestore_for_mixed_definitions(run, bag_dir):
    """A .mcap file alone reads like its directory."""
    path = _bag(bag_dir, "ref_mcap", run)
    data = read_bag(next(path.glob("*.mcap")))
    assert data.series["branch_forces"].count == len(run.t_force)


# ------------------------------------------------------------------------- metrics
def test_metrics_against_injected_truth(run, summary):
    s, _ = summary
    m = s.runs["SCDD"]
    truth = run.truth
    assert m.hold_phase.start_s == pytest.approx(truth["hold_start"], abs=1e-9)
    off = np.linalg.norm(truth["offset"])
    assert m.path.max_error_m == pytest.approx(off, rel=1e-6)
    assert m.path.final_position_error_m == pytest.approx(off, rel=1e-6)
    np.testing.assert_allclose(m.path.final_error_vector_m, truth["offset"], atol=1e-9)
    for b, peak in zip(run.branch_names, truth["peak_force"], strict=True):
        assert m.branch_forces.peak_N[b] == pytest.approx(peak, rel=1e-12)
    v = m.vibration["left"]
    assert abs(v.f_d_hz - truth["f_d"]) < 1.0
    assert v.zeta == pytest.approx(truth["zeta"], rel=0.05)
    assert v.amplitude_N == pytest.approx(truth["amplitude"], rel=0.02)
    assert not v.aliased
    assert m.vibration["right"].amplitude_N == pytest.approx(0.5 * truth["amplitude"], rel=0.02)
    assert m.gap.max_m == pytest.approx(truth["gap_max"], rel=1e-6)
    assert 0.10 <= m.gap.t_max_s < 0.12
    assert m.gap.final_m < 1e-12
    for n, peak in zip(run.motor_names, truth["peak_torque"], strict=True):
        assert m.torques.peak_Nm[n] == pytest.approx(peak, rel=1e-12)
    assert m.command_age["reported_by_plant"]["max"] == 0.001
    assert m.streams["branch_forces"].rate_hz == pytest.approx(5000.0)
    assert m.warnings == []
    assert len(s.model_natural_hz) == 2


def test_report_files_and_plots(summary):
    s, out = summary
    assert json.loads((out / "summary.json").read_text()) == s.to_dict()
    md = (out / "summary.md").read_text()
    assert "| residual vibration left: frequency [Hz] | 552 | 552 | " in md
    assert "| L-D'A - SCDD |" in md
    for name in ("path", "branch_forces", "gap", "torques", "tracking_error", "spectrum", "force_difference",
                 "path_difference"):
        png = out / s.plots[name]
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_nan_joint_states_are_plotted_as_gaps(run, bag_dir, tmp_path):
    """Joint states with NaN rows (a recording of a fault) give every plot, the path's deviation
    panel too, from the finite samples (it raised 'x must be finite' before)."""
    from dataclasses import replace
    q = run.q.copy()
    q[200:203] = np.nan
    s = analyze(MODEL, [_bag(bag_dir, "nan_q_mcap", replace(run, q=q))], tmp_path)
    png = tmp_path / s.plots["path"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_aliasing_at_the_control_rate_is_detected_and_unfolded(bag_dir):
    """Branch forces sampled at 1 kHz: the 552 Hz mode shows at 448 Hz; the model's modes unfold it."""
    slow = synthetic_run(force_rate=1000.0)
    s = analyze(MODEL, [_bag(bag_dir, "forces_1khz", slow)], bag_dir / "out_1khz", plots_on=False)
    m = s.runs["forces_1khz"]
    v = m.vibration["left"]
    assert v.aliased and abs(v.f_apparent_hz - 448.0) < 1.0
    assert abs(v.f_d_hz - 552.0) < 1.0
    assert any("Nyquist" in w and "aliased" in w for w in m.warnings)


def test_two_bags_side_by_side(run, other, summary):
    s, _ = summary
    comp = s.comparison[0]
    assert (comp.baseline, comp.other) == ("SCDD", "L-D'A")
    d = comp.metric_difference
    assert d["path.max_error_m"] == pytest.approx(3e-4 - np.linalg.norm(run.truth["offset"]), rel=1e-6)
    assert d["vibration.left.amplitude_N"] == pytest.approx(-1.0, abs=0.02)
    # Same motion, force oscillation halved: the difference of the series is an oscillation of 1 N
    # (its largest sample: cos(0.3) at the hold start, then decaying).
    assert 0.93 < comp.series_difference["branch_force_left_max_abs_N"] < 1.0
    assert comp.series_difference["end_effector_max_distance_m"] == pytest.approx(
        np.linalg.norm(np.array([0.0, 3e-4]) - run.truth["offset"]), rel=1e-6)
    assert s.runs["L-D'A"].bag.storage == "sqlite3"


def test_topics_found_by_type_and_words_or_given(run, bag_dir):
    msgs = run_messages(run, make_typestore(), command="float64")
    renamed = {"/joint_states": "/robot/joint_states", "/reference_joint_states": "/desired_joint_states",
               "/branch_forces": "/legs", "/torque_command": "/effort_cmd"}
    path = bag_dir / "renamed"
    write_bag(path, [(renamed.get(t, t), ty, ns, m) for t, ty, ns, m in msgs], "mcap")
    data = read_bag(path)
    assert data.roles["joint_states"] == "/robot/joint_states"
    assert data.roles["reference"] == "/desired_joint_states"
    assert data.roles["branch_forces"] == "/legs"
    assert data.roles["torque_command"] == "/effort_cmd"
    assert data.series["torque_command"].stamp_source == "receive"  # Float64MultiArray: no header
    data = read_bag(path, {"reference": "robot/joint_states", "joint_states": "/desired_joint_states"})
    assert data.roles["reference"] == "/robot/joint_states"
    with pytest.raises(BagError, match="/legs is elastic_pm_dyn_msgs/msg/BranchForces"):
        read_bag(path, {"joint_states": "/legs"})
    s = analyze(MODEL, [path], bag_dir / "out_renamed", plots_on=False).runs["renamed"]
    # Unnamed Float64MultiArray columns are the model's motors; times moved onto the header clock.
    assert s.torques.peak_Nm["left_motor"] == pytest.approx(run.truth["peak_torque"][0], rel=1e-12)
    assert any("/effort_cmd: stamped on another clock" in w for w in s.warnings)


def test_missing_topics_are_reported_and_the_rest_analyzed(run, bag_dir):
    path = bag_dir / "partial"
    write_bag(path, run_messages(run, make_typestore(), topics={"/joint_states", "/torque_command"}), "sqlite3")
    s = analyze(MODEL, [path], bag_dir / "out_partial", plots_on=False).runs["partial"]
    w = " | ".join(s.warnings)
    assert "branch_forces: no topic of type elastic_pm_dyn_msgs/msg/BranchForces" in w
    assert "reference: no topic" in w and "hold phase not found" in w
    assert s.path is None and s.vibration == {}
    assert s.branch_forces.source.startswith("joint states")  # F = c u + d du/dt of the states
    assert s.gap.max_m == pytest.approx(run.truth["gap_max"], rel=1e-6)
    # The hold phase can be given instead (then the forces from the states are fitted).
    s = analyze(MODEL, [path], bag_dir / "out_partial2", hold_start=0.2, plots_on=False).runs["partial"]
    assert s.hold_phase.to_dict() == {"start_s": 0.2, "from": "--hold-start"}


# ------------------------------------------------------------------- bounded memory
def test_large_bag_is_decimated_with_a_full_rate_window(run, bag_dir):
    path = _bag(bag_dir, "ref_mcap", run)
    data = read_bag(path, max_samples=200, window_samples=800)
    bf = data.series["branch_forces"]
    assert bf.count == len(run.t_force) and bf.stride == 16 and 100 <= len(bf.t) <= 200
    np.testing.assert_array_equal(bf.fields["force"], run.forces[::16])  # uniform decimation
    np.testing.assert_allclose(bf.peak_hi["force"], run.forces.max(axis=0))  # peaks over all messages
    w = bf.window  # armed online where the reference came to rest
    assert len(w.t) == 800
    np.testing.assert_array_equal(w.fields["force"], run.forces[1000:1800])
    # More stamps than 5 x max_samples: timing from a histogram of 1 % bins, counts exact.
    assert not bf.timing.exact and bf.timing.count == len(run.t_force) and bf.timing.gaps == 0
    assert bf.timing.rate == pytest.approx(5000.0, rel=0.01)
    s = analyze(MODEL, [path], bag_dir / "out_decimated", plots_on=False, max_samples=200,
                window_samples=800).runs["ref_mcap"]
    assert abs(s.vibration["left"].f_d_hz - 552.0) < 1.0
    assert s.vibration["left"].zeta == pytest.approx(0.012, rel=0.05)
    assert s.branch_forces.peak_N["left"] == pytest.approx(run.truth["peak_force"][0], rel=1e-12)
    assert any("decimated by 16" in w for w in s.warnings)


def test_sample_buffer_window_and_timer_stay_bounded():
    buf = SampleBuffer(1, cap=8)
    for k in range(100):
        buf.append(np.array([k]))
    assert buf.stride == 16 and list(buf.rows[:, 0]) == list(range(0, 100, 16))
    ring = WindowBuffer(1, 5)
    for k in range(12):
        ring.append(np.array([k]))
    assert list(ring.rows[:, 0]) == [7, 8, 9, 10, 11]
    rng = np.random.default_rng(3)
    stamps = np.cumsum(1e-3 + 2e-5 * rng.standard_normal(5000))
    stamps[2000:] += 0.05  # one gap of 50 ms
    exact, timer = StreamTimer(10_000), StreamTimer(100)
    for s in stamps:
        exact.add(s)
        timer.add(s)
    a, b = exact.stats(), timer.stats()
    assert a.exact and not b.exact
    assert b.count == a.count and b.gaps == a.gaps == 1
    assert b.longest_gap == pytest.approx(a.longest_gap, rel=1e-12)
    assert b.period_median == pytest.approx(a.period_median, rel=0.01)
    assert b.period_p99 == pytest.approx(a.period_p99, rel=0.01)


# ---------------------------------------------------------------- export, command line
def test_export_one_csv_per_topic(run, bag_dir, tmp_path):
    from elastic_pm_dyn.analysis.export import export_bag

    exported = {e.topic: e for e in export_bag(_bag(bag_dir, "sqlite3_False", run, "sqlite3", False), tmp_path)}
    assert set(exported) == {"/joint_states", "/branch_forces", "/torque_command", "/reference_joint_states",
                             "/ee_pose", "/diagnostics"}
    with exported["/joint_states"].file.open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(run.t_state)
    k = len(rows) // 2
    assert float(rows[k]["position.right_elbow"]) == run.q[k, run.joint_names.index("right_elbow")]  # repr: exact
    assert rows[0]["header.stamp"] == "1000.000000000"
    with exported["/diagnostics"].file.open() as fh:
        diag = next(csv.DictReader(fh))
    assert diag["status.0.values.command_age_s"] == "0.001"
    assert exported["/branch_forces"].columns == 1 + 2 + 2 * 3  # time, header, force/deflection/rate per branch


def _cli(argv: list[str]) -> int:
    """The main CLI with our subcommands registered (as elastic_pm_dyn.cli does)."""
    from elastic_pm_dyn import cli
    from elastic_pm_dyn.analysis.cli import register_cli

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    if "analyze" not in sub.choices:
        register_cli(sub)
    orig = cli.build_parser
    cli.build_parser = lambda: parser
    try:
        return cli.main(argv)
    finally:
        cli.build_parser = orig


def test_command_line(run, bag_dir, tmp_path, capsys):
    bag = _bag(bag_dir, "ref_mcap", run)
    assert _cli(["analyze", str(bag), "--model", str(MODEL), "--out", str(tmp_path / "a"), "--no-plots"]) == 0
    assert "left: 552.0 Hz" in capsys.readouterr().out
    assert json.loads((tmp_path / "a" / "summary.json").read_text())["runs"]["ref_mcap"]["path"]
    assert _cli(["export", str(bag), "--out", str(tmp_path / "e"), "--topics", "branch_forces"]) == 0
    assert [p.name for p in (tmp_path / "e").iterdir()] == ["branch_forces.csv"]
    assert _cli(["analyze", str(tmp_path / "nothing"), "--out", str(tmp_path / "b")]) == 2
    assert "no such bag" in capsys.readouterr().err
    assert _cli(["analyze", str(bag), str(bag), "--labels", "x", "--out", str(tmp_path / "c")]) == 2
    assert _cli(["export", str(bag), "--out", str(tmp_path / "e2"), "--topics", "/nope"]) == 2
    assert "no topic /nope" in capsys.readouterr().err
    # a topic the user names that the bag lacks: one line, exit 2, nothing written (it was a warning and exit 0)
    assert _cli(["analyze", str(bag), "--out", str(tmp_path / "d"), "--joint-states", "/nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "topic /nope (--joint-states) is not in the bag" in err[0] and str(bag) in err[0]
    assert not (tmp_path / "d").exists()


def test_paper_figures(tmp_path):
    """Figs. 2-4 on a short manoeuvre: SCDD equals L-D'A, the one-pass loop drifts."""
    from elastic_pm_dyn.analysis.paper import RUNS, paper_figures
    from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
    from elastic_pm_dyn.motion.trajectory import QuinticLine

    line = QuinticLine(REFERENCE_MANOEUVRE.line.start, REFERENCE_MANOEUVRE.line.end, move=0.05, hold=0.03)
    runs = {k: v for k, v in RUNS.items() if k != "SCDD (no stabilisation)"}
    figs = paper_figures(tmp_path, MODEL, line, runs)
    for name in ("fig2_path.png", "fig3_branch_forces.png", "fig4_gap.png", "fig2_path.csv", "summary.md"):
        assert (tmp_path / name).stat().st_size > 1000
    assert json.loads((tmp_path / "paper_figures.json").read_text())["fig4_gap"] == figs["fig4_gap"]
    diff = figs["difference_to_L-D'A"]
    assert diff["SCDD"]["max_joint_difference"] < 1e-9
    gaps = figs["fig4_gap"]["runs"]
    assert gaps["SCDD one-pass (paper)"]["max_m"] > 1e3 * gaps["SCDD"]["max_m"]
    vib = figs["fig3_branch_forces"]["runs"]["SCDD"]["residual_vibration"]["left"]
    assert 500.0 < vib["f_d_hz"] < 600.0
    header = (tmp_path / "fig4_gap.csv").read_text().splitlines()[0]
    assert header.startswith('"t","L-D\'A gap"')
