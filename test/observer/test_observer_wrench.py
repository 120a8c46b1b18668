"""The observer's end-effector wrench states against the plant's true wrench (a different
integrator: the plant's RK4 with the wrench evaluated per 0.1 ms step, the filter's ETD2 with
the wrench held as a state), and contact detection on them.

What physics says and the tests check: a force on the tool is seen by the accelerometer at once
(it accelerates the end-effector mass directly) and kept by the encoders (the hold loop's
deflection): a step is estimated within 10 % in 20 ms and without bias after it; the states'
standard deviations cover their errors (NEES in its band); a stiff wall is detected within
5 ms of touching it and normal motion is not taken for a contact.
"""

import numpy as np
import pytest

from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.core.contact import ContactDetector
from elastic_pm_dyn.observer.testing.wrench_runs import run, step_scores
from elastic_pm_dyn.sim.wrench import ExternalWrench, StepWrench, Wall


def _step(mech, comp, size, duration=0.45, t_step=0.2, **kw):
    w = np.zeros(6)
    w[comp] = size
    r = run(mech, ExternalWrench([StepWrench(t_step, w)]), duration, integrator="rk4", **kw)
    return r, step_scores(r, t_step, comp, size)


@pytest.mark.parametrize("comp", [0, 1])
def test_five_bar_step_force(five_bar, comp):
    r, s = _step(five_bar, comp, 2.0)
    assert s["error_at_20ms"] < 0.10 and s["steady_error"] < 0.05, s
    assert s["steady_abs_error"] < 0.05, s  # bias and noise: the unknown torque's share in the wrench
    assert s["nees_in_band"] > 0.7, s
    before = r.t < 0.2
    assert np.all(np.abs(r.estimate[before & (r.t > 0.05)]) < 0.5)  # nothing pushes before the step


def test_hexa_step_couple():
    mech = Mechanism(load_model("config/hexa.yaml", elastic_dof_per_chain=2))
    r, s = _step(mech, 3, 0.2, duration=0.35)
    assert r.names[3] == "torque_x"
    assert s["error_at_20ms"] < 0.10 and s["steady_error"] < 0.06, s


def test_hexa_step_force_z():
    """The Hexa's z axis, where a motor torque maps to the largest force (12 N per N m): the
    0.02 N m unknown torque is 12 % of the 2 N step if the wrench states take it all, as they did
    with the generic [5, 50] Hz disturbance bands and a fast wrench random walk. Three seeds: an
    accelerometer sample that the unknown torque pushes past the jump gate after the step (about
    one run in ten) leaves a few percent of bias in that run's steady state."""
    mech = Mechanism(load_model("config/hexa.yaml", elastic_dof_per_chain=2))
    mae = []
    for seed in (4343, 4344, 4345):
        r, s = _step(mech, 2, 2.0, duration=0.6, seed=seed, kp=60.0, kd=0.5)  # the bench's stiffer hold
        assert r.names[2] == "force_z" and 0.2 in np.round(r.jumps, 6), r.jumps  # the step carried by the jump
        assert s["error_at_20ms"] < 0.10 and s["nees_in_band"] > 0.7, (seed, s)
        mae.append(s["steady_abs_error"])
    assert np.median(mae) < 0.05 and max(mae) < 0.08, mae


def test_wall_detected_within_5ms_and_stopped(five_bar):
    rate = np.array([0.3, -0.3])  # the motors drive the end effector towards -y at ~0.16 m/s
    free = run(five_bar, ExternalWrench(), 0.2, ref_rate=rate, disturbance_rms=0.02)
    v = (free.ee[200] - free.ee[100]) / 0.1
    wall = Wall(free.ee[150], -v / np.linalg.norm(v), 1e4, 10.0)
    det = {}

    def stop(k, row, layout):
        det.setdefault("d", ContactDetector(layout))
        return det["d"].update(row) is not None

    r = run(five_bar, ExternalWrench([wall]), 0.3, ref_rate=rate, stop=stop)
    touch = r.t[np.argmax([wall.depth(p) > 0 for p in r.ee])]
    assert r.stopped_at is not None and touch - 1e-9 <= r.stopped_at <= touch + 0.005
    event = det["d"].events[0]
    assert event.kind == "contact" and event.t == r.stopped_at
    assert event.wrench @ wall.normal[:2] > 0  # the wall pushes back along its normal


