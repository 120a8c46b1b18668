"""``elastic-pm-dyn batch`` / ``epd.batch`` (elastic_pm_dyn.fleet): many items, same results as one by one.

Tiny recordings made here with the package's own recording tools; the pool and a Dask
LocalCluster of two workers against the single-item commands run in this process, bit for
bit; a corrupt bag is one failed row; a re-run skips what is complete; a worker SIGKILLed
mid-item is retried and no item runs twice. The Dask and the Ctrl-C (a subprocess) tests
run with ``pytest --fleet-long``.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from elastic_pm_dyn.cli import main as cli_main
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.fleet import store
from elastic_pm_dyn.fleet.api import batch
from elastic_pm_dyn.fleet.items import Inputs, discover
from elastic_pm_dyn.fleet.pool import LocalPool
from elastic_pm_dyn.fleet.runners import deterministic, run_item
from elastic_pm_dyn.fleet.study import study_items
from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag

CONFIG = Path(__file__).resolve().parents[1].parent / "config"
MODEL = CONFIG / "five_bar.yaml"
OPTIONS = {"sensors": ["encoders", "imu"], "no_bag": True}


@pytest.fixture(scope="module")
def bags(five_bar, tmp_path_factory) -> Path:
    """Three 0.15 s recordings and a corrupt one (garbage where the mcap file should be)."""
    root = tmp_path_factory.mktemp("fleet") / "bags"
    for k in range(3):
        write_bag(generate(five_bar, RecordingSpec(duration=0.15, seed=500 + k)), root / f"robot{k}")
    bad = root / "robot9"
    bad.mkdir()
    (bad / "robot9_0.mcap").write_bytes(b"\x89MCAP0\r\n" + os.urandom(300))
    return root


@pytest.fixture(scope="module")
def one_by_one(bags, tmp_path_factory) -> Path:
    """Each good bag through ``elastic-pm-dyn observe`` in this process, as a user would."""
    out = tmp_path_factory.mktemp("single")
    for k in range(3):
        assert cli_main(["observe", "--model", str(MODEL), "--bag", str(bags / f"robot{k}"), "--out",
                         str(out / f"robot{k}"), "--sensors", "encoders", "imu", "--no-bag"]) == 0
    return out


@pytest.fixture(scope="module")
def pool():
    """Two warm workers for every batch of the module (each new pool pays the start-up again)."""
    with LocalPool(2) as p:
        yield p


@pytest.fixture(scope="module")
def pooled(bags, pool, tmp_path_factory):
    out = tmp_path_factory.mktemp("pool")
    return batch("observe", [bags], out, model=MODEL, options=OPTIONS, engine=pool, progress=False), out


def _figures(path: Path) -> dict:
    return {k: v for k, v in deterministic(json.loads(path.read_text())["figures"]).items()}


def _assert_same_as_one_by_one(out: Path, one_by_one: Path) -> None:
    for k in range(3):
        item = out / "items" / f"robot{k}"
        assert (item / "estimates.csv").read_bytes() == (one_by_one / f"robot{k}" / "estimates.csv").read_bytes()
        single = json.loads((one_by_one / f"robot{k}" / "summary.json").read_text())
        batched = json.loads((item / "summary.json").read_text())
        for d in (single, batched):
            for key in [k for k in d if any(w in k for w in ("wall", "speed"))]:
                del d[key]
        assert batched == single


def test_pool_gives_the_results_of_one_by_one_and_a_corrupt_bag_is_one_failed_row(one_by_one, pooled) -> None:
    res, out = pooled
    assert res.counts == {"items": 4, "ok": 3, "failed": 1, "skipped": 0, "missing": 0}
    _assert_same_as_one_by_one(out, one_by_one)
    with open(out / "results.csv") as f:
        rows = {r["id"]: r for r in csv.DictReader(f)}
    assert sorted(rows) == ["robot0", "robot1", "robot2", "robot9"]
    bad = rows["robot9"]
    assert bad["status"] == "failed" and "robot9" in bad["error"] and "\n" not in bad["error"]
    assert all(rows[f"robot{k}"]["status"] == "ok" and rows[f"robot{k}"]["error"] == "" for k in range(3))
    # the table's figures are the items' own, every double written to round-trip
    for k in range(3):
        rec = json.loads((out / "items" / f"robot{k}" / "item.json").read_text())
        assert float(rows[f"robot{k}"]["rows"]) == rec["figures"]["rows"] > 100
    assert (out / "failed" / "robot9.json").is_file()
    assert (out / "overview_distributions.png").stat().st_size > 1000


def test_parquet_holds_the_csv_table(pooled) -> None:
    pq = pytest.importorskip("pyarrow.parquet", reason="pyarrow not installed (extra 'batch')")
    _, out = pooled
    table = pq.read_table(out / "results.parquet").to_pylist()
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["id"] for r in table] == [r["id"] for r in rows]
    for p, c in zip(table, rows, strict=True):
        for name, value in p.items():
            if isinstance(value, float):
                assert value == float(c[name])


def test_rerun_skips_complete_items_and_tries_the_failed_one_again(pooled, pool, bags) -> None:
    _, out = pooled
    before = {k: (out / "items" / f"robot{k}" / "item.json").stat().st_mtime_ns for k in range(3)}
    res = batch("observe", [bags], out, model=MODEL, options=OPTIONS, engine=pool, progress=False)
    assert res.counts == {"items": 4, "ok": 0, "failed": 1, "skipped": 3, "missing": 0}
    assert before == {k: (out / "items" / f"robot{k}" / "item.json").stat().st_mtime_ns for k in range(3)}


def test_resume_runs_only_what_is_missing(pooled, pool, bags, one_by_one, tmp_path) -> None:
    """As after Ctrl-C: one folder never finished (its hidden temporary left), one changed option."""
    _, out = pooled
    import shutil
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    shutil.rmtree(copy / "items" / "robot1")
    (copy / "items" / ".robot1.999999.tmp").mkdir()
    (copy / "items" / ".robot1.999999.tmp" / "estimates.csv").write_text("cut")
    res = batch("observe", [bags / "robot0", bags / "robot1", bags / "robot2"], copy, model=MODEL, options=OPTIONS,
                engine=pool, progress=False, plots_on=False)
    assert res.counts == {"items": 3, "ok": 1, "failed": 0, "skipped": 2, "missing": 0}
    assert not (copy / "items" / ".robot1.999999.tmp").exists()
    _assert_same_as_one_by_one(copy, one_by_one)


def test_dask_local_cluster_gives_identical_results(fleet_long, bags, one_by_one, tmp_path) -> None:
    pytest.importorskip("distributed", reason="Dask distributed not installed (extra 'batch')")
    res = batch("observe", [bags], tmp_path, model=MODEL, options=OPTIONS, cluster="local:2", progress=False,
                plots_on=False)
    assert res.counts["ok"] == 3 and res.counts["failed"] == 1
    _assert_same_as_one_by_one(tmp_path, one_by_one)


STUDY = """
model: {model}
fixed: {{integrator: {integrator}, sample: 2.0e-3, dt: {dt}}}
grid:
  stiffness_scale: [0.5, 2.0]
  move: {moves}
  payload: [0.2]
