"""The reference manoeuvre is written once; joint splines pass through their waypoints."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.motion.manoeuvre import REFERENCE_MANOEUVRE
from elastic_pm_dyn.motion.trajectory import JointSpline

CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_reference_line_is_made_from_the_manoeuvre() -> None:
    line = REFERENCE_MANOEUVRE.line
    np.testing.assert_array_equal(line.start, REFERENCE_MANOEUVRE.start)
    np.testing.assert_array_equal(line.end, REFERENCE_MANOEUVRE.end)
    assert (line.move, line.hold) == (REFERENCE_MANOEUVRE.move, REFERENCE_MANOEUVRE.hold)
    line.start[0] = 99.0  # every line has arrays of its own
    assert REFERENCE_MANOEUVRE.line.start[0] == REFERENCE_MANOEUVRE.start[0]


@pytest.mark.parametrize("change", [{"control_rate": 0.0}, {"sample": -1e-4}, {"move": 0.0}, {"hold": -0.1},
                                    {"end": (0.05, 0.45, 0.0)}])
def test_manoeuvre_rejects_bad_numbers(change: dict) -> None:
    with pytest.raises(InputError):
        replace(REFERENCE_MANOEUVRE, **change)


def test_feedforward_parameter_file_repeats_the_reference_manoeuvre() -> None:
    """config/feedforward.yaml spells the defaults out for its readers: they must be the constants."""
    params = yaml.safe_load((CONFIG / "feedforward.yaml").read_text())["/**"]["ros__parameters"]
    m = REFERENCE_MANOEUVRE
    assert params["rate"] == m.control_rate
    assert params["line"] == {"start": list(m.start), "end": list(m.end), "move": m.move, "hold": m.hold,
                              "law": ""}  # "": the method's own law (quintic for rigid)
    assert params["method"] == "rigid"


def test_launch_files_take_the_manoeuvre_from_the_parameter_file() -> None:
    """No launch file sets the manoeuvre's numbers itself (they would be a second copy)."""
    for path in (CONFIG.parent / "launch").glob("*.py"):
        text = path.read_text()
        assert "feedforward.yaml" in text or "feedforward" not in text, path
        for key in ("line.start", "line.end", "line.move", "line.hold", '"rate"'):
            assert key not in text, (path, key)


def test_joint_spline_meets_waypoints_in_output_order_and_rests_outside() -> None:
    times = [0.5, 1.0, 2.0]
    pos = [[0.0, 1.0], [0.2, 1.5], [0.1, 2.0]]  # columns: joint b, joint a
    vel = [[0.0, 0.0], [0.3, -1.0], [0.0, 0.0]]
    path = JointSpline(times, pos, [1, 0], vel)  # output: a, b
    for t, p, v in zip(times, pos, vel, strict=True):
        q, qd, _ = path(t)
        np.testing.assert_allclose(q, p[::-1], atol=1e-12)
        if t not in (path.start, path.end):
            np.testing.assert_allclose(qd, v[::-1], atol=1e-12)
    for t in (0.0, 3.0):
        q, qd, qdd = path(t)
        np.testing.assert_array_equal(q, path.positions[0 if t < 1 else -1])
        assert not qd.any() and not qdd.any()
    with pytest.raises(InputError, match="accelerations need velocities"):
        JointSpline(times, pos, [0, 1], accelerations=vel)


def test_feedforward_command_defaults_to_the_reference_manoeuvre(tmp_path: Path) -> None:
    """`elastic-pm-dyn feedforward` without --line/--move/--hold/--rate writes the reference manoeuvre's torques."""
    from elastic_pm_dyn.cli import main
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.motion.feedforward import line_torques

    out = tmp_path / "torques.csv"
    assert main(["feedforward", "--model", str(CONFIG / "five_bar.yaml"), "--out", str(out)]) == 0
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    times, torques, _ = line_torques(load_model(CONFIG / "five_bar.yaml"), REFERENCE_MANOEUVRE.line,
                                     REFERENCE_MANOEUVRE.control_rate)
    np.testing.assert_allclose(table[:, 0], times, rtol=0, atol=1e-12)
    np.testing.assert_allclose(table[:, 1:], torques, rtol=1e-12, atol=1e-12)
