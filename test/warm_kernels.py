"""Compile (or load) the observer's numba kernels beside the test suite, on the other core.

``scripts/test.sh`` starts this in the background as pytest starts. On a cold numba cache the
suite's first observer test otherwise compiles the observer's kernels for about 4 minutes on
one core while the second idles (CI: 234 s in test_examples' set-up). numba's cache lives in
files next to the sources, so what this process compiles, the suite loads; if the suite gets
there first it compiles the kernel itself, as without this script. It changes nothing a test
computes, prints nothing and ignores its own failures (the tests report theirs).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def warm() -> None:
    """The observer first (the suite's longest compile), from events of a robot at rest made
    here, so that no simulator compiles before it; the simulator's kernels then."""
    import numpy as np

    from elastic_pm_dyn.dynamics.statics import holding_torques, rest_state
    from elastic_pm_dyn.kinematics.mechanism import Mechanism
    from elastic_pm_dyn.model.loader import load_model
    from elastic_pm_dyn.observer import ObserverConfig
    from elastic_pm_dyn.observer.drivers import event_filter
    from elastic_pm_dyn.observer.drivers.bag_input import Event
    from elastic_pm_dyn.observer.drivers.bag_output import write_outputs

    mech = Mechanism(load_model(ROOT / "config" / "five_bar.yaml"))
    cfg = ObserverConfig.from_parameters({"sensors": ["encoders", "imu"]})
    q = rest_state(mech)
    names = [mech.joint_names[i] for i in mech.active]
    tau = np.asarray(holding_torques(mech, q), dtype=float)
    acc = np.array([0.0, 0.0, 9.81])
    events = []
    for k in range(200):
        ns = 1_000_000_000 + 1_000_000 * k
        events += [Event(ns, "joint_state", (names, q[mech.active].copy(), np.zeros(0), np.zeros(0))),
                   Event(ns, "imu", (acc, "ee")), Event(ns, "command", (names, tau))]
    run = event_filter.filter_all(mech, cfg, events, "stamp", lambda line: None)  # offline and per message
    with tempfile.TemporaryDirectory(prefix="epd-warm-") as scratch:
        write_outputs(Path(scratch), run.obs, run.rows, True, "mcap", None)
    from elastic_pm_dyn.observer.testing.scenarios import chirp_recording
    chirp_recording(mech, duration=0.01)  # the simulator's kernels


if __name__ == "__main__":
    try:
        warm()
    except Exception:  # an extra: the tests report what is wrong (ELASTIC_PM_DYN_WARM_DEBUG=1 shows it)
        if os.environ.get("ELASTIC_PM_DYN_WARM_DEBUG") == "1":
            raise
        sys.exit(0)
