"""The closed loop (docs/nodes.md, "Closing the loop"): the PD law on its own, then one short lockstep
run of the five-bar through ROS 2 (plant with sensors, observer node, controller, recorder)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from ros_harness import domain_id, require

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.motion.feedback import EncoderError, EncoderRates, gains, pd_torque

REPO = Path(__file__).resolve().parents[2]


def test_pd_law_is_feedforward_plus_pd() -> None:
    tau = pd_torque(np.array([1.0, -2.0]), np.array([0.5, 0.2]), np.array([0.1, 0.0]), np.array([0.4, 0.3]),
                    np.array([0.3, -0.5]), np.array([10.0, 20.0]), 2.0)
    np.testing.assert_allclose(tau, [1.0 + 10.0 * 0.1 + 2.0 * -0.2, -2.0 + 20.0 * -0.1 + 2.0 * 0.5], rtol=1e-15)
    assert pd_torque(np.ones(3), np.zeros(3), np.zeros(3), np.ones(3), np.ones(3), 0.0, 0.0).tolist() == [1.0] * 3
    assert gains([3.0], 2, "kp").tolist() == [3.0, 3.0] and gains([1.0, 2.0], 2, "kp").tolist() == [1.0, 2.0]
    for bad in ([1.0, 2.0, 3.0], [-1.0], [math.nan]):
        with pytest.raises(InputError, match="kp"):
            gains(bad, 2, "kp")


def test_encoder_rates_difference_by_stamp_or_take_the_velocity() -> None:
    enc = EncoderRates(["a", "b"])
    q, qd = enc.sample(1_000_000, ["b", "x", "a"], [2.0, 9.0, 1.0])  # other joints ignored, any order
    assert q.tolist() == [1.0, 2.0] and qd.tolist() == [0.0, 0.0]  # the first sample: at rest
    q, qd = enc.sample(3_000_000, ["a", "b"], [1.002, 1.998])  # 2 ms later
    assert np.allclose(qd, [1.0, -1.0], rtol=1e-9)
    _, qd = enc.sample(4_000_000, ["a", "b"], [1.0, 2.0], [0.25, 0.5])  # the sample's own rates win
    assert qd.tolist() == [0.25, 0.5]
    for names, pos, stamp, kind in ((["a"], [1.0], 5_000_000, "missing joint"),
                                    (["a", "a", "b"], [1.0, 1.0, 1.0], 5_000_000, "duplicate name"),
                                    (["a", "b"], [math.nan, 1.0], 5_000_000, "not finite"),
                                    (["a", "b"], [1.0, 1.0], 4_000_000, "old stamp")):
        with pytest.raises(EncoderError) as err:
            enc.sample(stamp, names, pos)
        assert err.value.kind == kind


def test_closed_loop_five_bar_lockstep(tmp_path: Path) -> None:
    """0.25 s: every command is the PD law on the encoder sample of its stamp, one estimate per
    plant state, the live estimates equal observe over the bag, the figures finite."""
    require("rclpy")
    require("rosbags")
    from elastic_pm_dyn.ros.demos.loop_demo import LoopOptions, run_loop_demo
    out = tmp_path / "loop"
    opts = LoopOptions(REPO / "config" / "five_bar.yaml", duration=0.25, seed=3, timeout=300.0,
                       domain_id=domain_id(71))
    s = run_loop_demo(out, opts)
    n = s["loop_periods"]
    assert n == 250
    pd = s["controller"]
    assert pd["commands_checked"] == n and pd["commands_equal_to_pd_on_their_sample"] == n
    assert min(pd["kp"]) > 0 and min(pd["kd"]) > 0
    assert s["plant_states_without_estimate"] == 0 and s["estimates_per_stamp_max"] == 1
    assert s["estimates"] == s["plant_states_in_loop"] == s["encoder_samples_in_loop"]
    assert s["live_equals_offline"] and s["live_offline_compared_rows"] == s["estimates"]
    for key in ("branch_force_error_rms_N", "branch_force_error_rms_open_loop_N",
                "branch_force_error_ratio_to_open_loop", "nees_mean", "nees_in_band", "force_stddev_mean_N"):
        assert math.isfinite(s[key]), key
    assert s["branch_force_error_rms_N"] > 0 and s["branch_force_error_rms_open_loop_N"] > 0
    for name in ("branch_forces", "path", "torques"):
        assert (out / f"{name}.png").stat().st_size > 10_000
    assert "Traceback" not in "".join(p.read_text() for p in (out / "logs").glob("*.log"))


def test_launch_file_names_installed_executables_and_configs() -> None:
    """launch/closed_loop.launch.py cannot run with the pip-only ROS; check what it refers to."""
    import ast
    import re
    tree = ast.parse((REPO / "launch" / "closed_loop.launch.py").read_text())
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    scripts = set(re.findall(r'"(\w+) = elastic_pm_dyn\.', (REPO / "setup.py").read_text()))
    assert {"plant_node", "observer_node", "feedforward_node", "recorder_node"} <= scripts & strings
    for name in ("plant_sensors.yaml", "observer_node.yaml", "feedforward.yaml", "recorder.yaml"):
        assert name in strings and (REPO / "config" / name).is_file()
    assert "elastic_pm_dyn.ros.demos.loop_demo" in strings  # the loop's start, python -m
    from elastic_pm_dyn.ros.demos.loop_demo import TOPICS
    assert set(TOPICS.values()) <= strings | {"/disturbance"}
