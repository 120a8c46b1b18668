"""Issue #44's acceptance: a 20-bag fleet folder (16 good, one of another machine, two corrupt,
a stray file at the top) through `elastic-pm-dyn batch observe`:

1. one by one in this process (the reference outputs, the warm loop's time);
2. a 2-worker pool (`batch` as a process) with one worker SIGKILLed and another SIGSTOPped
   mid-item, `results.csv` read while it runs, a second run on the same folder started
   meanwhile (must be refused): every good item once and equal to the loop, the bad ones
   failed rows with one line each, the run ending by itself within its item limit;
3. a real `dask scheduler` + 2 `dask worker` processes with one worker SIGKILLed mid-item:
   nothing finished computed again (each item's starts counted in OUT/attempts/);
4. the batch process SIGKILLed after a quarter of the items: the table readable, no worker
   traceback, a re-run finishing the rest;
5. the pool's speed against the loop (fresh and warm pool) and the live table's cost per
   record.

    .venv/bin/python bench/benchmarks/bench_batch_faults.py              # 20 x 1 s, --item-timeout 30
    .venv/bin/python bench/benchmarks/bench_batch_faults.py --seconds 0.3 # a loaded machine

Output: bench/results/batch_faults.json and .md (git-ignored); work in bench/results/batch_faults/.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from common import RESULTS, commit, write

REPO = Path(__file__).resolve().parents[2]
MODEL = REPO / "config" / "five_bar.yaml"
OPTIONS = {"sensors": ["encoders", "imu"], "no_bag": True}
CLI_OPTIONS = ["-o", "sensors=encoders imu", "-o", "no_bag=true"]
ENV = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def make_fleet(root: Path, seconds: float) -> Path:
    """16 good five-bar bags in four robot folders, a triglide bag, a cut and a garbage bag,
    and a stray garbage .mcap at the top (made once, reused)."""
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag
    fleet = root / f"fleet_{seconds:g}s"
    if (fleet / "done").is_file():
        return fleet
    shutil.rmtree(fleet, ignore_errors=True)
    mech = Mechanism(load_model(MODEL))
    for k in range(16):
        write_bag(generate(mech, RecordingSpec(duration=seconds, seed=4400 + k)),
                  fleet / f"robot{k // 4}" / f"rec{k % 4}")
    tri = Mechanism(load_model(REPO / "config" / "triglide.yaml"))
    write_bag(generate(tri, RecordingSpec(motion="chirp", duration=seconds, seed=4499)),
              fleet / "robot9" / "other_machine")
    cut = fleet / "robot0" / "cut"
    shutil.copytree(fleet / "robot0" / "rec0", cut)
    data = next(cut.glob("*.mcap"))
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    (fleet / "robot1" / "garbage").mkdir()
    (fleet / "robot1" / "garbage" / "garbage_0.mcap").write_bytes(b"\x89MCAP0\r\n" + os.urandom(4000))
    (fleet / "stray.mcap").write_bytes(os.urandom(3000))
    (fleet / "done").write_text("")
    return fleet


BAD = {"robot0-cut", "robot1-garbage", "robot9-other_machine", "stray"}


def items_of(fleet: Path):
    from elastic_pm_dyn.fleet.api import items_of as find
    return find("observe", [fleet], MODEL, OPTIONS)


def loop(items, out: Path) -> float:
    from elastic_pm_dyn.fleet.runners import run_item
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    for it in items:
        run_item(it, out)
    return time.perf_counter() - start


def same(a: Path, b: Path, ids) -> list[str]:
    """The items whose estimates.csv differ (or exist in one folder only)."""
    differ = []
    for i in ids:
        fa, fb = a / "items" / i / "estimates.csv", b / "items" / i / "estimates.csv"
        if fa.is_file() != fb.is_file() or (fa.is_file() and fa.read_bytes() != fb.read_bytes()):
            differ.append(i)
    return differ


class Tamper(threading.Thread):
    """Send each victim item's worker its signal on the item's first start (the pid is in the
    name of the item's hidden temporary folder)."""

    def __init__(self, out: Path, victims: dict[str, signal.Signals]):
        super().__init__(daemon=True)
        self.out, self.victims, self.hit = out, victims, {}
        self.done = threading.Event()

    def run(self) -> None:
        while len(self.hit) < len(self.victims) and not self.done.wait(0.002):
            for item_id, sig in self.victims.items():
                for tmp in (self.out / "items").glob(f".{item_id}.*.tmp") if item_id not in self.hit else ():
                    self.hit[item_id] = int(tmp.name.rsplit(".", 2)[1])
                    os.kill(self.hit[item_id], sig)
                    self.hit[item_id] = (self.hit[item_id], time.monotonic())

    def release(self) -> None:
        self.done.set()
        for pid, _ in self.hit.values():
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)


