"""No silent loss (issue #23 item 6): a bag that yields fewer messages than it says it holds,
and numbers that cannot be written as numbers in a summary, are named in one line."""

from __future__ import annotations

import json
import logging
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
from bag_factory import run_messages, synthetic_run, write_bag

from elastic_pm_dyn.analysis.report import analyze
from elastic_pm_dyn.analysis.report_types import non_finite
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.typestore import make_typestore

FIVE_BAR = Path(__file__).resolve().parents[2] / "config" / "five_bar.yaml"


def test_a_damaged_chunk_without_crc_that_loses_a_message_is_reported(tmp_path: Path, caplog) -> None:
    src = tmp_path / "plain"
    write_bag(src, run_messages(synthetic_run(), make_typestore()), "mcap")  # plain rosbags: chunk CRC 0
    data = next(src.glob("*.mcap")).read_bytes()
    for offset in range(1000, len(data) // 2, 997):  # 16 zero bytes somewhere in the first chunk
        bag = tmp_path / f"damaged_{offset}"
        shutil.copytree(src, bag)
        damaged = bytearray(data)
        damaged[offset:offset + 16] = bytes(16)
        next(bag.glob("*.mcap")).write_bytes(damaged)
        caplog.clear()
        try:
            with caplog.at_level(logging.WARNING, logger="elastic_pm_dyn.bags"), open_bag(bag) as b:
                read = sum(1 for _ in b.messages(b.connections))
                said = b.message_count
        except Exception:  # a damage the reader detects is an error: not the case looked for
            continue
        if read != said:
            break
    else:
        raise AssertionError("no damage that loses messages silently was found")
    lines = [r.getMessage() for r in caplog.records if "index says" in r.getMessage()]
    assert len(lines) == 1 and "\n" not in lines[0]
    assert f"read {read} messages" in lines[0] and f"says {said}" in lines[0] and str(bag) in lines[0]


def test_non_finite_values_are_found_by_their_key_path() -> None:
    summary = {"torques": {"peak_Nm": {"left": float("inf"), "right": 1.0}}, "gap": [0.0, float("nan")],
               "fit": np.array([1.0, np.inf])}
    assert non_finite(summary) == ["torques.peak_Nm.left", "gap[1]", "fit[1]"]


def test_infinite_efforts_are_named_in_the_summary(tmp_path: Path) -> None:
    run = synthetic_run()
    tau = run.tau.copy()
    tau[10:15, 0] = np.inf
    tau[:, 1] = np.nan
    bag = tmp_path / "bag"
    write_bag(bag, run_messages(replace(run, tau=tau), make_typestore()), "mcap")
    summary = analyze(FIVE_BAR, [bag], tmp_path / "out", plots_on=False)
    written = json.loads((tmp_path / "out" / "summary.json").read_text())
    (label, m), = written["runs"].items()
    warning = [w for w in m["warnings"] if "not finite" in w]
    assert warning, m["warnings"]
    left, right = run.motor_names
    assert f"{left} 5 of" in warning[0] and f"{right} {len(tau)} of {len(tau)}" in warning[0]
    assert m["torques"]["peak_Nm"][right] is None and np.isfinite(m["torques"]["peak_Nm"][left])
    assert summary.runs[label].warnings == m["warnings"]
