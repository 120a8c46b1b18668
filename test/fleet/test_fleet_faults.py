"""``batch`` against what fleets do to it (issue #44): hung and killed workers, recordings of
another machine, corrupt bags and strays, misspelled options, two runs on one folder, a
table read while the batch runs, a heartbeat in the log.

The default tests take about 40 s on 2 cores (one 2-worker pool, one item left SIGSTOPped
until its 15 s limit). With ``--fleet-long``: a Dask LocalCluster with a worker killed
(nothing finished computed again) and the batch process SIGKILLed (the table readable, no
worker traceback, a second run refused while the first runs). The 20-bag version with a
real ``dask scheduler`` + workers is ``bench/benchmarks/bench_batch_faults.py``.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from test_fleet import MODEL, OPTIONS, bags, one_by_one  # noqa: F401 (fixtures)

from elastic_pm_dyn.cli import main as cli_main
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet import lock
from elastic_pm_dyn.fleet.api import batch
from elastic_pm_dyn.fleet.items import Inputs, discover
from elastic_pm_dyn.fleet.progress import Progress
from elastic_pm_dyn.fleet.runners import run_item
from elastic_pm_dyn.fleet.timeouts import item_timeout
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag

CONFIG = MODEL.parent
LIMIT_S = 15.0  # the SIGSTOPped item's limit: a 0.15 s recording's item takes about 0.5 s (5 s at load 8)


@pytest.fixture(scope="module")
def other_machine(tmp_path_factory) -> Path:
    """A recording of the triglide (three legs, its own joint names), for the five-bar's model."""
    mech = Mechanism(load_model(CONFIG / "triglide.yaml"))
    return write_bag(generate(mech, RecordingSpec(motion="chirp", duration=0.15, seed=4401)),
                     tmp_path_factory.mktemp("other") / "triglide")


@pytest.fixture(scope="module")
def fleet(bags, other_machine, tmp_path_factory) -> Path:  # noqa: F811
    """A fleet folder as one is found: a stray garbage .mcap at the top, good bags in two
    line folders, one of another machine, a bag cut in half and one of garbage."""
    root = tmp_path_factory.mktemp("fleet44") / "fleet"
    for line, k in (("line1", 0), ("line1", 1), ("line2", 2)):
        shutil.copytree(bags / f"robot{k}", root / line / f"robot{k}")
    shutil.copytree(other_machine, root / "line2" / "other")
    cut = root / "line1" / "cut"
    shutil.copytree(bags / "robot0", cut)
    data = next(cut.glob("*.mcap"))
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    shutil.copytree(bags / "robot9", root / "line2" / "garbage")
    (root / "stray.mcap").write_bytes(b"not a bag at all\n" * 10)
    return root


def _ids(root: Path) -> list[str]:
    return [it.id for it in discover([str(root)], Inputs("observe", str(MODEL), {}))]


def test_a_stray_file_is_its_own_item_and_the_bags_beside_and_below_it_still_run(fleet) -> None:
    assert _ids(fleet) == ["line1-cut", "line1-robot0", "line1-robot1", "line2-garbage", "line2-other",
                           "line2-robot2", "stray"]
    assert _ids(fleet / "line2" / "garbage") == ["garbage"]  # a folder of storage files only is one bag


def _no_engine():
    class NoEngine:
        name = "no engine"

        def run(self, *args, **kwargs):
            raise AssertionError("a worker started although the options are wrong")
    return NoEngine()


@pytest.mark.parametrize("options, words", [
    ({"sensrs": "imu"}, "observe has no option 'sensrs' (an -o option or a manifest column; item robot0): did you "
                        "mean 'sensors'?"),
    ({"sensors": "gyro"}, "item robot0: elastic-pm-dyn observe: argument --sensors: invalid choice: 'gyro'"),
])
def test_a_bad_option_is_one_line_before_any_worker_starts(bags, tmp_path, options, words) -> None:  # noqa: F811
    with pytest.raises(InputError) as err:
        batch("observe", [bags / "robot0"], tmp_path, model=MODEL, options=options, engine=_no_engine(),
              progress=False)
    assert str(err.value).startswith(words) and "\n" not in str(err.value)