class Reader(threading.Thread):
    """Reads results.csv every 20 ms while the batch runs: rows seen, files that did not parse."""

    def __init__(self, path: Path):
        super().__init__(daemon=True)
        self.path, self.sizes, self.bad = path, [], 0
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.wait(0.02):
            if not self.path.is_file():
                continue
            try:
                with open(self.path) as f:
                    rows = list(csv.DictReader(f))
                if not all(r["id"] and r["status"] in ("ok", "failed") for r in rows):
                    self.bad += 1
                self.sizes.append(len(rows))
            except (OSError, csv.Error, KeyError):
                self.bad += 1


def batch_cmd(fleet: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "elastic_pm_dyn", "batch", "observe", str(fleet), "--model", str(MODEL), "--out",
            str(out), *CLI_OPTIONS, "--no-plots", *extra]


def rows_of(out: Path) -> dict[str, dict]:
    with open(out / "results.csv") as f:
        return {r["id"]: r for r in csv.DictReader(f)}


def verdict(out: Path, ref: Path, items, tampered: set[str]) -> dict:
    rows = rows_of(out)
    good = [it.id for it in items if it.id not in BAD]
    return {"rows": len(rows), "ok": sorted(i for i, r in rows.items() if r["status"] == "ok") == sorted(good),
            "failed_rows": {i: rows[i]["error"] for i in sorted(BAD) if i in rows},
            "bad_ones_failed_one_line": all(rows.get(i, {}).get("status") == "failed" and rows[i]["error"]
                                            and "\n" not in rows[i]["error"] for i in BAD),
            "attempts_of_untampered_good": sorted({rows[i]["attempt"] for i in good if i not in tampered}),
            "attempts_of_tampered": {i: rows[i]["attempt"] for i in sorted(tampered) if i in rows},
            "outputs_differ_from_loop": same(out, ref, good),
            "temporaries_left": len(list((out / "items").glob(".*.tmp")))}


