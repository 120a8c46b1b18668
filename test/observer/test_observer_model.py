"""The fixed observer model (``ObserverModel``) shared by observers of other noise levels and
disturbance models, and ``tuning.evaluate`` on a recording prepared once: the same numbers
as an observer built from the mechanism alone."""

from __future__ import annotations

import numpy as np
import pytest

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.core.observer_model import ObserverModel
from elastic_pm_dyn.observer.drivers.bag_input import Event
from elastic_pm_dyn.observer.drivers.event_filter import run_events
from elastic_pm_dyn.observer.drivers.prepared import prepare
from elastic_pm_dyn.observer.testing.scenarios import manoeuvre_recording
from elastic_pm_dyn.observer.tuning import tuning

SENSORS = ["encoders", "imu"]
# candidate configurations of one model key: noise levels, the disturbance spectrum, timing
CANDIDATES = [{}, {"process.disturbance_stddev": 0.05, "imu.stddev": [0.01]},
              {"encoders.position_stddev": [3e-5], "process.torque_noise_psd": 1e-8,
               "process.disturbance_bandwidth": [2.0, 40.0]},
              {"imu.sample_timing": "auto", "command_delay": 0.0005}]


@pytest.fixture(scope="module")
def events(five_bar) -> list[Event]:
    rec = manoeuvre_recording(five_bar, duration=0.1, seed=5)
    names, out = list(rec.active_names), []
    for k, ns in enumerate(rec.stamp_ns):
        for kind, data in (("joint_state", (names, np.asarray(rec.encoder[k], dtype=float), np.zeros(0), np.zeros(0))),
                           ("imu", (np.asarray(rec.accel[k], dtype=float), "")), ("command", (names, rec.tau_cmd[k]))):
            out.append(Event(int(ns), kind, data, len(out)))
    return out


def _cfg(extra: dict) -> ObserverConfig:
    return ObserverConfig.from_parameters({"sensors": SENSORS, **extra})


def test_a_shared_model_gives_the_observer_of_the_mechanism_bit_for_bit(five_bar, events) -> None:
    model = ObserverModel.build(five_bar, _cfg({}))
    for extra in CANDIDATES:
        cfg = _cfg(extra)
        runs = []
        for source in (five_bar, model):
            obs = Observer(source, cfg, t0=events[0].stamp_ns * 1e-9)
            rows, _, fault = run_events(obs, events)
            assert fault == ""
            runs.append((obs, rows))
        (o1, r1), (o2, r2) = runs
        assert np.array_equal(r1.table(), r2.table(), equal_nan=True), extra
        assert np.array_equal(np.array(r1.nis), np.array(r2.nis), equal_nan=True), extra
        for name in o1.stats:
            assert vars(o1.stats[name]) == vars(o2.stats[name]), (extra, name)
    assert model.encoders.pos_var[0] == _cfg({}).encoders.position_stddev[0] ** 2  # the model's own untouched


def test_tuning_evaluate_on_a_prepared_recording_equals_a_fresh_pass(five_bar, events) -> None:
    prepared = prepare(five_bar, _cfg({}), events)  # once, as tune does
    for extra in CANDIDATES:
        params = dict(_cfg(extra).parameters)
        got = tuning.evaluate(five_bar, params, events, prepared=prepared)
        obs = Observer(five_bar, _cfg(extra), t0=0.0)
        obs.gating = False
        _, _, fault = run_events(obs, events, "arrival", origin_ns=events[0].stamp_ns)
        assert got.fault == fault == ""
        assert got.nll == sum(obs.stats[s].nll for s in SENSORS), extra


def test_a_model_serves_only_configurations_of_its_key(five_bar) -> None:
    model = ObserverModel.build(five_bar, _cfg({}))
    with pytest.raises(InputError, match="not its model's"):
        Observer(model, ObserverConfig.from_parameters({"sensors": ["encoders"]}))
    with pytest.raises(InputError, match="not its model's"):
        Observer(model, _cfg({"process.disturbance_joints": ["left_motor"]}))


def test_the_rk4_substep_from_the_model_resolves_its_fastest_mode(five_bar) -> None:
    """process.dt: 0 halves 1e-4 s until omega h <= 0.2 for the fastest elastic mode (motors
    free). The reference five-bar's spring modes are ~520-570 Hz (docs/five_bar.md: 523 / 557 Hz
    with the motors held): omega h = 0.35 at 1e-4 s, 0.18 at 5e-5 s."""
    model = ObserverModel.build(five_bar, ObserverConfig.from_parameters())
    f = model.fastest_mode_hz
    assert 520.0 < f < 620.0
    assert model.substep(0.0) == 5e-5 and 2 * np.pi * f * 5e-5 <= 0.2 < 2 * np.pi * f * 1e-4
    assert model.substep(3e-5) == 3e-5  # given: kept
    obs = Observer(model, ObserverConfig.from_parameters({"process.integrator": "rk4"}))
    assert obs.dt == 5e-5 and obs.fast_timing()[1] == 5e-5
    assert obs.diagnostics()["process.dt_in_use"] == "5e-05"
    # ETD2 (the default) integrates the springs exactly: two steps per 1 ms interval, whatever the springs
    obs = Observer(model, ObserverConfig.from_parameters())
    assert obs.dt == 5e-4 and obs.fast_timing()[1] == 5e-4
