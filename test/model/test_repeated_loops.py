"""Closure rows that repeat other loops' rows (issue #26): a body closed twice is reduced
exactly, as rows that hold by themselves are, and the machine matches MuJoCo (constraints
tightened) on the same file. Here the welded-knees leg of test_published_constructs with its
first knee's rocker also joined to its top by a <connect> at a point off the weld: the
connect's rows repeat the weld's (pos + turn x offset)."""

from __future__ import annotations

import pytest
from test_published_constructs import WELD_LEG, _write, dropped_lines, leg_against_mujoco

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model

CLOSED_TWICE = WELD_LEG.replace(
    '<weld body1="rocker2_top" body2="rocker2"/>',
    '<weld body1="rocker2_top" body2="rocker2"/>\n'
    '    <connect body1="rocker_top" body2="rocker" anchor="-0.03 0.02 0.01"/>')


# the same knee welded twice (the second weld written rocker to rocker_top): its three rows that
# do not hold by themselves (the two positions across the hinges, the turn about them) repeat the
# first weld's
WELDED_TWICE = CLOSED_TWICE.replace('<connect body1="rocker_top" body2="rocker" anchor="-0.03 0.02 0.01"/>',
                                    '<weld body1="rocker" body2="rocker_top"/>')


@pytest.mark.parametrize(("text", "repeated"), [(CLOSED_TWICE, 0b011), (WELDED_TWICE, 0b100011)],
                         ids=["weld-and-connect", "two-welds"])
def test_a_body_closed_twice_is_reduced_and_matches_mujoco(tmp_path, text, repeated):
    path = _write(tmp_path, text)
    mech = Mechanism(load_model(path))
    closure = mech.model.closure
    # pair 3's rows that do not hold by themselves all repeat the first weld's
    assert len(closure.pairs) == 3 and dict(closure.repeated) == {2: repeated}
    assert mech.m == 6 and len(mech.passive) == 6  # 6 + 6 + 3 rows in the file, 6 kept
    moved, err = leg_against_mujoco(path, mech)
    print(f"\nknee closed twice ({bin(repeated)} repeated) against MuJoCo (tightened): roll moved {moved:.3g} rad, "
          f"max |q - q_mujoco| {err:.2e} rad")
    assert moved > 0.05
    assert err < 1e-6


def test_check_says_which_rows_repeat_other_loops(tmp_path):
    dropped = dropped_lines(_write(tmp_path, CLOSED_TWICE))
    again = [line for line in dropped if "repeat rows of the other closures" in line]
    assert len(again) == 1 and "closure 3" in again[0], dropped
    assert any("holds by itself" in line and "closure 3" in line for line in dropped), dropped


def test_a_weld_that_contradicts_another_is_still_refused_in_one_line(tmp_path):
    """Two welds of one body pair at different turns: no pose holds both (inconsistent, not repeated)."""
    from elastic_pm_dyn.errors import ModelError
    text = CLOSED_TWICE.replace('<connect body1="rocker_top" body2="rocker" anchor="-0.03 0.02 0.01"/>',
                                '<weld body1="rocker_top" body2="rocker" relpose="0 0 0 0.9 0.4 0 0"/>')
    with pytest.raises(ModelError) as err:
        load_model(_write(tmp_path, text))
    message = str(err.value)
    assert "\n" not in message and "robot.xml" in message and "cannot all hold" in message
    lines = [n for n, row in enumerate(text.splitlines(), 1) if "<weld body1=\"rocker_top\"" in row]
    assert all(f"(line {n})" in message for n in lines), message  # both welds of the pair, by line