def pool_run(fleet: Path, items, ref: Path, work: Path, limit: float) -> dict:
    out = work / "pool"
    shutil.rmtree(out, ignore_errors=True)
    good = [it.id for it in items if it.id not in BAD]
    killed, stopped = good[2], good[5]
    tamper, reader = Tamper(out, {killed: signal.SIGKILL, stopped: signal.SIGSTOP}), Reader(out / "results.csv")
    start = time.monotonic()
    proc = subprocess.Popen(batch_cmd(fleet, out, "--jobs", "2", "--item-timeout", f"{limit:g}", "--heartbeat", "5"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    tamper.start()
    reader.start()
    while proc.poll() is None and not (out / "items").is_dir():
        time.sleep(0.01)
    second = subprocess.run(batch_cmd(fleet, out, "--jobs", "2"), capture_output=True, text=True, env=ENV,
                            timeout=600)
    try:
        stdout, err = proc.communicate(timeout=limit * 4 + 600)
    finally:
        tamper.release()
        reader.done.set()
    wall = time.monotonic() - start
    lines = err.splitlines()
    stop_at = tamper.hit.get(stopped, (0, start))[1]
    return {"exit": proc.returncode, "wall_s": wall, "item_timeout_s": limit, "killed": killed, "stopped": stopped,
            "tampered": sorted(tamper.hit), "ended_after_stop_s": time.monotonic() - stop_at,
            **verdict(out, ref, items, {killed, stopped}),
            "worker_lines": [ln for ln in lines if "worker pid" in ln],
            "heartbeat_lines": sum(ln.startswith("[") for ln in lines),
            "tracebacks": err.count("Traceback"),
            "second_run": {"exit": second.returncode, "stderr": second.stderr.strip().splitlines()},
            "reader": {"reads": len(reader.sizes), "unreadable": reader.bad,
                       "rows_seen": sorted(set(reader.sizes))}, "last_line": stdout.strip()}


def dask_run(fleet: Path, items, ref: Path, work: Path) -> dict:
    """A scheduler and two single-threaded workers as separate processes (as on a cluster)."""
    out = work / "dask"
    shutil.rmtree(out, ignore_errors=True)
    sched_file = work / "scheduler.json"
    sched_file.unlink(missing_ok=True)
    dask = str(Path(sys.executable).with_name("dask"))
    procs = [subprocess.Popen([dask, "scheduler", "--scheduler-file", str(sched_file), "--port", "0",
                               "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV)]
    try:
        while not sched_file.is_file():
            time.sleep(0.1)
        procs.append(subprocess.Popen([dask, "worker", "--scheduler-file", str(sched_file), "--nworkers", "2",
                                       "--nthreads", "1", "--no-dashboard"], stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL, env=ENV))
        address = json.loads(sched_file.read_text())["address"]
        from distributed import Client
        with Client(address, timeout="60s") as c:
            c.wait_for_workers(2, timeout=120)
        from elastic_pm_dyn.fleet.api import batch
        good = [it.id for it in items if it.id not in BAD]
        killed = good[4]
        tamper = Tamper(out, {killed: signal.SIGKILL})
        tamper.start()
        lines: list[str] = []
        res = batch("observe", [fleet], out, model=MODEL, options=OPTIONS, cluster=address, progress=False,
                    plots_on=False, log=lines.append)
        tamper.release()
        starts = {it.id: len((out / "attempts" / it.id).read_text().splitlines())
                  for it in items if (out / "attempts" / it.id).is_file()}
        return {"wall_s": res.wall_s, "counts": res.counts, "killed": killed, "tampered": sorted(tamper.hit),
                **verdict(out, ref, items, {killed}),
                "started_more_than_once": {i: n for i, n in starts.items() if n > 1},
                "worker_lines": [ln for ln in lines if "worker" in ln]}
    finally:
        for p in reversed(procs):
            p.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(30)
            if p.poll() is None:
                p.kill()


def parent_killed(fleet: Path, items, work: Path) -> dict:
    out = work / "killed_parent"
    shutil.rmtree(out, ignore_errors=True)
    cmd = batch_cmd(fleet, out, "--jobs", "2")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    while proc.poll() is None and len(list(out.glob("items/*/item.json"))) < len(items) // 4:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=300)  # EOF once the workers (holding stderr too) are gone
    rows = rows_of(out)
    folders = len(list(out.glob("items/*/item.json")))
    again = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=3600)
    return {"rows_after_kill": len(rows), "ok_rows_after_kill": sum(r["status"] == "ok" for r in rows.values()),
            "complete_folders_after_kill": folders,
            "tracebacks": err.count("Traceback"), "broken_pipe": err.count("BrokenPipe"),
            "rerun_exit": again.returncode, "rerun_counts": json.loads((out / "batch.json").read_text())["counts"]}


def speed(fleet: Path, items, work: Path, repeats: int) -> dict:
    """The good items: the warm loop against a fresh and a warm 2-worker pool (medians)."""
    import statistics

    from elastic_pm_dyn.fleet.api import batch
    from elastic_pm_dyn.fleet.pool import LocalPool
    good = [fleet / it.source for it in items if it.id not in BAD]
    loops, fresh, warm = [], [], []
    with LocalPool(2) as keep:
        batch("observe", good[:2], work / "speed_w", model=MODEL, options=OPTIONS, engine=keep, progress=False,
              plots_on=False)  # the kept workers warm
        for _ in range(repeats):
            loops.append(loop([it for it in items if it.id not in BAD], work / "speed_loop"))
            for times, engine in ((fresh, LocalPool(2)), (warm, keep)):
                shutil.rmtree(work / "speed_pool", ignore_errors=True)
                times.append(batch("observe", good, work / "speed_pool", model=MODEL, options=OPTIONS, engine=engine,
                                   progress=False, plots_on=False).wall_s)
    m = statistics.median
    return {"loop_s": loops, "fresh_pool_s": fresh, "warm_pool_s": warm, "speedup_fresh": m(loops) / m(fresh),
            "speedup_warm": m(loops) / m(warm), "load_1min": os.getloadavg()[0]}


def table_cost(work: Path) -> dict:
    """Milliseconds per record of the live table (results.csv + batch.json rewritten) at 20
    and 2000 rows of 40 figures."""
    from elastic_pm_dyn.fleet.items import Item
    from elastic_pm_dyn.fleet.live import LiveTable
    out: dict = {}
    for n in (20, 2000):
        folder = work / f"table{n}"
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        items = [Item("observe", f"i{k:05d}", "m", f"s{k}") for k in range(n)]
        records: dict = {}
        live = LiveTable(folder, "observe", items, records, lambda: {})
        start = time.perf_counter()
        for it in items:
            live.add({"id": it.id, "kind": "observe", "status": "ok", "attempt": 1, "wall_s": 1.0,
                      "figures": {f"f{j}": j * 0.1 for j in range(40)}, "item": it.row()})
        out[f"ms_per_record_{n}"] = (time.perf_counter() - start) / n * 1e3
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=1.0, help="length of each recording")
    ap.add_argument("--item-timeout", type=float, default=30.0, help="the pool run's --item-timeout")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each speed timing (medians)")
    ap.add_argument("--skip-dask", action="store_true")
    a = ap.parse_args()
    work = RESULTS / "batch_faults"
    work.mkdir(parents=True, exist_ok=True)
    fleet = make_fleet(work, a.seconds)
    items = items_of(fleet)
    report: dict = {"commit": commit(), "setup": vars(a), "items": len(items), "cpus": os.cpu_count(),
                    "load_start": os.getloadavg()}
    report["loop_s"] = loop(items, work / "loop")
    report["pool"] = pool_run(fleet, items, work / "loop", work, a.item_timeout)
    print("pool", json.dumps(report["pool"]), flush=True)
    if not a.skip_dask:
        report["dask"] = dask_run(fleet, items, work / "loop", work)
        print("dask", json.dumps(report["dask"]), flush=True)
    report["parent_killed"] = parent_killed(fleet, items, work)
    report["speed"] = speed(fleet, items, work, a.repeats)
    report["live_table"] = table_cost(work)
    report["load_end"] = os.getloadavg()
    p, d, k, s = report["pool"], report.get("dask", {}), report["parent_killed"], report["speed"]
    md = "\n".join([
        f"# batch under faults (issue #44), commit {report['commit']}, {len(items)} items x {a.seconds:g} s",
        "", "| check | result |", "|---|---|",
        f"| pool: good items ok once, equal to the loop | {p['ok']}, attempts {p['attempts_of_untampered_good']}, "
        f"differ {p['outputs_differ_from_loop']} |",
        f"| pool: killed / stopped item attempts | {p['attempts_of_tampered']} |",
        f"| pool: bad ones failed, one line | {p['bad_ones_failed_one_line']} ({len(p['failed_rows'])}) |",
        f"| pool: wall, ended after the SIGSTOP | {p['wall_s']:.1f} s, {p['ended_after_stop_s']:.1f} s "
        f"(limit {a.item_timeout:g} s) |",
        f"| second run on the same folder | exit {p['second_run']['exit']}: {p['second_run']['stderr']} |",
        f"| results.csv read while running | {p['reader']['reads']} reads, {p['reader']['unreadable']} unreadable |",
        f"| dask scheduler + 2 workers, one killed: started twice | {d.get('started_more_than_once')} |",
        f"| dask: good ok, equal to the loop | {d.get('ok')}, differ {d.get('outputs_differ_from_loop')} |",
        f"| batch SIGKILLed: rows (ok) / complete folders, tracebacks, re-run | {k['rows_after_kill']} "
        f"({k['ok_rows_after_kill']}) / {k['complete_folders_after_kill']}, {k['tracebacks']} tracebacks, "
        f"re-run exit {k['rerun_exit']} {k['rerun_counts']} |",
        f"| observe speed-up, fresh / warm 2-worker pool | {s['speedup_fresh']:.2f}x / {s['speedup_warm']:.2f}x |",
        f"| live table, ms per record (20 / 2000 rows) | {report['live_table']['ms_per_record_20']:.2f} / "
        f"{report['live_table']['ms_per_record_2000']:.1f} |"])
    write(RESULTS, "batch_faults", report, md)


if __name__ == "__main__":
    main()
