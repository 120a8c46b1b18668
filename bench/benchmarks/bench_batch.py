"""Issue #28's acceptance: batch observe + tune over recordings and a simulate study, the local
pool against one by one, a Dask LocalCluster against the pool, a corrupt bag, a killed worker,
Ctrl-C and resume; per-item costs for the cluster estimate of docs/batch.md.

    .venv/bin/python bench/benchmarks/bench_batch.py                       # the acceptance: 40 x 1 s, 200 points
    .venv/bin/python bench/benchmarks/bench_batch.py --recordings 8 --seconds 0.5 --max-evaluations 16 --points 40

Output: bench/results/batch.json (git-ignored), a summary on stdout. The recordings are made
once into bench/results/batch_bags/ (reused when present). "One by one" runs every item with
the single-item code in this process, one after the other (what a shell loop over
``elastic-pm-dyn observe``/``tune`` does, without its process start-ups: the fair baseline).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import signal
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
            "items_started_more_than_once": sorted(k for k, a in attempts.items() if a > 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--recordings", type=int, default=40)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--max-evaluations", type=int, default=160)
    ap.add_argument("--points", type=int, default=200)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--skip-dask", action="store_true")
    a = ap.parse_args()
    from elastic_pm_dyn.fleet.api import batch, items_of
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
    for name, kind, inputs, options, st in (
            ("observe", "observe", bags, OPTIONS, None), ("tune", "tune", bags, tune_opts, None),
            ("study", "simulate", (), None, study)):
        items = items_of(kind, inputs, MODEL if st is None else None, options, st)
        if name == "observe":  # warm the compiled kernels' cache for every phase alike
            one_by_one(items[:1], work / "warm")
        serial = one_by_one(items, work / f"{name}_serial")
        cli_s = cli_loop(items, work / f"{name}_cli") if name == "observe" else None
        shutil.rmtree(work / f"{name}_pool", ignore_errors=True)
        res = batch(kind, inputs, work / f"{name}_pool", model=MODEL if st is None else None, options=options,
                    study=st, jobs=a.jobs, progress=False, plots_on=True)
        row = {"items": len(items), "serial_s": serial, "cli_loop_s": cli_s, "pool_s": res.wall_s,
               "speedup": serial / res.wall_s,
               "counts": res.counts, "pool_equals_serial": same(work / f"{name}_serial", work / f"{name}_pool", items),
               "failed": {r["id"]: r["error"] for r in res.failed},
               "item_s_mean": sum(r["wall_s"] or 0 for r in res.records) / max(1, len(res.records))}
        if not a.skip_dask and name != "study":
            shutil.rmtree(work / f"{name}_dask", ignore_errors=True)
            d = batch(kind, inputs, work / f"{name}_dask", model=MODEL, options=options, cluster=f"local:{a.jobs}",
                      progress=False, plots_on=False)
            row |= {"dask_s": d.wall_s, "dask_equals_pool": same(work / f"{name}_pool", work / f"{name}_dask", items)}
        report[name] = row
        print(name, json.dumps(row), flush=True)
    total_serial = report["observe"]["serial_s"] + report["tune"]["serial_s"]
    total_pool = report["observe"]["pool_s"] + report["tune"]["pool_s"]
    report["observe_tune_speedup"] = total_serial / total_pool
    seconds = (a.recordings - 1) * a.seconds
    report["per_recording_second"] = {"observe_cpu_s": report["observe"]["serial_s"] / seconds,
                                      "tune_cpu_s": report["tune"]["serial_s"] / seconds}
    report["worker_killed"] = kill_one_worker(bags, work / "killed", a.jobs)
    report["ctrl_c_resume"] = interrupt_and_resume(bags, work / "resume", after=max(2, a.recordings // 4))
    report["machine"]["loadavg_end"] = os.getloadavg()
    (results / "batch.json").write_text(json.dumps(report, indent=1, default=str) + "\n")
    print(json.dumps({k: report[k] for k in ("observe_tune_speedup", "per_recording_second", "worker_killed",
                                             "ctrl_c_resume")},
                     indent=1))


if __name__ == "__main__":
    main()
