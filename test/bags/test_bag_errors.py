"""Bad bags through the command line: one line and exit 2, never a traceback; a recording
whose writer was killed gives its data and one warning line instead.

Cases: an mcap cut to its 8 magic bytes, a finished bag truncated, flipped bytes in an
mcap chunk, garbage CDR in a sqlite3 bag, a known topic carrying another type, a bag
without messages, and the cut recordings (mcap without footer, sqlite3 never closed).
"""

from __future__ import annotations

import csv
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.bags import cdr
from elastic_pm_dyn.bags.msgtypes import JOINT_STATE
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.cli import main
from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

MODEL = str(Path(__file__).resolve().parents[1].parent / "config" / "five_bar.yaml")
N = 400  # joint states of the small bags, 1 ms apart


def _joint_states(n: int = N) -> tuple[np.ndarray, np.ndarray]:
    ns = 5 * 10**9 + np.arange(n, dtype=np.int64) * 1_000_000
    k = np.arange(n, dtype=float)[:, None]
    return ns, cdr.encode_joint_state_batch(ns, ["left_motor", "right_motor"], np.hstack([k, -k]),
                                             np.zeros((n, 2)), np.zeros((n, 2)))


def write_states(path: Path, storage: str) -> Path:
    """A finished bag of N joint states."""
    ns, msgs = _joint_states()
    with BagWriter(path, storage) as w:
        c = w.add_connection("/joint_states", JOINT_STATE)
        for k in range(N):
            w.write(c, int(ns[k]), msgs[k].tobytes())
    return path


def killed_recording(path: Path, storage: str, kill_after: int) -> Path:
    """A bag whose writer was SIGKILLed after ``kill_after`` messages, flushed every 100 (in a fork:
    the kill ends the writing process as it would the recorder, without a Python start-up)."""
    ns, msgs = _joint_states()
    pid = os.fork()
    if pid == 0:  # the child writes and is killed; it never returns into pytest
        try:
            w = BagWriter(path, storage)
            c = w.add_connection("/joint_states", JOINT_STATE)
            for k in range(kill_after):
                w.write(c, int(ns[k]), msgs[k].tobytes())
                if (k + 1) % 100 == 0:
                    w.flush()
        finally:
            os.kill(os.getpid(), signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
    return path


def run_cli(args: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, err: str, *words: str) -> None:
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], lines[0]


def storage_file(bag: Path) -> Path:
    return next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))


@pytest.mark.parametrize(("command", "single_file"), [("analyze", False), ("export", True)])
def test_mcap_cut_to_its_magic_bytes(tmp_path, capsys, command, single_file):
    bag = write_states(tmp_path / "bag", "mcap")
    f = storage_file(bag)
    os.truncate(f, 8)
    code, _, err = run_cli([command, str(f if single_file else bag), "--out", str(tmp_path / "out")], capsys)
    assert_one_line_error(code, err, str(f if single_file else bag))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
@pytest.mark.parametrize("fraction", [0.1, 0.5, 0.97])
def test_a_finished_bag_truncated_is_an_error(tmp_path, capsys, storage, fraction):
    bag = write_states(tmp_path / "bag", storage)
    f = storage_file(bag)
    os.truncate(f, int(f.stat().st_size * fraction))
    code, _, err = run_cli(["export", str(bag), "--out", str(tmp_path / "out")], capsys)
    assert_one_line_error(code, err, str(bag))


@pytest.fixture(scope="module")
def observer_bags(five_bar, tmp_path_factory):
    rec = manoeuvre_recording(five_bar, duration=0.05, seed=3)
    root = tmp_path_factory.mktemp("observer_bags")
    for storage in ("mcap", "sqlite3"):
        recording_to_bag(rec, root / storage, use=("encoders", "imu"), storage=storage)
    return root


def _observe(bag: Path, tmp_path: Path, capsys) -> tuple[int, str, str]:
    return run_cli(["observe", "--model", MODEL, "--bag", str(bag), "--out", str(tmp_path / "obs"),
                    "--sensors", "encoders", "imu"], capsys)


