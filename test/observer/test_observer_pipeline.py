"""``observe_bag(pipeline=True)`` (read, filter, write at once) gives what one stage after the other gives."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.bags.msgtypes import BRANCH_FORCES, HEADER, IMU, JOINT_STATE, NS, QUATERNION, TIME, VECTOR3
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import ObserverConfig
from elastic_pm_dyn.observer.drivers import bag_input, event_filter
from elastic_pm_dyn.observer.drivers import pipeline as observe_pipeline
from elastic_pm_dyn.observer.offline import observe_bag
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording

pytest.importorskip("rosbags")

TIMES = ("wall_read_s", "wall_filter_s", "wall_write_s", "wall_total_s", "speed_factor")


@pytest.fixture(scope="module")
def rec(five_bar):
    return manoeuvre_recording(five_bar, duration=0.3, seed=3)


def _write(rec, path: Path, nan_at=(), late=(), gated_at=(), branch_at=(), storage="mcap", skip=()) -> None:
    """A lockstep bag (joint state, imu, command per stamp, log time = bag order) with glitches:
    NaN encoders at ``nan_at``, ``late`` = ((k, j), ...): the joint state of stamp j arrives after
    stamp k's messages, a gated encoder sample at ``gated_at``, branch forces at ``branch_at``,
    nothing else of the stamps in ``skip``."""
    names = list(rec.active_names)
    z = np.zeros(0)
    log = iter(range(NS, 2 * NS, 1000))

    with BagWriter(path, storage) as w:
        types = w.typestore.types
        T, H, JS, BF, Imu = types[TIME], types[HEADER], types[JOINT_STATE], types[BRANCH_FORCES], types[IMU]
        V3, Q = types[VECTOR3], types[QUATERNION]

        def hdr(ns, frame=""):
            return H(stamp=T(sec=int(ns) // NS, nanosec=int(ns) % NS), frame_id=frame)

        c_cmd = w.add_connection("/torque_command", JOINT_STATE)
        c_js = w.add_connection("/measured_joint_states", JOINT_STATE)
        c_imu = w.add_connection("/ee_imu", IMU)
        c_bf = w.add_connection("/measured_branch_forces", BRANCH_FORCES)

        def js(ns, enc):
            w.write_message(c_js, next(log), JS(header=hdr(ns), name=names, position=np.asarray(enc, float),
                                                velocity=z, effort=z))

        unknown = np.full(9, -1.0)
        for k, ns in enumerate(rec.stamp_ns):
            for kk, j in late:
                if kk == k - 1:
                    js(rec.stamp_ns[j], rec.encoder[j])
            if k in skip:
                continue
            enc = rec.encoder[k]
            if k in nan_at:
                enc = [np.nan, enc[1]]
            if k in gated_at:
                enc = enc + np.array([0.5, 0.0])
            if k not in [j for _, j in late]:
                js(ns, enc)
            a = rec.accel[k]
            w.write_message(c_imu, next(log), Imu(
                header=hdr(ns, "ee_imu"), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=unknown,
                angular_velocity=V3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=unknown,
                linear_acceleration=V3(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                linear_acceleration_covariance=np.zeros(9)))
            if k in branch_at:
                w.write_message(c_bf, next(log), BF(
                    header=hdr(ns), name=list(rec.branch_names), force=rec.branch[k], deflection=z,
                    deflection_rate=z, force_stddev=z))
            w.write_message(c_cmd, next(log), JS(header=hdr(ns), name=names, position=z, velocity=z,
                                                 effort=rec.tau_cmd[k]))


def _files(out: Path) -> dict:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.name != "summary.json"}


def _run(mech, bag, out, pipeline, order="stamp", storage="mcap", sensors=("encoders", "imu", "branch_forces")):
    cfg = ObserverConfig.from_parameters({"sensors": list(sensors)})
    return observe_bag(mech, cfg, bag, out, order=order, storage=storage, log=lambda s: None, pipeline=pipeline)


def _same(a, b, out_a: Path, out_b: Path) -> None:
    assert a.rows.t == b.rows.t and len(a.rows.t) > 0
    assert np.array_equal(a.rows.table(), b.rows.table(), equal_nan=True)
    assert np.array_equal(np.array(a.rows.nis), np.array(b.rows.nis), equal_nan=True)
    fa, fb = _files(out_a), _files(out_b)
    assert sorted(fa) == sorted(fb) and "estimates.csv" in fa
    for name in fa:
        assert fa[name] == fb[name], name
    sa, sb = (json.loads((o / "summary.json").read_text()) for o in (out_a, out_b))
    assert list(sa) == list(sb)
    for k in TIMES:
        sa.pop(k), sb.pop(k)
    assert sa == sb


@pytest.mark.parametrize(("chunk", "lag_ns", "order"), [(37, 4_000_000, "stamp"), (101, 2_500_000, "stamp"),
                                                        (50, 0, "arrival"), (2000, 1_000_000_000, "stamp")])
def test_pipeline_equals_sequential(five_bar, rec, tmp_path, monkeypatch, chunk, lag_ns, order) -> None:
    """Small chunks and lags: chunk boundaries all over the glitches (NaN, a gated sample, late
    joint states within the lag, branch forces), the same rows, files and summary."""
    bag = tmp_path / "in"
    _write(rec, bag, nan_at=(40, 41, 120), gated_at=(77,), late=((52, 50), (130, 129)), branch_at=(90, 91))
    monkeypatch.setattr(observe_pipeline, "CHUNK_EVENTS", chunk)
    monkeypatch.setattr(observe_pipeline, "STAMP_LAG_NS", lag_ns)
    feeds, starts = [], []
    feed, inner = event_filter.EventFilter.feed, event_filter.run_events
    monkeypatch.setattr(event_filter.EventFilter, "feed", lambda self, ev: feeds.append(len(ev)) or feed(self, ev))
    monkeypatch.setattr(event_filter, "run_events", lambda *a, **k: starts.append(1) or inner(*a, **k))
    seq = _run(five_bar, bag, tmp_path / "seq", False, order)
    feeds.clear()
    pipe = _run(five_bar, bag, tmp_path / "pipe", True, order)
    _same(seq, pipe, tmp_path / "seq", tmp_path / "pipe")
    assert not (tmp_path / "pipe" / observe_pipeline._STAGE).exists()
    assert len(starts) == 1  # the sequential run's: no start-over
    assert sum(feeds) == sum(seq.summary.messages.values())
    assert len(feeds) > (5 if chunk < 2000 else 0)


@pytest.mark.parametrize("order", ["stamp", "arrival"])
def test_pipeline_starts_over_on_an_out_of_order_bag(five_bar, rec, tmp_path, monkeypatch, order) -> None:
    """A joint state stamped far before what the filter has taken already: with stamp order it
    starts over (arrival order takes it as a late sample), the same results either way."""
    bag = tmp_path / "in"
    _write(rec, bag, late=((200, 30),), nan_at=(100,))
    monkeypatch.setattr(observe_pipeline, "CHUNK_EVENTS", 60)
    monkeypatch.setattr(observe_pipeline, "STAMP_LAG_NS", 5_000_000)
    starts = []
    inner = event_filter.run_events
    monkeypatch.setattr(event_filter, "run_events", lambda *a, **k: starts.append(1) or inner(*a, **k))
    seq = _run(five_bar, bag, tmp_path / "seq", False, order)
    pipe = _run(five_bar, bag, tmp_path / "pipe", True, order)
    _same(seq, pipe, tmp_path / "seq", tmp_path / "pipe")
    assert len(starts) == (2 if order == "stamp" else 1)  # stamp order: the sequential rerun


def test_pipeline_arrival_order_starts_over_before_the_start(five_bar, rec, tmp_path, monkeypatch) -> None:
    """Arrival order: a message stamped before the stamps the observer started from (its t0)."""
    bag = tmp_path / "in"
    _write(rec, bag, late=((150, 0),), skip=(0,))
    monkeypatch.setattr(observe_pipeline, "CHUNK_EVENTS", 60)
    starts = []
    inner = event_filter.run_events
    monkeypatch.setattr(event_filter, "run_events", lambda *a, **k: starts.append(1) or inner(*a, **k))
    seq = _run(five_bar, bag, tmp_path / "seq", False, "arrival")
    pipe = _run(five_bar, bag, tmp_path / "pipe", True, "arrival")
    _same(seq, pipe, tmp_path / "seq", tmp_path / "pipe")
    assert len(starts) == 2


def test_pipeline_sqlite3_and_no_bag_out(five_bar, rec, tmp_path, monkeypatch) -> None:
    bag = tmp_path / "in"
    _write(rec, bag, nan_at=(60,), storage="sqlite3")
    monkeypatch.setattr(observe_pipeline, "CHUNK_EVENTS", 64)
    monkeypatch.setattr(observe_pipeline, "STAMP_LAG_NS", 3_000_000)
    seq = _run(five_bar, bag, tmp_path / "seq", False, storage="sqlite3")
    pipe = _run(five_bar, bag, tmp_path / "pipe", True, storage="sqlite3")
    _same(seq, pipe, tmp_path / "seq", tmp_path / "pipe")
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
    res = observe_bag(five_bar, cfg, bag, tmp_path / "csv_only", write_estimates_bag=False, log=lambda s: None)
    assert sorted(p.name for p in (tmp_path / "csv_only").iterdir()) == ["estimates.csv", "summary.json"]
    assert res.rows.t == seq.rows.t


def test_pipeline_truncated_bag_same_error_and_no_output(five_bar, rec, tmp_path, monkeypatch) -> None:
    bag = tmp_path / "in"
    _write(rec, bag)
    mcap = next(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    monkeypatch.setattr(observe_pipeline, "CHUNK_EVENTS", 50)
    monkeypatch.setattr(observe_pipeline, "STAMP_LAG_NS", 2_000_000)
    errors = []
    for pipeline in (False, True):
        out = tmp_path / f"out{pipeline}" / "deeper"
        with pytest.raises(Exception) as info:
            _run(five_bar, bag, out, pipeline)
        errors.append((type(info.value), str(info.value)))
        assert not out.exists() and not out.parent.exists()
    assert errors[0] == errors[1]
    assert "\n" not in errors[1][1]
    with pytest.raises(InputError, match="no such bag"):
        _run(five_bar, tmp_path / "missing", tmp_path / "o", True)


def test_pipeline_error_while_filtering_same_error_and_no_output(five_bar, rec, tmp_path, monkeypatch) -> None:
    """An error in the reading thread after the filter and the writer have started."""
    bag = tmp_path / "in"
    _write(rec, bag)
    monkeypatch.setattr(observe_pipeline, "CHUNK_EVENTS", 50)
    monkeypatch.setattr(observe_pipeline, "STAMP_LAG_NS", 2_000_000)
    inner = bag_input._decode
    for pipeline in (False, True):
        calls = []

        def decode(*args, calls=calls):
            calls.append(1)
            if len(calls) == 700:
                raise RuntimeError("message 700: broken")
            return inner(*args)

        monkeypatch.setattr(bag_input, "_decode", decode)
        out = tmp_path / f"out{pipeline}"
        with pytest.raises(RuntimeError, match=r"^message 700: broken$"):
            _run(five_bar, bag, out, pipeline)
        assert not out.exists()
