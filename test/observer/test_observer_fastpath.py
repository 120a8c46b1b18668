"""The compiled per-period steps (``observer.core.period``), live one message at a time and offline many
periods in one call, equal the per-message API's Python bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.drivers.bag_input import Event
from elastic_pm_dyn.observer.drivers.event_filter import run_events
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording


@pytest.fixture(scope="module")
def rec(five_bar):
    return manoeuvre_recording(five_bar, duration=0.2, seed=5)


def _events(rec, imu=True, branch_at=(), corrupt=None, skip=(), late=(), reorder=(), frame="", bad_cmd=(),
            effort_at=(), skip_cmd=(), huge_cmd=()):
    """Lockstep events (joint state, imu, command per stamp) with glitches where asked."""
    corrupt = corrupt or {}
    names = list(rec.active_names)
    out = []

    def add(ns, kind, data):
        out.append(Event(int(ns), kind, data, len(out)))

    for k, ns in enumerate(rec.stamp_ns):
        c = corrupt.get(k, {})
        group = []
        if k not in skip:
            enc = np.asarray(c.get("encoder", rec.encoder[k]), dtype=float)
            eff = np.array([1.0, 2.0]) if k in effort_at else np.zeros(0)
            group.append(("joint_state", (names, enc, np.zeros(0), eff)))
            if imu:
                group.append(("imu", (np.asarray(c.get("accel", rec.accel[k]), dtype=float), frame)))
            if k in branch_at:
                group.append(("branch_forces", (list(rec.branch_names), rec.branch[k])))
        tau = np.array([np.nan, 0.0]) if k in bad_cmd else rec.tau_cmd[k]
        tau = np.array([1e15, -1e15]) if k in huge_cmd else tau
        if k not in skip_cmd:
            group.append(("command", (names, tau)))
        if k in reorder:
            group = group[::-1]
        for kind, data in group:
            add(ns, kind, data)
        for j in late:
            if j[0] == k:  # an old joint state arrives now (arrival order)
                add(rec.stamp_ns[j[1]], "joint_state", (names, rec.encoder[j[1]], np.zeros(0), np.zeros(0)))
    return out


def _same_float(a, b) -> bool:
    return (a == b) or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


@pytest.fixture
def count_steps(monkeypatch) -> dict[str, int]:
    """Messages the per-message API took through the compiled steps (the Observer's callers of
    period.sample_step and command_step; the kernels themselves stay untouched: a compiled
    caller such as period.run_periods binds them when it is compiled)."""
    taken = {"sample_step": 0, "command_step": 0}
    inner_samples, inner_command = Observer._fast_samples, Observer._fast_command

    def samples(self, *args):
        r = inner_samples(self, *args)
        taken["sample_step"] += r is not None
        return r

    def command(self, *args):
        r = inner_command(self, *args)
        taken["command_step"] += bool(r)
        return r

    monkeypatch.setattr(Observer, "_fast_samples", samples)
    monkeypatch.setattr(Observer, "_fast_command", command)
    return taken


def _compare(mech, params, events, order="stamp", min_fast=1):
    """The per-message API's Python (the reference), the per-message API through the compiled
    steps (the live node's way) and the offline fast path: the same in everything."""
    cfg = ObserverConfig.from_parameters(params)
    runs = []
    for fast, compiled in ((False, False), (False, True), (True, True)):
        obs = Observer(mech, cfg, t0=events[0].stamp_ns * 1e-9)
        obs.steps_compiled = compiled
        rows, stream, fault = run_events(obs, events, order, fast=fast)
        runs.append((obs, rows, stream, fault))
    for other in runs[1:]:
        _same(runs[0], other)
    return runs[-1][0], runs[-1][1]


def _same(one, other) -> None:
    (o1, r1, s1, f1), (o2, r2, s2, f2) = one, other
    assert f1 == f2
    assert r1.t == r2.t
    assert len(r1.t) > 0
    assert np.array_equal(r1.table(), r2.table(), equal_nan=True)
    assert np.array_equal(np.array(r1.nis), np.array(r2.nis), equal_nan=True)
    for name in o1.stats:
        a, b = o1.stats[name], o2.stats[name]
        for key in ("accepted", "rejected", "late", "nan", "other", "consecutive_rejections", "last_reason"):
            assert getattr(a, key) == getattr(b, key), (name, key)
        assert _same_float(a.last_nis, b.last_nis), name
        assert list(a.window) == list(b.window), name
    assert s1.bad_commands == s2.bad_commands
    # (Hpt only means something with an accelerometer: without one it is scratch)
    for key in ("q", "qd", "z", "P", "Phi", "Qd", "tau_hold", "tau_last") + (("Hpt",) if o1.with_point else ()):
        assert np.array_equal(getattr(o1, key), getattr(o2, key), equal_nan=True), key
    assert (o1.t, o1.t_command, o1._lin_age, o1._lin_T) == (o2.t, o2.t_command, o2._lin_age, o2._lin_T)
    assert o1.diagnostics() == o2.diagnostics()


def test_fast_path_equals_per_message_api_with_glitches(five_bar, rec, count_fast, count_steps) -> None:
    n = len(rec.stamp_ns)
    bad = {30: {"encoder": rec.encoder[30] + [0.5, 0.0]},  # gated
           40: {"encoder": [np.nan, rec.encoder[40][1]]},  # NaN entry: the other one is used
           50: {"accel": rec.accel[50] + [50.0, 0.0, 0.0]},  # gated
           60: {"accel": [np.nan, 0.0, 0.0]}}
    events = _events(rec, corrupt=bad, skip=(70, 71, 72), bad_cmd=(80,), branch_at=(90,), reorder=(100,),
                     effort_at=(110,))
    params = {"sensors": ["encoders", "imu", "branch_forces"]}
    obs, _ = _compare(five_bar, params, events)
    assert obs.stats["encoders"].rejected >= 1 and obs.stats["imu"].rejected >= 1
    assert obs.stats["encoders"].nan == 1 and obs.stats["imu"].nan == 1
    # Most periods went the fast way, offline and message by message.
    assert sum(count_fast) > 0.8 * n
    assert count_steps["sample_step"] > 1.6 * n and count_steps["command_step"] > 0.8 * n


def test_fast_path_encoders_only_and_measurement_start(five_bar, rec, count_fast) -> None:
    events = _events(rec, imu=False, corrupt={20: {"encoder": [np.nan, np.nan]}})
    _compare(five_bar, {"sensors": ["encoders"], "initial.source": "measurement"}, events)
    assert sum(count_fast) > 0.8 * len(rec.stamp_ns)


def test_fast_path_arrival_order_late_samples_and_timeout(five_bar, rec, count_fast) -> None:
    events = _events(rec, late=((50, 47), (51, 20)), frame="ee_imu")
    _compare(five_bar, {"sensors": ["encoders", "imu"]}, events, order="arrival")
    _compare(five_bar, {"sensors": ["encoders", "imu"]}, events, order="stamp")
    # A command timeout shorter than some gaps: the held torque drops to zero there.
    gappy = _events(rec, skip=tuple(range(60, 66)), skip_cmd=tuple(range(60, 66)))
    _compare(five_bar, {"sensors": ["encoders", "imu"], "timing.command_timeout": 0.0025}, gappy)
    assert sum(count_fast) > 0


def test_fast_path_stops_at_a_fault(five_bar, rec) -> None:
    """A torque that blows the model up: the same fault, state, statistics and rows either way."""
    obs, rows = _compare(five_bar, {"sensors": ["encoders", "imu"]}, _events(rec, huge_cmd=(50,)))
    assert obs.fault and len(rows.t) < len(rec.stamp_ns)


@pytest.mark.parametrize("hours", [0.0, 3.0, 24.0])
def test_hours_into_a_run_the_linearisation_keeps_its_schedule(five_bar, rec, hours: float) -> None:
    # The filter runs on seconds since the stream's origin. Hours into a run those seconds
    # carry 1e-12 .. 1e-11 s of round-off, and equal 1 ms intervals came out unequal: a test of
    # 1e-12 s relinearised a quarter to half of all periods (2-4x the cost on the Hexa). The
    # schedule must be process.relinearize_every's, however long the run.
    from elastic_pm_dyn.observer.drivers.stream import ObserverStream
    every = 8
    obs = Observer(five_bar, ObserverConfig.from_parameters({"sensors": ["encoders"],
                                                             "process.relinearize_every": every}))
    stream = ObserverStream(obs, origin_ns=int(rec.stamp_ns[0]) - round(hours * 3600e9))
    names = list(rec.active_names)
    fresh = 0  # periods that linearised anew
    for k, ns in enumerate(rec.stamp_ns):
        stream.on_joint_state(int(ns), names, rec.encoder[k])
        stream.on_torque_command(int(ns), names, rec.tau_cmd[k])
        fresh += k > 0 and obs._lin_age == 1
    assert obs.initialised and obs.fault is None and obs.t >= hours * 3600.0
    periods = len(rec.stamp_ns) - 1
    assert fresh <= math.ceil(periods / every) + 1, (fresh, periods)


def test_a_step_that_skips_saving_phi_and_qd_never_relinearises(five_bar, rec) -> None:
    """A compiled step saves Phi and Qd for its undo only when ``period._may_relinearise`` says the
    prediction may renew them. Its "no" must be certain: over prediction spans, linearisation ages
    and lengths, command timeouts and delayed commands around the boundaries, ``advance`` must
    leave Phi and Qd exactly as they were wherever it said no (and it must say no on the
    ordinary period, or the saving is never made)."""
    from elastic_pm_dyn.observer.core import period

    obs = Observer(five_bar, ObserverConfig.from_parameters({"sensors": ["encoders"]}))
    names = list(rec.active_names)
    for k in range(30):  # a filter in motion, linearised along the way
        obs.update_joint_states(rec.t[k], names, rec.encoder[k])
        obs.command(rec.t[k], rec.tau_cmd[k])
    ma, fixed, proc = obs.mech.arrays, obs.model.fixed, obs._proc
    rng = np.random.default_rng(11)
    said_no = renewed_after_no = 0
    every = float(obs.cfg.process.relinearize_every)
    dt = 1e-3
    for _ in range(400):
        state = tuple(a.copy() for a in obs._state())
        cmd, ctl = obs._kernel_control(4, np.inf)
        timing = obs.fast_timing()
        t = ctl[period.T_NOW]
        # the ordinary period (one 1 ms piece of the linearisation's length, not due), each
        # feature changed on its own with probability 1/4
        span, ctl[period.LIN_AGE], ctl[period.LIN_T] = dt, 1.0, dt
        if rng.random() < 0.25:
            span = float(rng.choice([0.0, 1e-10, 0.5 * dt, dt + 4e-10, dt + 6e-10, dt - 6e-10, 2 * dt,
                                     timing[period.MAX_INTERVAL] + 1e-4]))
        if rng.random() < 0.25:
            ctl[period.LIN_AGE] = float(rng.choice([0.0, every - 1.0, every, every + 1.0]))
        if rng.random() < 0.25:
            ctl[period.LIN_T] = float(rng.choice([dt + 3e-10, dt + 7e-10, 0.5 * dt, 2 * dt]))
        if rng.random() < 0.25:  # a command timeout that may end inside the span
            timing[period.TIMEOUT] = float(rng.choice([0.2e-3, 1e-3, 1.5e-3, 5e-3]))
            ctl[period.T_COMMAND] = t - float(rng.choice([0.0, 0.5e-3, 1e-3, 4.5e-3]))
        if rng.random() < 0.25:  # a delayed command waiting to act
            cmd[2][0] = t + float(rng.choice([0.2e-3, 0.5e-3, 3e-3]))
            cmd[3][0] = obs.tau_hold
            ctl[period.HEAD], ctl[period.TAIL] = 0.0, 1.0
        no = not period._may_relinearise(cmd, ctl, timing, t + span)
        phi, qd_ = state[4].copy(), state[5].copy()
        period.advance(ma, fixed, proc, state, cmd, ctl, timing, t + span, np.zeros(five_bar.n))
        if no:
            said_no += 1
            renewed_after_no += not (np.array_equal(phi, state[4]) and np.array_equal(qd_, state[5]))
    assert renewed_after_no == 0
    assert said_no > 80


def test_fast_path_with_wrench_states(five_bar, rec, count_fast) -> None:
    """The wrench states (process.wrench) live = offline too, a gated accelerometer sample (the
    wrench's jump, taken by the Observer's Python) included."""
    bad = {50: {"accel": rec.accel[50] + [5.0, 0.0, 0.0]}, 60: {"encoder": rec.encoder[60] + [0.5, 0.0]},
           70: {"accel": rec.accel[70] + [500.0, 0.0, 0.0]}}
    obs, _ = _compare(five_bar, {"sensors": ["encoders", "imu"], "process.wrench": "random_walk"},
                      _events(rec, corrupt=bad))
    # the 5 m/s^2 sample was taken as a jump of the wrench (and the next ones as its way back), the
    # 500 m/s^2 one stays an outlier
    assert obs.nw == 2 and obs.wrench_jumps[0] == pytest.approx(rec.t[50]) and obs.stats["imu"].rejected >= 1
    assert sum(count_fast) > 0.8 * len(rec.stamp_ns)