def test_a_misspelled_manifest_column_names_the_nearest_option(bags, tmp_path, capsys) -> None:  # noqa: F811
    manifest = tmp_path / "fleet.csv"
    manifest.write_text(f"id,bag,max_evaluation\nA-1,{bags / 'robot0'},20\n")
    assert cli_main(["batch", "tune", str(manifest), "--model", str(MODEL), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tune has no option 'max_evaluation'" in err[0] and "'max_evaluations'" in err[0], err
    assert not (tmp_path / "o").exists()


class _Quick:
    """An engine without workers: each item's record made up, the table read after each."""

    name = "quick engine"

    def __init__(self, out: Path, pause: float = 0.0):
        self.out, self.pause, self.seen = out, pause, []

    def run(self, items, out, on_record, retries, timeouts, watch) -> None:
        for k, it in enumerate(items):
            watch.running(1)
            time.sleep(self.pause)
            on_record({"id": it.id, "kind": it.kind, "key": it.key, "attempt": 1, "status": "ok", "error": None,
                       "wall_s": 0.01, "figures": {"rows": k}, "item": it.row()})
            with open(self.out / "results.csv") as f:
                self.seen.append([r["id"] for r in csv.DictReader(f)])
            self.seen_state = json.loads((self.out / "batch.json").read_text())["state"]


def _items_folder(tmp_path: Path, n: int) -> Path:
    """``n`` bag folders (metadata only: the quick engine opens none)."""
    for k in range(n):
        (tmp_path / "in" / f"b{k}").mkdir(parents=True)
        (tmp_path / "in" / f"b{k}" / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    return tmp_path / "in"


def test_the_table_grows_as_items_finish_and_a_heartbeat_goes_to_the_log(tmp_path) -> None:
    out = tmp_path / "out"
    engine = _Quick(out, pause=0.2)
    lines: list[str] = []
    stream = io.StringIO()
    progress = Progress(3, stream=stream, every=0.1)
    progress.beat()
    time.sleep(0.35)
    progress.close()
    assert len(stream.getvalue().splitlines()) >= 2 and "running 0" in stream.getvalue()
    res = batch("observe", [_items_folder(tmp_path, 3)], out, model=MODEL, engine=engine, progress=False,
                plots_on=False, log=lines.append)
    assert engine.seen == [["b0"], ["b0", "b1"], ["b0", "b1", "b2"]]
    assert engine.seen_state == "running" and json.loads((out / "batch.json").read_text())["state"] == "finished"
    assert res.counts["ok"] == 3


def test_a_second_batch_on_the_same_output_is_refused_in_one_line_or_waits(tmp_path) -> None:
    inputs = _items_folder(tmp_path, 2)
    out = tmp_path / "out"
    out.mkdir()
    with lock.held(out):
        with pytest.raises(lock.FolderInUse, match=r"another batch is running on this output folder \(pid \d+"):
            batch("observe", [inputs], out, model=MODEL, engine=_Quick(out), progress=False)
        lines: list[str] = []
        done: list = []
        waiter = threading.Thread(target=lambda: done.append(batch(
            "observe", [inputs], out, model=MODEL, engine=_Quick(out), progress=False, plots_on=False, wait=True,
            log=lines.append)))
        waiter.start()
        time.sleep(0.5)
        assert not done and any("waiting for the batch running on" in ln for ln in lines)
    waiter.join(60)
    assert done and done[0].counts["ok"] == 2


def test_default_item_timeout_follows_the_recording(bags, tmp_path) -> None:  # noqa: F811
    it = discover([str(bags / "robot0")], Inputs("observe", str(MODEL), {}))[0]
    tune = discover([str(bags / "robot0")], Inputs("tune", str(MODEL), {"max_evaluations": 20}))[0]
    assert item_timeout(it) == pytest.approx(120 + 30 * 0.15, abs=0.5)
    assert item_timeout(tune) == pytest.approx(120 + 30 * 0.15 * 20, abs=5)
    assert item_timeout(it, 7.0) == 7.0


@pytest.mark.parametrize("kind, options, words", [
    ("observe", {"sensors": "encoders imu", "no_bag": True}, "no estimate from this recording: joint state at"),
    ("tune", {"sensors": "encoders imu", "max_evaluations": 8},
     "no sensor sample the model can use (encoders 0, imu 0)"),
    ("analyze", {"no_plots": True}, "the commands name no motor of the model (recording: leg1_drive"),
])
def test_a_recording_of_another_machine_is_a_failed_row_with_its_reason(other_machine, tmp_path, kind, options,
                                                                       words) -> None:
    item = discover([str(other_machine)], Inputs(kind, str(MODEL), options))[0]
    record = run_item(item, tmp_path)
    assert record["status"] == "failed" and words in record["error"], record["error"]
    assert "\n" not in record["error"] and not (tmp_path / "items" / item.id).exists()


def _tamper(out: Path, victims: dict[str, signal.Signals]) -> tuple[threading.Thread, dict[str, int]]:
    """Send each victim item's worker its signal on the item's first attempt (the worker's pid
    is in the item's hidden temporary folder's name)."""
    hit: dict[str, int] = {}
    stop = threading.Event()

    def run() -> None:
        while len(hit) < len(victims) and not stop.wait(0.002):
            for item_id, sig in victims.items():
                for tmp in (out / "items").glob(f".{item_id}.*.tmp") if item_id not in hit else ():
                    hit[item_id] = int(tmp.name.rsplit(".", 2)[1])
                    os.kill(hit[item_id], sig)

    thread = threading.Thread(target=run, daemon=True)
    thread.stop = stop  # type: ignore[attr-defined]
    thread.start()
    return thread, hit


def _read_while_running(path: Path, stop: threading.Event, seen: list[int]) -> None:
    while not stop.wait(0.01):
        if path.is_file():
            with open(path) as f:
                rows = list(csv.DictReader(f))
            assert all(r["id"] and r["status"] in ("ok", "failed") for r in rows)
            seen.append(len(rows))


def test_a_fleet_with_a_killed_worker_a_stopped_one_and_bad_recordings(fleet, one_by_one, tmp_path) -> None:  # noqa: F811
    """The acceptance's pool run in small: every good item once, equal to one by one; each bad
    one a failed row with its line; the SIGSTOPped worker killed at its limit, its item re-run."""
    out = tmp_path / "out"
    thread, hit = _tamper(out, {"line1-robot1": signal.SIGKILL, "line2-robot2": signal.SIGSTOP})
    lines: list[str] = []
    stop, seen = threading.Event(), []
    reader = threading.Thread(target=_read_while_running, args=(out / "results.csv", stop, seen), daemon=True)
    reader.start()
    try:
        res = batch("observe", [fleet], out, model=MODEL, options=OPTIONS, jobs=2, item_timeout_s=LIMIT_S,
                    progress=False, plots_on=False, log=lines.append)
    finally:
        thread.stop.set()
        stop.set()
        for pid in hit.values():  # nothing left stopped if the test fails
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
    reader.join(5)
    assert set(hit) == {"line1-robot1", "line2-robot2"}, "an item finished before it could be tampered with"
    rows = {r["id"]: r for r in res.records}
    good = {"line1-robot0": 0, "line1-robot1": 1, "line2-robot2": 2}
    assert res.counts == {"items": 7, "ok": 3, "failed": 4, "skipped": 0, "missing": 0}
    assert {k: rows[k]["attempt"] for k in good} == {"line1-robot0": 1, "line1-robot1": 2, "line2-robot2": 2}
    for item_id, k in good.items():
        assert (out / "items" / item_id / "estimates.csv").read_bytes() == \
            (one_by_one / f"robot{k}" / "estimates.csv").read_bytes()
    errors = {k: r["error"] for k, r in rows.items() if r["status"] == "failed"}
    assert "no joint of the model" in errors["line2-other"]
    assert all(e and "\n" not in e for e in errors.values()) and set(errors) == {
        "line1-cut", "line2-garbage", "line2-other", "stray"}
    assert any(f"worker pid {hit['line1-robot1']} died (signal 9) holding item line1-robot1" in ln for ln in lines)
    assert any(f"worker pid {hit['line2-robot2']} timed out after {LIMIT_S:g} s holding item line2-robot2" in ln
               for ln in lines), lines
    assert not list((out / "items").glob(".*.tmp"))
    with open(out / "results.csv") as f:
        assert sorted(r["id"] for r in csv.DictReader(f)) == sorted(rows)
    assert seen and max(seen) == 7 and min(seen) < 7  # read as it grew


def test_dask_a_killed_worker_recomputes_nothing_finished(fleet_long, bags, one_by_one, tmp_path) -> None:  # noqa: F811
    pytest.importorskip("distributed", reason="Dask distributed not installed (extra 'batch')")
    inputs = tmp_path / "in"
    for k in range(6):
        shutil.copytree(bags / f"robot{k % 3}", inputs / f"r{k}")
    out = tmp_path / "out"
    thread, hit = _tamper(out, {"r3": signal.SIGKILL})
    lines: list[str] = []
    res = batch("observe", [inputs], out, model=MODEL, options=OPTIONS, cluster="local:2", progress=False,
                plots_on=False, log=lines.append)
    thread.stop.set()
    assert hit, "the item finished before it could be killed"
    assert res.counts["ok"] == 6 and res.counts["failed"] == 0
    starts = {f"r{k}": len((out / "attempts" / f"r{k}").read_text().splitlines()) for k in range(6)}
    assert starts == {"r0": 1, "r1": 1, "r2": 1, "r3": 2, "r4": 1, "r5": 1}  # nothing finished ran again
    assert {r["id"]: r["attempt"] for r in res.records}["r3"] == 2
    told = [ln for ln in lines if "holding item r3" in ln]
    assert len(told) == 1 and "holding item r3 (attempt 1)" in told[0], lines  # the death told once
    for k in range(6):
        assert (out / "items" / f"r{k}" / "estimates.csv").read_bytes() == \
            (one_by_one / f"robot{k % 3}" / "estimates.csv").read_bytes()
    assert not list((out / "items").glob(".*.tmp"))


def test_sigkill_of_the_batch_leaves_a_readable_table_and_no_worker_traceback(fleet_long, bags, tmp_path) -> None:  # noqa: F811
    inputs = tmp_path / "in"
    for k in range(8):
        shutil.copytree(bags / f"robot{k % 3}", inputs / f"r{k}")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "elastic_pm_dyn", "batch", "observe", str(inputs), "--model", str(MODEL), "--out",
           str(out), "--jobs", "2", "-o", "no_bag=true", "--no-plots", "--heartbeat", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 600
    while proc.poll() is None and len(list(out.glob("items/*/item.json"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    second = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert second.returncode == 2 and "another batch is running on this output folder" in second.stderr
    assert len(second.stderr.strip().splitlines()) == 1, second.stderr
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=120)  # EOF: the workers, which hold stderr too, have ended
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) >= 2 and all(r["status"] == "ok" for r in rows)
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert json.loads((out / "batch.json").read_text())["counts"]["skipped"] >= len(rows)


def test_an_item_timeout_on_dask_ends_the_item_by_its_watchdog(fleet_long, tmp_path) -> None:
    """A worker whose item runs past its limit kills itself; the row says timed out."""
    pytest.importorskip("distributed", reason="Dask distributed not installed (extra 'batch')")
    study = tmp_path / "study.yaml"
    study.write_text(f"model: {MODEL}\nfixed: {{integrator: rk4, sample: 2.0e-3, dt: 1.0e-6}}\n"
                     "grid:\n  move: [0.3]\n  hold: [0.2]\n")
    res = batch("simulate", out=tmp_path / "out", study=study, cluster="local:1", retries=0, item_timeout_s=3.0,
                progress=False, plots_on=False)
    bad = res.records[0]
    assert bad["status"] == "failed" and bad["error"].startswith("timed out after 3 s, 1 time(s)"), bad["error"]


@pytest.mark.parametrize("where", ["this host", "another host"])
def test_a_stopped_dask_worker_is_ended_from_outside_and_its_item_runs_again(fleet_long, bags, one_by_one,  # noqa: F811
                                                                             tmp_path, monkeypatch, where) -> None:
    """A SIGSTOPped worker runs no watchdog: OVERDUE_S past its item's limit the engine kills it
    (on this host) or has the scheduler remove it (a worker on another host: the batch takes its
    own host for another here), another worker runs the item, and the batch ends by itself with
    every item once."""
    pytest.importorskip("distributed", reason="Dask distributed not installed (extra 'batch')")
    from elastic_pm_dyn.fleet import engines
    from elastic_pm_dyn.fleet.engines import OVERDUE_S
    if where == "another host":
        monkeypatch.setattr(engines, "_whoami", lambda: f"{os.getpid()} elsewhere")  # in this process only
    inputs = tmp_path / "in"
    for k in range(3):
        shutil.copytree(bags / f"robot{k}", inputs / f"r{k}")
    out = tmp_path / "out"
    thread, hit = _tamper(out, {"r1": signal.SIGSTOP})
    lines: list[str] = []
    try:
        res = batch("observe", [inputs], out, model=MODEL, options=OPTIONS, cluster="local:2", item_timeout_s=LIMIT_S,
                    progress=False, plots_on=False, log=lines.append)
    finally:
        thread.stop.set()
        for pid in hit.values():
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
    assert hit, "the item finished before it could be stopped"
    assert res.counts["ok"] == 3 and res.counts["failed"] == 0
    assert {r["id"]: r["attempt"] for r in res.records} == {"r0": 1, "r1": 2, "r2": 1}
    told = [ln for ln in lines if "item r1" in ln]
    how = "killed" if where == "this host" else "removed from the scheduler"
    assert len(told) == 1 and f"(pid {hit['r1']} on" in told[0] and how in told[0], lines
    assert f"{OVERDUE_S:g} s over its {LIMIT_S:g} s limit" in told[0]
    for k in range(3):
        assert (out / "items" / f"r{k}" / "estimates.csv").read_bytes() == \
            (one_by_one / f"robot{k}" / "estimates.csv").read_bytes()
    assert not list((out / "items").glob(".*.tmp"))