"""


def _study(tmp_path: Path, integrator: str = "rk4", dt: float = 2e-4, moves: str = "[0.05, 0.08]") -> Path:
    path = tmp_path / "study.yaml"
    path.write_text(STUDY.format(model=MODEL, integrator=integrator, dt=dt, moves=moves) + "  hold: [0.02]\n")
    return path


def test_study_grid_points_equal_their_single_runs_and_softer_springs_deflect_more(pool, tmp_path) -> None:
    study = _study(tmp_path, moves="[0.05]")
    items = study_items(study)
    assert [dict(it.study)["stiffness_scale"] for it in items] == [0.5, 2.0]
    res = batch("simulate", out=tmp_path / "out", study=study, engine=pool, progress=False)
    assert res.counts["ok"] == 2
    for it in items:
        single = run_item(it, tmp_path / "single")
        assert single["status"] == "ok"
        assert (tmp_path / "out" / "items" / it.id / "simulation.csv").read_bytes() == \
            (tmp_path / "single" / "items" / it.id / "simulation.csv").read_bytes()
    rows = {r["id"]: r for r in res.table}
    soft, stiff = rows[items[0].id], rows[items[1].id]  # same move, a quarter of the stiffness
    assert soft["peak_deflection.left_spring"] > 2 * stiff["peak_deflection.left_spring"]
    assert (tmp_path / "out" / "sensitivity.png").is_file()


def _kill_first_point(out: Path, times: int) -> tuple[threading.Thread, list[int]]:
    """SIGKILL the worker running the first study point, on each of its first ``times``
    attempts (seen by the hidden temporary folder of the item, which carries the worker's pid)."""
    killed: list[int] = []

    def killer() -> None:
        deadline = time.monotonic() + 600
        while len(killed) < times and time.monotonic() < deadline:
            for tmp in (out / "items").glob(".p00000.*.tmp") if (out / "items").is_dir() else ():
                pid = int(tmp.name.split(".")[2])
                if pid not in killed:
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
            time.sleep(0.002)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    return thread, killed


def test_a_worker_killed_mid_item_costs_only_that_item(pool, tmp_path) -> None:
    """Every point completes; the killed one on a fresh worker, every other point exactly once
    (a broken ProcessPoolExecutor ran the other worker's item again)."""
    study = _study(tmp_path, dt=2e-5)  # a small step: each point takes a second or so
    out = tmp_path / "out"
    thread, killed = _kill_first_point(out, 1)
    res = batch("simulate", out=out, study=study, engine=pool, progress=False, plots_on=False)
    thread.join(1)
    assert killed, "the item finished before it could be killed"
    assert res.counts["ok"] == 4 and res.counts["failed"] == 0
    attempts = {r["id"]: r["attempt"] for r in res.records}
    assert attempts == {"p00000": 2, "p00001": 1, "p00002": 1, "p00003": 1}
    assert res.records[0]["pid"] not in killed
    assert not list((out / "items").glob(".*.tmp")) and not (out / "failed").exists()


def test_a_worker_killed_on_every_attempt_is_one_failed_row(pool, tmp_path) -> None:
    study = _study(tmp_path, dt=2e-5, moves="[0.05]")
    out = tmp_path / "out"
    thread, killed = _kill_first_point(out, 2)
    res = batch("simulate", out=out, study=study, engine=pool, retries=1, progress=False, plots_on=False)
    thread.join(1)
    assert len(killed) == 2
    assert res.counts["ok"] == 1 and res.counts["failed"] == 1
    bad = res.records[0]
    assert bad["id"] == "p00000" and bad["attempt"] == 2 and bad["error"].startswith("worker died (signal 9)")
    assert res.records[1]["attempt"] == 1
    assert json.loads((out / "failed" / "p00000.json").read_text())["error"] == bad["error"]


def test_manifest_rows_carry_their_model_options_and_robot(bags, tmp_path) -> None:
    manifest = tmp_path / "fleet.csv"
    manifest.write_text(f"id,bag,robot,date,sensors\nA-1,{bags / 'robot0'},delta7,2025-01-02,encoders\n"
                        f"A-2,{bags / 'robot1'},delta7,2025-01-03,\n")
    items = discover([str(manifest)], Inputs("tune", str(MODEL), {"max_evaluations": 20}))
    assert [it.id for it in items] == ["A-1", "A-2"]
    assert dict(items[0].meta) == {"robot": "delta7", "date": "2025-01-02"}
    assert items[0].argv_options() == ["--max-evaluations", "20", "--sensors", "encoders"]
    assert items[1].argv_options() == ["--max-evaluations", "20"]
    assert items[0].key != items[1].key


def test_item_key_follows_the_inputs(bags, tmp_path) -> None:
    a = discover([str(bags / "robot0")], Inputs("observe", str(MODEL), {}))[0]
    b = discover([str(bags / "robot0")], Inputs("observe", str(MODEL), {"sensors": "encoders"}))[0]
    assert a.key != b.key and a.key == discover([str(bags / "robot0")], Inputs("observe", str(MODEL), {}))[0].key


@pytest.mark.parametrize("argv, words", [
    (["batch", "observe", "/no/such/bags", "--model", str(MODEL)], "no such file or folder"),
    (["batch", "observe", "--model", str(MODEL)], "no inputs"),
    (["batch", "tune", "--study", "x.yaml"], "simulate only"),
    (["batch", "observe", ".", "-o", "sensors"], "NAME=VALUE"),
    (["batch", "simulate", "--cluster", "local:0", "--study", str(CONFIG / "five_bar.yaml")], "unknown keys"),
])
def test_bad_batch_input_is_one_line(argv, words, tmp_path, capsys) -> None:
    assert cli_main([*argv, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err


def test_study_errors_are_one_line(tmp_path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(f"model: {MODEL}\ngrid: {{stiffnes_scale: [1]}}\n")
    with pytest.raises(InputError, match="unknown study parameter 'stiffnes_scale'"):
        study_items(path)
    path.write_text(f"model: {MODEL}\nsample: {{n: 3, seed: 1, ranges: {{move: [0.3, 0.1]}}}}\n")
    with pytest.raises(InputError, match="low <= high"):
        study_items(path)


def test_random_sample_is_reproducible_and_in_range(tmp_path) -> None:
    path = tmp_path / "s.yaml"
    path.write_text(f"model: {MODEL}\nsample: {{n: 50, seed: 7, ranges: {{stiffness_scale: {{low: 0.5, high: 2, "
                    "log: true}, integrator: {choices: [rk4, etd2]}}}\n")
    a, b = study_items(path), study_items(path)
    assert [it.key for it in a] == [it.key for it in b]
    k = [dict(it.study)["stiffness_scale"] for it in a]
    assert min(k) >= 0.5 and max(k) <= 2.0 and min(k) < 0.8 and max(k) > 1.4
    assert {dict(it.study)["integrator"] for it in a} == {"rk4", "etd2"}


def test_store_sees_a_changed_input_as_not_complete(pooled, bags) -> None:
    _, out = pooled
    item = discover([str(bags / "robot0")], Inputs("observe", str(MODEL), OPTIONS))[0]
    assert store.complete(out, item) is not None
    other = discover([str(bags / "robot0")], Inputs("observe", str(MODEL), {"sensors": ["encoders"]}))[0]
    assert store.complete(out, other) is None


def test_ctrl_c_keeps_finished_items_and_a_rerun_finishes_only_the_rest(fleet_long, tmp_path) -> None:
    import subprocess
    import sys
    study = _study(tmp_path, dt=1e-5)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "elastic_pm_dyn", "batch", "simulate", "--study", str(study), "--out", str(out),
           "--jobs", "1", "--no-plots"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 600
    while proc.poll() is None and not list(out.glob("items/*/item.json")) and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    kept = sorted(p.parent.name for p in out.glob("items/*/item.json"))
    assert proc.returncode == 130 and 1 <= len(kept) < 4, (proc.returncode, kept, err)
    assert "interrupted (Ctrl-C)" in err and "Traceback" not in err
    assert not list((out / "items").glob(".*.tmp"))  # the stopped item left nothing half-written behind
    stamps = {k: (out / "items" / k / "item.json").stat().st_mtime_ns for k in kept}
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    status = json.loads((out / "batch.json").read_text())["counts"]
    assert status == {"items": 4, "ok": 4 - len(kept), "failed": 0, "skipped": len(kept), "missing": 0}
    assert stamps == {k: (out / "items" / k / "item.json").stat().st_mtime_ns for k in kept}


def test_tune_and_analyze_items_are_the_single_commands(bags, tmp_path) -> None:
    """A tune item (run with --threads 1) writes the file `elastic-pm-dyn tune` (2 threads)
    writes; an analyze item the summary `elastic-pm-dyn analyze` writes."""
    bag = bags / "robot0"
    assert cli_main(["tune", "--model", str(MODEL), "--bag", str(bag), "--out", str(tmp_path / "tuned.yaml"),
                     "--sensors", "encoders", "imu", "--max-evaluations", "8"]) == 0
    item = discover([str(bag)], Inputs("tune", str(MODEL), {"sensors": "encoders imu", "max_evaluations": 8}))[0]
    record = run_item(item, tmp_path / "b")
    assert record["status"] == "ok", record
    assert (tmp_path / "b" / "items" / "robot0" / "tuned.yaml").read_bytes() == (tmp_path / "tuned.yaml").read_bytes()
    assert record["figures"]["nll_after"] <= record["figures"]["nll_before"]
    assert any(k.startswith("tuned.") for k in record["figures"])
    assert cli_main(["analyze", str(bag), "--model", str(MODEL), "--out", str(tmp_path / "a"), "--no-plots"]) == 0
    item = discover([str(bag)], Inputs("analyze", str(MODEL), {"no_plots": True}))[0]
    record = run_item(item, tmp_path / "b")
    assert record["status"] == "ok", record
    single = json.loads((tmp_path / "a" / "summary.json").read_text())
    batched = json.loads((tmp_path / "b" / "items" / "robot0" / "summary.json").read_text())
    assert batched["runs"] == single["runs"]


def test_simulate_items_over_torque_tables_equal_the_simulate_command(pool, tmp_path) -> None:
    tables = tmp_path / "tables"
    tables.mkdir()
    for move in ("0.1", "0.15"):
        assert cli_main(["feedforward", "--model", str(MODEL), "--move", move, "--hold", "0.05",
                         "--out", str(tables / f"move{move}.csv")]) == 0
    res = batch("simulate", [tables], tmp_path / "out", model=MODEL, options={"dt": 2e-4}, engine=pool, progress=False,
                plots_on=False)
    assert res.counts["ok"] == 2
    for move, duration in (("0.1", "0.15"), ("0.15", "0.2")):
        single = tmp_path / f"single{move}.csv"
        assert cli_main(["simulate", "--model", str(MODEL), "--torques", str(tables / f"move{move}.csv"),
                         "--duration", duration, "--dt", "2e-4", "--out", str(single)]) == 0
        batched = tmp_path / "out" / "items" / f"move{move}" / "simulation.csv"
        assert batched.read_bytes() == single.read_bytes()


def test_bags_in_the_output_folder_are_not_items(tmp_path) -> None:
    """`batch observe . --out runs/x` must not take its own items' estimate bags for new recordings."""
    own = tmp_path / "runs" / "x" / "items" / "a" / "estimates"
    own.mkdir(parents=True)
    (own / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    with pytest.raises(InputError, match="no items outside the output folder"):
        batch("observe", [tmp_path], tmp_path / "runs" / "x", model=MODEL, progress=False)


def test_study_parameters_change_the_model_and_a_payload_loads_the_branches(tmp_path) -> None:
    from elastic_pm_dyn.fleet.items import Item
    from elastic_pm_dyn.fleet.runners import study_model
    from elastic_pm_dyn.model.loader import load_model
    model = load_model(MODEL)

    def total(m) -> float:
        return sum(j.body.mass for c in m.chains for j in c.joints if j.body is not None)

    springs = [j.stiffness for c in model.chains for j in c.joints if j.role == "elastic"]
    assert total(study_model(model, {"payload": 0.5})) == pytest.approx(total(model) + 0.5, rel=1e-12)
    assert total(study_model(model, {"mass_scale": 2.0})) == pytest.approx(2 * total(model), rel=1e-12)
    stiff = study_model(model, {"stiffness_scale": 3.0})
    assert [j.stiffness for c in stiff.chains for j in c.joints if j.role == "elastic"] == [3 * k for k in springs]
    peak = {}
    for payload in (0.0, 1.0):
        point = {"payload": payload, "move": 0.2, "hold": 0.02, "integrator": "etd2", "sample": 1e-3}
        record = run_item(Item("simulate", f"m{payload}", str(MODEL), study=tuple(sorted(point.items()))), tmp_path)
        peak[payload] = record["figures"]["peak_branch_force_N"]
    assert peak[1.0] > 1.5 * peak[0.0]  # a kilogram at the tip, where the model has 0.2 kg


def test_a_warm_up_that_fails_is_silent_and_the_item_says_why(tmp_path, capfd) -> None:
    from elastic_pm_dyn.fleet.items import Item
    from elastic_pm_dyn.fleet.warm import warm_up
    item = Item("observe", "gone", str(MODEL), source=str(tmp_path / "no_such_bag"))
    assert warm_up(item) is None
    assert capfd.readouterr() == ("", "")
    record = run_item(item, tmp_path / "out")
    assert record["status"] == "failed" and "no_such_bag" in record["error"]