def test_flipped_bytes_in_an_mcap_chunk(observer_bags, tmp_path, capsys):
    bag = tmp_path / "bag"
    shutil.copytree(observer_bags / "mcap", bag)
    f = storage_file(bag)
    data = bytearray(f.read_bytes())
    for i in range(len(data) // 3, len(data) // 3 + 40, 7):  # inside the message data of the chunk
        data[i] ^= 0x5A
    f.write_bytes(bytes(data))
    code, _, err = _observe(bag, tmp_path, capsys)
    assert_one_line_error(code, err, str(bag), "corrupt")


@pytest.mark.parametrize("garbage", [b"\x00\x01\x00\x00\xde\xad", b"\x07\x07garbage!", b"", os.urandom(64)])
def test_garbage_cdr_in_a_sqlite3_bag(observer_bags, tmp_path, capsys, garbage):
    bag = tmp_path / "bag"
    shutil.copytree(observer_bags / "sqlite3", bag)
    with sqlite3.connect(storage_file(bag)) as con:
        con.execute("UPDATE messages SET data = ? WHERE id % 5 = 2", (garbage,))
    con.close()
    code, _, err = _observe(bag, tmp_path, capsys)
    assert_one_line_error(code, err, str(bag))


@pytest.mark.parametrize("msgtype", ["std_msgs/msg/String", "geometry_msgs/msg/PoseStamped"])
def test_a_known_topic_with_another_type(tmp_path, capsys, msgtype):
    bag = tmp_path / "bag"
    with BagWriter(bag, "mcap") as w:
        c = w.add_connection("/joint_states", msgtype)
        t = w.typestore.types
        if msgtype.endswith("String"):
            msg = t[msgtype](data="not a joint state")
        else:
            hdr = t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="")
            pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=0.0, y=0.4, z=0.0),
                                               orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0,
                                                                                             w=1.0))
            msg = t[msgtype](header=hdr, pose=pose)
        for k in range(20):
            w.write_message(c, 10**9 + k * 10**6, msg)
    code, _, err = run_cli(["analyze", str(bag), "--out", str(tmp_path / "out"), "--no-plots"], capsys)
    assert_one_line_error(code, err, "/joint_states", msgtype, JOINT_STATE)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_bag_without_messages(tmp_path, capsys, storage):
    bag = tmp_path / "bag"
    with BagWriter(bag, storage) as w:
        w.add_connection("/joint_states", JOINT_STATE)
    with open_bag(bag) as b:
        assert b.end_ns - b.start_ns == 0  # a duration of nothing, never negative
    for command in ("analyze", "export"):
        code, _, err = run_cli([command, str(bag), "--out", str(tmp_path / command)], capsys)
        assert_one_line_error(code, err, str(bag), "empty")


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_killed_recording_gives_its_data_and_one_warning(tmp_path, capsys, caplog, storage):
    bag = killed_recording(tmp_path / "bag", storage, kill_after=350)  # flushed up to message 300
    code, _, err = run_cli(["export", str(bag), "--out", str(tmp_path / "csv")], capsys)
    assert code == 0, err
    warning = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warning) == 1 and "cut off" in warning[0] and "\n" not in warning[0], warning
    assert "300 messages" in warning[0] and f"{(5 * 10**9 + 299 * 10**6) * 1e-9:.6f}" in warning[0], warning
    with (tmp_path / "csv" / "joint_states.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["position.left_motor"]) for r in rows] == list(range(300))


def test_the_cut_warning_is_one_line_on_stderr(tmp_path):
    bag = killed_recording(tmp_path / "bag", "mcap", kill_after=250)
    proc = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "export", str(bag), "--out", str(tmp_path / "csv")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("warning: ") and "cut off" in lines[0], proc.stderr
    assert "200 messages" in lines[0]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_recording_killed_before_its_first_flush(tmp_path, capsys, storage):
    """Nothing recovered: the bag opens as cut and empty, analyze says so in one line."""
    bag = killed_recording(tmp_path / "bag", storage, kill_after=50)
    code, _, err = run_cli(["analyze", str(bag), "--out", str(tmp_path / "out"), "--no-plots"], capsys)
    assert code == 2 and "Traceback" not in err, err
    assert "empty" in err and "cut off" in err