def test_no_false_contact_in_chirp(five_bar):
    sign = np.array([1.0, -1.0])

    def chirp(t):
        return 3.0 * np.sin(2 * np.pi * (20 * t + 390 * t * t)) * sign * min(1.0, t / 0.02, (1 - t) / 0.02)

    det = {}

    def stop(k, row, layout):
        det.setdefault("d", ContactDetector(layout))
        return det["d"].update(row) is not None

    r = run(five_bar, ExternalWrench(), 1.0, extra=chirp, stop=stop)
    assert r.stopped_at is None and det["d"].events == []


def test_off_by_default_keeps_the_layout(five_bar):
    off = Observer(five_bar, ObserverConfig.from_parameters({}))
    on = Observer(five_bar, ObserverConfig.from_parameters({"process.wrench": "random_walk"}))
    assert off.nw == 0 and off.layout.width == on.layout.width - 4 - (on.nx ** 2 - off.nx ** 2) - 2
    assert not any("wrench" in c for c in off.layout.csv_columns())
    assert on.layout.csv_columns()[-4:] == ["wrench_force_x", "wrench_force_y", "wrench_force_x_std",
                                            "wrench_force_y_std"]
    with pytest.raises(ValueError, match="wrench states"):
        ContactDetector(off.layout)


def test_observe_bag_and_analyze_plot_the_wrench(five_bar, tmp_path):
    """``observe`` with the wrench states writes them (CSV columns, WrenchStamped topics, the contact
    events) and ``analyze`` plots them with the contacts; a push the accelerometer reads (+4 m/s^2
    from 60 ms) is estimated as a force along it and detected."""
    import csv

    from elastic_pm_dyn.analysis.report import analyze
    from elastic_pm_dyn.observer.offline import observe_bag
    from elastic_pm_dyn.observer.testing.recordings import RecordingSpec, generate, write_bag

    rec = generate(five_bar, RecordingSpec(duration=0.15, seed=77, disturbance_rms=0.02))
    rec.accel[60:] += [4.0, 0.0, 0.0]
    write_bag(rec, tmp_path / "bag", use=("encoders", "imu"))
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"], "process.wrench": "random_walk",
                                          "imu.sample_timing": "before_command"})
    observe_bag(five_bar, cfg, tmp_path / "bag", tmp_path / "out", log=lambda s: None)
    with open(tmp_path / "out" / "estimates.csv") as fh:
        rows = list(csv.DictReader(fh))
    fx = np.array([float(r["wrench_force_x"]) for r in rows])
    assert abs(np.mean(fx[20:55])) < 0.3 and np.mean(fx[80:]) > 1.0  # nothing, then a push along +x
    # the push is a contact: in contacts.csv and summary.json, at the stamp the bag's event has
    import json

    from elastic_pm_dyn.bags.reader import open_bag
    with open(tmp_path / "out" / "contacts.csv") as fh:
        events = list(csv.DictReader(fh))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert events and events[0]["kind"] == "contact" and len(summary["contacts"]) == len(events)
    assert [int(e["stamp_ns"]) for e in events] == [c["stamp_ns"] for c in summary["contacts"]]
    stamp_of = {int(r["stamp_ns"]): float(r["t"]) for r in rows}
    t_row = stamp_of[int(events[0]["stamp_ns"])]  # the event sits on a row, from the push on
    assert abs(float(events[0]["t"]) - t_row) < 1e-12 and t_row > 0.06 - 1e-9
    topics = ("/observer/contact", "/observer/contact_release")
    with open_bag(tmp_path / "out" / "estimates") as b:
        bag_events = sorted(ns for _, ns, _ in b.messages([c for c in b.connections if c.topic in topics]))
    assert bag_events == [int(e["stamp_ns"]) for e in events]
    report = analyze(five_bar, tmp_path / "out" / "estimates", tmp_path / "an")
    assert (tmp_path / "an" / "wrench.png").exists()
    assert report is not None
