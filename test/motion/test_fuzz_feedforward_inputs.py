"""Property: feedforward's inputs and goals give a result or one line, and their bounds hold before any work.

Waypoint files (mutated rows, cells, headers, sizes) load or raise one one-line InputError;
``feedforward``'s --rate, --move, --hold (NaN, Inf, huge, tiny, negative) either start the
inverse dynamics within the documented bounds (rate <= 1e5 Hz, <= 1e6 samples) or exit 2
with one line before it; a goal's stamp is its start inside the window or one line; a
Cartesian goal message (names, frame, times, poses, quaternions, twists) is a path or one
line. Budgets: conftest's fuzz_settings (fixed and derandomised; ``--fuzz-long`` for a hunt).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import fuzz_settings
from hypothesis import example, given
from hypothesis import strategies as st

from elastic_pm_dyn import cli
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.motion.waypoints import MAX_WAYPOINTS, read_waypoints
from elastic_pm_dyn.ros.feedforward.goal_stamps import NS, STAMP_FUTURE, STAMP_PAST, goal_start, late_start

CONFIG = Path(__file__).resolve().parents[1].parent / "config"
FIVE_BAR = CONFIG / "five_bar.yaml"
NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(
    [0.0, -0.0, 1e-300, 5e-324, 1e300, -1.0, 1e5, 1e5 + 1, 1e6, 1e7, 0.01, 1000.0]))
CELLS = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.sampled_from(
    ["", " ", "x", "1e999", "nan", "-inf", "1_0", "0x10", "1,2", "\ufeff1", "1e-400", "--1", "0.3"]))


def _one_line(text: str) -> None:
    assert text and "\n" not in text and len(text) <= 600, text


@st.composite
def waypoint_files(draw: st.DrawFn) -> str:
    header = draw(st.sampled_from(["t,x,y", "t,left_motor,right_motor", "x,y", "t", "t,x,x", "", "t,x,y,z"]))
    n = draw(st.sampled_from([0, 1, 2, 3, 10, MAX_WAYPOINTS + 1]))
    if n > 50:  # many rows: plain ones (the row bound is what is tested)
        return header + "\n" + "".join(f"{k * 1e-3},-0.05,0.35\n" for k in range(n))
    rows = []
    t = 0.0
    for _ in range(n):
        t += draw(st.sampled_from([0.1, 0.0, -0.1, 1e-9, 100.0]))
        cells = [repr(t)] + [draw(CELLS) if draw(st.booleans()) else repr(draw(st.floats(-1, 1)))
                             for _ in range(draw(st.integers(0, 4)))]
        rows.append(",".join(cells))
    comment = draw(st.sampled_from(["", "# a comment\n", "\n\n"]))
    return comment + header + "\n" + "\n".join(rows) + draw(st.sampled_from(["", "\n", "\r\n"]))


@fuzz_settings(150)
@given(text=waypoint_files())
def test_a_waypoint_file_loads_or_is_one_line(text: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "poses.csv"
        path.write_text(text)
        try:
            columns, table = read_waypoints(path)
        except InputError as err:
            _one_line(str(err))
            assert str(path) in str(err)
            return
    assert 1 <= len(table) <= MAX_WAYPOINTS and table.shape[1] == len(columns) + 1
    assert np.all(np.isfinite(table)) and table[0, 0] >= 0 and np.all(np.diff(table[:, 0]) > 0)


class _WorkStarted(Exception):
    pass


@fuzz_settings(120)
@given(rate=st.one_of(st.none(), NUMBERS), move=st.one_of(st.none(), NUMBERS), hold=st.one_of(st.none(), NUMBERS),
       waypoints=st.booleans())
@example(rate=None, move=None, hold=None, waypoints=False)  # the defaults: the work starts
@example(rate=1e5, move=None, hold=None, waypoints=True)  # at the bound
@example(rate=1000.0, move=999.0, hold=0.3, waypoints=False)  # 999 300 samples
def test_feedforward_sizes_are_checked_before_any_work(rate: float | None, move: float | None,
                                                       hold: float | None, waypoints: bool,
                                                       monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture) -> None:
    """Whatever --rate, --move and --hold hold: exit 2 with one line, or the inverse dynamics
    start with a rate and a table within the bounds (they are stopped there: no run here)."""
    started: list[tuple[float, float]] = []

    def work(model, path, rate, *args, **kwargs):
        started.append((rate, path.duration))
        raise _WorkStarted

    from elastic_pm_dyn.motion import feedforward
    monkeypatch.setattr(feedforward, "path_torques", work)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "tau.csv"
        argv = ["feedforward", "--model", str(FIVE_BAR), "--out", str(out)]
        if waypoints:
            poses = Path(tmp) / "poses.csv"
            poses.write_text("t,x,y\n0,-0.05,0.35\n0.2,0.0,0.4\n")
            argv += ["--waypoints", str(poses)]
        elif move is not None:
            argv.append(f"--move={move!r}")  # (= : a negative number is a value, not an option)
        argv += [f"--{name}={value!r}" for name, value in (("rate", rate), ("hold", hold)) if value is not None]
        try:
            code = cli.main(argv)
        except _WorkStarted:
            code = None
        except SystemExit as exc:  # argparse: a value that is no number
            code = exc.code
        err = capsys.readouterr().err
        assert not out.exists()
    if code is None:  # the work started: within the bounds
        (used, duration), = started
        assert 0 < used <= cli.MAX_CONTROL_RATE and math.isfinite(duration)
        assert duration * used <= cli.MAX_TORQUE_SAMPLES * 1.01  # (a shaper or pre-actuation adds a little)
        return
    assert code == 2 and not started
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(("elastic-pm-dyn: error:", "elastic-pm-dyn feedforward: error:")), err


@fuzz_settings(300)
@given(stamp=st.one_of(st.just(0), st.integers(0, 2**63 - 1), st.integers(-10 * NS, 70 * NS)),
       now=st.one_of(st.integers(0, 2**62), st.integers(0, 100 * NS)), relative=st.booleans(),
       period=st.floats(1e-4, 1.0))
def test_a_goal_stamp_is_a_start_inside_the_window_or_one_line(stamp: int, now: int, relative: bool,
                                                                period: float) -> None:
    if relative:
        stamp = max(0, now + stamp)
    try:
        start = goal_start(stamp, now, "wall time")
    except InputError as err:
        _one_line(str(err))
        assert stamp and not -STAMP_PAST * NS <= stamp - now <= STAMP_FUTURE * NS
        assert "wall time" in str(err) and f"{stamp / NS:.9f} s" in str(err)
        return
    if stamp == 0:
        assert start is None
        return
    assert start == stamp and -STAMP_PAST * NS <= start - now <= STAMP_FUTURE * NS
    late = late_start(start, now, period)
    assert late == 0.0 or late > period  # a passed start: the whole goal, now (never cut by its lateness)


@st.composite
def goal_messages(draw: st.DrawFn) -> Any:
    from test_ros_cartesian_goals import goal
    n = draw(st.integers(0, 5))
    times = sorted(draw(st.lists(st.sampled_from([0.0, 0.001, 0.05, 0.2, 0.3, 1.0, 200.0, -0.1]), min_size=n,
                                 max_size=n)))
    if draw(st.booleans()):
        times = times[::-1]
    xyz = [[draw(st.sampled_from([-0.05, 0.0, 0.05, 0.5, np.nan, 1e300])),
            draw(st.sampled_from([0.35, 0.4, 0.45, -0.3, np.inf])),
            draw(st.sampled_from([0.0, 0.0, 0.01]))] for _ in range(n)]
    quats = [draw(st.sampled_from([[0, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0.0436, 0.999], [0, 0, 0, 1.01],
                                   [np.nan, 0, 0, 1]])) for _ in range(n)]
    twist = draw(st.one_of(st.none(), st.sampled_from([[0.0] * 6, [0.1, 0, 0, 0, 0, 0], [0, 0, 0.1, 0, 0, 0],
                                                       [0, 0, 0, 0, 0, 0.1], [np.nan] * 6])))
    return goal(times, xyz, quats, name=draw(st.sampled_from(["end_effector", "tool0", ""])),
                frame=draw(st.sampled_from(["world", "", "map"])), twist=twist)


@fuzz_settings(100)
@given(data=st.data())
def test_a_cartesian_goal_is_a_path_or_one_line(data: st.DataObject) -> None:
    pytest.importorskip("trajectory_msgs")
    from elastic_pm_dyn.ros.feedforward.cartesian_goals import MAX_SAMPLES, MIN_PERIODS, goal_path
    msg = data.draw(goal_messages())
    try:
        path = goal_path(msg, _five_bar(), "world", data.draw(st.sampled_from([2, 4])), 1000.0)
    except (InputError, ValueError) as err:  # (the node's callback takes both)
        _one_line(str(err))
        return
    assert MIN_PERIODS <= path.move * 1000.0 <= MAX_SAMPLES
    y, yd, ydd = path(0.0)
    assert np.all(np.isfinite(np.concatenate([y, yd, ydd])))


_MODEL: list[Any] = []


def _five_bar() -> Any:
    if not _MODEL:
        from elastic_pm_dyn.model.loader import load_model
        _MODEL.append(load_model(FIVE_BAR))
    return _MODEL[0]


@fuzz_settings(150)
@given(names=st.lists(st.sampled_from(["left_motor", "right_motor", "left_elbow", ""]), max_size=3),
       times=st.lists(st.sampled_from([0.0, 0.1, 0.2, 0.2, -1.0, 1e300, np.nan]), max_size=5),
       values=st.lists(st.lists(st.sampled_from([2.6, 0.87, 0.0, np.nan, np.inf, 1e300]), max_size=3), max_size=5),
       rates=st.booleans(), accelerations=st.booleans())
def test_a_joint_trajectory_is_a_path_or_one_line(names: list[str], times: list[float], values: list[list[float]],
                                                  rates: bool, accelerations: bool) -> None:
    """What the node checks in its callback, before a goal's process: names, sizes, times, NaN."""
    from elastic_pm_dyn.motion.references import joint_path
    mech = _rigid()
    vel = values if rates else None
    acc = values if accelerations else None
    try:
        path = joint_path(mech, names, times, values, vel, acc)
    except InputError as err:  # (the node's callback takes these: anything else would end its executor)
        _one_line(str(err))
        return
    assert sorted(names) == sorted(mech.active_names)
    qa, qda, qdda = path(float(path.start))
    assert np.all(np.isfinite(np.concatenate([qa, qda, qdda])))


def _rigid() -> Any:
    from elastic_pm_dyn.motion.feedforward import rigid_feedforward
    return rigid_feedforward(_five_bar()).mech
