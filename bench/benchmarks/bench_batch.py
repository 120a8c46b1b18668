"""Issue #28's acceptance: batch observe + tune over recordings and a simulate study, the local
pool against one by one, a Dask LocalCluster against the pool, a corrupt bag, a killed worker,
Ctrl-C and resume; per-item costs for the cluster estimate of docs/batch.md.

    .venv/bin/python bench/benchmarks/bench_batch.py                       # the acceptance: 40 x 1 s, 200 points
    .venv/bin/python bench/benchmarks/bench_batch.py --quick    # loaded machine: 6 x 0.5 s, 12 points, 3 repeats

Output: bench/results/batch.json (git-ignored), a summary on stdout. The recordings are made
once into bench/results/batch_bags/ (reused when present). "One by one" runs every item with
the single-item code in this process, one after the other (what a shell loop over
``elastic-pm-dyn observe``/``tune`` does, without its process start-ups: the fair baseline),
against the pool as one ``batch`` call starts it (its workers' start-up included) and a pool
whose warm workers serve every phase; each timing ``--repeats`` times, alternately, medians
with the 1-minute load average beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
MODEL = REPO / "config" / "five_bar.yaml"
OPTIONS = {"sensors": ["encoders", "imu"], "no_bag": True}


def make_bags(root: Path, n: int, seconds: float) -> list[Path]:
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag
    mech = Mechanism(load_model(MODEL))
    paths = []
    for k in range(n - 1):  # the last one is corrupt
        path = root / f"robot{k // 4:02d}_rec{k % 4}"
        if not path.exists():
            write_bag(generate(mech, RecordingSpec(duration=seconds, seed=2800 + k, disturbance_rms=0.05)), path)
        paths.append(path)
    bad = root / "robot99_corrupt"
    bad.mkdir(parents=True, exist_ok=True)
    (bad / "robot99_corrupt_0.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 4)
    return [*paths, bad]


def study_file(path: Path, points: int) -> Path:
    path.write_text(f"model: {MODEL}\nfixed: {{integrator: etd2, sample: 1.0e-3}}\nsample:\n  n: {points}\n  seed: 28\n"
                    "  ranges:\n    stiffness_scale: {low: 0.3, high: 3.0, log: true}\n"
                    "    damping_scale: {low: 0.5, high: 2.0}\n    payload: [0.0, 0.5]\n    move: [0.15, 0.3]\n")
    return path


def one_by_one(items, out: Path) -> float:
    from elastic_pm_dyn.fleet.runners import run_item
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    for it in items:
        run_item(it, out)
    return time.perf_counter() - start


def cli_loop(items, out: Path) -> float:
    """Each item as its own `elastic-pm-dyn` process, one after the other: a shell loop."""
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    for it in items:
        argv = [it.kind, "--model", it.model, "--bag", it.source, "--out", str(out / it.id), *it.argv_options()]
        subprocess.run([sys.executable, "-m", "elastic_pm_dyn", *argv], capture_output=True, timeout=3600)
    return time.perf_counter() - start


def same(a: Path, b: Path, items) -> bool:
    """Every output file of every complete item equal byte for byte (the item records' timing aside)."""
    for it in items:
        da, db = a / "items" / it.id, b / "items" / it.id
        if da.is_dir() != db.is_dir():
            return False
        if not da.is_dir():
            continue
        for f in sorted(p for p in da.rglob("*") if p.is_file() and p.name not in ("item.json", "log.txt")):
            g = db / f.relative_to(da)
            if f.name == "summary.json":
                ja, jb = (json.loads(x.read_text()) for x in (f, g))
                for j in (ja, jb):
                    for k in [k for k in j if "wall" in k or "speed" in k]:
                        del j[k]
                if ja != jb:
                    return False
            elif not g.is_file() or f.read_bytes() != g.read_bytes():
                return False
    return True


def interrupt_and_resume(bags: list[Path], out: Path, after: int) -> dict:
    """SIGINT a `batch observe` process after ``after`` items are complete, then run it again."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "elastic_pm_dyn", "batch", "observe", *map(str, bags), "--model", str(MODEL),
           "--out", str(out), "--jobs", "2", "-o", "no_bag=true", "--no-plots", "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while proc.poll() is None and len([p for p in (out / "items").glob("*/item.json")]) < after:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=600)
    kept = len(list((out / "items").glob("*/item.json")))
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    status = json.loads((out / "batch.json").read_text())
    return {"first_exit": proc.returncode, "first_last_line": err.strip().splitlines()[-1:], "kept_after_ctrl_c": kept,
            "rerun_exit": again.returncode, "rerun_counts": status["counts"]}


def kill_one_worker(bags: list[Path], out: Path, jobs: int) -> dict:
    """SIGKILL the worker running the second bag's item mid-item (its hidden folder names its pid)."""
    import threading

    from elastic_pm_dyn.fleet.api import batch
    shutil.rmtree(out, ignore_errors=True)
    victim = bags[1].name
    killed: list[int] = []

    def killer() -> None:
        deadline = time.monotonic() + 3600
        while not killed and time.monotonic() < deadline:
            for tmp in (out / "items").glob(f".{victim}.*.tmp") if (out / "items").is_dir() else ():
                os.kill(int(tmp.name.split(".")[2]), signal.SIGKILL)
                killed.append(int(tmp.name.split(".")[2]))
                break
            time.sleep(0.005)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    res = batch("observe", bags, out, model=MODEL, options=OPTIONS, jobs=jobs, progress=False, plots_on=False)
    thread.join(1)
    attempts = {r["id"]: r["attempt"] for r in res.records}
    return {"killed_pid": killed, "counts": res.counts, "attempts_of_killed_item": attempts.get(victim),
            "items_started_more_than_once": sorted(k for k, a in attempts.items() if a > 1 and k != victim)}


QUICK = {"recordings": 6, "seconds": 0.5, "max_evaluations": 16, "points": 12, "repeats": 3}


def median(xs: list[float]) -> float:
    return statistics.median(xs) if xs else float("nan")


def load() -> float:
    return round(os.getloadavg()[0], 2)


def phase(name: str, kind: str, inputs, options, st, a, work: Path, keep) -> dict:
    """One kind of item: one by one in this (warm) process against the pool, ``a.repeats``
    times alternately, medians and the ratio of medians, the 1-min load beside each run."""
    from elastic_pm_dyn.fleet.api import batch, items_of
    from elastic_pm_dyn.fleet.pool import LocalPool
    model = MODEL if st is None else None
    items = items_of(kind, inputs, model, options, st)
    one_by_one(items[:1], work / f"{name}_warm")  # the kernels loaded: the loop below is warm
    serial, fresh, kept, loads = [], [], [], []
    records: list[dict] = []
    for _ in range(a.repeats):
        loads.append(load())
        serial.append(one_by_one(items, work / f"{name}_serial"))
        for pool_s, engine in ((fresh, LocalPool(a.jobs)), (kept, keep)):
            shutil.rmtree(work / f"{name}_pool", ignore_errors=True)
            res = batch(kind, inputs, work / f"{name}_pool", model=model, options=options, study=st, engine=engine,
                        progress=False, plots_on=False)
            pool_s.append(res.wall_s)
            records = res.records
        loads.append(load())
    item_s = sorted(r["wall_s"] for r in records if r["wall_s"] is not None)
    row = {"items": len(items), "repeats": a.repeats, "load_1min": loads,
           "serial_s": serial, "pool_s": fresh, "warm_pool_s": kept,
           "serial_median_s": median(serial), "pool_median_s": median(fresh), "warm_pool_median_s": median(kept),
           "speedup": median(serial) / median(fresh), "speedup_warm_pool": median(serial) / median(kept),
           "item_s_median": median(item_s), "counts": res.counts,
           "pool_equals_serial": same(work / f"{name}_serial", work / f"{name}_pool", items),
           "failed": {r["id"]: r["error"] for r in res.failed}}
    if name != "study" and not a.skip_cli:
        row["cli_loop_s"] = cli_loop(items, work / f"{name}_cli")
        row["speedup_vs_cli_loop"] = row["cli_loop_s"] / row["pool_median_s"]
    if not a.skip_dask and name == "observe":
        shutil.rmtree(work / f"{name}_dask", ignore_errors=True)
        d = batch(kind, inputs, work / f"{name}_dask", model=MODEL, options=options, cluster=f"local:{a.jobs}",
                  progress=False, plots_on=False)
        row |= {"dask_s": d.wall_s, "dask_equals_pool": same(work / f"{name}_pool", work / f"{name}_dask", items)}
    return row


def warm_overhead(bags: list[Path], a, work: Path, serial_s: float) -> dict:
    """Per-item overhead of a fresh pool without and with the workers' warm-up:
    (pool wall x workers - the warm loop's time) / items, and the items' own times."""
    from elastic_pm_dyn.fleet.api import batch
    from elastic_pm_dyn.fleet.pool import LocalPool
    out: dict = {}
    for warm in (False, True):
        walls, firsts, loads = [], [], []
        for _ in range(a.repeats):
            shutil.rmtree(work / "overhead", ignore_errors=True)
            loads.append(load())
            res = batch("observe", bags, work / "overhead", model=MODEL, options=OPTIONS,
                        engine=LocalPool(a.jobs, warm=warm), progress=False, plots_on=False)
            walls.append(res.wall_s)
            firsts.append(max(r["wall_s"] or 0 for r in res.records))
        n = len(bags)
        out["warm" if warm else "cold"] = {
            "load_1min": loads, "pool_median_s": median(walls),
            "overhead_per_item_s": (median(walls) * a.jobs - serial_s) / n,
            "slowest_item_median_s": median(firsts)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="a loaded machine's run: " + ", ".join(f"{k} {v}" for k, v in QUICK.items()))
    ap.add_argument("--recordings", type=int, default=40)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--max-evaluations", type=int, default=160)
    ap.add_argument("--points", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=1, help="runs of each timing (medians reported)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--skip-dask", action="store_true")
    ap.add_argument("--skip-cli", action="store_true", help="no loop of one elastic-pm-dyn process per item")
    a = ap.parse_args()
    if a.quick:
        for k, v in QUICK.items():
            setattr(a, k, v)
    from elastic_pm_dyn.fleet.pool import LocalPool
    results = Path(a.out)
    work = results / "batch_work"
    bags = make_bags(results / f"batch_bags_{a.seconds:g}s", a.recordings, a.seconds)
    report: dict = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                "loadavg_start": os.getloadavg()},
                    "setup": vars(a)}
    tune_opts = {**OPTIONS, "max_evaluations": a.max_evaluations}
    tune_opts.pop("no_bag")
    work.mkdir(parents=True, exist_ok=True)
    study = study_file(work / "study.yaml", a.points)
    with LocalPool(a.jobs) as keep:  # the warm-pool runs: workers started once for every phase
        for name, kind, inputs, options, st in (
                ("observe", "observe", bags, OPTIONS, None), ("tune", "tune", bags, tune_opts, None),
                ("study", "simulate", (), None, study)):
            report[name] = phase(name, kind, inputs, options, st, a, work, keep)
            print(name, json.dumps(report[name]), flush=True)
    serial = report["observe"]["serial_median_s"] + report["tune"]["serial_median_s"]
    report["observe_tune_speedup"] = serial / (report["observe"]["pool_median_s"] + report["tune"]["pool_median_s"])
    report["observe_tune_speedup_warm_pool"] = serial / (report["observe"]["warm_pool_median_s"]
                                                         + report["tune"]["warm_pool_median_s"])
    seconds = (a.recordings - 1) * a.seconds
    report["per_recording_second"] = {"observe_cpu_s": report["observe"]["serial_median_s"] / seconds,
                                      "tune_cpu_s": report["tune"]["serial_median_s"] / seconds}
    report["warm_up"] = warm_overhead(bags, a, work, report["observe"]["serial_median_s"])
    report["worker_killed"] = kill_one_worker(bags, work / "killed", a.jobs)
    report["ctrl_c_resume"] = interrupt_and_resume(bags, work / "resume", after=max(2, a.recordings // 4))
    report["machine"]["loadavg_end"] = os.getloadavg()
    (results / "batch.json").write_text(json.dumps(report, indent=1, default=str) + "\n")
    print(json.dumps({k: report[k] for k in ("observe_tune_speedup", "observe_tune_speedup_warm_pool",
                                             "per_recording_second", "warm_up", "worker_killed", "ctrl_c_resume")},
                     indent=1))


if __name__ == "__main__":
    main()
