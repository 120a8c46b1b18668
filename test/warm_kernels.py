"""Compile (or load) the observer's numba kernels beside the test suite, on the other core.

``scripts/test.sh`` starts this in the background as pytest starts. On a cold numba cache the
suite's first observer test otherwise compiles the observer's kernels for about 4 minutes on
one core while the second idles (CI: 234 s in test_examples' set-up). numba's cache lives in
files next to the sources, so what this process compiles, the suite loads; if the suite gets
there first it compiles the kernel itself, as without this script. It changes nothing a test
computes, prints nothing and ignores its own failures (the tests report theirs).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def warm() -> None:
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer import Observer, ObserverConfig
    from elastic_pm_dyn.observer.drivers.bag_input import recording_to_bag
    from elastic_pm_dyn.observer.offline import observe_bag
    from elastic_pm_dyn.observer.testing.evaluation import feed
    from elastic_pm_dyn.observer.testing.scenarios import chirp_recording

    mech = Mechanism(load_model(ROOT / "config" / "five_bar.yaml"))
    rec = chirp_recording(mech, duration=0.03)
    sensors = ("encoders", "imu")
    cfg = ObserverConfig.from_parameters({"sensors": list(sensors)})
    with tempfile.TemporaryDirectory(prefix="epd-warm-") as scratch:
        bag = Path(scratch) / "in"
        recording_to_bag(rec, bag, use=sensors)
        observe_bag(mech, cfg, bag, Path(scratch) / "out", log=lambda s: None)  # the compiled offline path
    feed(Observer(mech, cfg), rec, sensors)  # the per-message path (the observer node's)


if __name__ == "__main__":
    try:
        warm()
    except Exception:  # an extra: the tests report what is wrong
        sys.exit(0)
